"""Declarative validation of scenario tables: describe the types, get precise errors.

A schema is built from small spec objects; ``validate(spec, value, where)`` checks a
parsed TOML value against it and returns the normalized value (defaults filled in,
quantities converted to SI, paths resolved) or raises ``ScenarioError`` naming the
file, the key path (``fmus[2].parameters.Kp``), the value given and what was expected.

Example (a job adding its own table)::

    CONTROLLER = Table({
        "mode": Field(String(choices=("standard", "model_based")), default="model_based"),
        "period": Field(Number(unit="s", gt=0), default=4e-4, doc="controller period"),
        "kp": Field(List(Number(min=0), length=6), required=True),
    })
    doc = validate(Table({"scenario": Field(SCENARIO_TABLE, required=True),
                          "controller": Field(CONTROLLER, required=True)}), raw, Where(path))

Specs: ``Number`` (optionally with a unit: SI number or ``"400 us"``), ``Integer``,
``Boolean``, ``String`` (choices, regex), ``FilePath`` (resolved against the scenario
file's folder, optionally must exist), ``List``, ``Table`` (fixed keys; unknown keys
are errors unless ``extra`` gives a spec for free-form keys), ``AnyValue``.
"""
from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cosim.scenario.errors import ScenarioError
from cosim.scenario.units import UnitError, to_si

_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")
MISSING: Any = object()


@dataclass(frozen=True)
class Where:
    """A position in a scenario document: the file and the key path."""

    file: Path | str | None = None   # a str is a label such as "<dict>" (no folder: paths are relative to the cwd)
    keys: tuple[str | int, ...] = ()
    origins: Any = field(default=None, compare=False, repr=False)
    """A :class:`cosim.scenario.inherit.Origins` when the document was read from files: errors
    then name the file each key came from (a base scenario's for an inherited key) and its line."""

    def __truediv__(self, key: str) -> "Where":
        return Where(self.file, self.keys + (key,), self.origins)

    def __getitem__(self, index: int) -> "Where":
        return Where(self.file, self.keys + (index,), self.origins)

    @property
    def key(self) -> str:
        """``fmus[2].parameters."q0[1]"`` (TOML-style quoting of non-bare keys)."""
        text = ""
        for k in self.keys:
            if isinstance(k, int):
                text += f"[{k}]"
            else:
                part = k if _BARE_KEY.match(k) else '"' + k.replace('"', '\\"') + '"'
                text += ("." if text else "") + part
        return text

    @property
    def base_dir(self) -> Path:
        """Folder relative paths are resolved against (the scenario file's, else the cwd)."""
        return self.file.parent if isinstance(self.file, Path) else Path.cwd()

    def error(self, expected: str, given: object = MISSING, problem: str | None = None) -> ScenarioError:
        """A ScenarioError at this position."""
        file, place = self.file, {}
        if self.origins is not None:
            origin = self.origins.file_of(self.keys)
            place["line"] = self.origins.line_of(self.keys)
            if origin is not None and isinstance(self.file, Path) and origin != self.file:
                file, place["inherited_by"] = origin, self.file
        if given is MISSING:
            return ScenarioError(file, self.key, expected, problem=problem, **place)
        return ScenarioError(file, self.key, expected, given, problem=problem, **place)


class Spec:
    """Base of all specs: ``check(value, where)`` returns the normalized value or raises."""

    expected: str = "a value"

    def check(self, value: Any, where: Where) -> Any:  # pragma: no cover - abstract
        raise NotImplementedError


@dataclass
class AnyValue(Spec):
    """Any TOML value (checked later, e.g. FMU parameters against the modelDescription)."""

    expected: str = "a value"

    def check(self, value: Any, where: Where) -> Any:
        return value


@dataclass
class Number(Spec):
    """A real number; with ``unit`` (SI unit, see units.UNITS) it may also be ``"<number> <unit>"``.

    Bounds (in SI): ``min``/``max`` inclusive, ``gt``/``lt`` exclusive. NaN/Inf rejected.
    """

    unit: str | None = None
    min: float | None = None
    max: float | None = None
    gt: float | None = None
    lt: float | None = None

    @property
    def expected(self) -> str:  # type: ignore[override]
        base = f"a number in {self.unit}" if self.unit else "a number"
        return base + self._bounds()

    def _bounds(self) -> str:
        parts = []
        if self.gt is not None:
            parts.append(f"> {self.gt:g}")
        if self.min is not None:
            parts.append(f">= {self.min:g}")
        if self.lt is not None:
            parts.append(f"< {self.lt:g}")
        if self.max is not None:
            parts.append(f"<= {self.max:g}")
        return (" " + " and ".join(parts)) if parts else ""

    def check(self, value: Any, where: Where) -> float:
        if self.unit is not None:
            try:
                number = to_si(value, self.unit)
            except UnitError as exc:
                raise where.error(str(exc) + self._bounds(), _short_repr(value)) from None
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            try:
                number = float(value)
            except OverflowError:
                raise where.error(self.expected + " (finite, within +-1.8e308)", _short_repr(value)) from None
        else:
            raise where.error(self.expected, value)
        if not math.isfinite(number):
            raise where.error(self.expected + " (finite)", value)
        if ((self.min is not None and number < self.min) or (self.max is not None and number > self.max)
                or (self.gt is not None and number <= self.gt) or (self.lt is not None and number >= self.lt)):
            raise where.error(self.expected, value)
        return number


def _short_repr(value: Any) -> Any:
    """The value, or for a huge integer (hundreds of digits) a short description of it, for messages."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 10**30:
        return _Abbreviated(f"an integer of {len(str(abs(value)))} digits")
    if isinstance(value, str) and len(value) > 80:
        return _Abbreviated(repr(value[:60] + "..."))
    return value


class _Abbreviated(str):
    def __repr__(self) -> str:
        return str(self)


@dataclass
class Integer(Spec):
    """An integer (not a bool, not a float) within ``min``/``max``."""

    min: int | None = None
    max: int | None = None

    @property
    def expected(self) -> str:  # type: ignore[override]
        parts = [f">= {self.min}" if self.min is not None else "", f"<= {self.max}" if self.max is not None else ""]
        bounds = " and ".join(p for p in parts if p)
        return "an integer" + (f" {bounds}" if bounds else "")

    def check(self, value: Any, where: Where) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise where.error(self.expected, value)
        if (self.min is not None and value < self.min) or (self.max is not None and value > self.max):
            raise where.error(self.expected, value)
        return value


@dataclass
class Boolean(Spec):
    """true or false."""

    expected: str = "true or false"

    def check(self, value: Any, where: Where) -> bool:
        if not isinstance(value, bool):
            raise where.error(self.expected, value)
        return value


@dataclass
class String(Spec):
    """A string, optionally one of ``choices`` or matching ``pattern`` (described by ``pattern_doc``)."""

    choices: Sequence[str] | None = None
    pattern: str | None = None
    pattern_doc: str = ""
    nonempty: bool = True

    @property
    def expected(self) -> str:  # type: ignore[override]
        if self.choices is not None:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if self.pattern is not None:
            return f"a string {self.pattern_doc or 'matching ' + self.pattern}"
        return "a non-empty string" if self.nonempty else "a string"

    def check(self, value: Any, where: Where) -> str:
        if not isinstance(value, str) or (self.nonempty and not value.strip()):
            raise where.error(self.expected, value)
        if self.choices is not None and value not in self.choices:
            raise where.error(self.expected, value)
        if self.pattern is not None and not re.fullmatch(self.pattern, value):
            raise where.error(self.expected, value)
        return value


@dataclass
class FilePath(Spec):
    """A path string, resolved against the scenario file's folder; ``must_exist`` and ``suffix`` checked."""

    must_exist: bool = True
    suffix: str | None = None

    @property
    def expected(self) -> str:  # type: ignore[override]
        what = f"a path to an existing {self.suffix or ''} file" if self.must_exist else "a file path"
        return what.replace("  ", " ") + " (relative to the scenario file's folder)"

    def check(self, value: Any, where: Where) -> Path:
        if not isinstance(value, str) or not value.strip():
            raise where.error(self.expected, value)
        path = Path(value).expanduser()
        if not path.is_absolute():
            path = where.base_dir / path
        if self.suffix is not None and path.suffix != self.suffix:
            raise where.error(self.expected, value, problem=f"not a {self.suffix} file")
        if self.must_exist and not path.is_file():
            raise where.error(self.expected, value, problem=f"file {str(path)!r} does not exist")
        return path


@dataclass
class List(Spec):
    """A list of ``item``; ``length`` exact or ``min_len``/``max_len``; ``unique`` items."""

    item: Spec
    length: int | None = None
    min_len: int = 0
    max_len: int | None = None
    unique: bool = False

    @property
    def expected(self) -> str:  # type: ignore[override]
        if self.length is not None:
            size = f"{self.length} "
        elif self.min_len:
            size = f"at least {self.min_len} "
        else:
            size = ""
        return f"a list of {size}items, each {self.item.expected}"

    def check(self, value: Any, where: Where) -> list:
        if not isinstance(value, list):
            raise where.error(self.expected, value)
        n = len(value)
        if (self.length is not None and n != self.length) or n < self.min_len or \
                (self.max_len is not None and n > self.max_len):
            raise where.error(self.expected, value, problem=f"{n} items")
        out = [self.item.check(v, where[i]) for i, v in enumerate(value)]
        if self.unique:
            seen: dict[Any, int] = {}
            for i, v in enumerate(out):
                key = repr(v)
                if key in seen:
                    raise where[i].error(f"a value not already given at index {seen[key]}", value[i],
                                         problem="duplicate")
                seen[key] = i
        return out


@dataclass
class Field:
    """One key of a Table: its spec, whether required, its default and a short description."""

    spec: Spec
    required: bool = False
    default: Any = MISSING
    doc: str = ""


@dataclass
class Table(Spec):
    """A TOML table with known keys (``fields``); unknown keys are errors unless ``extra`` is a spec.

    ``one_of`` lists groups of keys of which exactly one must be given (e.g. path/builtin).
    ``check_fn(table, where)`` runs after the fields, for checks across keys.
    """

    fields: Mapping[str, Field]
    extra: Spec | None = None
    one_of: Sequence[tuple[str, ...]] = ()
    check_fn: Callable[[dict, Where], None] | None = None
    doc: str = "a table"

    @property
    def expected(self) -> str:  # type: ignore[override]
        return self.doc

    def check(self, value: Any, where: Where) -> dict:
        if not isinstance(value, dict):
            raise where.error(f"{self.doc} with keys {', '.join(self.fields)}" if self.fields else self.doc, value)
        out: dict[str, Any] = {}
        for key, item in value.items():
            if key in self.fields:
                out[key] = self.fields[key].spec.check(item, where / key)
            elif self.extra is not None:
                out[key] = self.extra.check(item, where / key)
            else:
                raise (where / key).error(f"one of the keys {', '.join(self.fields)}", problem="unknown key")
        for key, f in self.fields.items():
            if key in out:
                continue
            if f.required:
                raise (where / key).error(f.doc or f.spec.expected, problem="missing required key")
            if f.default is not MISSING:
                out[key] = f.default
        for group in self.one_of:
            given = [k for k in group if k in value]
            if len(given) != 1:
                raise where.error(f"exactly one of the keys {', '.join(group)}",
                                  problem=f"{'none' if not given else ', '.join(given)} given")
        if self.check_fn is not None:
            self.check_fn(out, where)
        return out


def validate(spec: Spec, value: Any, where: Where) -> Any:
    """Check ``value`` against ``spec`` at ``where``; return the normalized value or raise ScenarioError."""
    return spec.check(value, where)


__all__ = ["AnyValue", "Boolean", "Field", "FilePath", "Integer", "List", "MISSING", "Number", "Spec", "String",
           "Table", "Where", "validate"]
