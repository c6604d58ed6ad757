"""``cosim serve`` as the docs describe it, checked with a controller that imports nothing of
the project (examples/socket_controller.py: ``socket`` and ``struct`` only):

* the PRes of cycle k carries the drives' position latched at t_k: floor(q_motor(t_k) ·
  counts_per_rad) of the plant, to the encoder count, for every node and cycle;
* the CAN log keeps the SoC counter the controller sent, also when its first group lands in a
  later cell cycle (the counter is not the cell's own cycle number);
* the example controller (examples/hil_external_controller.py) disables the drives before it
  stops and the run ends without a communication fault.

2 ms bus cycle, as the other served tests (the suite shares two cores)."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from fieldbus.canlog import read_frames
from realtime_support import hil_scenario

ROOT = Path(__file__).resolve().parents[3]
CONTROLLER = ROOT / "examples" / "socket_controller.py"
EXAMPLE = ROOT / "examples" / "hil_external_controller.py"
PORT = 45000 + (os.getpid() % 400) * 10
FIRST_COUNTER = 77  # not the counter of the cell cycle that takes the first group: the mapping is not 0


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    env["MPLBACKEND"] = "Agg"
    return env


def _scenario(tmp: Path, stop_time: str) -> Path:
    # the loss thresholds never trip here: a loaded test machine stalls the served cell (and the
    # controllers) by tens to hundreds of cycles now and then; what is checked is how each run ends
    path = hil_scenario(tmp, stop_time, loss_threshold=0)
    text = path.read_text().replace('signals = ["drive*.current_demand"]',
                                    'signals = ["drive*.current_demand", "plant.q_motor[*]"]')
    path.write_text(text)
    return path


def _ending(out: Path) -> tuple[list[int], dict]:
    """The statuswords of the last PRes of each node in the CAN log, and the served run's report."""
    (can_path,) = out.glob("can_*.parquet")
    frames = read_frames(can_path).frames
    last = []
    for node in range(1, 7):
        pick = np.flatnonzero((frames["id"] == 0x180 + node) & (frames["length"] == 8))
        last.append(int(frames["data"][pick[-1], :2].copy().view("<u2")[0]))
    summary = json.loads((out / "summary.json").read_text())
    (report,) = summary["hil"].values()
    return last, report


def _silent_at_the_end(report: dict) -> int:
    """Cycles lost in a row up to the run's last cycle (a controller that went silent)."""
    runs = report["lost_cycle_runs"]["runs"]
    end = report["cycles"] - 1
    return max([r["length"] for r in runs if r["first_cycle"] + r["length"] - 1 >= end - 1], default=0)


def _serve(scenario: Path, out: Path, port: int, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "cosim", "serve", str(scenario), "--out", str(out), "--quiet",
                             "--channel", f"127.0.0.1:{port}", "--scheduling", "normal", *extra],
                            env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_endpoint(out: Path, serve: subprocess.Popen) -> dict:
    path = out / "hil_endpoint.json"
    deadline = time.monotonic() + 120.0
    while not path.exists():
        if serve.poll() is not None:
            pytest.fail(f"cosim serve ended early: {serve.stderr.read()}")
        assert time.monotonic() < deadline, "no hil_endpoint.json"
        time.sleep(0.05)
    time.sleep(0.3)  # let the cell run some cycles alone: the controller's first group lands in a later one
    return json.loads(path.read_text())


@pytest.fixture(scope="module")
def plain_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wire")
    out = tmp / "out"
    serve = _serve(_scenario(tmp, "3 s"), out, PORT)
    desc = _wait_endpoint(out, serve)
    log = tmp / "controller.txt"
    ctrl = subprocess.run([sys.executable, str(CONTROLLER), desc["cell_channel"], desc["controller_channel"],
                           str(desc["nodes"]), str(FIRST_COUNTER), "300", str(log)],
                          capture_output=True, text=True, timeout=120)
    _, err = serve.communicate(timeout=180)
    assert ctrl.returncode == 0, ctrl.stderr
    return out, desc, log.read_text().split("\n"), serve.returncode, err


def test_pres_of_cycle_k_carries_the_position_latched_at_t_k(plain_run):
    out, desc, _, _, _ = plain_run
    period = desc["cycle_time_s"]
    cpr = np.array(desc["counts_per_rad"])
    (can_path,) = out.glob("can_*.parquet")
    (series_path,) = out.glob("timeseries_*.parquet")
    log = read_frames(can_path)
    frames = log.frames
    t = log.start_s + frames["t_ns"] / 1e9
    series = pq.read_table(series_path).to_pydict()
    rows = {int(round(ts / period)): i for i, ts in enumerate(series["time"])
            if abs(ts / period - round(ts / period)) < 1e-6}
    q_motor = np.array([series[f"plant.q_motor[{j}]"] for j in range(1, 7)]).T
    compared = equal = 0
    for node in range(1, 7):
        pick = np.flatnonzero((frames["id"] == 0x180 + node) & (frames["length"] == 8))
        cycles = np.floor(t[pick] / period + 1e-6).astype(int)  # the cell stamps its frames on its cycle schedule
        positions = frames["data"][pick, 2:6].copy().view("<i4").ravel()
        for k, p in zip(cycles.tolist(), positions.tolist()):
            if k in rows:
                compared += 1
                equal += p == math.floor(q_motor[rows[k], node - 1] * cpr[node - 1])
    assert compared > 6 * 1000
    assert equal == compared, f"{equal} of {compared} node-cycles carry floor(q_motor(t_k) counts_per_rad)"


def test_the_can_log_keeps_the_counter_the_controller_sent(plain_run):
    out, desc, lines, _, _ = plain_run
    period = desc["cycle_time_s"]
    sent = [int(line.split()[1]) for line in lines if line.startswith("S ")]
    (can_path,) = out.glob("can_*.parquet")
    log = read_frames(can_path)
    frames = log.frames
    socs = frames[frames["id"] == 0x080]
    counters = socs["data"][:, 0].tolist()
    # the cycle column is the cell's own cycle of every frame: each frame lies in that cycle's
    # window of the cell's schedule (a jittered SoC up to a few us before its nominal start)
    phase = log.timestamps / period - log.cycles
    assert log.cycles is not None and phase.min() > -0.01 and phase.max() < 1
    assert (np.diff(log.cycles) >= 0).all() and np.array_equal(np.unique(log.cycles), np.arange(log.cycles[-1] + 1))
    soc_cycles = log.cycles[frames["id"] == 0x080]
    assert np.unique(soc_cycles).size == soc_cycles.size  # one SoC per cell cycle at most
    cycles = log.cycles[frames["id"] == 0x080]
    own = ((cycles % desc["sync_counter_overflow"]) + 1).tolist()
    assert counters[0] == FIRST_COUNTER != own[0]  # the first group fixes the mapping; logged as sent
    assert cycles[0] > 0  # the first group landed in a later cell cycle
    assert set(counters) <= set(sent)  # every logged SoC carries a counter the controller sent
    # (where the controller's counter drifts from the cell's cycles - a stall of either - the cell
    # re-synchronises the mapping; the log still shows the counters as they were on the wire)


def test_pandas_reads_the_wire_counter_beside_the_cells_cycle(plain_run):
    """pandas alone (no project code) lines up the SoC counter on the wire with the cell's cycle."""
    import pandas as pd

    out, desc, _, _, _ = plain_run
    (can_path,) = out.glob("can_*.parquet")
    table = pd.read_parquet(can_path, columns=["seq", "cycle", "id", "sync_counter"]).sort_values("seq")
    socs = table[table["id"] == 0x080]
    log = read_frames(can_path)
    wire = log.frames["data"][log.frames["id"] == 0x080, 0]
    assert str(table["cycle"].dtype) == "int64" and not table["cycle"].isna().any()
    assert socs["sync_counter"].tolist() == wire.tolist()
    assert socs["cycle"].tolist() == log.cycles[log.frames["id"] == 0x080].tolist()
    assert int(socs["sync_counter"].iloc[0]) == FIRST_COUNTER
    assert int(socs["cycle"].iloc[0]) % desc["sync_counter_overflow"] + 1 != FIRST_COUNTER
    assert table["cycle"].is_monotonic_increasing  # in log (time) order


def test_the_plain_controller_enables_and_disables_without_a_fault(plain_run):
    out, _, lines, _, _ = plain_run
    received = [line.split() for line in lines if line.startswith("R ")]
    assert any(all(int(sw) & 0x6F == 0x27 for sw in row[1:7]) for row in received)  # enabled on the way
    last, report = _ending(out)
    assert all(sw & 0x6F == 0x21 for sw in last), [hex(s) for s in last]  # Ready to switch on at the end
    assert _silent_at_the_end(report) == 0


def test_the_example_controller_ends_with_the_drives_disabled_and_no_fault(tmp_path):
    """The example disables the drives after its motion and cycles on until the cell stops: the
    last PRes show Ready to switch on (no fault) and no cycle is lost at the end of the run (with
    the default thresholds the old example's silence tripped all six drives there). As the quick
    start: the cell waits for the controller's first datagram, so the run's 4 s start with it."""
    out = tmp_path / "out"
    serve = _serve(_scenario(tmp_path, "4 s"), out, PORT + 5, "--wait-for-controller", "60")
    _wait_endpoint(out, serve)
    ctrl = subprocess.run([sys.executable, str(EXAMPLE), str(out / "hil_endpoint.json"), "--amplitude", "0.2",
                           "--duration", "1.0"], env=_env(), capture_output=True, text=True, timeout=120)
    serve.communicate(timeout=180)
    assert ctrl.returncode == 0, ctrl.stderr
    assert "drives disabled" in ctrl.stdout, ctrl.stdout + ctrl.stderr
    last, report = _ending(out)
    assert all(sw & 0x6F == 0x21 for sw in last), [hex(s) for s in last]
    assert _silent_at_the_end(report) == 0
    assert report["fault_reactions"] == []
    # the summary describes the external controller's run, no placeholders of the job's controller
    summary = json.loads((out / "summary.json").read_text())
    (entry,) = summary["modes"].values()
    assert entry["controller"] == "external (cosim serve)"
    assert 0.0 <= entry["enabled_at_s"] < entry["motion_start_s"] < entry["motion_end_s"] < entry["enabled_until_s"]
    assert entry["motion_end_s"] - entry["motion_start_s"] == pytest.approx(1.0, abs=0.1)  # --duration 1.0
    assert entry["enabled_at_end"] is False
    for placeholder in ("controller_phase", "residual_vibration", "evaluated_samples", "path_completed",
                        "tcp_error_max_mm"):
        assert placeholder not in entry


def test_the_overrun_report_tells_a_stall_of_the_process_from_its_own_work():
    """Cycle 1: the pacer was woken 900 us late from its sleep (the machine); cycle 2: the work
    before it took 900 us of wall time but 50 us of CPU (descheduled); cycle 3: 900 us of CPU
    (the cell's own work); cycle 4: late with neither (other)."""
    from types import SimpleNamespace

    from cosim.execution.cell_side import overrun_causes
    from cosim.execution.timing.pacer import LatenessLog

    log = LatenessLog(16)
    us = 1000
    log.append(0, 0, False, -1, 100 * us)
    log.append(1, 950 * us, True, 100 * us, 900 * us)
    log.append(2, 600 * us, True, 900 * us, -1)
    log.append(3, 600 * us, True, 900 * us, -1)
    log.append(4, 300 * us, True, 100 * us, 10 * us)
    wall = np.array([100, 900, 900, 100, 0, 0]) * us  # index k-1: the work before cycle k
    cpu = np.array([100, 50, 900, 100, 0, 0]) * us
    link = SimpleNamespace(after_wall_ns=wall, after_cpu_ns=cpu, cycle=5)
    report = overrun_causes(link, SimpleNamespace(log=log, period_ns=400 * us))
    assert (report["stalled"], report["own_work"], report["other"]) == (2, 1, 1)
    assert report["stalls"] == {"woken_late": 1, "descheduled": 1}
    assert [e["cause"] for e in report["examples"]] == ["woken_late", "descheduled", "own_work", "other"]
    assert report["woken_late_us"]["max_us"] == 900.0
