"""Sweep files are checked completely before anything runs: unknown axes, values of the wrong
type, empty axes and other mistakes are ScenarioErrors naming the sweep file and the key;
the variants are the grid product times the zipped Monte Carlo draws, reproducibly."""
from __future__ import annotations

import math
import statistics
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from cosim.scenario import ScenarioError
from cosim.sweep import load_sweep
from cosim.scenario.keypath import KeyPathSyntaxError, format_key_path, parse_key_path, with_value

ROOT = Path(__file__).resolve().parents[3]
PLANT_DROP = ROOT / "scenarios" / "plant_drop.toml"
CALIBRATION = ROOT / "scenarios" / "calibration.toml"


def write_sweep(tmp_path: Path, body: str, base: Path = PLANT_DROP, name: str = "sweep.toml") -> Path:
    path = tmp_path / name
    path.write_text(f'[sweep]\nname = "t"\nbase = "{base}"\n' + textwrap.dedent(body), encoding="utf-8")
    return path


def error_of(path: Path) -> ScenarioError:
    with pytest.raises(ScenarioError) as info:
        load_sweep(path)
    assert info.value.file == path.resolve(), str(info.value)
    return info.value


def test_key_paths_round_trip():
    path = parse_key_path('fmus[0].parameters."q0[2]"')
    assert path == ("fmus", 0, "parameters", "q0[2]")
    assert format_key_path(path) == 'fmus[0].parameters."q0[2]"'
    assert parse_key_path(" tracker . noise_sigma ") == ("tracker", "noise_sigma")
    for bad in ("", "a..b", "a.", "a[x]", "a b"):
        with pytest.raises(KeyPathSyntaxError):
            parse_key_path(bad)
    doc = {"a": {"b": [1, {"c": 2}]}}
    assert with_value(doc, ("a", "b", 1, "c"), 5) == {"a": {"b": [1, {"c": 5}]}}
    assert doc == {"a": {"b": [1, {"c": 2}]}}  # a copy
    assert with_value(doc, ("x", "y"), 1)["x"] == {"y": 1}


def test_unknown_axis_names_file_key_and_known_keys(tmp_path):
    err = error_of(write_sweep(tmp_path, """
        [[axes]]
        key = "tracker.noise_mm"
        values = ["0.1 mm"]
        """, base=CALIBRATION))
    assert err.key == "axes[0].key" and err.given == "tracker.noise_mm"
    text = str(err)
    assert "unknown axis" in text and "noise_mm" in text and "position_sigma" in text and "'calibration'" in text


def test_unknown_fmu_parameter_axis_is_blamed_on_the_key(tmp_path):
    err = error_of(write_sweep(tmp_path, """
        [[axes]]
        key = 'fmus[0].parameters."q0[9]"'
        values = [0.1]
        """))
    assert err.key == "axes[0].key" and "unknown axis" in str(err) and "rx130l_plant.fmu" in str(err)


@pytest.mark.parametrize("key", ["fmus[3].step", "simulation.stop_time.x", "scenario.name", "output.dir", "nope"])
def test_keys_outside_the_schema_or_fixed_are_rejected(tmp_path, key):
    err = error_of(write_sweep(tmp_path, f"""
        [[axes]]
        key = '{key}'
        values = [1]
        """))
    assert err.key == "axes[0].key" and err.given == key


def test_wrong_type_value_names_the_axis_value_and_expectation(tmp_path):
    err = error_of(write_sweep(tmp_path, """
        [[axes]]
        key = "tracker.position_sigma"
        values = ["0.1 mm", "0.2 s"]
        """, base=CALIBRATION))
    assert err.key == "axes[0].values[1]" and err.given == "0.2 s"
    assert "a number in m" in str(err) and "tracker.position_sigma" in str(err)


def test_wrong_type_fmu_parameter_value(tmp_path):
    err = error_of(write_sweep(tmp_path, """
        [[axes]]
        key = 'fmus[0].parameters."q0[2]"'
        values = [0.1, "abc"]
        """))
    assert err.key == "axes[0].values[1]" and err.given == "abc" and "Real variable 'q0[2]'" in str(err)


def test_value_breaking_a_cross_key_rule_names_the_variant(tmp_path):
    err = error_of(write_sweep(tmp_path, """
        [[axes]]
        key = "simulation.macro_step"
        values = ["200 us", "300 us"]
        """))
    # macro_step itself is fine; stop_time 0.5 s is then no multiple of it
    assert err.key == "axes" and "v0001" in str(err) and "stop_time" in str(err)


@pytest.mark.parametrize("axis", ["values = []", "seeds = 0",
                                  'distribution = {kind = "normal", mean = 0.0, std = 0.1}\nsamples = 0'])
def test_empty_axis(tmp_path, axis):
    err = error_of(write_sweep(tmp_path, f"""
[[axes]]
key = 'fmus[0].parameters."q0[2]"'
{axis}
"""))
    assert "empty axis" in str(err) and err.key.startswith("axes[0].")


def test_other_sweep_file_mistakes(tmp_path):
    cases = {
        "no axes": ("", "axes"),
        "two sources": ("[[axes]]\nkey = 'simulation.stop_time'\nvalues = [0.2]\nseeds = 2\n", "axes[0]"),
        "overlap": ("[[axes]]\nkey = 'fmus[0].parameters'\nvalues = [{}]\n"
                    "[[axes]]\nkey = 'fmus[0].parameters.\"q0[2]\"'\nvalues = [0.1]\n", "axes[1].key"),
        "draw counts": ("[[axes]]\nkey = 'simulation.stop_time'\nseeds = 3\n"
                        "[[axes]]\nkey = 'fmus[0].parameters.\"q0[2]\"'\n"
                        "distribution = {kind = 'uniform', low = 0.0, high = 0.1}\nsamples = 2\n", "axes[1].samples"),
        "mixed units": ("[[axes]]\nkey = 'simulation.stop_time'\n"
                        "distribution = {kind = 'normal', mean = '1 s', std = '10 ms'}\nsamples = 2\n",
                        "axes[0].distribution"),
        "missing std": ("[[axes]]\nkey = 'simulation.stop_time'\n"
                        "distribution = {kind = 'normal', mean = 1.0}\nsamples = 2\n", "axes[0].distribution.std"),
        "report parameter": ("[[axes]]\nkey = 'simulation.stop_time'\nvalues = [0.2]\n"
                             "[report]\nmetric = 'sim_time_s'\nparameter = 'simulation.macro_step'\n",
                             "report.parameter"),
        "override of axis": ("[overrides]\n'simulation.stop_time' = 0.2\n"
                             "[[axes]]\nkey = 'simulation.stop_time'\nvalues = [0.2]\n", "overrides"),
    }
    for label, (body, key) in cases.items():
        err = error_of(write_sweep(tmp_path, body, name=f"{label.replace(' ', '_')}.toml"))
        assert err.key.startswith(key), (label, str(err))


def test_invalid_sweep_runs_nothing_and_exits_2(tmp_path):
    path = write_sweep(tmp_path, """
        [[axes]]
        key = "simulation.stop_tim"
        values = [0.1]
        """)
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "cosim", "sweep", str(path), "--out", str(out)],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert str(path.resolve()) in proc.stderr and "axes[0].key" in proc.stderr and "stop_tim" in proc.stderr
    assert not out.exists()


def test_variants_grid_product_times_zipped_monte_carlo(tmp_path):
    path = write_sweep(tmp_path, """
        [overrides]
        simulation.stop_time = "0.1 s"

        [[axes]]
        key = 'fmus[0].parameters."q0[2]"'
        values = [-0.3, 0.0]

        [[axes]]
        key = "record.period"
        values = ["1 ms", "2 ms", "5 ms"]

        [[axes]]
        key = 'fmus[0].parameters."q0[3]"'
        distribution = {kind = "normal", mean = 1.2, std = 0.05}
        samples = 4
        seed = 7

        [[axes]]
        key = 'fmus[0].parameters."q0[5]"'
        distribution = {kind = "uniform", low = 0.5, high = 0.7}
        samples = 4
        """)
    sweep = load_sweep(path)
    assert len(sweep.variants) == 2 * 3 * 4
    assert [v.id for v in sweep.variants[:2]] == ["v0000", "v0001"]
    first = sweep.variants[0]
    assert first.values["record.period"] == pytest.approx(1e-3)       # SI, as validated
    assert first.document["simulation"]["stop_time"] == "0.1 s"        # override in every variant
    # first grid axis slowest, Monte Carlo draws innermost and zipped
    assert [v.params['fmus[0].parameters."q0[2]"'] for v in sweep.variants[:13]] == [-0.3] * 12 + [0.0]
    draws = [v.params['fmus[0].parameters."q0[3]"'] for v in sweep.variants[:4]]
    assert len(set(draws)) == 4 and [v.params['fmus[0].parameters."q0[3]"'] for v in sweep.variants[4:8]] == draws
    assert all(0.5 <= v.values['fmus[0].parameters."q0[5]"'] <= 0.7 for v in sweep.variants)
    # reproducible: same file, same draws and hashes; hashes unique
    again = load_sweep(path)
    assert [v.hash for v in again.variants] == [v.hash for v in sweep.variants]
    assert len({v.hash for v in sweep.variants}) == len(sweep.variants)


def test_unit_draws_are_written_in_the_given_unit_and_converted_by_the_job(tmp_path):
    sweep = load_sweep(write_sweep(tmp_path, """
        [[axes]]
        key = "tracker.position_sigma"
        distribution = {kind = "lognormal", median = "0.1 mm", sigma = 0.3}
        samples = 50
        seed = 3
        """, base=CALIBRATION))
    given = [v.params["tracker.position_sigma"] for v in sweep.variants]
    assert all(g.endswith(" mm") for g in given)
    si = [v.values["tracker.position_sigma"] for v in sweep.variants]
    assert si == pytest.approx([float(g.split()[0]) * 1e-3 for g in given], rel=1e-15)
    logs = [math.log(x / 1e-4) for x in si]
    assert abs(statistics.median(logs)) < 0.15 and 0.2 < statistics.stdev(logs) < 0.4


def test_example_sweeps_are_valid():
    cal = load_sweep(ROOT / "scenarios" / "calibration_noise_sweep.toml")
    assert len(cal.variants) == 4 * 20 and cal.job == "calibration"
    assert sorted({v.values["tracker.noise_seed"] for v in cal.variants}) == list(range(20))
    iso = load_sweep(ROOT / "scenarios" / "iso9283_payload_sweep.toml")
    assert iso.job == "iso9283" and len(iso.variants) == 12
    assert {tuple(v.values["controller.modes"]) for v in iso.variants} == {("standard",), ("model_based",),
                                                                            ("model_based_elastic",)}
