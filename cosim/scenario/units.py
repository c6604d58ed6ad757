"""Unit-suffixed quantities in scenario files.

A numeric scenario value is a plain number in SI units (s, m, rad, N*m, ...), or a
string ``"<number> <unit>"`` with a unit of the same dimension, converted to SI when
the file is loaded: ``macro_step = "400 us"`` is 4e-4 s, ``"5 deg"`` is 0.0873 rad.
A unit of the wrong dimension (``"400 mm"`` for a time) is an error naming the units
accepted. Supported dimensions and units are listed in ``UNITS`` (docs/cosim.md).
"""
from __future__ import annotations

import math
import re

#: SI unit -> {accepted unit spelling: factor to SI}.
UNITS: dict[str, dict[str, float]] = {
    "s": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9, "min": 60.0, "h": 3600.0},
    "m": {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "µm": 1e-6},
    "rad": {"rad": 1.0, "mrad": 1e-3, "deg": math.pi / 180.0},
    "m/s": {"m/s": 1.0, "mm/s": 1e-3},
    "m/s^2": {"m/s^2": 1.0, "m/s2": 1.0, "mm/s^2": 1e-3, "mm/s2": 1e-3},
    "rad/s": {"rad/s": 1.0, "deg/s": math.pi / 180.0, "rpm": 2.0 * math.pi / 60.0},
    "rad/s^2": {"rad/s^2": 1.0, "rad/s2": 1.0, "deg/s^2": math.pi / 180.0, "deg/s2": math.pi / 180.0},
    "N*m": {"N*m": 1.0, "Nm": 1.0, "N.m": 1.0, "mNm": 1e-3},
    "N": {"N": 1.0, "kN": 1e3},
    "kg": {"kg": 1.0, "g": 1e-3},
    "A": {"A": 1.0, "mA": 1e-3},
    "V": {"V": 1.0, "mV": 1e-3},
    "Hz": {"Hz": 1.0, "kHz": 1e3},
}

_QUANTITY = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([^\d\s].*?)\s*$")


class UnitError(ValueError):
    """A quantity string that cannot be read in the expected dimension (message = what was expected)."""


def describe(si_unit: str) -> str:
    """Words for 'a number in <unit> or a string with a unit', used in error messages."""
    spellings = ", ".join(UNITS.get(si_unit, {si_unit: 1.0}))
    example = {"s": "400 us", "m": "5 mm", "rad": "90 deg"}.get(si_unit, f"1 {si_unit}")
    return f"a number in {si_unit} or a string like {example!r} (units: {spellings})"


def to_si(value: object, si_unit: str) -> float:
    """``value`` (number in SI, or ``"<number> <unit>"``) as a float in ``si_unit``; UnitError otherwise."""
    if isinstance(value, bool):
        raise UnitError(describe(si_unit))
    if isinstance(value, (int, float)):
        return _finite_float(value, si_unit)
    if isinstance(value, str) and si_unit in UNITS:
        m = _QUANTITY.match(value)
        if m and m.group(2) in UNITS[si_unit]:
            return _finite_float(m.group(1), si_unit) * UNITS[si_unit][m.group(2)]
    raise UnitError(describe(si_unit))


def _finite_float(value: object, si_unit: str) -> float:
    """``float(value)``; UnitError (not OverflowError) for an integer beyond the float range."""
    try:
        return float(value)  # type: ignore[arg-type]
    except OverflowError:
        raise UnitError(describe(si_unit) + " (finite, within +-1.8e308)") from None
