"""Fault injection and POWERLINK threshold counters: loss bursts trip at the right cycle
on the right side, every error and counter change is recorded, the drive gets its fault
reaction, fault reset recovers; garbage on the bus is counted and never stops the run."""
import json
import logging

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fieldbus import (Cia402DriveModel, DriveActuals, DriveState, EnableSequencer, PowerlinkNetwork, Setpoints,
                      decode_statusword, statusword_for)
from fieldbus.cia402 import motion_enabled
from fieldbus_support import ENABLED, scaling


def burst(node, start, cycles, frames="preq", kind="loss"):
    return {"faults": {"bursts": [{"node": node, "start_cycle": start, "cycles": cycles,
                                   "frames": frames, "kind": kind}]}}


def run_plain(network, cycles, controlword=None):
    """Run with enabled drives; ``controlword(k)`` may override the command."""
    setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
    actuals.statusword[:] = ENABLED
    out = []
    for k in range(cycles):
        setpoints.controlword[:] = controlword(k) if controlword else 0x0F
        result = network.run_cycle(k, setpoints, actuals)
        out.append((result.applied.copy(), result.observed.copy()))
    return out


def events(network, **match):
    return network.events.select(**match)


@pytest.mark.parametrize("threshold, trip_offset", [(15, 1), (24, 2), (0, None)])
def test_preq_loss_burst_trips_the_controlled_node_at_the_right_cycle(tmp_path, threshold, trip_offset):
    config = burst(3, 50, 3) | {"thresholds": {"cn_loss_of_preq": threshold, "mn_loss_of_pres": threshold}}
    with PowerlinkNetwork(config, scaling(), log_path=tmp_path / "burst.blf") as network:
        out = run_plain(network, 80)
        summary = network.summary()
    errors = events(network, side="cn", kind="loss_of_preq", event="error")
    assert [(e.node, e.cycle) for e in errors] == [(3, 50), (3, 51), (3, 52)]
    assert [e.cumulative for e in errors] == [1, 2, 3]
    tripped = events(network, side="cn", event="threshold_reached")
    if trip_offset is None:
        assert [e.counter for e in errors] == [0, 0, 0]  # threshold 0 disables counting
        assert not tripped and not any(a.comm_fault.any() for a, _ in out)
        return
    assert [e.counter for e in errors] == [8, 16, 24]
    trip = 50 + trip_offset
    assert [(e.node, e.cycle, e.counter, e.threshold) for e in tripped] == [(3, trip, 8 * (trip_offset + 1), threshold)]
    assert events(network, side="cn", event="fault_reaction")[0].cycle == trip
    # the drive gets the fault from the next SoC on: fault code 0x8100 (abort option 'fault')
    for k, (applied, _) in enumerate(out):
        assert applied.comm_fault[2] == (k > trip), k
        assert applied.fault_code[2] == (0x8100 if k > trip else 0)
        assert not applied.comm_fault[[0, 1, 3, 4, 5]].any()
    # the PRes of node 3 is missing too (no PReq, no answer): the MN trips and reports
    assert [e.cycle for e in events(network, side="mn", kind="loss_of_pres", event="threshold_reached")] == [trip]
    assert [k for k, (_, observed) in enumerate(out) if observed.node_fault[2]][0] == trip
    assert [k for k, (_, observed) in enumerate(out) if not observed.fresh[2]] == [50, 51, 52]
    # every counter change after the burst is recorded: 24 -> 0 one per cycle
    decrements = events(network, side="cn", node=3, kind="loss_of_preq", event="decrement")
    assert [e.counter for e in decrements] == list(range(8 * 3 - 1, -1, -1))
    assert [e.cycle for e in decrements] == list(range(53, 53 + 24))
    # the EMCY of node 3 is in the log, in the asynchronous slot of the trip cycle
    emcy = [m for m in can.LogReader(str(tmp_path / "burst.blf")) if m.arbitration_id == 0x083]
    assert len(emcy) == 1 and round(emcy[0].timestamp / 400e-6 - 0.5) == trip
    assert events(network, side="mn", event="emcy_received")[0].node == 3
    # summary lists each fault with node, cycle and counter values, JSON-ready
    faults = json.loads(json.dumps(summary["faults"]))
    assert {"side": "cn", "node": 3, "cycle": trip, "event": "threshold_reached",
            "kind": "loss_of_preq"}.items() <= next(f for f in faults if f["event"] == "threshold_reached").items()
    assert summary["comm_fault"] == [False, False, True, False, False, False]
    assert summary["node_fault"] == [False, False, True, False, False, False]
    assert sum(f["event"] == "injected" for f in faults) == 3


def test_pres_loss_burst_trips_only_the_managing_node():
    with PowerlinkNetwork(burst(5, 20, 2, frames="pres"), scaling()) as network:
        out = run_plain(network, 40)
    assert [(e.node, e.cycle) for e in events(network, side="mn", event="threshold_reached")] == [(5, 21)]
    assert not events(network, side="cn", event="error")
    assert not any(a.comm_fault.any() for a, _ in out)
    assert out[21][1].node_fault.tolist() == [False] * 4 + [True, False]
    assert not out[22][1].motion_allowed


def test_a_silent_node_is_reported_by_the_managing_node():
    config = {"faults": {"silent_nodes": [{"node": 2, "from_cycle": 10, "until_cycle": 30}]}}
    with PowerlinkNetwork(config, scaling()) as network:
        out = run_plain(network, 40)
    assert [e.cycle for e in events(network, side="mn", node=2, event="threshold_reached")] == [11]
    observed = [o for _, o in out]
    assert [k for k, o in enumerate(observed) if not o.fresh[1]] == list(range(10, 30))
    assert all(o.node_fault[1] for o in observed[11:])  # latched until a fault reset


def test_fault_reset_clears_both_sides_once_the_counters_are_below_threshold():
    def controlword(k):
        return 0x80 if k in (58, 70) else 0x0F  # a reset too early (counter 17), one in time
    with PowerlinkNetwork(burst(4, 50, 3), scaling()) as network:
        out = run_plain(network, 80, controlword)
    applied = [a for a, _ in out]
    observed = [o for _, o in out]
    assert applied[59].comm_fault[3] and observed[58].node_fault[3]  # 24 - 6 = 18 >= 15: refused
    assert not applied[71].comm_fault[3] and applied[71].controlword[3] == 0x80
    assert applied[70].comm_fault[3]
    assert not observed[70].node_fault[3]
    cleared = events(network, event="fault_cleared")
    assert sorted((e.side, e.cycle) for e in cleared) == [("cn", 71), ("mn", 70)]


def test_random_faults_are_seeded_counted_and_recorded():
    config = {"seed": 7, "faults": {"loss_probability": 2e-3, "late_probability": 1e-3, "corrupt_probability": 1e-3},
              "thresholds": {name: 0 for name in ("cn_loss_of_soc", "cn_loss_of_preq", "cn_crc_error",
                                                  "cn_soc_jitter", "mn_loss_of_pres", "mn_late_pres",
                                                  "mn_crc_error")}}
    tallies = []
    for _ in range(2):
        with PowerlinkNetwork(config, scaling()) as network:
            run_plain(network, 1500)
            tallies.append(network.events.tally())
            summary = network.summary()
    assert tallies[0] == tallies[1]
    injected = sum(v for k, v in tallies[0].items() if k.endswith(".injected"))
    assert 30 < injected < 150  # 4e-3 per frame, 13 frames per cycle, 1500 cycles -> ~78
    assert tallies[0].get("mn.late_pres.error", 0) > 0
    assert tallies[0].get("mn.crc_error.error", 0) + tallies[0].get("cn.crc_error.error", 0) > 0
    assert summary["frames_dropped"] > 0
    assert not any(summary["node_fault"]) and not any(summary["comm_fault"])


def test_quick_stop_option_presents_the_quick_stop_controlword():
    config = burst(1, 30, 2) | {"reaction": {"abort_connection_option": "quick_stop"}}
    with PowerlinkNetwork(config, scaling()) as network:
        out = run_plain(network, 40)
    assert out[32][0].controlword.tolist() == [0x02, 0x0F, 0x0F, 0x0F, 0x0F, 0x0F]
    assert out[32][0].fault_code.tolist() == [0] * 6
    assert out[31][0].controlword[0] == 0x0F


# ------------------------------------------------------------------ closed loop with drive models


def closed_loop(network, drives, cycles, on_cycle=None):
    """Controller with one EnableSequencer per drive, drives modelled in Python."""
    sequencers = [EnableSequencer() for _ in drives]
    setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
    states = []
    for k in range(cycles):
        actuals.statusword[:] = [d.statusword for d in drives]
        result = network.run_cycle(k, setpoints, actuals)
        for i, d in enumerate(drives):
            d.step(int(result.applied.controlword[i]), fault=bool(result.applied.fault_code[i]))
        observed = result.observed
        for i, sequencer in enumerate(sequencers):
            setpoints.controlword[i] = sequencer.next_controlword(int(observed.statusword[i]))
        states.append([decode_statusword(int(s)) for s in observed.statusword])
        if on_cycle:
            on_cycle(k, result, setpoints)
    return states


def test_enable_sequence_reaches_operation_enabled_over_the_bus(tmp_path):
    drives = [Cia402DriveModel() for _ in range(6)]
    with PowerlinkNetwork({}, scaling(), log_path=tmp_path / "enable.blf") as network:
        states = closed_loop(network, drives, 20)
    first = next(k for k, s in enumerate(states) if all(x is DriveState.OPERATION_ENABLED for x in s))
    assert first <= 12
    assert all(d.state is DriveState.OPERATION_ENABLED for d in drives)
    path = [to for _, _, to in drives[0].transitions]
    assert path == [DriveState.SWITCH_ON_DISABLED, DriveState.READY_TO_SWITCH_ON,
                    DriveState.SWITCHED_ON, DriveState.OPERATION_ENABLED]
    # the commands travelled in the RPDO1 telegrams: shutdown, switch on, enable operation
    words = [m.data[0] | m.data[1] << 8 for m in can.LogReader(str(tmp_path / "enable.blf"))
             if m.arbitration_id == 0x201]
    sequence = [w for i, w in enumerate(words) if i == 0 or w != words[i - 1]]
    assert sequence == [0x00, 0x06, 0x07, 0x0F]


def test_comm_fault_drives_the_fault_reaction_and_the_controller_recovers():
    drives = [Cia402DriveModel(fault_reaction_cycles=5) for _ in range(6)]
    with PowerlinkNetwork(burst(2, 40, 3), scaling()) as network:
        states = closed_loop(network, drives, 120)
    node2 = [s[1] for s in states]
    assert node2[30] is DriveState.OPERATION_ENABLED
    fault_cycles = [k for k, s in enumerate(node2) if s is DriveState.FAULT]
    assert fault_cycles and fault_cycles[0] > 41
    assert DriveState.FAULT_REACTION_ACTIVE in node2[41:fault_cycles[0]]
    assert not any(motion_enabled(int(statusword_for(s))) for s in node2[fault_cycles[0]:fault_cycles[-1]])
    # the sequencer's fault reset is applied once the counters fell below 15: back to enabled
    assert node2[-1] is DriveState.OPERATION_ENABLED
    assert all(s is DriveState.OPERATION_ENABLED for s in states[-1])
    assert [e.side for e in events(network, event="fault_cleared")] == ["mn", "cn"]


# ------------------------------------------------------------------ garbage on the bus

garbage = st.builds(
    lambda arbitration_id, data, error, remote, extended: can.Message(
        arbitration_id=arbitration_id, data=b"" if remote else data, is_error_frame=error,
        is_remote_frame=remote and not error, is_extended_id=extended, timestamp=0.0),
    arbitration_id=st.integers(0, 0x7FF), data=st.binary(max_size=8), error=st.booleans(),
    remote=st.booleans(), extended=st.booleans())


@settings(max_examples=300, deadline=None)
@given(msg=garbage)
def test_nodes_never_raise_on_any_frame(msg):
    network = NETWORK
    network.mn.receive(msg)
    network.cn.receive(msg)


NETWORK = PowerlinkNetwork({}, scaling())


def teardown_module():
    NETWORK.close()


def test_garbage_frames_are_counted_logged_and_do_not_stop_the_run(caplog):
    rng = np.random.default_rng(3)
    with PowerlinkNetwork({}, scaling()) as network:
        rogue = can.Bus(interface="simbus", channel=network.channel)
        setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
        actuals.statusword[:] = ENABLED
        caplog.set_level(logging.WARNING, logger="fieldbus")
        try:
            for k in range(200):
                if k % 10 == 5:  # random bytes on unknown ids, short and long frames on real ids
                    rogue.send(can.Message(arbitration_id=int(rng.integers(0x300, 0x7FF)),
                                           data=rng.bytes(int(rng.integers(0, 9))), is_extended_id=False))
                    rogue.send(can.Message(arbitration_id=0x204, data=b"\x01\x02", is_extended_id=False))
                    rogue.send(can.Message(arbitration_id=0x185, data=rng.bytes(3), is_extended_id=False))
                    rogue.send(can.Message(arbitration_id=0x1FFFF, data=b"", is_extended_id=True))
                result = network.run_cycle(k, setpoints, actuals)
        finally:
            rogue.shutdown()
        decode_errors = network.events.select(event="decode_error")
    reasons = {(e.side, e.kind) for e in decode_errors}
    assert {("mn", "unknown_id"), ("cn", "unknown_id"), ("cn", "short_frame"), ("mn", "short_frame")} <= reasons
    assert network.mn.decode_errors > 0 and network.cn.decode_errors > 0
    assert any("decode_error" in r.getMessage() for r in caplog.records)
    # the run went on and the process data kept flowing
    assert result.observed.fresh.all() and result.applied.fresh.all()
    # short frames addressed to a node count as CRC/format errors of that node only
    assert {e.node for e in network.events.select(event="error", kind="crc_error")} == {4, 5}


@pytest.mark.parametrize("frames, kind, delay_us, expected", [
    ("soc", "loss", 150.0, {("cn", "loss_of_soc")}),
    ("soc", "corrupt", 150.0, {("cn", "loss_of_soc"), ("cn", "crc_error")}),
    ("soc", "late", 150.0, {("cn", "soc_jitter")}),
    ("preq", "corrupt", 150.0, {("cn", "crc_error"), ("cn", "loss_of_preq"), ("mn", "loss_of_pres")}),
    ("preq", "late", 150.0, {("mn", "late_pres")}),
    ("preq", "late", 450.0, {("cn", "loss_of_preq"), ("mn", "late_pres")}),
    ("pres", "late", 150.0, {("mn", "late_pres")}),
    ("pres", "corrupt", 150.0, {("mn", "crc_error"), ("mn", "loss_of_pres")}),
])
def test_each_fault_kind_feeds_its_threshold_counters(frames, kind, delay_us, expected):
    config = burst(2, 10, 1, frames=frames, kind=kind)
    config["faults"]["late_delay_us"] = delay_us
    with PowerlinkNetwork(config, scaling()) as network:
        out = run_plain(network, 15)
    errors = events(network, event="error")
    assert {(e.side, e.kind) for e in errors} == expected
    assert {e.cycle for e in errors} == {10}
    nodes = {e.node for e in errors}
    assert nodes == ({1, 2, 3, 4, 5, 6} if frames == "soc" else {2})
    # one error is no trip, and the process data of the other cycles is untouched
    assert not events(network, event="threshold_reached")
    assert all(o.fresh.all() for k, (_, o) in enumerate(out) if k != 10)


def ramp_through_a_burst(cycles, burst_cycles):
    """Send a 1 mrad-per-cycle position ramp to every drive while node 1 loses the PReqs of
    ``burst_cycles`` cycles from cycle 10, drives extrapolating: the scaling, the applied set-points
    of each cycle and node 1's applied position in counts."""
    config = burst(1, 10, burst_cycles) | {"reaction": {"missing_setpoint": "extrapolate"}}
    sc = scaling()
    with PowerlinkNetwork(config, sc) as network:
        setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
        applied = []
        for k in range(cycles):
            setpoints.position[:] = 1e-3 * k
            applied.append(network.run_cycle(k, setpoints, actuals).applied.copy())
    return sc, applied, [int(sc.position_to_counts(a.position)[0]) for a in applied]


def test_extrapolating_policy_continues_the_ramp_over_a_lost_setpoint():
    sc, applied, counts = ramp_through_a_burst(14, 1)
    assert not applied[11].fresh[0] and applied[12].fresh[0]
    assert counts[11] - counts[10] == counts[10] - counts[9]  # the PReq of cycle 10 never arrived
    assert counts[12] == int(sc.position_to_counts(np.full(6, 11e-3))[0])


def test_extrapolation_lasts_one_cycle_then_holds():
    """A run of missing set-points: the first is extrapolated, the next ones hold it (a drive does not
    run on blind along a straight line while its controller is gone); fresh ones take over again."""
    sc, applied, counts = ramp_through_a_burst(18, 4)
    assert [bool(a.fresh[0]) for a in applied[10:17]] == [True, False, False, False, False, True, True]
    assert counts[11] - counts[10] == counts[10] - counts[9]  # extrapolated
    assert counts[12] == counts[13] == counts[14] == counts[11]  # then held
    assert counts[15] == int(sc.position_to_counts(np.full(6, 14e-3))[0])
