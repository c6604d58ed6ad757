"""The set-point look-ahead against ``python -m cosim serve`` over the udpcycle transport: a
controller in another process sends every PReq with the next K cycles' set-points and
deliberately leaves chosen cycles unanswered; the served cell applies the buffered
set-point for each lost cycle (as many as the look-ahead holds), counts every loss as
POWERLINK does, and logs the whole 64-byte RPDO1s. (2 ms cycle: a shared test machine.)"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

from fieldbus.canlog import open_log
from fieldbus.telegrams import rpdo1_length
from realtime_support import hil_scenario

ROOT = Path(__file__).resolve().parents[3]
PORT = 45000 + (os.getpid() % 400) * 10 + 4
K = 3
SKIPS = {200: 1, 300: 2, 400: 5}  # cell cycle (from the controller's first) -> cycles left unanswered

CONTROLLER = r"""
import json, math, sys, time
from pathlib import Path
from fieldbus import EnableSequencer, ManagingNodeEndpoint, Setpoints
from cosim.cell.wiring import joint_scaling

path, k, skips = Path(sys.argv[1]), int(sys.argv[2]), json.loads(sys.argv[3])
skip = {int(c) + j for c, n in skips.items() for j in range(n)}
while not path.exists():
    time.sleep(0.01)
desc = json.loads(path.read_text())
period = desc["cycle_time_s"]
config = {"cycle_time_us": round(period * 1e6, 6), "setpoint_lookahead": k,
          "bus": {"interface": "udpcycle", "channel": desc["controller_channel"], "receive_timeout_s": 0.05,
                  "options": {"peer": desc["cell_channel"]}}}
endpoint = ManagingNodeEndpoint(config, joint_scaling())
sp = Setpoints.zeros(desc["nodes"])
q0 = desc["q_start_rad"]
sp.position[:] = q0
sequencers = [EnableSequencer() for _ in range(desc["nodes"])]
first, skipped = None, []
endpoint.send_following(sp)
while True:
    got = endpoint.follow(0.5 if first is not None else 120.0)
    if got is None:
        break
    cycle, observed = got
    cell_cycle = int(endpoint.peer_time_s // period + 1e-9)
    first = cell_cycle if first is None else first
    for i, seq in enumerate(sequencers):
        sp.controlword[i] = seq.next_controlword(int(observed.statusword[i]))
    t = (cell_cycle - first) * period
    sp.position[:] = [q + 0.05 * math.sin(2.0 * t) for q in q0]
    if cell_cycle + 1 - first in skip:
        skipped.append(cell_cycle + 1)
        continue  # this cycle's group never goes out
    endpoint.send_following(sp)
endpoint.close()
print(json.dumps({"first": first, "skipped": skipped}))
"""


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
            "MPLBACKEND": "Agg"}


def _runs(cycles):
    out = []
    for c in sorted(cycles):
        if out and c == out[-1][0] + out[-1][1]:
            out[-1][1] += 1
        else:
            out.append([c, 1])
    return out


def test_served_cell_covers_unanswered_cycles_from_the_lookahead(tmp_path):
    scenario = hil_scenario(tmp_path, "2 s", loss_threshold=0)  # counters never trip: every lost cycle is judged
    out = tmp_path / "out"
    controller = subprocess.Popen([sys.executable, "-c", CONTROLLER, str(out / "hil_endpoint.json"), str(K),
                                   json.dumps(SKIPS)], env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True)
    serve = subprocess.run([sys.executable, "-m", "cosim", "serve", str(scenario), "--out", str(out), "--quiet",
                            "--channel", f"127.0.0.1:{PORT}", "--scheduling", "normal"], env=_env(),
                           capture_output=True, text=True, timeout=300)
    ctrl_out, ctrl_err = controller.communicate(timeout=60)
    assert serve.returncode == 0, serve.stderr[-2000:]
    assert controller.returncode == 0, ctrl_err[-2000:]
    ctrl = json.loads(ctrl_out.strip().splitlines()[-1])
    summary = json.loads((out / "summary.json").read_text())
    hil = next(iter(summary["hil"].values()))
    cycles = hil["cycles"]
    lost = [row["cycle"] for row in hil["lost_cycles"]]
    assert len(lost) < 1000 and set(ctrl["skipped"]) <= set(lost)
    # each run of L lost cycles: min(L, K) set-points from the look-ahead, the rest by missing_setpoint
    runs = _runs(lost)
    complete = [length for start, length in runs if start + length + K + 2 < cycles]
    tail = sum(length for start, length in runs if start + length + K + 2 >= cycles)
    covered = set(hil["setpoint_lookahead"]["cycles_covered_per_node"].values())
    assert len(covered) == 1
    expected = sum(min(length, K) for length in complete)
    assert expected <= covered.pop() <= expected + min(tail, K), runs
    assert expected >= 1 + 2 + 3  # the planned runs alone
    assert set(hil["frames_lost_per_node"].values()) == {len(lost)}
    # the cell's CAN log: the whole RPDO1 with its 3 entries, none in the lost cycles
    logs = sorted(out.rglob("can_*.parquet"))  # the columnar CAN log (fieldbus/canlog.py)
    assert logs
    period = 2e-3
    preq_cycles = set()
    for msg in open_log(logs[0]):
        if msg.arbitration_id == 0x201:
            assert len(msg.data) == rpdo1_length(K) == 64 and msg.data[9] == K
            preq_cycles.add(round(msg.timestamp / period))
    assert not preq_cycles & set(lost)


def test_split_realtime_sends_the_lookahead_and_both_can_logs_are_whole(tmp_path):
    """``cosim run --split --realtime`` with ``setpoint_lookahead``: our controller's PReqs carry
    it; the controller's and the served cell's CAN logs are separate files, both readable to
    the end (they were one file written by both processes before)."""
    text = (ROOT / "tests" / "long_forms" / "iso9283_rigid.toml").read_text()
    text = text.replace('stop_time = "12.6 s"', 'stop_time = "0.6 s"')
    text = text.replace('modes = ["standard", "standard_speed_ff", "model_based"]', 'modes = ["model_based"]')
    text = text.replace('period = "400 us"            # paper section 2.3.2', 'period = "2 ms"')
    text = text.replace("cycle_time_us = 400", f"cycle_time_us = 2000\nsetpoint_lookahead = {K}\n"
                        "[fieldbus.thresholds]\ncn_loss_of_soc = 0\ncn_loss_of_preq = 0")
    text = text.replace('builtin = "servo_drive"',
                        'builtin = "servo_drive"\n[fmus.parameters]\nposition_sample_time = 0.002  # s, the bus cycle')
    text = text.replace("figures = true", "figures = false")
    assert "can_log = true" in text
    path = tmp_path / "iso.toml"
    path.write_text(text)
    out = tmp_path / "hil"
    done = subprocess.run([sys.executable, "-m", "cosim", "run", str(path), "--out", str(out), "--quiet", "--split",
                           "--realtime"], env=_env(), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    cell = summary["hil_split"]["model_based"]["cell_side"]
    controller_log = out / "can_model_based.parquet"
    cell_log = out / "cell_side_model_based" / "can_model_based.parquet"
    lengths = {}
    for name, log in (("controller", controller_log), ("cell", cell_log)):
        frames = list(open_log(log))  # readable to the end
        assert len(frames) > 250 * 13
        lengths[name] = {len(m.data) for m in frames if 0x201 <= m.arbitration_id <= 0x206}
    assert lengths == {"controller": {64}, "cell": {64}}
    lost = [row["cycle"] for row in cell["lost_cycles"]]
    complete = sum(min(length, K) for start, length in _runs(lost) if start + length + K + 2 < cell["cycles"])
    covered = cell["setpoint_lookahead"]["cycles_covered_per_node"]["1"]
    assert complete <= covered <= complete + K
