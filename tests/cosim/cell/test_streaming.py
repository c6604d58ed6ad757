"""The robot cell's jobs stream every series as the run goes: a SIGKILLed run leaves the
mode in progress readable (recording and controller log) up to near the kill; the log and
the compute-time statistics hold bounded memory; the chunked evaluation gives the same
figures as one pass over whole arrays."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from controller import ControllerLog
from controller.controller import LOG_COLUMNS
from controller.cycle_timer import CycleTimer
from cosim.results.timeseries import ParquetSink, iter_series, last_row, read_series, tail, write_columns

ROOT = Path(__file__).resolve().parents[3]


def _scenario(tmp_path: Path, stop_time: str) -> Path:
    text = (ROOT / "scenarios" / "iso9283_rigid.toml").read_text(encoding="utf-8")
    text = text.replace('stop_time = "12.6 s"', f'stop_time = "{stop_time}"')
    text = text.replace('modes = ["standard", "standard_speed_ff", "model_based"]', 'modes = ["standard"]')
    text = text.replace("can_log = true", "can_log = false").replace("figures = true", "figures = false")
    path = tmp_path / "cell.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _children(pid: int) -> list[int]:
    try:
        return [int(x) for x in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def test_sigkilled_cell_run_leaves_the_running_mode_readable(tmp_path):
    scenario = _scenario(tmp_path, "40 s")
    out = tmp_path / "out"
    env = dict(os.environ, COSIM_FLUSH_INTERVAL_S="0.25", PYTHONPATH=os.pathsep.join(
        [str(ROOT), os.environ.get("PYTHONPATH", "")]))
    child = subprocess.Popen([sys.executable, "-m", "cosim", "run", str(scenario), "--out", str(out), "--quiet"],
                             cwd=tmp_path, env=env, start_new_session=True, stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE)
    reached = 0.0
    deadline = time.monotonic() + 240
    try:
        while time.monotonic() < deadline and child.poll() is None:
            time.sleep(0.2)
            try:
                reached = float(json.loads((out / "summary.json").read_text()).get("sim_time_s") or 0.0)
            except (OSError, ValueError):
                continue
            if reached >= 6.0:
                break
        assert child.poll() is None, f"the run ended before the kill: {child.stderr.read()[-2000:]}"
        # python -m cosim run forks: the process that runs the job is the supervisor's child
        runner = _children(child.pid) or [child.pid]
        for pid in runner:
            os.kill(pid, signal.SIGKILL)
        child.wait(60)  # the supervisor notices and writes the final status
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
            child.wait(30)
    assert reached >= 6.0
    series = out / "timeseries_standard.parquet.partial"
    log = out / "controller_standard.parquet.partial"
    assert series.exists() and log.exists() and not (out / "tcp_standard.parquet").exists()
    names, data = read_series(series)
    assert names[0] == "time" and "plant.q[1]" in names and "tracker.x" in names
    log_names, log_data = read_series(log)
    assert log_names == list(LOG_COLUMNS)
    # up to near the kill: the summary's last heartbeat was at most 2 s of wall time before it;
    # rows reach the disk at least every 0.25 s of wall time (and in 1024-row blocks)
    for t in (data[:, 0], log_data[:, 0]):
        assert np.all(np.diff(t) > 0) and t[0] < 0.01
        assert t[-1] >= reached - 3.5, (t[-1], reached)
    assert np.isfinite(data).all()
    assert np.allclose(np.diff(log_data[:, 0]), 400e-6, rtol=1e-6)  # every cycle, none missing
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] != "running"  # the supervisor's final status (cosim/results/lastwords.py)


def test_streaming_log_holds_one_block(tmp_path):
    sink = ParquetSink(tmp_path / "c.parquet", buffer_rows=300, flush_interval_s=0.0)
    log = ControllerLog(capacity=10 ** 7)
    assert log.scalars.shape[0] <= 1 << 22  # address space only, and given back when streaming starts
    rows = []
    for k in range(5):  # rows before streaming go first
        log.append(k * 4e-4, k * 4e-4 + 8e-4, 1, 0.0, *(np.full(6, k + 0.5 * g) for g in range(6)), 3.0, 1)
    log.stream_to(sink, block_rows=64)
    for k in range(5, 1000):
        log.append(k * 4e-4, k * 4e-4 + 8e-4, 2, k * 1e-3, *(np.full(6, k + 0.5 * g) for g in range(6)), float(k), 0)
        assert log.scalars.shape[0] == 64
    rows = log.total_rows
    log.close_stream()
    names, data = read_series(tmp_path / "c.parquet")
    assert names == list(LOG_COLUMNS) and rows == 1000 and data.shape == (1000, len(LOG_COLUMNS))
    assert np.array_equal(data[:, 0], np.arange(1000) * 4e-4)
    assert np.array_equal(data[:, names.index("target3")], np.arange(1000) + 2.0)
    assert np.array_equal(data[:, names.index("q_obs6")], np.arange(1000) + 2.5)
    assert data[:5, names.index("phase")].tolist() == [1] * 5 and data[5:, names.index("phase")].max() == 2


def test_cycle_timer_folds_long_runs_into_a_histogram(monkeypatch):
    import controller.cycle_timer as cycle_timer

    monkeypatch.setattr(cycle_timer, "EXACT_CYCLES", 1000)
    durations = np.random.default_rng(1).lognormal(10.0, 0.4, 20000).astype(np.int64)
    timer = CycleTimer(50e-6, capacity=10 ** 7)
    for d in durations:
        timer.record(int(d), int(d) // 2)
    assert timer.durations_ns.size <= 1000 and not timer.exact
    s = timer.summary()
    assert s.cycles == 20000 and s.wall_over_budget == int((durations > 50000).sum())
    assert s.deadline_basis == "cpu_time" and s.deadline_misses == s.cpu_over_budget == int((durations // 2 > 50000).sum())
    assert s.max_us == durations.max() * 1e-3 and abs(s.mean_us - durations.mean() * 1e-3) < 1e-9 * s.mean_us
    assert abs(s.p50_us / (np.percentile(durations, 50) * 1e-3) - 1) < 0.005
    assert abs(s.p99_us / (np.percentile(durations, 99) * 1e-3) - 1) < 0.02


def test_chunked_readers(tmp_path):
    t = np.arange(10000) * 1e-3
    write_columns(tmp_path / "s.parquet", {"time": t, "x": np.sin(t)})
    write_columns(tmp_path / "s.csv", {"time": t, "x": np.sin(t)})
    for path in (tmp_path / "s.parquet", tmp_path / "s.csv"):
        blocks = [b for _, b in iter_series(path, ["x", "time"], rows=999)]
        assert max(len(b) for b in blocks) <= 1024
        whole = np.concatenate(blocks)
        assert np.array_equal(whole[:, 1], t) and np.array_equal(whole[:, 0], np.sin(t))
        assert last_row(path, ["time"])[0] == t[-1]
        _, end = tail(path, 0.5, ["time", "x"])
        assert end[0, 0] == t[t >= t[-1] - 0.5][0] and end[-1, 0] == t[-1]
