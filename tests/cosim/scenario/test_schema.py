"""The reusable validation helper: specs, key paths, unit strings."""
import math
from decimal import Decimal
from fractions import Fraction

import pytest

from cosim.scenario import ScenarioError
from cosim.scenario.schema import (AnyValue, Boolean, Field, FilePath, Integer, List, Number, String, Table, Where,
                                   validate)
from cosim.scenario.units import UNITS, UnitError, to_si


@pytest.mark.parametrize("text, unit, si", [
    ("400 us", "s", 4e-4), ("400us", "s", 4e-4), ("400 µs", "s", 4e-4), ("1.5e-3 s", "s", 1.5e-3),
    ("2 min", "s", 120.0), ("5 mm", "m", 5e-3), ("90 deg", "rad", math.pi / 2), ("500 mm/s", "m/s", 0.5),
    ("3000 rpm", "rad/s", 100 * math.pi), ("5 m/s^2", "m/s^2", 5.0), ("12 Nm", "N*m", 12.0), (0.25, "s", 0.25),
    (3, "m", 3.0),
])
def test_quantities_convert_to_si(text, unit, si):
    assert to_si(text, unit) == pytest.approx(si, rel=1e-12)


def test_decimal_units_are_exact():
    """A time with a unit is the same float as the plain number: "100 us" runs are "1e-4" runs."""
    assert to_si("100 us", "s") == 1e-4 and to_si("400 us", "s") == 4e-4 and to_si("0.1 ms", "s") == 1e-4
    assert to_si("200 us", "s") == 2e-4 and to_si("12.6 s", "s") == 12.6 and to_si("1.5 mm", "m") == 1.5e-3
    numbers = ["1", "100", "400", "0.1", "12.6", "3e-7", "-2.5", "123456789.123456789", "7.2e+5"]
    for si_unit, spellings in UNITS.items():
        for spelling, factor in spellings.items():
            if not isinstance(factor, Decimal):  # pi-based (deg, rpm): a float product
                continue
            for n in numbers:
                # the exact product rounded once (Fraction -> float is correctly rounded)
                assert to_si(f"{n} {spelling}", si_unit) == float(Fraction(n) * Fraction(factor)), (n, spelling)
    assert to_si("90 deg", "rad") == 90.0 * (math.pi / 180.0)
    with pytest.raises(UnitError, match="finite"):
        to_si("1e400 h", "s")


@pytest.mark.parametrize("text, unit", [("400 mm", "s"), ("fast", "s"), ("400", "s"), (True, "s"), ("1 kg", "m")])
def test_wrong_units_are_rejected_with_the_accepted_ones(text, unit):
    with pytest.raises(UnitError, match=f"a number in {unit}"):
        to_si(text, unit)


def test_key_paths_are_toml_like(tmp_path):
    w = Where(tmp_path / "s.toml")
    assert ((w / "fmus")[2] / "parameters" / "Kp").key == "fmus[2].parameters.Kp"
    assert ((w / "fmus")[0] / "parameters" / "q0[1]").key == 'fmus[0].parameters."q0[1]"'
    assert w.base_dir == tmp_path


SPEC = Table({
    "period": Field(Number(unit="s", gt=0), default=4e-4),
    "gains": Field(List(Number(min=0), length=3), required=True),
    "mode": Field(String(choices=("a", "b")), default="a"),
    "count": Field(Integer(min=1, max=10)),
    "enabled": Field(Boolean(), default=True),
    "file": Field(FilePath(must_exist=False, suffix=".csv")),
    "names": Field(List(String(), unique=True), default=[]),
    "free": Field(Table({}, extra=AnyValue()), default={}),
    "path": Field(String()),
    "builtin": Field(String()),
}, one_of=[("path", "builtin")])


def test_valid_table_is_normalized(tmp_path):
    out = validate(SPEC, {"gains": [1, 2.5, 0], "period": "1 ms", "path": "x", "file": "out.csv",
                          "free": {"anything": [1, "x"]}}, Where(tmp_path / "s.toml"))
    assert out["period"] == pytest.approx(1e-3) and out["gains"] == [1.0, 2.5, 0.0]
    assert out["mode"] == "a" and out["enabled"] is True and out["names"] == []
    assert out["file"] == tmp_path / "out.csv" and "count" not in out


@pytest.mark.parametrize("doc, key, words", [
    ({"gains": [1, 2], "path": "x"}, "t.gains", "a list of 3 items"),
    ({"gains": [1, -2, 3], "path": "x"}, "t.gains[1]", "a number >= 0"),
    ({"gains": [1, 2, 3], "path": "x", "count": True}, "t.count", "an integer >= 1 and <= 10"),
    ({"gains": [1, 2, 3], "path": "x", "count": 2.0}, "t.count", "an integer"),
    ({"gains": [1, 2, 3], "path": "x", "enabled": "yes"}, "t.enabled", "true or false"),
    ({"gains": [1, 2, 3], "path": "x", "mode": "c"}, "t.mode", "one of 'a', 'b'"),
    ({"gains": [1, 2, 3], "path": "x", "names": ["u", "u"]}, "t.names[1]", "duplicate"),
    ({"gains": [1, 2, 3], "path": "x", "file": "out.txt"}, "t.file", "not a .csv file"),
    ({"gains": [1, 2, 3], "path": "x", "period": "nan s"}, "t.period", "a number in s"),
    ({"gains": [1, 2, 3], "path": "x", "period": float("inf")}, "t.period", "finite"),
    ({"gains": [1, 2, 3]}, "t", "exactly one of the keys path, builtin"),
    ({"gains": [1, 2, 3], "path": "x", "builtin": "y"}, "t", "exactly one of the keys path, builtin"),
    ({"path": "x"}, "t.gains", "missing required key"),
    ({"gains": [1, 2, 3], "path": "x", "gain": 1}, "t.gain", "unknown key"),
    ([1, 2], "t", "a table"),
])
def test_errors_name_key_and_expectation(tmp_path, doc, key, words):
    with pytest.raises(ScenarioError) as info:
        validate(SPEC, doc, Where(tmp_path / "s.toml") / "t")
    assert info.value.key == key and words in str(info.value)
    assert str(info.value).startswith(str(tmp_path / "s.toml"))
