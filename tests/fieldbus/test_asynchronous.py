"""The asynchronous slot of the in-process bus (fieldbus/asynchronous.py) cycle by cycle: NMT stop
and start (PDO processing stops, CiA 402's abort-connection reaction, and starts again),
pre-operational, SDO to a stopped node, an EMCY taking the slot, a request a program submits,
the scenario keys' errors, and an idle slot that is never run."""
from __future__ import annotations

import numpy as np
import pytest

from cosim.cell.wiring import joint_scaling
from fieldbus import DriveActuals, FieldbusConfig, FieldbusConfigError, PowerlinkNetwork, Setpoints
from fieldbus.asynchronous import AsyncRequest
from fmus.servo_drive.object_dictionary import drive_object_dictionaries

T = 400e-6


def _network(requests=(), **table):
    config = FieldbusConfig.from_dict({"asynchronous": list(requests), **table})
    return PowerlinkNetwork(config, joint_scaling(), canopen=drive_object_dictionaries(config))


def _run(net, cycles, on_cycle=None):
    setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
    setpoints.controlword[:] = 0x0F
    rows = []
    for k in range(cycles):
        setpoints.position[:] = 1e-3 * k
        if on_cycle is not None:
            on_cycle(k, actuals)
        r = net.run_cycle(k, setpoints, actuals)
        a = r.applied
        rows.append((a.position.copy(), a.fresh.copy(), a.fault_code.copy(), a.controlword.copy()))
    return rows


def test_nmt_stop_holds_the_setpoint_faults_the_drive_and_start_resumes():
    net = _network([{"time_s": 10 * T, "node": 3, "nmt": "stop"},
                    {"time_s": 10 * T, "node": 3, "sdo": "read", "index": 0x1000},
                    {"time_s": 20 * T, "node": 3, "nmt": "start"}])
    rows = _run(net, 30)
    summary = net.summary()["asynchronous"]
    net.close()
    stop, read, start = summary["results"]
    assert (stop["sent_cycle"], start["sent_cycle"]) == (10, 20)
    assert read["answer"] == "no answer"  # CiA 301: no SDO in NMT state stopped
    held = rows[10][0][2]
    for k in range(11, 21):  # from the cycle after the stop to the cycle of the start: PDOs not taken
        position, fresh, fault, _ = rows[k]
        assert position[2] == held and not fresh[2] and fault[2] == 0x8100  # 0x6007: abort connection -> fault
        assert fresh[1] and abs(position[1] - 1e-3 * (k - 1)) < 1e-5  # the other nodes go on
    for k in range(21, 30):  # started in the slot of cycle 20: from cycle 21 the PReqs are taken again
        assert rows[k][1][2] and rows[k][2][2] == 0 and abs(rows[k][0][2] - 1e-3 * (k - 1)) < 1e-5
    assert summary["nmt_state"]["3"] == "operational" and summary["nmt_commands"] == 2


def test_pre_operational_holds_without_fault_and_quick_stop_option():
    net = _network([{"time_s": 5 * T, "node": 0, "nmt": "pre-operational"}])  # node 0: every node
    rows = _run(net, 12)
    net.close()
    for k in range(6, 12):
        assert (rows[k][0] == rows[5][0]).all() and not rows[k][1].any() and not rows[k][2].any()
    net = _network([{"time_s": 5 * T, "node": 2, "nmt": "stop"}], reaction={"abort_connection_option": "quick_stop"})
    rows = _run(net, 9)
    net.close()
    assert [int(r[3][1]) for r in rows[6:]] == [0x0002] * 3 and not rows[8][2].any()


def test_an_emcy_takes_the_slot_and_the_request_waits_for_the_next():
    net = _network([{"time_s": 4 * T, "node": 1, "sdo": "read", "index": 0x1001}])

    def error_at_4(k, actuals):
        actuals.error_code[0] = 0x8611 if k >= 4 else 0

    _run(net, 10, error_at_4)
    summary = net.summary()["asynchronous"]
    net.close()
    (read,) = summary["results"]
    assert summary["slots_taken_by_emcy"] == 1 and read["sent_cycle"] == 5 and read["answered_cycle"] == 6
    assert read["answer"] == 0x21  # the error register 0x1001 the EMCY set: generic (bit 0) + device profile (bit 5)


def test_a_submitted_request_and_an_idle_slot():
    net = _network()
    assert net._async_next == float("inf")  # idle: one comparison per cycle, the slot never runs
    calls = []
    net.asynchronous.run = lambda *a, **k: calls.append(a) or []  # type: ignore[method-assign]
    _run(net, 5)
    assert calls == []
    net.close()
    net = _network()
    net.submit(AsyncRequest(0.0, 4, "write", 0x6065, 0, 1000, origin="controller"))
    net.submit(AsyncRequest(0.0, 4, "read", 0x6065, 0, origin="controller"))
    _run(net, 6)
    results = net.asynchronous.results
    net.close()
    assert [(r.answer, r.sent_cycle, r.answered_cycle) for r in results] == [("ok", 0, 1), (1000, 2, 3)]


@pytest.mark.parametrize("item, key, expected", [
    ({"time_s": -1, "node": 1, "sdo": "read", "index": 0x1000}, "asynchronous[0].time_s", "a time >= 0"),
    ({"time_s": 0, "node": 0, "sdo": "read", "index": 0x1000}, "asynchronous[0].node", "a node id 1..127"),
    ({"time_s": 0, "node": 1, "sdo": "get", "index": 0x1000}, "asynchronous[0].sdo", "one of read, write, raw"),
    ({"time_s": 0, "node": 1, "sdo": "write", "index": 0x6065}, "asynchronous[0].value", "an integer"),
    ({"time_s": 0, "node": 1, "sdo": "read", "index": 0x10000}, "asynchronous[0].index", "0x0000..0xFFFF"),
    ({"time_s": 0, "node": 1, "nmt": "halt"}, "asynchronous[0].nmt", "one of start, stop"),
    ({"time_s": 0, "node": 1, "nmt": "stop", "sdo": "read"}, "asynchronous[0]", "exactly one of"),
    ({"time_s": 0, "node": 1, "sdo": "raw", "data": [1] * 9}, "asynchronous[0].data", "0..8 bytes"),
    ({"time_s": 0, "node": 1, "sdo": "read", "index": 1, "wait": 2}, "asynchronous[0].wait", "one of the keys"),
])
def test_scenario_keys_are_checked(item, key, expected):
    with pytest.raises(FieldbusConfigError) as error:
        FieldbusConfig.from_dict({"asynchronous": [item]}, source="cell.toml")
    text = str(error.value)
    assert text.startswith(f"cell.toml: fieldbus.{key} = ") and expected in text


def test_asynchronous_is_a_list():
    with pytest.raises(FieldbusConfigError, match="fieldbus.asynchronous = .*a list of tables"):
        FieldbusConfig.from_dict({"asynchronous": {"time_s": 0}}, source="cell.toml")
    assert np.isinf(_network()._async_next)
