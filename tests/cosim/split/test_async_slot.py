"""SDO and NMT in the asynchronous slot of the cell's bus (fieldbus/asynchronous.py), scripted by
``[[fieldbus.asynchronous]]``: the same run in one process and split over two processes gives the
same answers and the same figures, paced in one process the same answers (a paced split run refuses
the requests: exit code 2); a lowered following-error window (0x6065) trips drive 1 with
0x8611 exactly 0x6066 = 10 ms after the cycle the SDO answer went out; every SDO/NMT/EMCY frame
sits alone in its cycle's slot after the SoA; tshark dissects both captures of the run with zero
malformed frames and zero expert errors (but the SDO request the scenario sends malformed on purpose)
and finds the SDO and NMT traffic in them."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from cosim.cli import main
from fieldbus.canlog import read_frames
from fieldbus.timing import CycleLayout
from realtime_support import ROOT, write_scenario

PERIOD = 400e-6
REQUESTS = """
[[fieldbus.asynchronous]]
time_s = 0.002
node = 1
sdo = "read"
index = 0x1008
[[fieldbus.asynchronous]]
time_s = 0.002
node = 2
sdo = "write"
index = 0x6060
value = 11
[[fieldbus.asynchronous]]
time_s = 0.002
node = 2
sdo = "write"
index = 0x6060
value = 7
[[fieldbus.asynchronous]]
time_s = 0.002
node = 2
sdo = "write"
index = 0x2345
value = 1
[[fieldbus.asynchronous]]
time_s = 0.002
node = 2
sdo = "write"
index = 0x1000
value = 5
[[fieldbus.asynchronous]]
time_s = 0.002
node = 2
sdo = "raw"
data = [0x40, 0x08]
[[fieldbus.asynchronous]]
time_s = 0.002
node = 9
nmt = "stop"
[[fieldbus.asynchronous]]
time_s = 0.02
node = 5
nmt = "pre-operational"
[[fieldbus.asynchronous]]
time_s = 0.02
node = 5
nmt = "start"
[[fieldbus.asynchronous]]
time_s = 0.03
node = 1
sdo = "write"
index = 0x6065
value = 1
[[fieldbus.asynchronous]]
time_s = 0.05
node = 1
sdo = "read"
index = 0x1003
subindex = 1
"""


def _run(scenario, out, *flags):
    done = subprocess.run([sys.executable, "-m", "cosim", "run", str(scenario), "--quiet", "--out", str(out), *flags],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 4, done.stderr  # 4: the drive tripped (docs/reference/verdicts.md), as the test wants
    return json.loads((out / "summary.json").read_text())["modes"]["model_based"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("async_slot")
    scenario = write_scenario(tmp, "80 ms", extra=REQUESTS)
    return tmp, _run(scenario, tmp / "one"), _run(scenario, tmp / "split", "--split"), _run(scenario, tmp / "paced",
                                                                                               "--realtime")


def _results(mode):
    return {(r["node"], r["service"], r.get("index"), r.get("value"), r.get("command")): r
            for r in mode["fieldbus"]["asynchronous"]["results"]}


def test_answers_aborts_and_counts(runs):
    one = runs[1]
    a = one["fieldbus"]["asynchronous"]
    r = _results(one)
    name = r[(1, "read", "0x1008", None, None)]
    assert name["answer"] == "RX130L virtual servo drive"
    assert name["answered_cycle"] - name["sent_cycle"] == 9  # initiate + 4 segments, request and answer each a slot
    assert r[(2, "write", "0x6060", 11, None)]["abort"] == "0x06090031"  # above 0x6060's high limit 10
    assert r[(2, "write", "0x6060", 7, None)]["abort"] == "0x06090032"  # below its low limit 8
    assert r[(2, "write", "0x2345", 1, None)]["abort"] == "0x06020000"  # no such object
    assert r[(2, "write", "0x1000", 5, None)]["abort"] == "0x06010002"  # read-only
    assert r[(9, "nmt", None, None, "stop")]["answer"] == "no node"
    assert a["aborts"] == {"0x05040001": 1, "0x06010002": 1, "0x06020000": 1, "0x06090031": 1, "0x06090032": 1}
    assert a["bad_input"] == {"malformed_sdo": 1, "unknown_object": 1, "nmt_to_missing_node": 1}
    assert a["requests"] == 11 and a["nmt_commands"] == 3 and a["no_answer"] == 0
    assert a["nmt_state"] == {str(n): "operational" for n in range(1, 7)}  # node 5 was started again


def test_a_lowered_following_error_window_trips_the_drive_when_it_should(runs):
    tmp, one = runs[:2]
    answered = _results(one)[(1, "write", "0x6065", 1, None)]
    assert answered["answer"] == "ok"
    log = read_frames(tmp / "one" / "can_model_based.parquet")
    ids, t = log.frames["id"], log.timestamps
    emcy = [(int(round(t[k] / PERIOD - 0.5)), bytes(log.frames["data"][k][:2])) for k in np.nonzero(ids == 0x081)[0]]
    # 0x6066 = 10 ms = 25 cycles beyond the window, from the cycle the answer went out
    assert emcy[0] == (answered["answered_cycle"] + 25, (0x8611).to_bytes(2, "little"))
    from fmus.servo_drive.object_dictionary import drive_object_dictionary

    violation = one["first_violation"]  # judged against the window the SDO write set (1 count), not the start value
    assert (violation["kind"], violation["joint"], violation["error_code"]) == ("following_error", 1, "0x8611")
    assert violation["limit"] == drive_object_dictionary(1).rad_per_count < violation["value"]
    history = _results(one)[(1, "read", "0x1003", None, None)]
    assert history["answer"] == 0x8611  # the error history (0x1003 sub 1) an SDO upload reads


def test_in_process_split_and_paced_give_the_same_answers(runs):
    _, one, split, paced = runs
    assert one["fieldbus"]["asynchronous"] == split["fieldbus"]["asynchronous"] == paced["fieldbus"]["asynchronous"]
    assert one["tcp_error_max_mm"] == split["tcp_error_max_mm"]
    assert one["fieldbus"]["event_tally"] == split["fieldbus"]["event_tally"]
    assert one["fieldbus"]["frames_sent"] == split["fieldbus"]["frames_sent"]


@pytest.mark.parametrize("side", ["one", "split"])
def test_one_asynchronous_frame_per_cycle_after_the_soa(runs, side):
    tmp = runs[0]
    log = read_frames(tmp / side / "can_model_based.parquet")
    ids, t = log.frames["id"].astype(np.int64), log.timestamps
    from fieldbus import FieldbusConfig

    layout = CycleLayout.from_config(FieldbusConfig.from_dict({}))
    slot = (ids == 0) | ((ids & ~0x7F) == 0x600) | ((ids & ~0x7F) == 0x580)
    if side == "one":  # the split run's managing node logs a received EMCY at its cycle's SoC, not at the slot
        slot |= ((ids & ~0x7F) == 0x080) & (ids != 0x080)
    cycles = np.floor(t[slot] / PERIOD + 1e-9).astype(int)
    assert len(cycles) == len(set(cycles.tolist())) > 20
    offset = t[slot] - cycles * PERIOD
    assert (offset > layout.nominal_end_of_isochronous).all() and (offset < layout.nominal_end_of_async).all()


def _tshark(*args):
    exe = shutil.which("tshark")
    assert exe, "tshark is not installed: .ci/run installs it (apt-get install tshark)"
    done = subprocess.run([exe, *args], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    return [line for line in done.stdout.splitlines() if line]


def test_tshark_decodes_the_sdo_and_nmt_traffic_with_nothing_malformed(runs, tmp_path):
    tmp, one = runs[:2]
    assert main(["export-pcap", str(tmp / "one"), "-o", str(tmp_path)]) == 0
    epl, can_capture = tmp_path / "powerlink_model_based.pcapng", tmp_path / "can_model_based.pcapng"
    canopen = ("-d", "can.subdissector,canopen")
    bad = "_ws.malformed || _ws.expert.severity == error"
    assert _tshark("-r", str(epl), "--disable-protocol", "opensafety", "-Y", bad) == []
    # the one frame tshark finds malformed is the request the scenario sends malformed on purpose (2 bytes)
    wrong = _tshark("-r", str(can_capture), *canopen, "-Y", bad, "-T", "fields", "-e", "can.id", "-e", "can.len")
    assert wrong == [f"{0x602}\t2"]
    a = one["fieldbus"]["asynchronous"]
    sdo = _tshark("-r", str(can_capture), *canopen, "-Y", "canopen.sdo.cmd", "-T", "fields", "-e", "can.id")
    assert len(sdo) == a["frames"] - a["nmt_commands"]
    nmt = _tshark("-r", str(can_capture), *canopen, "-Y", "canopen.nmt_ctrl.cd", "-T", "fields",
                  "-e", "canopen.nmt_ctrl.cd", "-e", "canopen.nmt_ctrl.node_id")
    assert nmt == ["0x02\t0x09", "0x80\t0x05", "0x01\t0x05"]
    commands = _tshark("-r", str(epl), "-Y", "epl.asnd.svid == 4", "-T", "fields", "-e", "epl.dest")
    assert commands == ["9", "5", "5"]
    asnd = _tshark("-r", str(epl), "-Y", "epl.asnd.svid == 0xa0")
    assert len(asnd) == len(sdo)
    invites = _tshark("-r", str(epl), "-Y", "epl.soa.svid == 255")
    assert len(invites) == a["answers"]


def test_a_paced_split_run_refuses_scripted_requests(runs, capsys):
    scenario = runs[0] / "rt_short.toml"
    assert main(["run", str(scenario), "--realtime", "--split", "--quiet", "--out", str(runs[0] / "no")]) == 2
    error = capsys.readouterr().err
    assert f"{scenario}: fieldbus.asynchronous: expected no scripted SDO/NMT requests with --realtime --split" in error
