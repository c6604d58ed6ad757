"""Pacer, overrun policies on the set-points, fault-plan wrapper, statistics, settings."""
from __future__ import annotations

import time

import numpy as np
import pytest

from cosim.execution.timing.pacer import LatenessLog, Pacer, VirtualClock
from cosim.execution.timing.policy import OverrunFaultPlan, SetpointGate
from cosim.execution.timing.stats import combine, lateness_summary, write_histogram
from fieldbus import FieldbusConfig, Setpoints
from fieldbus.faults import FaultPlan

T = 400e-6


def _virtual(tolerance_s=10e-6):
    clock = VirtualClock()
    return clock, Pacer(T, 0.0, tolerance_s, clock_ns=clock.now_ns, sleep=clock.sleep)


def test_on_time_cycles_wait_for_their_deadline_and_are_not_late():
    clock, pacer = _virtual()
    starts = []
    for k in range(10):
        assert pacer.wait(k) is False
        starts.append(clock.now_ns())
        clock.advance_ns(123_000)   # the cycle's work
    assert starts == [k * 400_000 for k in range(10)]
    assert pacer.log.overrun_cycles == [] and np.all(pacer.log.lateness_us == 0.0)
    np.testing.assert_array_equal(pacer.log.work_us, 123.0)


def test_lateness_above_the_tolerance_is_an_overrun_below_it_is_not():
    clock, pacer = _virtual(tolerance_s=10e-6)
    pacer.wait(0)
    clock.advance_ns(405_000)        # 5 us late: within tolerance
    assert pacer.wait(1) is False
    clock.advance_ns(411_000)        # cycle 1 started 5 us late + 411 us of work: 16 us late
    assert pacer.wait(2) is True
    assert pacer.log.lateness_us.tolist() == [0.0, 5.0, 16.0]
    assert pacer.log.overrun_cycles == [2]


def test_whole_missed_periods_are_dropped_not_caught_up():
    clock, pacer = _virtual()
    pacer.wait(0)
    clock.advance_ns(1_000_000)      # 2.5 cycles of work
    assert pacer.wait(1) is True     # 600 us late: one whole tick dropped
    assert pacer.log.missed_ticks == 1
    start1 = clock.now_ns()
    assert pacer.wait(2) is False    # next deadline on the shifted grid: 1.2 ms
    assert clock.now_ns() == 1_200_000 and start1 == 1_000_000


def test_first_wait_defines_the_origin_for_any_cycle_number():
    clock, pacer = _virtual()
    clock.advance_ns(5_000_000)
    pacer.wait(7)
    assert pacer.deadline_ns(7) == 5_000_000 and pacer.deadline_ns(8) == 5_400_000


def test_real_clock_pacing_never_runs_ahead_of_the_wall_clock():
    pacer = Pacer(T, 100e-6, 10e-6)
    t0 = time.perf_counter_ns()
    for k in range(40):
        pacer.wait(k)
    elapsed = time.perf_counter_ns() - t0
    assert elapsed >= 39 * 400_000
    assert np.all(pacer.log.lateness_ns[:40] >= 0)


def test_pacer_rejects_bad_settings():
    with pytest.raises(ValueError, match="period_s"):
        Pacer(0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="spin_s"):
        Pacer(T, -1.0, 0.0)


def _sp(position, cw=15, tq=0.5):
    sp = Setpoints.zeros(6)
    sp.position[:] = position
    sp.controlword[:] = cw
    sp.torque_offset[:] = tq
    return sp


def test_hold_repeats_the_last_sent_setpoints():
    gate = SetpointGate("hold", 6)
    gate.send(_sp(1.0), False)
    gate.send(_sp(2.0, tq=0.7), False)
    out = gate.send(_sp(3.0, cw=7, tq=0.9), True)
    np.testing.assert_array_equal(out.position, 2.0)
    np.testing.assert_array_equal(out.torque_offset, 0.7)
    np.testing.assert_array_equal(out.controlword, 15)
    np.testing.assert_array_equal(gate.send(_sp(4.0), True).position, 2.0)   # still holding
    np.testing.assert_array_equal(gate.send(_sp(5.0), False).position, 5.0)
    assert gate.substituted == 2


def test_skip_continues_at_constant_velocity():
    gate = SetpointGate("skip", 6)
    gate.send(_sp(1.0), False)
    gate.send(_sp(1.5), False)
    np.testing.assert_allclose(gate.send(_sp(9.0), True).position, 2.0)
    np.testing.assert_allclose(gate.send(_sp(9.0), True).position, 2.5)
    np.testing.assert_allclose(gate.send(_sp(3.1), False).position, 3.1)


def test_lost_frame_passes_the_setpoints_on_and_first_cycle_is_never_substituted():
    gate = SetpointGate("lost_frame", 6)
    np.testing.assert_array_equal(gate.send(_sp(1.0), True).position, 1.0)
    assert SetpointGate("hold", 6).send(_sp(4.0), True).position[0] == 4.0   # nothing sent before
    with pytest.raises(ValueError, match="overrun policy"):
        SetpointGate("drop", 6)


def test_overrun_fault_plan_loses_every_preq_of_marked_cycles_on_top_of_configured_faults():
    config = FieldbusConfig.from_dict({"faults": {"bursts": [{"node": 2, "start_cycle": 5, "cycles": 1,
                                                              "frames": "pres", "kind": "late"}]}})
    plan = OverrunFaultPlan(FaultPlan(config), 6)
    assert plan.for_cycle(4) is None
    plan.mark_lost(5)
    plan.mark_lost(9)
    assert plan.for_cycle(5).kinds == {8: "late", **{n: "loss" for n in range(1, 7)}}
    assert plan.for_cycle(9).kinds == {n: "loss" for n in range(1, 7)}
    assert plan.is_lost(9) and not plan.is_lost(6)


def test_summary_percentiles_and_histogram(tmp_path):
    log = LatenessLog(4)
    values = [0, 1000, 2000, 500_000] + [0] * 96
    for k, v in enumerate(values):
        log.append(k, v, v > 10_000, 200_000)
    s = lateness_summary(log)
    assert s["cycles"] == 100 and s["overruns"] == 1 and s["overrun_fraction"] == 0.01
    assert s["lateness"]["max_us"] == 500.0
    assert s["lateness"]["p50_us"] == 0.0
    assert s["lateness"]["p99_us"] == pytest.approx(np.percentile(np.array(values) / 1e3, 99))
    assert s["overrun_cycles"] == [3]
    both = combine([log, log])
    assert both.count == 200 and lateness_summary(both)["overruns"] == 2
    png = write_histogram(tmp_path / "j.png", log, period_s=T, tolerance_s=10e-6)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
