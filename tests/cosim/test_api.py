"""The public Python API (cosim.api, re-exported from cosim): load/validate/describe a scenario
from a path, a TOML text or a dict with dotted-key overrides; run it into a folder or a
temporary one and read its summary, time series and files; bad input raises the documented
ScenarioError (file or "<dict>", key, expected) and writes nothing; a failed run raises
RunFailed carrying the summary; results equal `python -m cosim run` byte for byte."""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import numpy as np
import pytest

import cosim
from cosim_fmu_models import build_test_fmu

ROOT = Path(__file__).resolve().parents[2]

PLANT = textwrap.dedent("""
    connections = []

    [scenario]
    name = "drop"
    job = "fmus"
    description = "plant FMU falling from a pose"

    [simulation]
    stop_time = 0.05
    macro_step = "200 us"

    [[fmus]]
    name = "plant"
    builtin = "rx130l_plant"
    [fmus.parameters]
    "q0[2]" = -0.3

    [record]
    period = "1 ms"
    signals = ["plant.q[*]"]
    """)


def faulty_scenario(tmp_path: Path) -> dict:
    fmu = build_test_fmu("faulty", tmp_path)
    return {"connections": [],
            "scenario": {"name": "faulty", "job": "fmus"},
            "simulation": {"stop_time": 0.1, "macro_step": 0.01},
            "fmus": [{"name": "f", "path": str(fmu), "parameters": {"fail_time": 0.05, "mode": 1}}],
            "record": {"period": 0.01, "signals": ["f.y"]}}


def test_import_cosim_is_light():
    code = "import sys, cosim; print(sorted(m for m in ('numpy', 'fmpy', 'dask', 'cosim.api') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == "[]"
    assert cosim.run is cosim.api.run and cosim.ScenarioError is cosim.api.ScenarioError
    assert issubclass(cosim.ScenarioError, ValueError) and issubclass(cosim.RunFailed, RuntimeError)


def test_load_from_path_text_and_dict_with_overrides(tmp_path):
    path = tmp_path / "drop.toml"
    path.write_text(PLANT, encoding="utf-8")
    from_path = cosim.load_scenario(path)
    from_text = cosim.load_scenario(PLANT)
    from_dict = cosim.load_scenario(tomllib.loads(PLANT))
    assert (from_path.source, from_text.source, from_dict.source) == (str(path), "<string>", "<dict>")
    assert from_path.data["simulation"] == from_text.data["simulation"] == from_dict.data["simulation"]
    assert from_path.name == "drop" and from_path.job == "fmus" and from_path.path == path

    sc = cosim.load_scenario(path, overrides={"simulation.stop_time": "20 ms",
                                              'fmus[0].parameters."q0[3]"': 1.1})
    assert sc.data["simulation"]["stop_time"] == pytest.approx(0.02)
    assert sc.data["fmus"][0]["parameters"]["q0[3]"] == 1.1
    assert sc.overrides == {"simulation.stop_time": "20 ms", 'fmus[0].parameters."q0[3]"': 1.1}
    again = sc.with_overrides({"simulation.stop_time": "10 ms"})
    assert again.data["simulation"]["stop_time"] == pytest.approx(0.01) and len(again.overrides) == 2
    assert cosim.load_scenario(sc.to_toml()).data["simulation"] == sc.data["simulation"]
    text = sc.describe()
    for expected in ("scenario 'drop': job 'fmus'", f"from {path}", "overrides: simulation.stop_time = '20 ms'",
                     "simulation.stop_time = 0.02", "fmus[0].builtin = 'rx130l_plant'"):
        assert expected in text
    assert list(tmp_path.iterdir()) == [path]   # nothing written


@pytest.mark.parametrize("source", ["path", "dict"])
@pytest.mark.parametrize("overrides, key, expected, given", [
    ({"simulation.stop_tim": 1.0}, "simulation.stop_tim", "a key path of the 'fmus' job's scenario",
     "simulation.stop_tim"),
    ({"simulation.stop_time": "20 kg"}, "simulation.stop_time", "a number in s", "20 kg"),
    ({"simulation.macro_step": True}, "simulation.macro_step", "a number in s", True),
    ({"record.signals": "plant.q[1]"}, "record.signals", "a list of", "plant.q[1]"),
    ({'fmus[0].parameters."q0[9]"': 0.1}, 'fmus[0].parameters."q0[9]"', "a variable of rx130l_plant.fmu", None),
    ({"scenario.job": "iso9283"}, "scenario.job", "a key other than scenario.job", "scenario.job"),
])
def test_bad_overrides_raise_scenario_error_and_write_nothing(tmp_path, monkeypatch, source, overrides, key,
                                                              expected, given):
    path = tmp_path / "drop.toml"
    path.write_text(PLANT, encoding="utf-8")
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr("tempfile.tempdir", str(scratch))
    scenario = path if source == "path" else tomllib.loads(PLANT)
    for call in (lambda: cosim.load_scenario(scenario, overrides),
                 lambda: cosim.run(scenario, out=tmp_path / "out", overrides=overrides),
                 lambda: cosim.run(scenario, overrides=overrides)):
        with pytest.raises(cosim.ScenarioError) as info:
            call()
        err = info.value
        assert err.file == (path if source == "path" else "<dict>")
        assert err.key == key and expected in err.expected, str(err)
        if given is not None:
            assert err.given == given
        assert str(err).startswith(f"{err.file}: {key}: ")
    assert not (tmp_path / "out").exists() and list(scratch.iterdir()) == []


def test_dict_without_job_or_invalid_names_dict(tmp_path):
    with pytest.raises(cosim.ScenarioError) as info:
        cosim.load_scenario({"scenario": {"name": "x"}, "simulation": {"stop_time": 1.0}})
    assert (info.value.file, info.value.key) == ("<dict>", "scenario.job")
    assert "one of the registered job types" in info.value.expected and "fmus" in info.value.expected
    with pytest.raises(cosim.ScenarioError) as info:
        cosim.load_scenario({"simulation": {}})
    assert (info.value.file, info.value.key) == ("<dict>", "scenario")
    doc = tomllib.loads(PLANT)
    doc["simulation"]["macro_step"] = "2 parsecs"
    with pytest.raises(cosim.ScenarioError) as info:
        cosim.run(doc, out=tmp_path / "out")
    assert (info.value.file, info.value.key, info.value.given) == ("<dict>", "simulation.macro_step", "2 parsecs")
    with pytest.raises(cosim.ScenarioError) as info:
        cosim.load_scenario("[scenario\nname = 1")
    assert info.value.file == "<string>" and info.value.expected == "valid TOML"
    with pytest.raises(cosim.ScenarioError) as info:
        cosim.load_scenario(tmp_path / "missing.toml")
    assert info.value.problem == "file not found"
    assert not (tmp_path / "out").exists()


def test_run_returns_summary_timeseries_and_equals_the_cli(tmp_path):
    path = tmp_path / "drop.toml"
    path.write_text(PLANT, encoding="utf-8")
    result = cosim.run(path, out=tmp_path / "api")
    assert result.ok and result.status == "ok" and not result.temporary and result.error is None
    s = result.summary
    assert (s.status, s.scenario, s.job, s.reason, s.stopped_at_s) == ("ok", "drop", "fmus", None, None)
    assert s.sim_time_s == pytest.approx(0.05) and s.realtime_factor > 0 and s.wall_time_s > 0
    assert s["rows_recorded"] == s.raw["rows_recorded"] == 51 and s.get("no.such", 7) == 7
    assert result.timeseries_names == ["timeseries"] and result.figures == [] and result.can_log == []
    ts = result.timeseries("timeseries", kind="numpy")
    assert ts.columns[0] == "time" and len(ts) == 51 and ts["time"][-1] == pytest.approx(0.05)
    assert ts.to_numpy().shape == (51, 7)
    assert np.all(np.isfinite(ts["plant.q[2]"])) and ts["plant.q[2]"][0] == pytest.approx(-0.3)
    with pytest.raises(KeyError, match="available: timeseries"):
        result.timeseries("nope")
    # the same scenario through the CLI writes the same time series, byte for byte
    cli = subprocess.run([sys.executable, "-m", "cosim", "run", str(path), "--out", str(tmp_path / "cli"),
                          "--quiet"], capture_output=True, text=True, cwd=ROOT)
    assert cli.returncode == 0, cli.stderr
    assert (tmp_path / "cli" / "timeseries.parquet").read_bytes() == \
        (tmp_path / "api" / "timeseries.parquet").read_bytes()
    assert cosim.RunResult.open(tmp_path / "cli").summary["rows_recorded"] == 51


def test_temporary_folder_and_cleanup():
    with cosim.run(PLANT, overrides={"simulation.stop_time": "10 ms"}) as result:
        assert result.temporary and (result.out / "summary.json").is_file()
        assert result.summary.sim_time_s == pytest.approx(0.01)
    assert not result.out.exists()


def test_failed_run_raises_run_failed_with_summary(tmp_path):
    doc = faulty_scenario(tmp_path)
    with pytest.raises(cosim.RunFailed) as info:
        cosim.run(doc, out=tmp_path / "out")
    err = info.value
    assert err.summary.status == "failed" and err.summary.stopped_at_s == pytest.approx(0.04)
    assert err.reason.startswith("f at t = 0.04 s: fmi2DoStep") and err.reason in str(err)
    assert err.result.out == tmp_path / "out"
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["status"] == "failed"
    assert err.result.timeseries("timeseries", kind="numpy")["f.y"][-1] == pytest.approx(0.04)
    result = cosim.run(doc, out=tmp_path / "again", check=False)
    assert result.status == "failed" and result.summary.reason == err.reason


def test_build_sweep_validates_every_variant_before_running(tmp_path):
    path = tmp_path / "drop.toml"
    path.write_text(PLANT, encoding="utf-8")
    base = cosim.load_scenario(path, overrides={"simulation.stop_time": "20 ms"})
    with pytest.raises(cosim.ScenarioError) as info:
        cosim.build_sweep(base, {"simulation.stop_tim": [0.1]}, name="s")
    assert (info.value.file, info.value.key) == ("<python>", "axes[0].key")
    assert "unknown axis" in str(info.value)
    with pytest.raises(cosim.ScenarioError) as info:
        cosim.build_sweep(base, {"simulation.stop_time": ["10 ms", "2 kg"]}, name="s")
    assert (info.value.file, info.value.key, info.value.given) == ("<python>", "axes[0].values[1]", "2 kg")
    with pytest.raises(cosim.ScenarioError) as info:
        cosim.build_sweep(base, [{"key": "simulation.stop_time", "values": []}], name="s")
    assert info.value.key == "axes[0].values" and info.value.problem == "empty axis"
    sweep = cosim.build_sweep(base, {'fmus[0].parameters."q0[3]"': [1.0, 1.2],
                                     "simulation.stop_time": ["10 ms", "30 ms"]},
                              name="s", overrides={"record.period": "2 ms"}, metrics=["rows_recorded"])
    assert [v.id for v in sweep.variants] == ["v0000", "v0001", "v0002", "v0003"]
    assert sweep.variants[3].values == {'fmus[0].parameters."q0[3]"': 1.2, "simulation.stop_time": 0.03}
    assert all(v.document["record"]["period"] == "2 ms" for v in sweep.variants)
    assert sweep.base.raw["simulation"]["stop_time"] == "20 ms"     # the base keeps its own overrides
    assert list(tmp_path.iterdir()) == [path]                        # nothing written


def test_cli_help_imports_nothing_heavy():
    # how fast --help answers is a benchmark figure (benchmarks/), not a timed test
    out = subprocess.run([sys.executable, "-m", "cosim", "--help"], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0 and "run" in out.stdout
    code = ("import sys, cosim.cli; cosim.cli.build_parser(); "
            "print(sorted(m for m in ('cosim.api', 'cosim.sweep', 'dask', 'fmpy', 'pandas') if m in sys.modules))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert loaded.stdout.strip() == "[]", loaded.stdout        # the parser imports no API, sweep or Dask code
