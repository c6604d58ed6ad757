"""The cell side of a hardware-in-the-loop run (``DriveEndpoint.run_cycle_paced``) on a
virtual clock: a controller late by more than its slot in chosen cycles produces exactly
POWERLINK's lost frames and threshold-counter increments in those cycles."""
from __future__ import annotations

import re

import can
import numpy as np
import pytest

from fieldbus import DriveActuals, DriveEndpoint, JointScaling, ManagingNodeEndpoint, Setpoints
from fieldbus.simbus import unique_channel
from fieldbus.telegrams import RPDO1_BASE, SYNC_ID, TPDO1_BASE, FastMessage
from paced_support import Clock, paced_run

SCALING = JointScaling([100.0] * 6, 2**20, [10.0] * 6)
CONFIG = {"seed": 1}


def _ramp(k: int, sp: Setpoints) -> None:
    sp.position[:] = 1e-3 * k


def _run(late_cycles, cycles, log_path=None, skip=()):
    return paced_run(CONFIG, SCALING, cycles, _ramp, late=late_cycles, skip=skip, log_path=log_path)


def _errors(cn, kind):
    return [(e.cycle, e.node, e.counter) for e in cn.events.events if e.kind == kind and e.event == "error"]


def test_on_time_controller_loses_nothing():
    cn, applied = _run(set(), 30)
    assert _errors(cn, "loss_of_preq") == [] and _errors(cn, "loss_of_soc") == []
    assert cn.frames_late == 0
    assert all(fresh.all() for _, _, fresh in applied[1:])


def test_late_cycles_are_lost_frames_with_counter_increments_in_exactly_those_cycles(tmp_path):
    late = {10, 20, 21}
    cn, applied = _run(late, 40, log_path=tmp_path / "cell.blf")
    preq = _errors(cn, "loss_of_preq")
    assert sorted({c for c, _, _ in preq}) == [10, 20, 21]
    assert len(preq) == 3 * 6
    # +8 per lost cycle, -1 per good one: 8 at cycle 10; 8 at 20 (drained by then), 16 at 21 -> trip
    assert {c: v for c, n, v in preq if n == 1} == {10: 8, 20: 8, 21: 16}
    assert {c for c, _, _ in _errors(cn, "loss_of_soc")} == {10, 20, 21}
    trips = [(e.cycle, e.node) for e in cn.events.events if e.event == "threshold_reached"]
    assert {c for c, _ in trips} == {21} and {n for _, n in trips} == set(range(1, 7))
    # each late group arrives in the next window, where it is dropped
    assert cn.frames_late == 3 * 7
    # the set-point applied with one cycle of dead time is missing (held) after a lost cycle
    assert not applied[11][2].any() and applied[12][2].all()
    # the cell's CAN log: SoC and PReqs absent in the lost cycles, PRes every cycle
    frames = list(can.LogReader(str(tmp_path / "cell.blf")))
    soc_cycles = sorted(round(m.timestamp / 4e-4) for m in frames if m.arbitration_id == SYNC_ID)
    assert soc_cycles == [k for k in range(40) if k not in late]
    assert sum(1 for m in frames if m.arbitration_id == RPDO1_BASE + 3) == 40 - 3
    assert sum(1 for m in frames if m.arbitration_id == TPDO1_BASE + 3) == 40


def test_a_controller_that_stops_sending_trips_the_counters_and_faults_the_drives():
    cn, applied = _run(set(), 12, skip=set(range(5, 12)))
    trips = sorted({e.cycle for e in cn.events.events if e.event == "threshold_reached"})
    assert trips == [6]  # 8 at cycle 5, 16 >= 15 at cycle 6
    # from the next SoC on, the drives get the communication fault code
    assert cn.nodes.comm_fault == [True] * 6
    # once every node has reacted, the silent controller is not counted any further
    assert max(c for c, _, _ in _errors(cn, "loss_of_preq")) == 6


def test_a_constant_phase_from_the_start_is_aligned_not_lost():
    """The first group fixes the mapping of the controller's SoC counter onto the cell's
    cycles: a controller whose frames always land one window later is in phase."""
    cn, applied = _run(set(range(0, 30)), 30)
    assert _errors(cn, "loss_of_preq") == []  # cycle 0 came before any frame: not operational yet
    assert cn.frames_late == 0
    np.testing.assert_allclose(applied[10][0], np.full(6, 1e-3 * 8), atol=1e-6)


def _follow_run(cycles, late=(), silent=()):
    """Cell side paced (virtual clock), controller side following it (ManagingNodeEndpoint.follow)."""
    channel = unique_channel("hil")
    mn = ManagingNodeEndpoint(CONFIG, SCALING, channel=channel)
    cn = DriveEndpoint(CONFIG, SCALING, channel=channel)
    clock = Clock()
    sp, act = Setpoints.zeros(6), DriveActuals.zeros(6)
    seen, applied = [], []
    for k in range(cycles):
        act.statusword[:] = 0x27
        act.position[:] = 1e-3 * k
        clock.t = k * 4e-4 + 2e-4
        a = cn.run_cycle_paced(k, act, deadline=clock.t, clock=clock)
        applied.append(a.position.copy())
        if k in late or k in silent:
            continue  # the controller misses this cycle's PRes (slow) or is gone
        got = mn.follow(0.0)
        assert got is not None
        cycle, observed = got
        seen.append((k, cycle, observed.position[0]))
        sp.controlword[:] = 0x0F
        sp.position[:] = observed.position + 0.5
        mn.send_following(sp)
    cn.close()
    mn.close()
    return cn, seen, applied


def test_a_following_controller_stays_in_step_with_the_paced_cell():
    cn, seen, applied = _follow_run(50)
    assert all(k == cycle for k, cycle, _ in seen)  # its count of the cell's cycles is right
    np.testing.assert_allclose([p for _, _, p in seen[:3]], [0.0, 0.001, 0.002], atol=1e-5)  # quantised
    assert _errors(cn, "loss_of_preq") == []  # nothing counts before its first frames
    # the set-point computed from the values of cycle k is applied from cycle k + 2 (dead time 1)
    np.testing.assert_allclose(applied[20], np.full(6, 1e-3 * 18 + 0.5), atol=1e-5)


def test_a_controller_that_misses_a_cycle_catches_up_with_one_loss():
    cn, seen, applied = _follow_run(50, late={20})
    # after the miss, it sees two PRes batches at once and counts both
    assert [(k, c) for k, c, _ in seen if k in (19, 21, 22)] == [(19, 19), (21, 21), (22, 22)]
    assert {c for c, _, _ in _errors(cn, "loss_of_preq")} == {21}
    assert not any(e.event == "threshold_reached" for e in cn.events.events)


def _self_clocked_run(controller_cycle_s, cycles, cell_cycle_s=4e-4):
    """A controller on its own clock (not following the cell) at ``controller_cycle_s``;
    its k-th group goes out at k * controller_cycle_s, the cell's windows close on a virtual clock."""
    channel = unique_channel("hil")
    mn = ManagingNodeEndpoint(CONFIG, SCALING, channel=channel)
    cn = DriveEndpoint(CONFIG, SCALING, channel=channel)
    clock = Clock()
    sp, act = Setpoints.zeros(6), DriveActuals.zeros(6)
    sp.controlword[:] = 0x0F
    sent = 0
    for k in range(cycles):
        clock.t = k * cell_cycle_s + cell_cycle_s / 2
        while sent * controller_cycle_s <= clock.t:
            mn.send_setpoints(sent, sp)
            mn._read_now()  # the PRes frames: this controller does not look at them
            sent += 1
        act.statusword[:] = 0x27
        cn.run_cycle_paced(k, act, deadline=clock.t, clock=clock)
    cn.close()
    mn.close()
    return cn


def _mismatch_events(cn):
    return [e for e in cn.events.events if e.kind == "cycle_time_mismatch"]


def test_a_slower_controller_is_a_counted_logged_cycle_time_mismatch(caplog):
    cn = _self_clocked_run(1e-3, 1500)
    events = _mismatch_events(cn)
    assert len(events) == 1 and events[0].event == "error"  # one episode, logged once
    # the estimate from blocks of 250 cell cycles is good to about one SoC group (0.4 of 100): ~1 %
    estimate = re.search(r"its cycle is about ([0-9.]+) ms, the cell's 0.4 ms", events[0].detail)
    assert estimate and float(estimate.group(1)) == pytest.approx(1.0, rel=0.01), events[0].detail
    report = cn.cadence.report()
    assert report["controller_cycle_time_s_estimate"] == pytest.approx(1e-3, rel=0.02)
    assert report["blocks"] == report["blocks_judged"] >= 4
    assert any("cycle_time_mismatch" in r.getMessage() for r in caplog.records)
    # and its frames are what POWERLINK makes of them: lost cycles, trips
    assert _errors(cn, "loss_of_preq") and any(e.event == "threshold_reached" for e in cn.events.events)


def test_a_faster_controller_is_a_cycle_time_mismatch():
    cn = _self_clocked_run(2e-4, 1500)
    report = cn.cadence.report()
    assert report is not None and report["controller_cycle_time_s_estimate"] == pytest.approx(2e-4, rel=0.02)
    assert len(_mismatch_events(cn)) == 1


def test_controllers_in_step_are_no_mismatch():
    assert _self_clocked_run(4e-4, 1500).cadence.report() is None
    cn, _, _ = _follow_run(1500, late={300, 700, 701})  # a follower that misses cycles and catches up
    assert cn.cadence.report() is None and cn.cadence.blocks >= 4
    cn, _ = _run({100, 500}, 1500)
    assert cn.cadence.report() is None and not _mismatch_events(cn)


def test_a_restarted_controller_counter_jump_is_no_mismatch():
    from fieldbus.endpoints import ControllerCadence

    cadence = ControllerCadence(240, 4e-4)
    for k in range(2000):
        counter = (k + (97 if k >= 600 else 0)) % 240 + 1  # it restarted at cycle 600 with another counter
        if 560 <= k < 600:
            continue  # gone for 40 cycles first
        assert cadence.note(k, counter) is None
    assert cadence.report() is None and cadence.blocks >= 7


def test_a_late_group_after_a_stall_does_not_shift_the_controllers_cycles():
    """The controller sends nothing in cycles 30-31 (a stall) and its groups of 32 and 33 late (they
    arrive one window later): the cell lost 30-33, but the late group of 32, the only one in window
    33, is not taken as a restart (re-synchronising on it shifted every later set-point by a cycle);
    from 34 on the cell applies exactly what the run without the stall applies."""
    config = {**CONFIG, "thresholds": {"cn_loss_of_soc": 0, "cn_loss_of_preq": 0}}  # counted, never tripping
    clean = paced_run(config, SCALING, 60, _ramp)[1]
    cn, applied = paced_run(config, SCALING, 60, _ramp, late=(32, 33), skip=(30, 31))
    assert [c for c, node, _ in _errors(cn, "loss_of_preq") if node == 1] == [30, 31, 32, 33]
    for k in range(36, 60):
        assert np.array_equal(applied[k][0], clean[k][0]), k


def test_a_group_delivered_many_cycles_late_is_dropped_not_a_restart():
    """The controller computed its group of cycle 30 and then stalled before it went out: the group
    arrives 23 cycles late, alone in window 53, and nothing else comes until cycle 55. It is a late
    group (its counter is that of a past cycle), not a restarted controller: dropped, and from 55 on
    the cell applies what the run without the stall applies (before: re-synchronised on it, every
    later set-point 23 cycles old until the next re-synchronisation)."""
    config = {**CONFIG, "thresholds": {"cn_loss_of_soc": 0, "cn_loss_of_preq": 0}}
    clean = paced_run(config, SCALING, 90, _ramp)[1]
    channel = unique_channel("hil")
    mn = ManagingNodeEndpoint(config, SCALING, channel=channel)
    cn = DriveEndpoint(config, SCALING, channel=channel)
    clock = Clock()
    sp, act = Setpoints.zeros(6), DriveActuals.zeros(6)
    stashed, applied = [], []
    try:
        for k in range(90):
            sp.controlword[:] = 0x0F
            _ramp(k, sp)
            act.statusword[:] = 0x27
            if k == 30:  # computed, then the process stalled before its sendto
                send, mn._transmit = mn._transmit, lambda frames: stashed.extend(FastMessage(
                    m.timestamp, m.arbitration_id, bytearray(m.data)) for m in frames) or frames
                mn.send_setpoints(k, sp)
                mn._transmit = send
            elif 31 <= k <= 54:
                mn._begin(k)
            else:
                mn.send_setpoints(k, sp)
            if k == 53:
                mn.bus.send_many(stashed)  # the stale group of 30 reaches the cell in window 53
            clock.t = k * 4e-4 + 2e-4
            a = cn.run_cycle_paced(k, act, deadline=clock.t, clock=clock)
            applied.append(a.position.copy())
            mn.collect_actuals(k)
    finally:
        cn.close()
        mn.close()
    assert [c for c, node, _ in _errors(cn, "loss_of_preq") if node == 1] == list(range(30, 55))
    for k in range(57, 90):
        assert np.array_equal(applied[k], clean[k][0]), k
