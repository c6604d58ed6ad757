"""``python -m cosim run SCENARIO --realtime``: settings validation, summary.json 'realtime', jitter figure."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from cosim.execution.config import execution_options
from cosim.results import read_series
from cosim.scenario import ScenarioError, load_scenario
from realtime_support import ROOT, write_scenario


def _run(*args):
    return subprocess.run([sys.executable, "-m", "cosim", "run", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=600)


def test_paced_run_writes_realtime_statistics_and_histogram(tmp_path):
    scenario = write_scenario(tmp_path, "40 ms", extra='[realtime]\noverrun_policy = "skip"\nscheduling = "normal"\n'
                                                          'cpu = "none"\n')
    out = tmp_path / "out"
    done = _run(scenario, "--realtime", "--quiet", "--out", out)
    assert done.returncode == 0, done.stderr
    summary = json.loads((out / "summary.json").read_text())
    rt = summary["realtime"]
    assert rt["cycles"] == 101 and rt["policy"] == "skip" and rt["scheduling"] == "normal, not pinned"
    assert 0 <= rt["overruns"] <= rt["cycles"] and rt["overrun_fraction"] == rt["overruns"] / rt["cycles"]
    lat = rt["lateness"]
    assert 0.0 <= lat["p50_us"] <= lat["p99_us"] <= lat["max_us"]
    assert rt["tolerance_us"] == pytest.approx(400.0 - 136.56)   # cycle minus the isochronous phase
    assert rt["thresholds_us"]["first_preq_slot"] == pytest.approx(8.72)
    assert set(rt["late_fraction"]) == {"first_preq_slot", "isochronous_phase", "whole_cycle"}
    assert rt["late_fraction"]["isochronous_phase"] == rt["overrun_fraction"]
    assert rt["runs"]["model_based"]["cycles"] == 101
    assert (out / rt["histogram"]).read_bytes()[:4] == b"\x89PNG"
    assert (out / "jitter_model_based.png").exists()
    assert summary["execution"]["realtime"] is True and summary["execution"]["mode"] == "in_process"
    assert summary["status"] == "ok" and summary["modes"]["model_based"]["status"] == "ok"
    assert read_series(out / "timeseries_model_based.parquet")[1].shape[0] == 101   # 400 us rows
    # every cycle's lateness, read back by pandas (report.html plots it against the tolerance)
    import numpy as np
    import pandas as pd

    assert rt["runs"]["model_based"]["series"] == "lateness_model_based.parquet"
    cycles = pd.read_parquet(out / "lateness_model_based.parquet")
    assert list(cycles.columns) == ["t", "cycle", "lateness_us", "work_us", "overrun", "tolerance_us"]
    assert len(cycles) == 101 and np.array_equal(cycles["t"], cycles["cycle"] * 400e-6)
    assert cycles["lateness_us"].max() == lat["max_us"] and cycles["overrun"].sum() == rt["overruns"]
    assert (cycles["tolerance_us"] == rt["tolerance_us"]).all()


def test_bad_realtime_settings_name_the_key(tmp_path):
    for extra, key in (('[realtime]\noverrun_policy = "drop"\n', "realtime.overrun_policy"),
                       ('[realtime]\ntolerance = "soon"\n', "realtime.tolerance"),
                       ('[realtime]\nspin = "1 s"\n', "realtime.spin"),
                       ('[execution]\nmode = "threads"\n', "execution.mode"),
                       ('[realtime]\ncpu = -1\n', "realtime.cpu")):
        with pytest.raises(ScenarioError, match=key.replace(".", r"\.")):
            load_scenario(write_scenario(tmp_path, "40 ms", extra=extra))


def test_flags_override_the_file_and_jobs_without_a_cell_refuse(tmp_path):
    scenario = load_scenario(write_scenario(tmp_path, "40 ms", extra='[execution]\nrealtime = true\n'))
    opts = execution_options(scenario.data, split=True)
    assert opts.realtime and opts.split and opts.settings.overrun_policy == "hold"
    assert not execution_options(load_scenario(write_scenario(tmp_path, "40 ms")).data).active
    done = _run(ROOT / "scenarios" / "plant_drop.toml", "--realtime", "--out", tmp_path / "pd")
    assert done.returncode == 2 and "runs no robot cell" in done.stderr
    assert not (tmp_path / "pd").exists()
