"""Scenarios that say only what differs: ``extends = "iso9283"`` and where each key came from.

A scenario file may name another scenario to start from with the top-level key
``extends``: a path relative to the file's folder, or the name of one of the project's
scenarios (``"iso9283"``, ``"scenarios/iso9283.toml"``). The base is read (and its own
``extends`` followed, any depth, circles refused), then the file's keys are laid over it:

* a table merges key by key, at any depth (``[controller] period`` replaces only that key);
* any other value replaces the base's value whole, arrays included (``[[fmus]]`` in the
  derived file replaces the base's list of FMUs; a table inside an array is not merged);
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
    _lines: dict[Path, dict[KeyPath, int]] = field(default_factory=dict, repr=False)

    @classmethod
    def of_file(cls, path: Path) -> "Origins":
        return cls({(): path})

    def file_of(self, keys: KeyPath) -> Path | None:
        for n in range(len(keys), -1, -1):
            found = self.files.get(tuple(keys[:n]))
            if found is not None:
                return found
        return None

    def line_of(self, keys: KeyPath) -> int | None:
        """The line (1-based) of the key ``keys`` (or of its nearest written parent) in its file."""
        path = self.file_of(keys)
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
    for candidate in candidates:
        if candidate.is_file():
            return candidate.resolve()
    raise ScenarioError(derived, where_key, expected, name, problem="no such scenario")


def _mark(origins: Origins, value: Any, prefix: KeyPath, path: Path) -> None:
    """Every key of ``value`` (below ``prefix``) came from ``path``."""
    for key in [k for k in origins.files if k[:len(prefix)] == prefix and len(k) >= len(prefix)]:
        del origins.files[key]
    origins.files[prefix] = path


def _merge(base: dict, overlay: dict, origins: Origins, path: Path, prefix: KeyPath) -> None:
    for key, value in overlay.items():
        here = prefix + (key,)
        if isinstance(value, dict) and isinstance(base.get(key), dict):
            _merge(base[key], value, origins, path, here)
        else:
            base[key] = copy.deepcopy(value)
            _mark(origins, value, here, path)


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


__all__ = ["EXTENDS", "Origins", "find_base", "key_lines", "resolve"]
