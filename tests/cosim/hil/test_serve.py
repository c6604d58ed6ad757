"""``python -m cosim serve``: the cell side of a hardware-in-the-loop run, driven by the
minimal external controller of examples/ (python-can + the documented telegrams only) in
another process; its death makes the cell's counters trip and the drives stop the arm.

The served cell runs on the wall clock. The test suite shares two cores with other
tests, so these runs use a 2 ms bus cycle (the same code paths as 400 µs, more slack);
the 400 µs figures are benchmarks (benchmarks/bench_hil.py, ``cosim bench``)."""
from __future__ import annotations

import json
import os
import select
import signal
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import can

from fieldbus.canlog import open_log
import numpy as np
import pandas as pd
import pytest

from cosim.api import RunResult
from realtime_support import hil_scenario

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "examples" / "hil_external_controller.py"
PORT = 46000 + (os.getpid() % 400) * 10


def _scenario(tmp_path: Path, stop_time: str = "5 s") -> Path:
    # a loaded test machine stalls a process by milliseconds now and then: the counters
    # trip after 10 lost cycles here (20 ms) instead of 2, a stop of the controller still trips them
    return hil_scenario(tmp_path, stop_time, loss_threshold=80)


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    env["MPLBACKEND"] = "Agg"
    return env


def _serve(scenario: Path, out: Path, port: int, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "cosim", "serve", str(scenario), "--out", str(out), "--quiet",
                             "--channel", f"127.0.0.1:{port}", "--scheduling", "normal", *extra],
                            env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_endpoint(out: Path, serve: subprocess.Popen, timeout: float = 120.0) -> dict:
    path = out / "hil_endpoint.json"
    deadline = time.monotonic() + timeout
    while not path.exists():
        if serve.poll() is not None:
            pytest.fail(f"cosim serve ended early: {serve.stderr.read()}")
        assert time.monotonic() < deadline, "no hil_endpoint.json"
        time.sleep(0.05)
    return json.loads(path.read_text())


def _controller(endpoint: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(EXAMPLE), str(endpoint), *extra], env=_env(), capture_output=True,
                          text=True, timeout=120)


@pytest.fixture(scope="module")
def served_then_killed(tmp_path_factory):
    """One served run: the example controller enables the drives, moves, and goes silent
    mid-motion (--stop-after), as if killed."""
    tmp = tmp_path_factory.mktemp("hil")
    out = tmp / "out"
    serve = _serve(_scenario(tmp, "8 s"), out, PORT)
    desc = _wait_endpoint(out, serve)
    ctrl = _controller(out / "hil_endpoint.json", "--amplitude", "0.3", "--duration", "2.0", "--stop-after", "1.3")
    _, err = serve.communicate(timeout=180)
    return out, desc, ctrl, serve.returncode, err


def test_endpoint_description_names_what_a_controller_needs(served_then_killed):
    _, desc, _, _, _ = served_then_killed
    assert desc["interface"] == "udpcycle" and desc["cell_channel"] == f"127.0.0.1:{PORT}"
    assert desc["nodes"] == 6 and desc["cycle_time_s"] == pytest.approx(2e-3)
    assert len(desc["counts_per_rad"]) == 6 and len(desc["q_start_rad"]) == 6


def test_external_controller_enables_and_moves_the_arm(served_then_killed):
    out, desc, ctrl, code, err = served_then_killed
    assert ctrl.returncode == 0, ctrl.stderr
    # the drives tripped on the lost cycles after the controller went silent: verdict fault, exit 5
    assert code == 5, err
    result = RunResult(out)
    assert result.summary.status == "fault"
    mode = result.summary.raw["modes"]["model_based"]
    assert mode["verdict"] == "fault" and mode["first_violation"]["kind"] == "fault_reaction"
    assert "model_based: fault: fault_reaction joint" in err and "exit code 5" in err
    hil = result.summary.raw["hil"]["model_based"]
    assert hil["controller"]["first_cycle"] is not None and hil["controller"]["cycles_in_time"] > 200
    ts = result.timeseries("timeseries_model_based", kind="numpy")
    q1 = np.asarray(ts["plant.q[1]"])
    # the cosine move out reached a good part of its 0.3 rad before the controller went silent
    assert q1.max() - desc["q_start_rad"][0] > 0.1


def test_the_served_runs_report_shows_where_it_stopped(served_then_killed, browser):
    """report.html of the served run (verdict fault) in headless Chromium: the timing report, the
    fault and where the run stopped (docs/how-to/view_results.md)."""
    from browser_support import console_errors, open_report, report_state

    out, _, _, _, _ = served_then_killed
    open_report(browser, out / "report.html")
    assert console_errors(browser) == []
    state = report_state(browser)
    assert state["runs"] == ["model_based"]
    assert any(k.startswith("hil.model_based.") for k in state["keys"])  # the served run's timing report
    assert any("ended 'fault'" in n for n in state["notes"]), state["notes"]
    assert any(row[2] == "fault_reaction" for row in state["events"]), state["events"]
    assert "plot-tcp_error" in state["plots"] and "plot-events" in state["plots"]
    # every served cycle's lateness, with the window's end (the overrun tolerance) as a line
    hil = RunResult(out).summary.raw["hil"]["model_based"]
    plotted = browser.execute_script(
        "var d = document.getElementById('plot-lateness'); var x = d.data[0].x;"
        "return [d.data.length, d.layout.shapes.map(function (s) { return s.y0; }), x.length];")
    cycles = pd.read_parquet(out / "lateness_model_based.parquet")
    assert plotted[0] == 1 and len(cycles) == hil["cycles"]
    assert plotted[1] == [cycles["tolerance_us"].iloc[0]]
    assert cycles["overrun"].sum() == hil["overruns"]


def test_a_killed_controller_trips_the_counters_and_the_drives_stop_the_arm(served_then_killed):
    out, desc, _, _, _ = served_then_killed
    result = RunResult(out)
    hil = result.summary.raw["hil"]["model_based"]
    reactions = [f for f in hil["fault_reactions"] if f["event"] == "fault_reaction"]
    assert {f["node"] for f in reactions} == set(range(1, 7))
    trip = max(f["time_s"] for f in reactions)
    # within the threshold: 80 with +8 per lost cycle -> the tenth lost cycle in a row trips
    lost = hil["frames_lost_per_node"]
    assert all(v >= 10 for v in lost.values())
    ts = result.timeseries("timeseries_model_based", kind="numpy")
    t = np.asarray(ts["time"])
    qd = np.column_stack([np.asarray(ts[f"plant.qd[{j}]"]) for j in range(1, 7)])
    moving_before = np.abs(qd[(t > trip - 0.3) & (t < trip)]).max()
    after = np.abs(qd[t >= trip + 0.5]).max()
    assert moving_before > 1e-2  # it was stopped mid-motion
    assert after < 1e-3  # all joints below 1e-3 rad/s within 0.5 s
    # recorded in the CAN log: the EMCY frames of the reaction
    log = list(open_log(out / "can_model_based.parquet"))
    emcy = [m for m in log if 0x81 <= m.arbitration_id <= 0x86 and len(m.data) == 8]
    assert {m.arbitration_id - 0x80 for m in emcy} == set(range(1, 7))
    assert hil["figure"] and (out / hil["figure"]).exists()


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "Ctrl-C"])
def test_serve_stops_cleanly_on_sigterm_and_ctrl_c(tmp_path, sig):
    out = tmp_path / "out"
    serve = _serve(_scenario(tmp_path, "60 s"), out, PORT + 5 if sig == signal.SIGTERM else PORT + 6)
    _wait_endpoint(out, serve)
    time.sleep(1.0)
    serve.send_signal(sig)
    _, err = serve.communicate(timeout=120)
    assert serve.returncode == 130, err
    assert "Traceback" not in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted"
    assert (out / "timeseries_model_based.csv").exists() or (out / "timeseries_model_based.parquet").exists()


def test_a_port_in_use_is_a_clear_error(tmp_path):
    with can.Bus(interface="udpcycle", channel=f"127.0.0.1:{PORT + 7}"):
        serve = _serve(_scenario(tmp_path), tmp_path / "out", PORT + 7)
        _, err = serve.communicate(timeout=120)
    assert serve.returncode == 2, err
    assert "in use" in err and "Traceback" not in err


@pytest.mark.parametrize("option, value, message", [
    ("--channel", "localhost", "--channel 'localhost': expected host:port"),
    ("--channel", "10.255.255.1:47000", "the address cannot be used"),  # not an address of this machine
    ("--channel", "nosuchhost.invalid:47000", "cannot resolve 'nosuchhost.invalid'"),
    ("--peer", "nosuchhost.invalid:47000", "--peer 'nosuchhost.invalid:47000': cannot resolve"),
    ("--accept-from", "nosuchhost.invalid", "--accept-from: cannot resolve"),
], ids=["no-port", "not-local", "channel-unresolvable", "peer-unresolvable", "accept-from-unresolvable"])
def test_bad_addresses_are_refused_before_anything_runs(tmp_path, option, value, message):
    serve = subprocess.run([sys.executable, "-m", "cosim", "serve", str(_scenario(tmp_path)), "--out",
                            str(tmp_path / "out"), option, value], env=_env(), capture_output=True, text=True,
                           timeout=60)
    assert serve.returncode == 2, serve.stderr
    assert message in serve.stderr and "Traceback" not in serve.stderr
    assert len(serve.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_a_bad_channel_is_refused_before_anything_runs(tmp_path):
    serve = subprocess.run([sys.executable, "-m", "cosim", "serve", str(_scenario(tmp_path)), "--out",
                            str(tmp_path / "out"), "--channel", "localhost"], env=_env(), capture_output=True,
                           text=True, timeout=60)
    assert serve.returncode == 2
    assert "--channel 'localhost': expected host:port" in serve.stderr
    assert not (tmp_path / "out").exists()


def test_split_realtime_runs_our_controller_against_the_served_cell(tmp_path):
    """``cosim run --split --realtime``: our controller follows the served cell in another
    process; the run completes and tracks the ISO path like the in-process run."""
    text = (ROOT / "tests" / "long_forms" / "iso9283_rigid.toml").read_text()
    text = text.replace('stop_time = "12.6 s"', 'stop_time = "1 s"')
    text = text.replace('modes = ["standard", "standard_speed_ff", "model_based"]', 'modes = ["model_based"]')
    text = text.replace('period = "400 us"            # paper section 2.3.2', 'period = "2 ms"')
    # a loaded 2-core test machine deschedules the controller process for up to ~10 ms now and then
    # (wakeup after PRes 5 ms p99, 10 ms max, at SCHED_FIFO: other real-time processes, hypervisor
    # steal), in bursts of 2-4 lost cycles that add up: at +8 per lost cycle and -1 per good one, 20
    # lost cycles in 230 tripped the drives at 80 (0x8100) and the arm stopped 33 mm off the path.
    # Here the controller sends 4 cycles of set-points ahead (as scenarios/hil.toml), so a stall of
    # up to 4 cycles costs no set-point, and the counters trip only beyond what the test tolerates
    # anyway (10 % of the 500 cycles lost: 50 x 8 = 400)
    text = text.replace("cycle_time_us = 400", "cycle_time_us = 2000\nsetpoint_lookahead = 4\n"
                        "[fieldbus.thresholds]\ncn_loss_of_soc = 400\ncn_loss_of_preq = 400")
    text = text.replace('builtin = "servo_drive"',
                        'builtin = "servo_drive"\n[fmus.parameters]\nposition_sample_time = 0.002  # s, the bus cycle')
    text = text.replace("figures = true", "figures = false").replace("can_log = true", "can_log = false")
    path = tmp_path / "iso.toml"
    path.write_text(text)
    runs = {}
    for name, flags in (("in_process", []), ("hil", ["--split", "--realtime"])):
        done = subprocess.run([sys.executable, "-m", "cosim", "run", str(path), "--out", str(tmp_path / name),
                               "--quiet", *flags], env=_env(), capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-2000:]
        runs[name] = json.loads((tmp_path / name / "summary.json").read_text())
    hil = runs["hil"]["hil_split"]["model_based"]
    assert hil["controller_side"]["cycles"] >= 490 and hil["cell_side"]["controller"]["first_cycle"] == 0
    assert hil["round_trip"]["p50_us"] is not None
    # the timing report on both sides (docs/how-to/served_cell.md, "Read the timing report")
    sides = ((hil["controller_side"], tmp_path / "hil"), (hil["cell_side"], tmp_path / "hil" / hil["cell_results"]))
    for side, folder in sides:
        assert {"cycles", "overruns", "overrun_fraction", "longest_overrun_run"} <= set(side)
        assert 0.0 <= side["overrun_fraction"] <= 1.0 and side["longest_overrun_run"] <= side["overruns"]
        assert {"p50_us", "p99_us", "p99_9_us", "max_us"} <= set(side["lateness"])
        assert (folder / side["figure"]).stat().st_size > 10_000
    assert {"p50_us", "p99_us", "max_us"} <= set(hil["round_trip"])
    cell_side = hil["cell_side"]
    nodes = {"1", "2", "3", "4", "5", "6"}
    assert set(cell_side["frames_lost_per_node"]) == set(cell_side["cycles_held_per_node"]) == nodes
    assert {"frames_late", "fault_reactions", "lost_cycles"} <= set(cell_side)
    assert (tmp_path / "hil" / hil["cell_results"] / "summary.json").exists()
    assert hil["cell_side"]["controller"]["cycles_in_time"] >= 0.9 * hil["cell_side"]["cycles"]
    e_in = runs["in_process"]["modes"]["model_based"]["tcp_error_max_mm"]
    e_hil = runs["hil"]["modes"]["model_based"]["tcp_error_max_mm"]
    # it follows the path (the standard cascade is ~18 mm off); each lost cycle holds the set-point and the
    # feed-forward for a cycle, so on a shared test machine the split run is not the in-process figure
    # (benchmarks/bench_hil.py --iso measures it at 400 us)
    assert e_in < 0.05 and e_hil < 5.0


def test_a_controller_at_another_cycle_time_is_a_counted_logged_mismatch(tmp_path):
    """A controller on its own 6 ms clock against the cell's 2 ms cycle: no hang, no traceback;
    the run ends normally, the mismatch is counted in summary.json and named on stderr."""
    out = tmp_path / "out"
    serve = _serve(_scenario(tmp_path, "3 s"), out, PORT + 3)
    desc = _wait_endpoint(out, serve)
    bus = can.Bus(interface="udpcycle", channel=desc["controller_channel"], peer=desc["cell_channel"])
    try:
        counter, next_at = 0, time.monotonic()
        while serve.poll() is None and time.monotonic() < next_at + 60:
            frames = [can.Message(arbitration_id=0x080, data=bytes([counter % 240 + 1]), is_extended_id=False)]
            frames += [can.Message(arbitration_id=0x200 + i, data=bytes(8), is_extended_id=False) for i in range(1, 7)]
            bus.send_many(frames)
            counter += 1
            next_at += 3 * desc["cycle_time_s"]
            while bus.recv(max(next_at - time.monotonic(), 0.0)) is not None:
                pass  # the PRes frames: this controller keeps its own time
    finally:
        bus.shutdown()
    _, err = serve.communicate(timeout=120)
    # two of every three cycles are lost for the cell: the counters trip, the drives react: verdict fault
    assert serve.returncode == 5, err
    assert "Traceback" not in err and "cycle-time mismatch" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "fault" and summary["first_violation"]["kind"] == "fault_reaction"
    found = summary["hil"]["model_based"]["cycle_time_mismatch"]
    assert found["controller_cycle_time_s_estimate"] == pytest.approx(6e-3, rel=0.15)


def _stranger_datagram(sequence: int) -> bytes:
    """A valid udpcycle datagram (docs/reference/fieldbus.md) with a SoC and six PReqs that would
    disable every drive (controlword 0), from a program that is not the cell's controller."""
    frames = [(0x080, bytes([sequence % 240 + 1]))] + [(0x200 + n, struct.pack("<Hih", 0, 0, 0)) for n in range(1, 7)]
    body = b"".join(struct.pack(">IBBHd", can_id, len(data), 0, 0, 0.0) + data for can_id, data in frames)
    return struct.pack(">4sBBHIIQ", b"RXCB", 1, 0, len(frames), 0xBAD, sequence, time.time_ns()) + body


def test_a_controller_killed_mid_motion_stops_the_arm(tmp_path):
    """The example controller really killed (SIGKILL, its socket gone: the cell's datagrams to
    it bounce) in the middle of its motion: the cell's counters trip, every drive reacts, all
    joints are below 1e-3 rad/s 0.5 s after the trip, the reaction is in the CAN log and the
    summary. The controller started again resets the faults and re-enables the drives through
    CiA 402, moves the arm and stops; the served run ends normally. On the way, bad input on the cell's port:
    garbage and a truncated datagram before the controller comes (malformed), and another
    program sending valid PReqs while the arm moves (foreign): counted, named on stderr,
    never obeyed."""
    out = tmp_path / "out"
    scenario = _scenario(tmp_path, "10 s")  # and seeded transport faults from the scenario: duplicated PRes
    scenario.write_text(scenario.read_text().replace(
        "[fieldbus.recording]", '[fieldbus.bus]\ninterface = "udpcycle"\nchannel = "127.0.0.1:47400"\n'
        "[fieldbus.bus.options]\nduplicate_probability = 0.05\nfault_seed = 7\n[fieldbus.recording]"))
    serve = _serve(scenario, out, PORT + 8)
    desc = _wait_endpoint(out, serve)
    host, port = desc["cell_channel"].rsplit(":", 1)
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    stranger.sendto(b"garbage", (host, int(port)))
    stranger.sendto(_stranger_datagram(0)[:30], (host, int(port)))
    ctrl = subprocess.Popen([sys.executable, str(EXAMPLE), str(out / "hil_endpoint.json"), "--amplitude", "0.3",
                             "--duration", "3.0"], env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    ready, _, _ = select.select([ctrl.stdout], [], [], 60.0)
    assert ready, "the example controller did not enable the drives within 60 s"
    assert "drives enabled" in ctrl.stdout.readline(), ctrl.communicate()
    for sequence in range(1, 51):  # 0.1 s of a stranger's PReqs, then about a third into the 3 s cosine
        stranger.sendto(_stranger_datagram(sequence), (host, int(port)))
        time.sleep(0.002)
    stranger.close()
    time.sleep(0.9)
    assert ctrl.poll() is None, ctrl.communicate()
    ctrl.kill()
    ctrl.communicate(timeout=30)
    time.sleep(1.5)  # the trip and the stop
    again = subprocess.run([sys.executable, str(EXAMPLE), str(out / "hil_endpoint.json"), "--amplitude", "0.1",
                            "--duration", "1.0"], env=_env(), capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr
    assert "drives enabled" in again.stdout
    _, err = serve.communicate(timeout=180)
    assert serve.returncode == 5, err  # the drives' fault reactions on the kill: verdict fault (docs/reference/verdicts.md)
    assert "Traceback" not in err
    assert "datagrams dropped by the cell: 2 malformed, 50 foreign" in err
    result = RunResult(out)
    assert result.summary.status == "fault"
    hil = result.summary.raw["hil"]["model_based"]
    assert hil["transport"]["malformed"] == 2 and hil["transport"]["foreign"] == 50
    sent = hil["transport"]["sent"]
    assert 0.02 * sent < hil["transport"]["injected_duplicates"] < 0.08 * sent  # 5 %, seeded
    reactions = [f for f in hil["fault_reactions"] if f["event"] == "fault_reaction"]
    assert {f["node"] for f in reactions} == set(range(1, 7))
    # the kill: each node's first reaction (the controller started again trips them once more when it ends)
    trip = max(min(f["time_s"] for f in reactions if f["node"] == node) for node in range(1, 7))
    assert all(v >= 10 for v in hil["frames_lost_per_node"].values())  # threshold 80, +8 per lost cycle
    ts = result.timeseries("timeseries_model_based", kind="numpy")
    t = np.asarray(ts["time"])
    qd = np.column_stack([np.asarray(ts[f"plant.qd[{j}]"]) for j in range(1, 7)])
    assert np.abs(qd[(t > trip - 0.3) & (t < trip)]).max() > 1e-2  # it was moving
    # each drive ramps to standstill, holds the axis for the brake's closing time (0.1 s), then the
    # closed brake takes over the motor's torque: no load falls onto the brake spring, no creep
    # (a controller that dies); all six joints below 1e-3 rad/s 0.5 s after the trip
    cleared = [f for f in hil["fault_reactions"] if f["event"] == "fault_cleared" and f["time_s"] > trip]
    assert {f["node"] for f in cleared} == set(range(1, 7)), hil["fault_reactions"]
    back = min(f["time_s"] for f in cleared)
    stopped = (t >= trip + 0.5) & (t < back)
    assert stopped.any()
    assert np.abs(qd[stopped]).max() < 1e-3
    emcy = [m for m in open_log(out / "can_model_based.parquet")
            if 0x81 <= m.arbitration_id <= 0x86 and len(m.data) == 8]
    assert {m.arbitration_id - 0x80 for m in emcy} == set(range(1, 7))
    # the controller came back: every node's fault cleared, the arm moved again
    assert np.abs(qd[t > back]).max() > 1e-2
