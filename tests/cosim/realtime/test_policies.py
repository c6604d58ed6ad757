"""Overrun policies on the real cell (plant + six drive FMUs + POWERLINK bus + controller):
a deliberately slowed controller produces exactly the overruns it should, and the drives
react as the policy says. The wall clock is a VirtualClock that moves only when the
slowed controller 'works', so the expected overruns do not depend on the machine."""
from __future__ import annotations

import time

import numpy as np
import pytest

from cosim.execution.config import ExecutionOptions, RealtimeSettings
from cosim.execution.timing.network import auto_tolerance_s
from cosim.execution.timing.pacer import Pacer, VirtualClock
from realtime_support import BUS_TARGETS, PERIOD, build_cell, column_block, write_scenario

SLOW_AT = (150, 200)        # controller cycles that take 700 us of (virtual) wall time
SLOW_NS = 700_000           # -> the next cycle starts 300 us late: past the 263.44 us tolerance


def _slow_down(controller, delays: dict[int, float], advance) -> None:
    """Make ``controller.step`` take ``delays[cycle]`` ns of wall time in those cycles."""
    step = controller.step

    def slowed(inputs):
        out = step(inputs)
        if inputs.cycle in delays:
            advance(delays[inputs.cycle])
        return out

    controller.step = slowed


def _run(tmp_path, policy: str, delays: dict[int, int], stop_time: str = "100 ms"):
    from cosim.execution import run_cell
    from fieldbus.timing import check_cycle_budget

    cell, controller, ctx = build_cell(write_scenario(tmp_path, stop_time), tmp_path / "out")
    clock = VirtualClock()
    _slow_down(controller, delays, clock.advance_ns)
    tolerance = auto_tolerance_s(check_cycle_budget(cell.fieldbus))
    pacer = Pacer(PERIOD, 0.0, tolerance, clock_ns=clock.now_ns, sleep=clock.sleep)
    options = ExecutionOptions(realtime=True, settings=RealtimeSettings(overrun_policy=policy, scheduling="normal",
                                                                       cpu=None))
    run = run_cell(cell, controller, ctx, mode="paced", options=options, pacer=pacer)
    rec = run.recording
    t = rec.column("time")
    np.testing.assert_allclose(t, np.arange(t.size) * PERIOD, atol=1e-12)  # row k = cycle k
    return run, run.pacer, controller, column_block(rec, BUS_TARGETS)


def _loss_events(cell, side: str, kind: str, event: str) -> set[tuple[int, int]]:
    return {(e["cycle"], e["node"]) for e in cell.fieldbus["faults"] if e["side"] == side and e["kind"] == kind
            and e["event"] == event}


def _cn_errors(cell) -> list[dict]:
    return [e for e in cell.fieldbus["faults"] if e["event"] in ("error", "threshold_reached")]


def test_exact_overruns_and_hold_keeps_the_last_setpoint(tmp_path):
    cell, pacer, controller, targets = _run(tmp_path, "hold", {k: SLOW_NS for k in SLOW_AT})
    assert cell.failure is None
    assert controller.motion_start_cycle is not None and controller.motion_start_cycle < min(SLOW_AT) - 5
    # the cycle after each slowed one starts 300 us late (> 400 - 136.56 us: its isochronous phase
    # would end after the next SoC): an overrun; nothing else is late
    assert pacer.log.overrun_cycles == [k + 1 for k in SLOW_AT]
    lat = dict(zip(pacer.log.cycles[:pacer.log.count].tolist(), pacer.log.lateness_us.tolist()))
    assert [lat[k + 1] for k in SLOW_AT] == [300.0, 300.0]
    assert pacer.log.missed_ticks == 0
    d = 1
    for k in SLOW_AT:
        late = k + 1
        # the late cycle's PReqs carry the previous set-points: applied at late + d, equal to late + d - 1
        np.testing.assert_array_equal(targets[late + d], targets[late + d - 1])
        assert np.any(targets[late + d - 1] != targets[late + d - 2])  # the arm is moving there
        assert np.any(targets[late + d + 1] != targets[late + d])       # and moves on after
    assert not _cn_errors(cell)


def test_skip_extrapolates_the_dropped_setpoint(tmp_path):
    from cosim.cell.wiring import joint_scaling

    cell, pacer, _, targets = _run(tmp_path, "skip", {k: SLOW_NS for k in SLOW_AT})
    assert cell.failure is None
    assert pacer.log.overrun_cycles == [k + 1 for k in SLOW_AT]
    count = joint_scaling().rad_per_count
    for k in SLOW_AT:
        i = k + 1 + 1   # late cycle + dead time
        predicted = 2.0 * targets[i - 1] - targets[i - 2]
        assert np.all(np.abs(targets[i] - predicted) <= count * 1.0001)   # one encoder count of quantisation
        assert np.any(targets[i] != targets[i - 1])
    assert not _cn_errors(cell)


def test_lost_frame_feeds_the_threshold_counters_without_tripping_once(tmp_path):
    cell, pacer, controller, targets = _run(tmp_path, "lost_frame", {k: SLOW_NS for k in SLOW_AT})
    assert cell.failure is None and not controller.stopped
    late = [k + 1 for k in SLOW_AT]
    assert pacer.log.overrun_cycles == late
    expected = {(c, node) for c in late for node in range(1, 7)}
    assert _loss_events(cell, "cn", "loss_of_preq", "error") == expected
    assert _loss_events(cell, "mn", "loss_of_pres", "error") == expected  # no PReq, no PRes
    assert not any(e["event"] == "threshold_reached" for e in cell.fieldbus["faults"])
    counters = {(c["side"], c["node"], c["kind"]): c for c in cell.fieldbus["counters"]}
    assert all(counters[("cn", n, "loss_of_preq")]["cumulative"] == 2 for n in range(1, 7))
    for c in late:   # missing set-point: the drive holds ([fieldbus.reaction] missing_setpoint = "hold")
        np.testing.assert_array_equal(targets[c + 1], targets[c])


def test_lost_frame_twice_in_a_row_trips_the_counters_and_stops_the_controller(tmp_path):
    cell, pacer, controller, _ = _run(tmp_path, "lost_frame", {150: SLOW_NS, 151: SLOW_NS})
    assert pacer.log.overrun_cycles[:2] == [151, 152]
    tripped = {(e["side"], e["node"], e["kind"], e["cycle"]) for e in cell.fieldbus["faults"]
               if e["event"] == "threshold_reached"}
    assert {("cn", n, "loss_of_preq", 152) for n in range(1, 7)} <= tripped   # 8 + (8 - 1) = 15
    assert {("mn", n, "loss_of_pres", 152) for n in range(1, 7)} <= tripped
    assert controller.stopped and "node fault" in controller.stop_reason
    assert controller.stopped_at_s == pytest.approx(152 * PERIOD)
    assert all(cell.fieldbus["comm_fault"])


def test_a_late_cycle_by_whole_periods_drops_ticks_instead_of_catching_up(tmp_path):
    _, pacer, _, _ = _run(tmp_path, "hold", {150: 1_300_000}, stop_time="70 ms")
    log = pacer.log
    assert log.overrun_cycles == [151]
    assert log.missed_ticks == 2   # 1300 us = 3.25 cycles: 900 us late, two whole ticks dropped
    assert log.lateness_us[151] == pytest.approx(900.0)
    assert np.all(log.lateness_us[152:] == 0.0)


def test_real_wall_clock_slowed_controller_overruns_after_each_slow_cycle(tmp_path):
    """On the real clock (machine-independent assertions only): busy-waiting 1.5 ms in two
    controller cycles makes each following cycle late by at least 1.1 ms, and a paced run
    never runs faster than the wall clock."""
    from cosim.execution import run_cell

    cell, controller, ctx = build_cell(write_scenario(tmp_path, "60 ms"), tmp_path / "out")

    def busy(ns):
        end = time.perf_counter_ns() + ns
        while time.perf_counter_ns() < end:
            pass

    _slow_down(controller, {50: 1_500_000, 100: 1_500_000}, busy)
    wall0 = time.perf_counter()
    options = ExecutionOptions(realtime=True, settings=RealtimeSettings(scheduling="normal", cpu=None))
    cell = run_cell(cell, controller, ctx, mode="paced", options=options)
    pacer = cell.pacer
    wall = time.perf_counter() - wall0
    log = pacer.log
    lat = log.lateness_us
    assert log.count == 151
    for k in (51, 101):
        assert k in log.overrun_cycles and lat[k] >= 1100.0
    assert wall >= 150 * PERIOD
    targets = column_block(cell.recording, BUS_TARGETS)
    np.testing.assert_array_equal(targets[52], targets[51])   # hold


def test_a_substituted_setpoint_keeps_the_mode_and_its_setpoints():
    """hold/skip repeat the last cycle's mode of operation and velocity/torque set-points:
    a late controller never switches a drive out of the mode it commanded."""
    from fieldbus import Setpoints
    from cosim.execution.timing.policy import SetpointGate

    for policy in ("hold", "skip"):
        gate = SetpointGate(policy, 6)
        sp = Setpoints.zeros(6)
        sp.modes_of_operation[:] = 10
        sp.target_torque[:] = 12.5
        sp.target_velocity[:] = 0.3
        sp.velocity_offset[:] = 0.1
        gate.send(sp, late=False)
        out = gate.send(Setpoints.zeros(6), late=True)
        assert (out.modes_of_operation == 10).all() and (out.target_torque == 12.5).all()
        assert (out.target_velocity == 0.3).all() and (out.velocity_offset == 0.1).all()
