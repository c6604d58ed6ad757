"""Key paths into scenario documents: ``tracker.noise_sigma``, ``fmus[0].parameters."q0[2]"``.

The syntax is the one ``Where.key`` prints in validation errors: dotted TOML keys (bare
``[A-Za-z0-9_-]+`` or double-quoted), each optionally followed by ``[index]`` into a
list. Functions here parse a path, check it against a job's schema (so an axis on a
key the job does not have is an error before anything runs), and read or set the
value it names in a document.
"""
from __future__ import annotations

import copy
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cosim.scenario.schema import MISSING, FilePath, List, Spec, String, Table, Where

if TYPE_CHECKING:  # pragma: no cover
    from cosim.scenario.loader import Scenario

KeyPath = tuple[str | int, ...]

_TOKEN = re.compile(r'\s*(?:(?P<bare>[A-Za-z0-9_-]+)|"(?P<quoted>(?:[^"\\]|\\.)*)")(?P<rest>.*)', re.S)
_INDEX = re.compile(r"\[\s*(\d+)\s*\]")


class KeyPathSyntaxError(ValueError):
    """A key path that cannot be parsed (message = what is wrong)."""


def parse_key_path(text: str) -> KeyPath:
    """``'fmus[0].parameters."q0[2]"'`` -> ``("fmus", 0, "parameters", "q0[2]")``; KeyPathSyntaxError otherwise."""
    if not isinstance(text, str) or not text.strip():
        raise KeyPathSyntaxError("an empty key path")
    parts: list[str | int] = []
    rest = text.strip()
    while True:
        m = _TOKEN.match(rest)
        if m is None:
            raise KeyPathSyntaxError(f"no key at {rest!r}")
        parts.append(m.group("bare") if m.group("bare") is not None
                     else re.sub(r"\\(.)", r"\1", m.group("quoted")))
        rest = m.group("rest").lstrip()
        while (mi := _INDEX.match(rest)) is not None:
            parts.append(int(mi.group(1)))
            rest = rest[mi.end():].lstrip()
        if not rest:
            return tuple(parts)
        if not rest.startswith("."):
            raise KeyPathSyntaxError(f"expected '.' or '[index]' before {rest!r}")
        rest = rest[1:]


def format_key_path(path: KeyPath) -> str:
    """The canonical text of ``path`` (as ``Where.key`` prints it)."""
    return Where(None, tuple(path)).key


def _keys_of(table: Table) -> str:
    names = list(table.fields)
    return ", ".join(names) if names else "none"


def spec_at(schema: Spec, path: KeyPath, document: Any) -> Spec:
    """The spec ``schema`` gives the value at ``path`` (list indices must exist in ``document``).

    Raises KeyPathSyntaxError with what the schema offers at the first step that does not
    exist (unknown key, index beyond the document's list, a key below a plain value).
    """
    spec: Spec = schema
    value: Any = document
    for depth, step in enumerate(path):
        here = format_key_path(path[:depth]) or "the top level"
        if isinstance(step, str):
            if not isinstance(spec, Table):
                raise KeyPathSyntaxError(f"{here} is {spec.expected}, not a table with key {step!r}")
            if step in spec.fields:
                spec = spec.fields[step].spec
            elif spec.extra is not None:
                spec = spec.extra
            else:
                raise KeyPathSyntaxError(f"unknown key {step!r} in {here} (keys: {_keys_of(spec)})")
            value = value.get(step, MISSING) if isinstance(value, dict) else MISSING
        else:
            if not isinstance(spec, List):
                raise KeyPathSyntaxError(f"{here} is {spec.expected}, not a list")
            size = len(value) if isinstance(value, list) else 0
            if step >= size:
                raise KeyPathSyntaxError(f"index [{step}] is beyond the base scenario's {here} ({size} items)")
            spec = spec.item
            value = value[step]
    return spec


def get_path(document: Any, path: KeyPath, default: Any = MISSING) -> Any:
    """The value at ``path`` in ``document`` (``default`` when absent; KeyError if no default)."""
    value = document
    for step in path:
        try:
            value = value[step]
        except (KeyError, IndexError, TypeError):
            if default is MISSING:
                raise KeyError(format_key_path(path)) from None
            return default
    return value


def with_value(document: dict, path: KeyPath, value: Any) -> dict:
    """A deep copy of ``document`` with ``value`` at ``path`` (missing tables are created)."""
    out = copy.deepcopy(document)
    node: Any = out
    for step, following in zip(path[:-1], path[1:]):
        if isinstance(step, str) and step not in node:
            node[step] = [] if isinstance(following, int) else {}
        node = node[step]
    node[path[-1]] = copy.deepcopy(value)
    return out


def absolute_paths(spec: Spec, value: Any, base_dir: Path) -> Any:
    """``value`` with every relative ``FilePath`` string the schema ``spec`` declares made absolute
    against ``base_dir`` (so a document keeps its meaning when written to another folder).

    Other file references (``"file.py:Class"``, ``referenced_files``) keep their text: they may be
    keys elsewhere in the document (``[planners.parameters."file.py:Class"]``); a document is run
    anchored at its scenario's folder instead (``VariantTask.anchor``)."""
    if isinstance(spec, FilePath):
        if isinstance(value, str) and value.strip() and not Path(value).expanduser().is_absolute():
            return str((base_dir / Path(value).expanduser()).resolve())
        return value
    if isinstance(spec, Table) and isinstance(value, dict):
        out = {}
        for key, item in value.items():
            sub = spec.fields[key].spec if key in spec.fields else spec.extra
            out[key] = item if sub is None else absolute_paths(sub, item, base_dir)
        return out
    if isinstance(spec, List) and isinstance(value, list):
        return [absolute_paths(spec.item, item, base_dir) for item in value]
    return value


def _file_of(spec: Spec, value: Any) -> str | None:
    """The file a value of ``spec`` refers to: a ``FilePath`` string, or what a spec with a
    ``referenced_file(value)`` method returns (e.g. ``"my_ctrl.py:MyController"`` -> ``"my_ctrl.py"``)."""
    if isinstance(spec, FilePath):
        return value if isinstance(value, str) and value.strip() else None
    finder = getattr(spec, "referenced_file", None)
    if callable(finder):
        return finder(value)
    if isinstance(spec, String):   # a plain string field holding a user class as 'file.py:Class'
        from cosim.scenario.user_class import class_spec_file

        return class_spec_file(value)
    return None


def referenced_files(spec: Spec, value: Any, prefix: KeyPath = ()) -> list[tuple[KeyPath, str]]:
    """Every file the document ``value`` refers to, by the schema ``spec``: ``[(key path, path text)]``.

    File paths are the values of ``FilePath`` specs (FMUs, URDFs, trajectory files, ...), of any
    spec offering the two methods ``referenced_file(value) -> str | None`` and
    ``relocated(value, path) -> value`` (a reference that holds a file inside a larger value),
    and the file of a user class named ``"file.py:Class"`` in a plain ``String`` field (a user
    controller or planner; ``"module:Class"`` names no file). A sweep ships these files to
    workers that cannot read them.
    """
    found = _file_of(spec, value)
    if found is not None:
        return [(tuple(prefix), found)]
    out: list[tuple[KeyPath, str]] = []
    if isinstance(spec, Table) and isinstance(value, dict):
        for key, item in value.items():
            sub = spec.fields[key].spec if key in spec.fields else spec.extra
            if sub is not None:
                out.extend(referenced_files(sub, item, tuple(prefix) + (key,)))
    elif isinstance(spec, List) and isinstance(value, list):
        for i, item in enumerate(value):
            out.extend(referenced_files(spec.item, item, tuple(prefix) + (i,)))
    return out


def relocate_file(spec: Spec, value: Any, path: str) -> Any:
    """``value`` (which refers to a file, see :func:`referenced_files`) made to refer to ``path`` instead."""
    mover = getattr(spec, "relocated", None)
    if callable(mover) and not isinstance(spec, FilePath):
        return mover(value, path)
    if isinstance(spec, String):
        from cosim.scenario.user_class import with_class_file

        return with_class_file(value, path)
    return path


def overlapping(a: KeyPath, b: KeyPath) -> bool:
    """True when one path is a prefix of the other (two axes would set the same value)."""
    n = min(len(a), len(b))
    return tuple(a[:n]) == tuple(b[:n])


#: Key paths a sweep axis or an override may not vary (they name the run, not the experiment).
FIXED_KEYS: tuple[KeyPath, ...] = (("scenario", "name"), ("scenario", "job"), ("output",))


def scenario_key_path(text: str, where: Where, base: Scenario, what: str = "axis") -> KeyPath:
    """Parse and check a key path against the base job's schema; ScenarioError at ``where`` otherwise.

    ``what`` names the key path in the error (``"axis"``, ``"override"``).
    """
    try:
        path = parse_key_path(text)
        spec_at(base.job.schema, path, base.raw)
    except KeyPathSyntaxError as exc:
        raise where.error(f"a key path of the {base.job.name!r} job's scenario (e.g. 'section.key', "
                          f"'list[0].key', quoted keys '\"q0[2]\"')", text, problem=f"unknown {what}: {exc}") from None
    for fixed in FIXED_KEYS:
        if overlapping(path, fixed):
            raise where.error(f"a key other than {format_key_path(fixed)} (a sweep names its variants itself; a run "
                              f"is named by its scenario and placed by its out folder)", text,
                              problem="not a sweep axis" if what == "axis" else f"not a valid {what}")
    return path


def flatten_overrides(table: dict[str, Any], where: Where, prefix: KeyPath = ()) -> list[tuple[KeyPath, Any, Where]]:
    """``{"a.b": 1, "c": {"d": 2}}`` -> [(("a","b"), 1, ...), (("c","d"), 2, ...)]."""
    out = []
    for key, value in table.items():
        w = where / key
        try:
            path = prefix + parse_key_path(key)
        except KeyPathSyntaxError as exc:
            raise w.error("a key path such as 'section.key'", key, problem=str(exc)) from None
        if isinstance(value, dict):
            out.extend(flatten_overrides(value, w, path))
        else:
            out.append((path, value, w))
    return out


__all__ = ["FIXED_KEYS", "KeyPath", "KeyPathSyntaxError", "absolute_paths", "flatten_overrides", "format_key_path",
           "get_path", "overlapping", "scenario_key_path",
           "parse_key_path", "referenced_files", "relocate_file", "spec_at", "with_value"]
