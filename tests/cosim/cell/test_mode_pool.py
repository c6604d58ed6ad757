"""The main job's modes side by side in worker processes (cosim/execution/mode_pool.py): the same
results bit for bit as one after another in one process, and #17's guarantees kept - Ctrl-C or
SIGTERM to the process group stops every worker in order with summary.json ``interrupted``
(mode, stopped_at_s, every unfinished mode's time) and their files readable; a worker that dies
fails the run naming its mode."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from fieldbus.canlog import open_log, read_frames
import numpy as np
import pytest

from cosim.results import read_series
from scenario_files import write_variant

ROOT = Path(__file__).resolve().parents[3]
SCENARIO = (ROOT / "scenarios" / "iso9283_rigid.toml").read_text(encoding="utf-8")
MODES_LINE = 'modes = ["standard", "standard_speed_ff", "model_based"]'
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
#: Summary fields that are wall-clock measurements (or name the folder), not results.
TIMING = {"cycle_wall_us", "cycle_compute_cpu_us", "deadline_misses", "cycles_over_budget_wall",
          "cycles_over_budget_cpu", "loop_wall_time_s", "loop_realtime_factor", "controller_cycles_timed",
          "warnings"}  # warnings: compute-budget warnings quote timings


def short(tmp_path: Path, name: str, stop: str = "0.5 s", modes: str | None = None) -> Path:
    edits = [('stop_time = "12.6 s"', f'stop_time = "{stop}"'), ('settle_time = "0.2 s"', 'settle_time = "0.1 s"')]
    if modes is not None:
        edits.append((MODES_LINE, f"modes = {modes}"))
    return write_variant(SCENARIO, tmp_path / f"{name}.toml", edits)


def run_command(path: Path, out: Path, processes: int) -> dict:
    proc = subprocess.run([sys.executable, "-m", "cosim", "run", str(path), "--out", str(out), "--quiet"],
                          env={**ENV, "COSIM_MODE_PROCESSES": str(processes)}, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    return json.loads((out / "summary.json").read_text())


def test_workers_give_the_results_of_one_process_bit_for_bit(tmp_path):
    path = short(tmp_path, "iso")
    alone = run_command(path, tmp_path / "one", 0)
    side = run_command(path, tmp_path / "three", 3)
    assert alone["mode_processes"] == 0 and side["mode_processes"] == 3
    assert side["sim_time_s"] == pytest.approx(alone["sim_time_s"]) == pytest.approx(1.5)
    assert list(side["modes"]) == list(alone["modes"]) == ["standard", "standard_speed_ff", "model_based"]
    for mode, entry in alone["modes"].items():
        other = side["modes"][mode]
        for key, value in entry.items():
            if key in TIMING:
                continue
            if key == "warnings":  # a compute-budget warning follows the machine's load (CPU time included)
                value = [w for w in value if w.get("kind") != "budget"]
                assert [w for w in other[key] if w.get("kind") != "budget"] == value, mode
            elif key == "fieldbus":
                value = {k: v for k, v in value.items() if k != "log_path"}
                other_value = {k: v for k, v in other[key].items() if k != "log_path"}
                assert value == other_value, mode
            else:
                assert other[key] == value, (mode, key)
    for key in ("improvement_factor", "improvement_factor_rms", "improvement_factor_vs_standard_speed_ff"):
        assert side[key] == alone[key]
    files = sorted(p.name for p in (tmp_path / "one").iterdir() if p.suffix in (".parquet", ".blf"))
    assert len(files) == 12 and files == sorted(p.name for p in (tmp_path / "three").iterdir()
                                                if p.suffix in (".parquet", ".blf"))
    for name in files:
        a, b = tmp_path / "one" / name, tmp_path / "three" / name
        if name.startswith("can_"):  # the CAN log: every frame the same
            fa, fb = read_frames(a), read_frames(b)
            assert np.array_equal(fa.frames, fb.frames) and (fa.start_s, fa.stop_s) == (fb.start_s, fb.stop_s), name
            continue
        (ca, da), (cb, db) = read_series(a), read_series(b)
        keep = [i for i, c in enumerate(ca) if "compute" not in c]  # the controller's wall-clock compute times
        assert ca == cb and np.array_equal(da[:, keep], db[:, keep], equal_nan=True), name


def start(scenario: Path, out: Path, processes: int) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "cosim", "run", str(scenario), "--out", str(out), "--quiet"],
                            env={**ENV, "COSIM_MODE_PROCESSES": str(processes)}, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)


def wait_until_simulating(proc: subprocess.Popen, out: Path, min_sim_s: float, timeout_s: float = 150.0) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        assert proc.poll() is None, proc.communicate()[1]
        try:
            if json.loads((out / "summary.json").read_text()).get("sim_time_s", 0.0) >= min_sim_s:
                return
        except (OSError, ValueError):
            pass
        time.sleep(0.1)
    proc.kill()
    raise AssertionError("the run did not start simulating in time")


def children(pid: int) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    found.append(int(entry.name))
            except (OSError, IndexError, ValueError):
                continue
    return sorted(found)


def workers_of(pid: int) -> list[int]:
    """The mode workers of the ``cosim run`` process ``pid``: its children, or under the supervisor
    (cosim/commands/supervisor.py) the children of the run's process; not the process that draws
    the figures (cosim/results/figure_process.py)."""
    kids = children(pid)
    if len(kids) == 1 and children(kids[0]):
        kids = children(kids[0])
    return [k for k in kids if not is_figure_process(k)]


def is_figure_process(pid: int) -> bool:
    from cosim.results.figure_process import PROCESS_NAME

    try:
        return (Path("/proc") / str(pid) / "comm").read_text().strip() == PROCESS_NAME
    except OSError:
        return False


def alive(pid: int) -> bool:
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_signal_to_the_group_stops_every_worker_in_order(tmp_path, signum):
    path = short(tmp_path, "long", stop="60 s", modes='["standard", "model_based"]')
    out = tmp_path / "out"
    proc = start(path, out, 2)
    wait_until_simulating(proc, out, 0.6)
    workers = workers_of(proc.pid)
    assert len(workers) == 2
    figures = [k for k in children(proc.pid) + [g for c in children(proc.pid) for g in children(c)]
               if is_figure_process(k)]
    assert len(figures) == 1  # forked at the start of `cosim run`, it waits to draw the figures
    os.killpg(proc.pid, signum)
    _, err = proc.communicate(timeout=150)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    name = signal.Signals(signum).name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["signal"] == name and summary["mode"] == "standard"
    by_mode = summary["stopped_at_s_by_mode"]
    assert set(by_mode) == {"standard", "model_based"}
    assert summary["stopped_at_s"] == by_mode["standard"]
    assert summary["sim_time_s"] == pytest.approx(sum(by_mode.values()), abs=0.05)
    for mode, stopped in by_mode.items():
        assert 0.0 < stopped < 60.0
        header, data = read_series(out / f"timeseries_{mode}.parquet")
        assert "plant.q[1]" in header and data[-1, 0] <= stopped + 1e-9 and data[-1, 0] >= stopped - 0.01
        frames = list(open_log(out / f"can_{mode}.parquet"))
        assert len(frames) > 1000 and frames[-1].timestamp <= stopped + 1e-3
    time.sleep(0.5)
    assert not [pid for pid in workers + figures if alive(pid)]


def test_a_killed_worker_fails_the_run_naming_its_mode(tmp_path):
    path = short(tmp_path, "mid", stop="12 s", modes='["standard", "model_based"]')
    out = tmp_path / "out"
    proc = start(path, out, 2)
    wait_until_simulating(proc, out, 0.3)
    workers = workers_of(proc.pid)
    assert len(workers) == 2
    os.kill(workers[1], signal.SIGKILL)  # the second worker started runs model_based
    _, err = proc.communicate(timeout=150)
    assert proc.returncode == 3, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and summary["mode"] == "model_based"
    # killed while simulating, or already evaluating at its end time (a quiet machine is quick)
    assert "died from SIGKILL" in summary["reason"] and 0.0 <= summary["stopped_at_s"] <= 12.0
    assert summary["modes"]["standard"]["status"] == "ok"  # the other mode ran to its end and is evaluated
    assert summary["modes"]["standard"]["sim_time_s"] == pytest.approx(12.0)
