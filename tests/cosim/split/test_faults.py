"""Split runs when things go wrong: a killed drive process is detected by the controller
through the POWERLINK threshold counters; a paced split run's lost_frame overruns reach
the drive process through the cycle marker and trip its counters."""
from __future__ import annotations

import dataclasses
import os
import signal

import pytest

from cosim.execution.config import ExecutionOptions, RealtimeSettings
from cosim.execution.timing.network import auto_tolerance_s
from cosim.execution.timing.pacer import Pacer, VirtualClock
from cosim.execution import run_cell
from realtime_support import PERIOD, build_cell, write_scenario

KILL_AT = 60


def test_killed_drive_process_is_detected_within_the_threshold(tmp_path):
    cell, controller, ctx = build_cell(write_scenario(tmp_path, "80 ms"), tmp_path / "out")
    cell = dataclasses.replace(cell, can_log=tmp_path / "mn.blf")
    killed = {}

    def kill(cycle, session):
        if cycle == KILL_AT:
            os.kill(session.process.pid, signal.SIGKILL)
            session.process.join(5)
            killed["cycle"] = cycle

    options = ExecutionOptions(mode="split", receive_timeout_s=0.3)
    cell = run_cell(cell, controller, ctx, mode="split", options=options, on_cycle=kill)
    pacer, info = cell.pacer, cell.split
    assert pacer is None and killed["cycle"] == KILL_AT
    # increment 8 per lost PRes, threshold 15: the second lost cycle trips the node fault
    assert info["controller_stop_cycle"] == KILL_AT + 2
    assert controller.stopped and "node fault" in controller.stop_reason
    assert info["drive_process_exit_code"] == -signal.SIGKILL
    assert cell.failure is not None and "drive process ended" in str(cell.failure)
    tripped = {(e["node"], e["cycle"]) for e in cell.fieldbus["faults"]
               if e["side"] == "mn" and e["kind"] == "loss_of_pres" and e["event"] == "threshold_reached"}
    assert tripped == {(n, KILL_AT + 2) for n in range(1, 7)}
    assert cell.fieldbus["drive_side"].startswith("unavailable")
    assert cell.rows_recorded <= KILL_AT + 2   # what the drive process handed over before it died (1 ms rows)


def test_paced_split_lost_frames_trip_the_drive_side_counters(tmp_path):
    cell, controller, ctx = build_cell(write_scenario(tmp_path, "80 ms"), tmp_path / "out")
    fb = cell.fieldbus
    clock = VirtualClock()
    step = controller.step

    def slowed(inputs):
        out = step(inputs)
        if inputs.cycle in (100, 101):
            clock.advance_ns(700_000)   # the next cycle starts >= 300 us late
        return out

    controller.step = slowed
    from fieldbus.timing import check_cycle_budget

    pacer = Pacer(PERIOD, 0.0, auto_tolerance_s(check_cycle_budget(fb)), clock_ns=clock.now_ns, sleep=clock.sleep)
    options = ExecutionOptions(mode="split", realtime=True, receive_timeout_s=2.0,
                               settings=RealtimeSettings(overrun_policy="lost_frame", scheduling="normal", cpu=None))
    cell = run_cell(cell, controller, ctx, mode="split", options=options, pacer=pacer)
    pacer, info = cell.pacer, cell.split
    assert pacer.log.overrun_cycles == [101, 102]
    assert info["lost_cycles_drive_side"] == 2 and info["drive_process_exit_code"] == 0
    tripped = {(e["side"], e["node"], e["kind"], e["cycle"]) for e in cell.fieldbus["faults"]
               if e["event"] == "threshold_reached"}
    assert {("cn", n, "loss_of_preq", 102) for n in range(1, 7)} <= tripped   # counted in the drive process
    assert all(cell.fieldbus["comm_fault"])
    assert controller.stopped and controller.stopped_at_s == pytest.approx(102 * PERIOD)
    assert info["frames_missing_controller_side"] == 0 and info["frames_missing_drive_side"] == 0
