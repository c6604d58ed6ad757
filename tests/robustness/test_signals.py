"""SIGTERM and SIGINT end a run cleanly: exit 130, summary.json ``interrupted`` with the signal, the
mode and ``stopped_at_s``, and everything recorded so far readable (time series, CAN log).

The runs are real ``python -m cosim run`` processes started with ``sys.executable``; SIGINT goes
to the whole process group, as Ctrl-C in a terminal does (the CAN-log writer child must not
die first).
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cosim.results import read_series
from scenario_files import write_variant

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}


def start(scenario: Path, out: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "cosim", "run", str(scenario), "--out", str(out), "--quiet",
                             *extra], env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)


def wait_until_simulating(proc: subprocess.Popen, out: Path, min_sim_s: float, timeout_s: float = 120.0) -> dict:
    """Poll summary.json until the run has simulated ``min_sim_s`` (the heartbeat rewrites it every 2 s)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        assert proc.poll() is None, proc.communicate()[1]
        try:
            data = json.loads((out / "summary.json").read_text())
            if data.get("sim_time_s", 0.0) >= min_sim_s:
                return data
        except (OSError, ValueError):
            pass
        time.sleep(0.1)
    proc.kill()
    raise AssertionError("the run did not start simulating in time")


def finish(proc: subprocess.Popen) -> tuple[int, str]:
    _, err = proc.communicate(timeout=120)
    assert "Traceback" not in err, err
    return proc.returncode, err


def read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    """The time series (Parquet, the default format) of ``path``'s stem."""
    return read_series(path.with_suffix(".parquet"))


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_fmus_job_interrupted_keeps_its_time_series(tmp_path, signum):
    text = (ROOT / "scenarios" / "plant_drop.toml").read_text()
    path = write_variant(text, tmp_path / "long.toml", [("stop_time = 0.5", "stop_time = 3000.0")])
    out = tmp_path / "out"
    proc = start(path, out)
    wait_until_simulating(proc, out, 0.5)
    os.kill(proc.pid, signum)
    code, err = finish(proc)
    assert code == 130, err
    name = signal.Signals(signum).name
    assert f"interrupted by {name}" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["signal"] == name and summary["job"] == "fmus"
    assert 0.5 <= summary["stopped_at_s"] < 3000.0
    assert summary["sim_time_s"] == pytest.approx(summary["stopped_at_s"])
    header, data = read_csv(out / "timeseries.parquet")
    assert header[0] == "time" and data.shape[0] >= 400  # rows every 1 ms up to where it stopped
    assert data[-1, 0] <= summary["stopped_at_s"] + 1e-9
    assert np.all(np.isfinite(data))
    assert not (out / "summary.json.tmp").exists()
    # the lock is released: the folder takes the next run
    short = write_variant(text, tmp_path / "short.toml", [("stop_time = 0.5", "stop_time = 0.01")])
    again = subprocess.run([sys.executable, "-m", "cosim", "run", str(short), "--out", str(out), "--quiet"],
                           env=ENV, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr


PYTHON_FMUS = """
connections = ["i.y -> s.u"]

[scenario]
name = "python_fmus"
job = "fmus"

[simulation]
stop_time = 3000.0
macro_step = 0.001

[[fmus]]
name = "i"
path = "Integrator.fmu"
[fmus.parameters]
u = 1.0

[[fmus]]
name = "s"
path = "Sampler.fmu"

[[fmus]]
name = "x"
path = "Interrupter.fmu"
[fmus.parameters]
signal_time = 0.5

[record]
period = 0.01
signals = ["i.y", "s.y", "x.y"]
"""


def test_ctrl_c_inside_a_python_fmu_is_an_interrupt(tmp_path):
    """FMUs implemented in Python (pythonfmu) run their model in the run's interpreter: SIGINT that
    arrives while one computes raises inside its do_step, which pythonfmu reports as an FMI error.
    The run still ends as interrupted (exit 130, the signal, no FMU blamed), with its rows up to where
    it stopped. The Interrupter FMU sends the SIGINT from inside its own do_step at 0.5 s."""
    from cosim_fmu_models import build_test_fmu

    for model in ("integrator", "sampler", "interrupter"):
        build_test_fmu(model, tmp_path)
    path = tmp_path / "python_fmus.toml"
    path.write_text(PYTHON_FMUS, encoding="utf-8")
    out = tmp_path / "out"
    proc = start(path, out)
    code, err = finish(proc)
    assert code == 130, err
    assert "interrupted by SIGINT" in err and "run failed" not in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["signal"] == "SIGINT", summary
    assert "failed_component" not in summary or summary["failed_component"] is None
    assert summary["stopped_at_s"] == pytest.approx(0.5, abs=1.5e-3)
    header, data = read_csv(out / "timeseries.parquet")
    assert header == ["time", "i.y", "s.y", "x.y"]
    assert data[-1, 0] == pytest.approx(0.5) and data.shape[0] == 51  # every 10 ms sample up to 0.5 s
    assert np.allclose(data[:, 1], data[:, 0], atol=1e-9)  # y = u t with u = 1, rows intact


def test_main_job_ctrl_c_to_the_process_group(tmp_path):
    """Ctrl-C (SIGINT to the group) during the first mode of the ISO job with the CAN log written by a
    background process: the mode's time series and CAN log are complete up to the stop."""
    from fieldbus.canlog import open_log

    text = (ROOT / "scenarios" / "iso9283.toml").read_text()
    # 60 s: the path and then a long standstill, so a fast machine is still simulating when Ctrl-C comes
    path = write_variant(text, tmp_path / "iso.toml",
                         [('modes = ["standard", "model_based", "model_based_elastic"]', 'modes = ["standard"]'),
                          ('stop_time = "12.6 s"', 'stop_time = "60 s"')])
    out = tmp_path / "out"
    proc = start(path, out)
    wait_until_simulating(proc, out, 0.3)
    os.killpg(proc.pid, signal.SIGINT)
    code, err = finish(proc)
    assert code == 130, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["signal"] == "SIGINT"
    assert summary["mode"] == "standard" and summary["job"] == "iso9283"
    stopped = summary["stopped_at_s"]
    assert 0.3 <= stopped < 60.0
    header, data = read_csv(out / "timeseries_standard.parquet")
    assert "plant.q[1]" in header and data.shape[0] >= 250
    assert stopped - 0.01 <= data[-1, 0] <= stopped + 1e-9  # recorded up to where it stopped
    frames = list(open_log(out / "can_standard.parquet"))
    assert len(frames) > 1000
    assert frames[-1].timestamp <= stopped + 1e-3


def test_split_run_ctrl_c_ends_the_drive_process_in_order(tmp_path):
    """--split: controller here, drives and plant in a child process; Ctrl-C to the process group. The
    drive process ignores it, gets the end marker, writes its rows; the mode's time series is kept."""
    text = (ROOT / "scenarios" / "iso9283.toml").read_text()
    path = write_variant(text, tmp_path / "iso.toml",
                         [('modes = ["standard", "model_based", "model_based_elastic"]', 'modes = ["standard"]')])
    out = tmp_path / "out"
    proc = start(path, out, "--split")
    log = out / "can_standard.parquet.partial"  # the columnar CAN log's stream while the run goes
    deadline = time.monotonic() + 150
    while time.monotonic() < deadline:  # the CAN log grows as the cycles run (flushed every 0.1 s simulated)
        assert proc.poll() is None, proc.communicate()[1]
        if log.exists() and log.stat().st_size > 100_000:
            break
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGINT)
    code, err = finish(proc)
    assert code == 130, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["mode"] == "standard"
    stopped = summary["stopped_at_s"]
    assert 0.0 < stopped < 12.6 and summary["sim_time_s"] == pytest.approx(stopped, abs=1e-3)
    header, data = read_csv(out / "timeseries_standard.csv")
    assert "plant.q[1]" in header and data.shape[0] > 100
    assert abs(data[-1, 0] - stopped) < 0.05  # the drive side recorded up to about where it stopped


def test_sweep_interrupted_closes_its_workers_and_says_so(tmp_path):
    """SIGTERM to the sweep's process group: the embedded Dask workers ignore it and are closed by the
    sweep; finished variants stay ok, the running ones and sweep.json say interrupted; exit 130."""
    base = write_variant((ROOT / "scenarios" / "plant_drop.toml").read_text(), tmp_path / "base.toml", [])
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(f'[sweep]\nname = "s"\nbase = "{base.name}"\n[[axes]]\nkey = "simulation.stop_time"\n'
                     f'values = [300.0, 300.1, 300.2, 300.3]\n')  # long: still running when SIGTERM comes
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "cosim", "sweep", str(sweep), "--out", str(out), "--workers", "2",
                             "--quiet"], env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not list(out.glob("variants/*/summary.json")):
        assert proc.poll() is None, proc.communicate()[1]
        time.sleep(0.2)
    time.sleep(1.0)
    children = descendants(proc.pid)
    assert children  # the cluster's nanny and worker processes
    os.killpg(proc.pid, signal.SIGTERM)
    code, err = finish(proc)
    assert code == 130, err
    time.sleep(1.0)
    assert not [pid for pid in children if alive(pid)]  # no worker process survived the sweep
    statuses = {p.parent.name: json.loads(p.read_text())["status"] for p in out.glob("variants/*/summary.json")}
    assert statuses and set(statuses.values()) <= {"ok", "interrupted"} and "interrupted" in statuses.values()
    assert json.loads((out / "sweep.json").read_text())["status"] == "interrupted"


def descendants(pid: int) -> list[int]:
    """Process ids below ``pid`` (children, grandchildren, ...), from /proc."""
    parents: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            parents.setdefault(ppid, []).append(int(entry.name))
    found, todo = [], [pid]
    while todo:
        for child in parents.get(todo.pop(), []):
            found.append(child)
            todo.append(child)
    return found


def alive(pid: int) -> bool:
    try:
        state = (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"
