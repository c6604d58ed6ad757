"""``python -m cosim run``: summary.json and time series for ok and failed runs; custom job types."""
import json
import subprocess
import sys
import time

import numpy as np
import pytest

from cosim.cli import main
from cosim.master import EndSimulation
from cosim.results import read_csv
from cosim.results.summary import SummaryWriter, process_started_perf_counter
from cosim.scenario import (COSIM_FIELDS, SCENARIO_FIELD, RunContext, ScenarioError, add_record, build_master,
                            check_cosim_tables, load_scenario, register_job)
from cosim.scenario.schema import Field, List, Number, String, Table
from scenario_files import run_scenario

FAILING = """
[scenario]
name = "failing"
job = "fmus"

[simulation]
stop_time = 2.0
macro_step = 0.01

[[fmus]]
name = "clock"
path = "Integrator.fmu"

[[fmus]]
name = "bad"
path = "Faulty.fmu"
debug_logging = true
[fmus.parameters]
fail_time = 0.5
mode = {mode}

[record]
period = 0.05
signals = ["bad.y", "clock.clock"]
"""


@pytest.mark.parametrize("mode, stopped_at, text", [(1, 0.49, "fmi2Discard"), (2, 0.5, "output 'y' is nan")])
def test_failed_run_writes_failed_summary_and_keeps_time_series(fmu_workdir, mode, stopped_at, text):
    path = fmu_workdir / "failing.toml"
    path.write_text(FAILING.format(mode=mode))
    out = fmu_workdir / "out"
    code, summary = run_scenario(path, out)
    assert code == 3  # failed run (cosim/results/exits.py)
    assert summary["status"] == "failed" and summary["scenario"] == "failing"
    assert text in summary["reason"] and "bad at t = " in summary["reason"]
    assert summary["stopped_at_s"] == pytest.approx(stopped_at)
    assert summary["failed_component"] == "bad"
    if mode == 1:
        assert any("solver diverged" in m for m in summary["fmu_messages"])
    columns, data = read_csv(out / "timeseries.csv")
    assert columns == ["time", "bad.y", "clock.clock"]
    assert np.allclose(data[:, 0], np.arange(10) * 0.05, atol=1e-12)  # every sample before the failure
    assert np.allclose(data[1:, 1], data[1:, 0], atol=1e-12)


def test_ok_run_via_subprocess_default_results_folder(fmu_workdir):
    path = fmu_workdir / "chain.toml"
    path.write_text(FAILING.format(mode=1).replace('name = "failing"', 'name = "fine"').replace(
        "fail_time = 0.5", "fail_time = 99.0"))
    proc = subprocess.run([sys.executable, "-m", "cosim", "run", str(path)], cwd=fmu_workdir, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "\r" not in proc.stderr  # no progress bar when stderr is not a terminal
    summary = json.loads((fmu_workdir / "results" / "fine" / "summary.json").read_text())
    assert summary["status"] == "ok" and "reason" not in summary
    assert summary["sim_time_s"] == pytest.approx(2.0)
    assert summary["wall_time_s"] > 0 and summary["realtime_factor"] == pytest.approx(2.0 / summary["wall_time_s"])
    _, data = read_csv(fmu_workdir / "results" / "fine" / "timeseries.csv")
    assert len(data) == 41 and data[-1, 0] == pytest.approx(2.0)


def test_cli_wall_time_counts_from_the_process_start(fmu_workdir):
    """``cosim run``'s realtime_factor is end to end: the wall clock starts when the interpreter
    started (here 0.6 s of sleep before the command is even parsed), not when the job starts."""
    path = fmu_workdir / "chain.toml"
    path.write_text(FAILING.format(mode=1).replace('name = "failing"', 'name = "fine"').replace(
        "fail_time = 0.5", "fail_time = 99.0"))
    code = ("import sys, time; time.sleep(0.6); from cosim.cli import main; "
            f"raise SystemExit(main(['run', {str(path)!r}, '--out', 'late', '--quiet']))")
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code], cwd=fmu_workdir, capture_output=True, text=True, timeout=120)
    elapsed = time.perf_counter() - t0
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((fmu_workdir / "late" / "summary.json").read_text())
    assert summary["wall_time_from"] == "process start"
    assert 0.6 <= summary["wall_time_s"] <= elapsed + 0.02  # clock tick resolution of the start time
    assert summary["realtime_factor"] == pytest.approx(2.0 / summary["wall_time_s"])


def test_process_start_is_in_the_past(tmp_path):
    started = process_started_perf_counter()
    assert started is not None and 0.0 < time.perf_counter() - started < 30 * 86400
    # a run from Python counts from its call; a given origin is kept
    assert SummaryWriter(tmp_path / "a.json", "s", "j").data["wall_time_from"] == "run call"
    writer = SummaryWriter(tmp_path / "b.json", "s", "j", wall_origin=time.perf_counter() - 5.0,
                           wall_time_from="process start")
    assert writer.wall_time_s >= 5.0 and writer.data["wall_time_from"] == "process start"


def test_help_mentions_run():
    out = subprocess.run([sys.executable, "-m", "cosim", "run", "--help"], capture_output=True, text=True, check=True)
    assert "--out" in out.stdout and "--quiet" in out.stdout


# --- a job type added from outside, reusing the schema helper and the co-simulation tables -------------------

def _run_ramp_job(scenario, ctx: RunContext):
    doc = scenario.data
    ramp = doc["ramp"]
    master = build_master(doc, master_variables={"ramp.u": ("Real", 0.0)})
    add_record(master, doc, ctx)
    u = {}

    def drive(t):
        u["u"][0] = ramp["slope"] * t
        if t >= ramp["until"]:
            raise EndSimulation

    master.add_task(drive, ramp["period"], setup=lambda m: u.update(u=m.view(["ramp.u"], writable=True)))
    ctx.attach(master, doc["simulation"]["stop_time"], label="ramp")
    status_at_start = json.loads(ctx.path("summary.json").read_text())["status"]
    with master:
        master.initialize(doc["simulation"]["stop_time"])
        reached = ctx.execute(master)
    return {"ended_at_s": reached, "tag": ramp["tag"], "status_at_start": status_at_start}


RAMP_TABLE = Table({
    "slope": Field(Number(unit="m/s"), required=True),
    "until": Field(Number(unit="s", gt=0), required=True),
    "period": Field(Number(unit="s", gt=0), default=0.1),
    "tag": Field(String(choices=("a", "b")), default="a"),
    "gains": Field(List(Number(min=0), length=3), default=[1.0, 1.0, 1.0]),
}, doc="the [ramp] table")

register_job(
    "test_ramp", _run_ramp_job,
    Table({"scenario": SCENARIO_FIELD, "ramp": Field(RAMP_TABLE, required=True), **COSIM_FIELDS}),
    lambda doc, where: check_cosim_tables(doc, where, master_variables={"ramp.u": "Real"}),
    "test job: a task ramps an input",
)

RAMP = """
connections = ["ramp.u -> a.u"]

[scenario]
name = "ramp"
job = "test_ramp"

[ramp]
slope = "500 mm/s"
until = 0.6
gains = [1, 2, 3]

[simulation]
stop_time = 1.0
macro_step = 0.1

[[fmus]]
name = "a"
path = "Integrator.fmu"

[record]
period = 0.1
signals = ["a.y", "ramp.u", "a.u"]
"""


def test_custom_job_reuses_schema_and_cosim_tables(fmu_workdir):
    path = fmu_workdir / "ramp.toml"
    path.write_text(RAMP)
    assert main(["run", str(path), "--out", str(fmu_workdir / "o"), "--quiet"]) == 0
    summary = json.loads((fmu_workdir / "o" / "summary.json").read_text())
    assert summary["job"] == "test_ramp" and summary["tag"] == "a" and summary["status_at_start"] == "running"
    assert summary["ended_at_s"] == pytest.approx(0.6) and summary["sim_time_s"] == pytest.approx(0.6)
    columns, data = read_csv(fmu_workdir / "o" / "timeseries.csv")
    assert columns == ["time", "a.y", "ramp.u", "a.u"]
    t = data[:, 0]
    assert np.allclose(data[:, 2], 0.5 * t, atol=1e-12)  # "500 mm/s" converted to 0.5 m/s
    assert np.allclose(data[:, 1], 0.5 * 0.1 * 0.1 * np.arange(7) * (np.arange(7) - 1) / 2, atol=1e-12)


@pytest.mark.parametrize("old, new, key", [
    ('slope = "500 mm/s"', 'slope = "500 mm"', "ramp.slope"),
    ("gains = [1, 2, 3]", "gains = [1, -2, 3]", "ramp.gains[1]"),
    ("gains = [1, 2, 3]", "gains = [1, 2]", "ramp.gains"),
    ('["ramp.u -> a.u"]', '["ramp.v -> a.u"]', "connections[0]"),
    ("until = 0.6", "until = 0.6\nuntill = 1", "ramp.untill"),
])
def test_custom_job_errors(fmu_workdir, old, new, key):
    path = fmu_workdir / "ramp.toml"
    path.write_text(RAMP.replace(old, new))
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert info.value.key == key


def test_progress_bar_shows_on_a_terminal_only(monkeypatch):
    import io

    from cosim.results import ProgressBar

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    for tty, quiet in ((True, False), (True, True), (False, False)):
        stream = Terminal() if tty else io.StringIO()
        monkeypatch.setattr(sys, "stderr", stream)
        bar = ProgressBar(2.0, "demo", enabled=not quiet, min_interval_s=0.0)
        bar.update(1.0)
        bar.update(2.0, force=True)
        bar.close()
        shown = stream.getvalue()
        assert ("demo" in shown and "2.000/2.000 s sim" in shown) == (tty and not quiet), shown
