"""Scenarios that say only what differs: ``extends = "iso9283"`` and where each key came from.

A scenario file may name another scenario to start from with the top-level key
``extends``: a path relative to the file's folder, or the name of one of the project's
scenarios (``"iso9283"``, ``"scenarios/iso9283.toml"``). The base is read (and its own
``extends`` followed, any depth, circles refused), then the file's keys are laid over it:

* a table merges key by key, at any depth (``[controller] period`` replaces only that key);
* ``[[fmus]]`` merges FMU by FMU on ``name``: an ``[[fmus]]`` table whose name the base has
  merges into that FMU (``[fmus.parameters]`` key by key), a new name is added after the
  base's FMUs (so ``name = "plant"`` plus ``[fmus.parameters] integration_step = 1e-4`` changes
  one parameter of the cell's plant and nothing else);
* any other value replaces the base's value whole, arrays included (``signals = [...]``,
  ``[[compare.controllers]]``; a table inside such an array is not merged);
* the derived file's ``[scenario]`` table merges like any other: give a new ``name`` so the
  results go to their own folder.

Relative file paths of the base (FMUs, URDFs, trajectory files: the ``FilePath`` keys of the
job's schema) are made absolute against the base's folder before the merge, so they keep
their meaning; a user class named as ``"file.py:Class"`` is found relative to the scenario
being run.

:class:`Origins` remembers, for every key of the merged document, the file it came from and
its line there, so a validation error names the base file and line when the wrong value was
inherited (``Where.error`` asks it).
"""
from __future__ import annotations

import copy
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cosim.scenario.errors import ScenarioError
from cosim.scenario.files import packaged_scenarios_dir, read_toml_file

KeyPath = tuple[str | int, ...]

EXTENDS = "extends"
"""The top-level key naming the base scenario."""

_SOURCE_SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"
"""The project's ``scenarios/`` folder in a source checkout (editable install)."""


@dataclass
class Origins:
    """Which file each key of a (merged) scenario document came from, and its line there.

    ``files`` maps key paths to files; a key not in it takes the file of its longest listed
    prefix (the empty path, the whole document, is the file that was run)."""

    files: dict[KeyPath, Path] = field(default_factory=dict)
    aliases: dict[KeyPath, KeyPath] = field(default_factory=dict)
    """A key of ``files`` whose path in its file differs from its path in the merged document
    (an ``[[fmus]]`` table merged by name: FMU 3 of the merged list may be FMU 0 of the file)."""
    _lines: dict[Path, dict[KeyPath, int]] = field(default_factory=dict, repr=False)

    @classmethod
    def of_file(cls, path: Path) -> "Origins":
        return cls({(): path})

    def _origin(self, keys: KeyPath) -> tuple[Path | None, KeyPath]:
        """(file, the path of ``keys`` in that file)."""
        for n in range(len(keys), -1, -1):
            prefix = tuple(keys[:n])
            found = self.files.get(prefix)
            if found is not None:
                return found, self.aliases.get(prefix, prefix) + tuple(keys[n:])
        return None, tuple(keys)

    def file_of(self, keys: KeyPath) -> Path | None:
        return self._origin(keys)[0]

    def line_of(self, keys: KeyPath) -> int | None:
        """The line (1-based) of the key ``keys`` (or of its nearest written parent) in its file."""
        path, keys = self._origin(keys)
        if path is None:
            return None
        lines = self._lines.get(path)
        if lines is None:
            try:
                lines = key_lines(path.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError):
                lines = {}
            self._lines[path] = lines
        for n in range(len(keys), 0, -1):
            found = lines.get(tuple(keys[:n]))
            if found is not None:
                return found
        return None

    def root(self) -> Path | None:
        return self.files.get(())


# --- the lines of the keys of a TOML file --------------------------------------------------------

_KEY_PART = r'(?:[A-Za-z0-9_-]+|"(?:[^"\\]|\\.)*"|\'[^\']*\')'
_DOTTED = rf"\s*{_KEY_PART}(?:\s*\.\s*{_KEY_PART})*\s*"
_HEADER = re.compile(rf"^\s*\[(?P<array>\[)?(?P<keys>{_DOTTED})\](?(array)\])\s*(?:#.*)?$")
_ASSIGN = re.compile(rf"^(?P<keys>{_DOTTED})=")
_PART = re.compile(_KEY_PART)


def _parts(text: str) -> list[str]:
    out = []
    for token in _PART.findall(text):
        if token.startswith('"'):
            token = re.sub(r"\\(.)", r"\1", token[1:-1])
        elif token.startswith("'"):
            token = token[1:-1]
        out.append(token)
    return out


def _open_brackets(text: str, depth: int, in_string: str | None) -> tuple[int, str | None]:
    """Bracket depth and open multi-line string after ``text`` (strings and comments skipped)."""
    i = 0
    while i < len(text):
        if in_string is not None:
            if text.startswith(in_string, i):
                i += len(in_string)
                in_string = None
                continue
            if text[i] == "\\" and in_string != "'''":
                i += 2
                continue
            i += 1
            continue
        ch = text[i]
        if ch == "#":
            break
        for quote in ('"""', "'''"):
            if text.startswith(quote, i):
                in_string = quote
                i += 3
                break
        else:
            if ch in "\"'":
                end = i + 1
                while end < len(text) and text[end] != ch:
                    end += 2 if (text[end] == "\\" and ch == '"') else 1
                i = end + 1
                continue
            if ch in "[{":
                depth += 1
            elif ch in "]}":
                depth -= 1
            i += 1
            continue
        continue
    return depth, in_string


def key_lines(text: str) -> dict[KeyPath, int]:
    """Key path -> 1-based line of every table header and key of the TOML ``text`` (arrays of
    tables get their index: ``[[fmus]]`` number 3 is ``("fmus", 2)``). A small scanner, not a
    parser: the file has already been parsed by tomllib, this only finds where keys are written."""
    lines: dict[KeyPath, int] = {}
    counts: dict[KeyPath, int] = {}
    table: KeyPath = ()
    depth, in_string = 0, None
    for number, line in enumerate(text.splitlines(), start=1):
        if depth > 0 or in_string is not None:
            depth, in_string = _open_brackets(line, depth, in_string)
            continue
        header = _HEADER.match(line)
        if header is not None:
            resolved: list[str | int] = []
            for part in _parts(header.group("keys")):
                resolved.append(part)
                if tuple(resolved) in counts and not (header.group("array") and
                                                      len(resolved) == len(_parts(header.group("keys")))):
                    resolved.append(counts[tuple(resolved)] - 1)
            if header.group("array"):
                key = tuple(resolved)
                counts[key] = counts.get(key, 0) + 1
                lines.setdefault(key, number)
                resolved.append(counts[key] - 1)
            table = tuple(resolved)
            lines.setdefault(table, number)
            continue
        assign = _ASSIGN.match(line)
        if assign is not None:
            lines.setdefault(table + tuple(_parts(assign.group("keys"))), number)
            depth, in_string = _open_brackets(line[assign.end():], 0, None)
    return lines


# --- extends --------------------------------------------------------------------------------------

def find_base(name: Any, derived: Path | None, where_key: str = EXTENDS) -> Path:
    """The file ``extends = name`` in ``derived`` refers to; ScenarioError naming the key if none."""
    expected = ("the path of a scenario .toml file (relative to this file) or the name of one of the "
                "project's scenarios, e.g. \"iso9283\"")
    if not isinstance(name, str) or not name.strip():
        raise ScenarioError(derived, where_key, expected, name)
    text = name.strip()
    candidates: list[Path] = []
    given = Path(text).expanduser()
    if given.is_absolute():
        candidates.append(given)
    else:
        anchor = derived.parent if derived is not None else Path.cwd()
        candidates += [anchor / given, anchor / given.with_name(given.name + ".toml")]
        stem = given.name if given.suffix == ".toml" else given.name + ".toml"
        if len(given.parts) == 1 or (len(given.parts) == 2 and given.parts[0] == "scenarios"):
            for folder in (packaged_scenarios_dir(), _SOURCE_SCENARIOS):
                if folder is not None:
                    candidates.append(folder / stem)
    found = [c.resolve() for c in candidates if c.is_file()]
    # a copy of a project scenario named like its base (cell.toml with extends = "cell") means the
    # project's base, not itself; only a file that names nothing else is a circle (reported by resolve)
    itself = derived.resolve() if derived is not None else None
    others = [c for c in found if c != itself]
    if found:
        return (others or found)[0]
    raise ScenarioError(derived, where_key, expected, name, problem="no such scenario")


MERGED_BY_NAME = ("fmus",)
"""Top-level arrays of tables that merge entry by entry on their ``name`` key."""


def _mark(origins: Origins, prefix: KeyPath, path: Path, in_file: KeyPath) -> None:
    """Every key below ``prefix`` came from ``path``, where it is written at ``in_file``."""
    for table in (origins.files, origins.aliases):
        for key in [k for k in table if k[:len(prefix)] == prefix]:
            del table[key]
    origins.files[prefix] = path
    if in_file != prefix:
        origins.aliases[prefix] = in_file


def _names(value: Any) -> list[str] | None:
    """The names of an array of tables that all have a distinct string ``name``, else None."""
    if not isinstance(value, list) or not all(isinstance(v, dict) and isinstance(v.get("name"), str) for v in value):
        return None
    names = [v["name"] for v in value]
    return names if len(set(names)) == len(names) else None


def _merge(base: dict, overlay: dict, origins: Origins, path: Path, prefix: KeyPath,
           in_file: KeyPath | None = None) -> None:
    in_file = prefix if in_file is None else in_file
    for key, value in overlay.items():
        here, there = prefix + (key,), in_file + (key,)
        if isinstance(value, dict) and isinstance(base.get(key), dict):
            _merge(base[key], value, origins, path, here, there)
        elif here in {(name,) for name in MERGED_BY_NAME} and _names(value) is not None \
                and _names(base.get(key)) is not None:
            index = {name: i for i, name in enumerate(_names(base[key]))}
            for j, entry in enumerate(value):
                i = index.get(entry["name"])
                if i is None:
                    base[key].append(copy.deepcopy(entry))
                    _mark(origins, here + (len(base[key]) - 1,), path, there + (j,))
                else:
                    _merge(base[key][i], entry, origins, path, here + (i,), there + (j,))
        else:
            base[key] = copy.deepcopy(value)
            _mark(origins, here, path, there)


def resolve(document: dict[str, Any], path: Path | None,
            _chain: tuple[Path, ...] = ()) -> tuple[dict[str, Any], Origins | None]:
    """``document`` with its ``extends`` chain laid out (the merged document has no ``extends``)
    and the origins of its keys; ``(document, None)`` when it extends nothing."""
    if EXTENDS not in document:
        return document, None
    from cosim.scenario.keypath import absolute_paths
    from cosim.scenario.registry import get_job

    base_path = find_base(document[EXTENDS], path)
    chain = _chain + ((path.resolve(),) if path is not None else ())
    if base_path in chain:
        names = " -> ".join(str(p) for p in chain + (base_path,))
        raise ScenarioError(path, EXTENDS, "a base scenario that does not extend this one again",
                            document[EXTENDS], problem=f"circular extends ({names})")
    base_doc = read_toml_file(base_path, "scenario")
    base_doc, base_origins = resolve(base_doc, base_path, chain)
    origins = base_origins if base_origins is not None else Origins()
    if base_origins is None:
        for key in base_doc:
            origins.files[(key,)] = base_path
    else:
        for key in base_doc:
            origins.files.setdefault((key,), base_origins.file_of((key,)) or base_path)
        origins.files.pop((), None)
    job_name = base_doc.get("scenario", {}).get("job") if isinstance(base_doc.get("scenario"), dict) else None
    job = get_job(job_name) if isinstance(job_name, str) else None
    merged = copy.deepcopy(base_doc)
    if job is not None:
        merged = absolute_paths(job.schema, merged, base_path.parent)
    overlay = {k: v for k, v in document.items() if k != EXTENDS}
    _merge(merged, overlay, origins, path if path is not None else Path("<document>"), ())
    if path is not None:
        origins.files[()] = path.resolve()
    return merged, origins


__all__ = ["EXTENDS", "MERGED_BY_NAME", "Origins", "find_base", "key_lines", "resolve"]
