"""A run's process that dies without writing its status still leaves a final one (the supervisor,
cosim/commands/supervisor.py): an FMU running in process that calls ``_exit()``, SIGKILL of the run's
process (what the out-of-memory killer sends), of a sweep's process, and of the supervisor itself.

The runs are real ``python -m cosim`` processes; the run's process is the child whose pid the
results folder's lock file holds (``<out>/.cosim.lock``).
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from c_test_fmus import build_misbehave_fmu
from cosim.results import lastwords, read_series
from scenario_files import write_variant

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
ENV.pop("COSIM_SUPERVISE", None)

MISBEHAVE = """
connections = ["clock.y -> bad.u"]

[scenario]
name = "misbehave"
job = "fmus"

[simulation]
stop_time = 2.0
macro_step = 0.001

[[fmus]]
name = "clock"
path = "Misbehave.fmu"

[[fmus]]
name = "bad"
path = "Misbehave.fmu"

[fmus.parameters]
mode = 4
fail_time = 1.5

[record]
period = 0.01
signals = ["clock.y", "bad.y", "bad.echo"]
"""


def cosim(*args: str, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "cosim", *args], env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True, **kwargs)


def summary_of(path: Path) -> dict:
    return json.loads(path.read_text())


def wait_for(predicate, proc: subprocess.Popen, timeout_s: float = 120.0, what: str = "") -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()[1]
        try:
            if predicate():
                return
        except (OSError, ValueError, KeyError):
            pass
        time.sleep(0.1)
    proc.kill()
    raise AssertionError(f"timed out waiting for {what}")


def run_process(out: Path) -> int:
    """The pid of the process running into ``out`` (written into the lock file by the run)."""
    return int((out / ".cosim.lock").read_text().split()[0])


def gone(pid: int) -> bool:
    try:
        state = (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return True
    return state == "Z"


def test_in_process_fmu_that_calls_exit_leaves_failed(tmp_path):
    build_misbehave_fmu(tmp_path)
    path = tmp_path / "s.toml"
    path.write_text(MISBEHAVE)
    out = tmp_path / "out"
    proc = cosim("run", str(path), "--out", str(out), "--quiet")
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 3, err  # a failed run (the process's own code is in the summary)
    assert "Traceback" not in err and "exited with code 3 without writing its final status" in err
    summary = summary_of(out / "summary.json")
    assert summary["status"] == "failed" and summary["exit_code"] == 3 and summary["job"] == "fmus"
    assert "_exit()" in summary["reason"] and "job fmus, t = 1.49" in summary["reason"]
    assert 1.45 <= summary["stopped_at_s"] <= 1.5  # the heartbeat's last note before the FMU's exit at 1.5 s
    assert summary["status_written_by"] == "supervisor"
    header, data = read_series(out / "timeseries.parquet")  # the stream is readable (rows of the last flush)
    assert header == ["time", "clock.y", "bad.y", "bad.echo"]
    assert data.shape[1] == 4 and (data.size == 0 or data[-1, 0] <= 1.5)
    assert not (out / "summary.json.tmp").exists()


def test_sigkill_of_the_run_process_leaves_failed_with_where(tmp_path):
    """What the out-of-memory killer does: SIGKILL to the run's process during the ISO job's first mode."""
    text = (ROOT / "scenarios" / "iso9283_rigid.toml").read_text()
    path = write_variant(text, tmp_path / "iso.toml",
                         [('modes = ["standard", "standard_speed_ff", "model_based"]', 'modes = ["standard"]'),
                          ('stop_time = "12.6 s"', 'stop_time = "60 s"')])
    out = tmp_path / "out"
    proc = cosim("run", str(path), "--out", str(out), "--quiet")
    wait_for(lambda: summary_of(out / "summary.json")["sim_time_s"] >= 0.5, proc, what="0.5 s simulated")
    time.sleep(1.5)  # a flush of the time series (every second of wall time)
    os.kill(run_process(out), signal.SIGKILL)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL, err  # the supervisor ends as its child did: 137 in a shell
    assert "Traceback" not in err and "killed by SIGKILL" in err
    summary = summary_of(out / "summary.json")
    assert summary["status"] == "failed" and summary["signal"] == "SIGKILL" and summary["exit_code"] == 137
    assert summary["mode"] == "standard" and summary["failed_in"] == "standard" and summary["job"] == "iso9283"
    assert "out-of-memory" in summary["reason"] and "mode standard, t = " in summary["reason"]
    stopped = summary["stopped_at_s"]
    assert 0.5 <= stopped < 60.0
    header, data = read_series(out / "timeseries_standard.parquet")  # the stream up to its last flush
    assert "plant.q[1]" in header and data.shape[0] > 100 and data[-1, 0] <= stopped + 0.2
    # the lock died with the process: the folder takes the next run
    again = subprocess.run([sys.executable, "-m", "cosim", "run", str(ROOT / "scenarios" / "plant_drop.toml"),
                            "--out", str(out), "--quiet"], env=ENV, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr


def test_sigkill_of_the_supervisor_interrupts_the_run(tmp_path):
    """The supervisor killed: its child gets SIGHUP (PR_SET_PDEATHSIG) and ends interrupted."""
    text = (ROOT / "scenarios" / "plant_drop.toml").read_text()
    path = write_variant(text, tmp_path / "long.toml", [("stop_time = 0.5", "stop_time = 3000.0")])
    out = tmp_path / "out"
    proc = cosim("run", str(path), "--out", str(out), "--quiet")
    wait_for(lambda: summary_of(out / "summary.json")["sim_time_s"] > 0.0, proc, what="the run to start")
    child = run_process(out)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=30)
    deadline = time.monotonic() + 60
    while not gone(child) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert gone(child)
    summary = summary_of(out / "summary.json")
    assert summary["status"] == "interrupted" and summary["signal"] == "SIGHUP" and summary["stopped_at_s"] > 0
    _, data = read_series(out / "timeseries.parquet")
    assert data.shape[0] > 0


def test_sigkill_of_a_sweep_fails_the_sweep_and_its_running_variants(tmp_path):
    base = write_variant((ROOT / "scenarios" / "plant_drop.toml").read_text(), tmp_path / "base.toml", [])
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(f'[sweep]\nname = "s"\nbase = "{base.name}"\n[[axes]]\nkey = "simulation.stop_time"\n'
                     f'values = [300.0, 300.1]\n')
    out = tmp_path / "out"
    proc = cosim("sweep", str(sweep), "--out", str(out), "--workers", "1", "--quiet")
    wait_for(lambda: any(summary_of(p)["sim_time_s"] > 0 for p in out.glob("variants/*/summary.json")), proc,
             what="a variant to run")
    children = [int(p) for p in (Path("/proc") / str(proc.pid) / "task" / str(proc.pid) / "children")
                .read_text().split()]
    assert len(children) == 1
    os.kill(children[0], signal.SIGKILL)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL, err
    definition = summary_of(out / "sweep.json")
    assert definition["status"] == "failed" and definition["signal"] == "SIGKILL"
    statuses = [summary_of(p) for p in out.glob("variants/*/summary.json")]
    assert statuses and all(s["status"] != "running" for s in statuses)
    assert any(s["status"] == "failed" and "sweep.json" in s["reason"] for s in statuses)


def test_the_table_keeps_the_last_complete_entry():
    """Two halves per slot: an entry is replaced only once the new one is complete; long fields are
    left out rather than the entry; retracted entries are gone; a forked worker does not publish."""
    table = lastwords.create(slots=2)
    try:
        lastwords.adopt()
        lastwords.publish("/x/summary.json", {"status": "running", "sim_time_s": 1.0, "stopped_at_s": 1.0})
        lastwords.note_time("/x/summary.json", 2.5, 0.5)
        lastwords.publish("/y/summary.json", {"status": "running", "log": ["m" * 1000] * 1000, "sim_time_s": 0.0})
        entries = {e["path"]: e for e in table.entries()}
        assert entries["/x/summary.json"]["data"]["sim_time_s"] == 2.5
        assert entries["/x/summary.json"]["data"]["stopped_at_s"] == 0.5
        assert entries["/y/summary.json"]["data"]["log"].startswith("(left out")
        # a write torn by the process's death: only the unused half was touched, the current one stands
        used, current, *_ = lastwords._HEADER.unpack_from(table.memory, 0)
        start = lastwords._HEAD_BYTES + (1 - current) * lastwords.HALF_BYTES
        table.memory[start:start + 5] = b"{torn"
        assert {e["path"] for e in table.entries()} == {"/x/summary.json", "/y/summary.json"}
        lastwords.publish("/z/summary.json", {"status": "running"})  # no free slot: dropped, not overwritten
        lastwords.retract("/y/summary.json")
        assert [e["path"] for e in table.entries()] == ["/x/summary.json"]
        pid = os.fork()
        if pid == 0:  # a worker forked from the run's process
            lastwords.publish("/w/summary.json", {"status": "running"})
            os._exit(0)
        os.waitpid(pid, 0)
        assert [e["path"] for e in table.entries()] == ["/x/summary.json"]
    finally:
        lastwords._table = lastwords._owner = None
        lastwords._slots.clear()


def test_third_interrupt_ends_a_run_stuck_in_an_in_process_fmu(tmp_path):
    """An FMU hanging in fmi2DoStep in process: no Python handler runs, so Ctrl-C cannot stop the run
    itself; the third interrupt makes the supervisor kill it and write interrupted (exit 130)."""
    build_misbehave_fmu(tmp_path)
    path = tmp_path / "s.toml"
    path.write_text(MISBEHAVE.replace("mode = 4", "mode = 5"))  # hangs from 1.5 s on
    out = tmp_path / "out"
    proc = cosim("run", str(path), "--out", str(out), "--quiet")
    wait_for(lambda: summary_of(out / "summary.json")["status"] == "running", proc, what="the run to start")
    time.sleep(3.0)  # 1.5 s simulated take well under a second: it hangs now
    for _ in range(3):
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C, three times
        time.sleep(0.5)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "did not end after 3 interrupts" in err
    summary = summary_of(out / "summary.json")
    assert summary["status"] == "interrupted" and summary["signal"] == "SIGINT"
    assert "stuck in native code" in summary["reason"] and 1.4 <= summary["stopped_at_s"] <= 1.5
    assert gone(run_process(out))
