"""Unit-suffixed quantities in scenario files.

A numeric scenario value is a plain number in SI units (s, m, rad, N*m, ...), or a
string ``"<number> <unit>"`` with a unit of the same dimension, converted to SI when
the file is loaded: ``macro_step = "400 us"`` is 4e-4 s, ``"5 deg"`` is 0.0873 rad.
A unit of the wrong dimension (``"400 mm"`` for a time) is an error naming the units
accepted. Supported dimensions and units are listed in ``UNITS`` (docs/reference/scenario_keys.md, generated from it).

Decimal factors (ms, us, mm, kN, min, ...) are applied exactly: the written number times
the factor is computed in decimal and rounded once to the nearest float, so ``"100 us"``
is the same float as ``1e-4`` and ``"0.4 ms"`` as ``4e-4`` (multiplying by the float
``1e-6`` would give 9.999999999999999e-05). Factors with pi (deg, rpm) are floats and
multiply the number's float.
"""
from __future__ import annotations

import decimal
import math
import re
from decimal import Decimal

_D = Decimal
_DEG = math.pi / 180.0

#: SI unit -> {accepted unit spelling: factor to SI}; a ``Decimal`` factor is exact.
UNITS: dict[str, dict[str, Decimal | float]] = {
    "s": {"s": _D(1), "ms": _D("1e-3"), "us": _D("1e-6"), "µs": _D("1e-6"), "ns": _D("1e-9"), "min": _D(60),
          "h": _D(3600)},
    "m": {"m": _D(1), "cm": _D("1e-2"), "mm": _D("1e-3"), "um": _D("1e-6"), "µm": _D("1e-6")},
    "rad": {"rad": _D(1), "mrad": _D("1e-3"), "deg": _DEG},
    "m/s": {"m/s": _D(1), "mm/s": _D("1e-3")},
    "m/s^2": {"m/s^2": _D(1), "m/s2": _D(1), "mm/s^2": _D("1e-3"), "mm/s2": _D("1e-3")},
    "rad/s": {"rad/s": _D(1), "deg/s": _DEG, "rpm": 2.0 * math.pi / 60.0},
    "rad/s^2": {"rad/s^2": _D(1), "rad/s2": _D(1), "deg/s^2": _DEG, "deg/s2": _DEG},
    "N*m": {"N*m": _D(1), "Nm": _D(1), "N.m": _D(1), "mNm": _D("1e-3")},
    "N": {"N": _D(1), "kN": _D("1e3")},
    "kg": {"kg": _D(1), "g": _D("1e-3")},
    "A": {"A": _D(1), "mA": _D("1e-3")},
    "V": {"V": _D(1), "mV": _D("1e-3")},
    "Hz": {"Hz": _D(1), "kHz": _D("1e3")},
}
#: Digits of the decimal product: exact for any number a float's repr or a person writes.
_CONTEXT = decimal.Context(prec=60, Emax=decimal.MAX_EMAX, Emin=decimal.MIN_EMIN, traps=[decimal.InvalidOperation])

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
            factor = UNITS[si_unit][m.group(2)]
            if isinstance(factor, Decimal):
                si = float(_CONTEXT.multiply(Decimal(m.group(1)), factor))  # one rounding, to the nearest float
                if not math.isfinite(si):
                    raise UnitError(describe(si_unit) + " (finite, within +-1.8e308)")
                return si
            return _finite_float(m.group(1), si_unit) * factor
    raise UnitError(describe(si_unit))


def _finite_float(value: object, si_unit: str) -> float:
    """``float(value)``; UnitError (not OverflowError) for an integer beyond the float range."""
    try:
        return float(value)  # type: ignore[arg-type]
    except OverflowError:
        raise UnitError(describe(si_unit) + " (finite, within +-1.8e308)") from None
