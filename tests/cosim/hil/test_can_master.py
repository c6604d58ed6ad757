"""A real CANopen master against ``cosim serve`` on a python-can bus.

``examples/canopen_master.py`` (the ``canopen`` library, python-can and the standard library
only) runs in its own process against ``cosim serve --interface udp_multicast`` in another:
the frames really cross a process boundary on python-can's ``udp_multicast`` interface
(loopback, a port of this test's own). The master loads the EDS that ``cosim device-files``
wrote, reads the identity, writes and reads back a limit, a gain and the PDO mapping, switches
the nodes to operational, enables the six drives with ``BaseNode402`` in cyclic synchronous
position, moves them, disables them and probes what the drives must refuse. The test needs the
``canopen`` package: it fails, not skips, without it."""
from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cosim.api import RunResult

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "examples" / "canopen_master.py"
SCENARIO = ROOT / "scenarios" / "can_master.toml"
PORT = 44000 + (os.getpid() % 500) * 3
GROUP = "239.74.163.17"


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    env["MPLBACKEND"] = "Agg"
    return env


def test_the_master_imports_only_canopen_can_and_the_standard_library():
    imported = set()
    for node in ast.walk(ast.parse(EXAMPLE.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            imported.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0
            imported.add(node.module.split(".")[0])
    assert {"canopen", "can"} <= imported
    assert imported - {"canopen", "can", "__future__"} <= set(sys.stdlib_module_names), imported


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    import canopen  # noqa: F401 - the master's library: an ImportError here fails the test (no skip)

    tmp = tmp_path_factory.mktemp("can_master")
    eds, out = tmp / "eds", tmp / "out"
    files = subprocess.run([sys.executable, "-m", "cosim", "device-files", str(eds)], env=_env(), cwd=ROOT,
                           capture_output=True, text=True, timeout=120)
    assert files.returncode == 0, files.stderr
    scenario = tmp / "can_master.toml"
    scenario.write_text(SCENARIO.read_text().replace('stop_time = "120 s"', 'stop_time = "40 s"'))
    bus = ["--interface", "udp_multicast", "--channel", GROUP, "--bus-option", f"port={PORT}"]
    serve = subprocess.Popen([sys.executable, "-m", "cosim", "serve", str(scenario), "--out", str(out), "--quiet",
                              "--scheduling", "normal", *bus], env=_env(), cwd=ROOT, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not (out / "hil_endpoint.json").exists():
        if serve.poll() is not None:
            pytest.fail(f"cosim serve ended early: {serve.stderr.read()}")
        assert time.monotonic() < deadline, "no hil_endpoint.json"
        time.sleep(0.05)
    master = subprocess.run([sys.executable, str(EXAMPLE), "--eds", str(eds), *bus[:4], "--bus-option",
                             f"port={PORT}", "--endpoint", str(out / "hil_endpoint.json"), "--probe-errors", "--amplitude", "0.02",
                             "--report", str(tmp / "master.json")], env=_env(), cwd=tmp, capture_output=True,
                            text=True, timeout=180)
    _, err = serve.communicate(timeout=180)
    assert master.returncode == 0, master.stdout[-3000:] + master.stderr[-3000:]
    return json.loads((tmp / "master.json").read_text()), out, serve.returncode, err


def test_sdo_round_trips_identity_and_boot_up(session):
    report, *_ = session
    assert all(report["boot_up"].values()) and len(report["boot_up"]) == 6
    # the library sets a node's own NMT state only from that node's heartbeats (0x05: operational)
    assert set(report["nmt"].values()) == {"OPERATIONAL"}
    trips = report["sdo_round_trips"]
    assert trips and all(t["ok"] for t in trips), [t for t in trips if not t["ok"]]
    touched = {(t["node"], t["index"]) for t in trips}
    for node in range(1, 7):  # a limit, a gain, the heartbeat, the mode and every PDO object it wrote
        for index in ("0x6072", "0x2001", "0x1017", "0x6060", "0x1400", "0x1600", "0x1800", "0x1A00", "0x1801",
                      "0x1A01"):
            assert (node, index) in touched
    ident = report["identity"]
    assert {ident[str(n)]["serial"] for n in range(1, 7)} == {f"0x{n:08X}" for n in range(1, 7)}
    assert all(i["device_type"] == "0x00020192" for i in ident.values())  # CiA 402 servo drive


def test_six_axes_reach_operation_enabled_and_move(session):
    report, out, code, err = session
    assert set(report["states"]["enabled"].values()) == {"OPERATION ENABLED"}
    assert set(report["states"]["mode"].values()) == {"CYCLIC SYNCHRONOUS POSITION"}
    assert set(report["states"]["after_motion"].values()) == {"OPERATION ENABLED"}
    assert set(report["states"]["disabled"].values()) == {"SWITCH ON DISABLED"}
    fe = report["following_error"]["max_rad"]
    assert len(fe) == 6 and all(0.0 < e < 0.02 for e in fe), fe  # reported, and below the 0.02 rad move itself
    cycle = report["cycle"]
    assert cycle["syncs"] > 400 and cycle["interval"]["p50_us"] == pytest.approx(report["cycle_time_s"] * 1e6, rel=0.2)
    print(f"master: cycle {report['cycle_time_s'] * 1e3:g} ms, SYNC interval {cycle['interval']}, "
          f"{cycle['late']} late of {cycle['syncs']}; max following error {max(fe) * 1e3:.3g} mrad")
    assert code == 0, err


def test_the_cells_timing_report_and_time_series_show_the_motion(session):
    report, out, _, _ = session
    result = RunResult(out)
    summary = result.summary.raw
    hil = next(iter(summary["hil"].values()))
    assert hil["interface"] == "udp_multicast" and hil["ended_by"] == "sync_timeout"
    assert hil["sync"]["received"] > 400 and hil["rpdo"]["taken"] > 6 * 400
    assert hil["sync"]["interval_us"]["p50_us"] == pytest.approx(report["cycle_time_s"] * 1e6, rel=0.2)
    assert len(hil["following_error_max_rad"]) == 6 and 0.0 < max(hil["following_error_max_rad"]) < 0.02
    entry = next(iter(summary["modes"].values()))
    assert entry["controller"] == "external (cosim serve)" and entry["verdict"] == "ok"
    start, end = entry["motion_start_s"], entry["motion_end_s"]
    assert entry["enabled_at_s"] is not None and start is not None and end - start > 1.0
    series = result.timeseries(f"timeseries_{next(iter(summary['modes']))}", kind="numpy")
    t = np.asarray(series["time"])
    q = np.column_stack([np.asarray(series[f"plant.q[{j}]"]) for j in range(1, 7)])
    moving = (t >= start) & (t <= end)
    swing = q[moving].max(axis=0) - q[moving].min(axis=0)
    assert np.all(swing > 0.015), swing  # each joint went out by about the 0.02 rad move and back
    back = np.abs(q[t <= end][-1] - q[t <= start][-1])  # the move ends where it began (the drives then disable)
    assert np.all(back < 0.003), back


def test_bad_input_gets_the_protocols_answer_and_is_counted(session):
    report, out, _, _ = session
    aborts = report["aborts"]
    assert aborts["out_of_range_0x6060_11"] == "0x06090031"  # value too high
    assert aborts["out_of_range_0x6060_3"] == "0x06090032"  # value too low
    assert aborts["unknown_index_0x5FFF"] == "0x06020000"
    assert aborts["read_only_0x6041"] == "0x06010002"
    hil = next(iter(RunResult(out).summary.raw["hil"].values()))
    bad = hil["bad_input"]
    assert bad["nmt_to_missing_node"] == 1 and bad["sdo_malformed"] >= 1 and bad["sdo_unknown_object"] >= 1
    nodes = hil["nodes"]
    assert all(nodes[str(n)]["heartbeats"] > 0 and nodes[str(n)]["boot_ups"] >= 2 for n in range(1, 7))
    assert hil["sdo_aborts"]["0x06090031"] >= 1 and hil["sdo_aborts"]["0x06090032"] >= 1


@pytest.mark.parametrize("interface,channel", [("no_such_interface", "x"), ("udp_multicast", "not-an-address"),
                                               ("socketcan", "can0")])
def test_a_bad_interface_or_channel_is_refused_in_one_line(interface, channel):
    run = subprocess.run([sys.executable, "-m", "cosim", "serve", str(SCENARIO), "--interface", interface, "--channel",
                          channel, "--quiet"], env=_env(), cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert run.returncode == 2, run.stderr  # docs/reference/verdicts.md: bad input
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: --interface") and "Traceback" not in run.stderr, run.stderr
    assert interface in lines[0] and channel in lines[0]
