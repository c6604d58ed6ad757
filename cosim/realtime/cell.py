"""The robot cell in one process, paced at the controller cycle (``cosim run --realtime``).

The same cell as :func:`cosim.jobs.robot_cell.run_cell` (FMUs, connections, the
controller task :class:`~cosim.jobs.robot_cell.FieldbusLink`, the laser tracker, the
recorder), with three differences that keep the loop free of work a real-time loop
must not do:

* the fieldbus is a :class:`~cosim.realtime.network.PacedNetwork`: every controller
  cycle waits for its wall deadline first, late cycles get the overrun policy;
* time series are kept in memory during the loop and written as CSV afterwards; the
  CAN log is buffered in memory (python-can writes it when the run ends); no
  summary.json heartbeat;
* the loop runs with cyclic GC off, pinned to one CPU and, when granted, under SCHED_FIFO.
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

from cosim.jobs import robot_cell
from cosim.jobs.laser_tracker import LaserTracker, TrackerConfig
from cosim.master import MemorySink, SimulationError
from cosim.realtime.config import RealtimeSettings
from cosim.realtime.network import PacedNetwork, auto_tolerance_s, lateness_thresholds
from cosim.realtime.pacer import Pacer, no_cyclic_gc, realtime_scheduling
from cosim.scenario.context import RunContext
from cosim.scenario.cosim_tables import build_master
from fieldbus import FieldbusConfig, PowerlinkNetwork

#: The CAN log is handed to python-can's Logger only when the run ends (in-loop hand-overs
#: encode thousands of frames at once: milliseconds of stall).
DEFERRED_FLUSH_CYCLES = 1 << 40


def deferred_recording(config: FieldbusConfig) -> FieldbusConfig:
    """``config`` with the CAN log buffered for the whole run."""
    return dataclasses.replace(config, recording=dataclasses.replace(config.recording,
                                                                     flush_every_cycles=DEFERRED_FLUSH_CYCLES))


def run_paced_cell(doc: dict[str, Any], controller, true_robot, ctx: RunContext, *, label: str, stop_time: float,
                   fieldbus: FieldbusConfig | dict[str, Any] | None, tracker: TrackerConfig | None,
                   record_file: str, can_log: Path | None, settings: RealtimeSettings,
                   pacer: Pacer | None = None, info=None) -> tuple[robot_cell.CellRun, Pacer, str]:
    """Run the cell from 0 to ``stop_time`` s paced at the controller cycle.

    Returns the CellRun (as run_cell), the :class:`Pacer` (its ``log``: lateness per cycle)
    and the scheduling granted ('fifo' or 'normal (...)'). ``pacer`` may be given (tests:
    a Pacer on a :class:`~cosim.realtime.pacer.VirtualClock`)."""
    fb_config = deferred_recording(robot_cell.cell_fieldbus_config(fieldbus, controller))
    period = fb_config.cycle_time_s
    if info is None:
        info = robot_cell.controller_info(controller, fb_config, label=label)
    laser = LaserTracker(true_robot.kinematic_model(), tracker)
    signals, record_period = robot_cell.cell_signals(doc, laser)
    master = build_master(robot_cell.cell_document(doc, true_robot, info.q_start),
                          master_variables=robot_cell.cell_variables())
    memory = MemorySink()
    engine = ""
    granted = "normal"
    failure: SimulationError | None = None
    wall0 = time.perf_counter()
    cpu0 = time.process_time()
    network = PowerlinkNetwork(fb_config, robot_cell.joint_scaling(), log_path=can_log)
    link = None
    try:
        tolerance = settings.tolerance_s if settings.tolerance_s is not None else auto_tolerance_s(network.layout)
        if pacer is None:
            pacer = Pacer(period, settings.spin_s, tolerance, capacity=int(stop_time / period) + 16)
        pacer.thresholds = lateness_thresholds(network.layout)
        paced = PacedNetwork(network, pacer, settings.overrun_policy, cycles=int(round(stop_time / period)) + 1)
        recorder, link = robot_cell.add_cell_tasks(master, paced, controller, period, laser, signals, record_period,
                                                   memory, info)
        with master:
            try:
                master.initialize(stop_time)
                engine = master.engine.name
                ctx.label = label
                with realtime_scheduling(settings.scheduling, settings.fifo_priority,
                                                             settings.cpu) as granted, no_cyclic_gc():
                    ctx.execute(master, stop_time)
            except SimulationError as exc:
                failure = exc
    finally:
        if link is not None:
            link.port.close()
        network.close()
    wall = time.perf_counter() - wall0
    cpu = time.process_time() - cpu0
    robot_cell.write_recording(memory, ctx.csv_sink(record_file))
    cell = robot_cell.CellRun(label, ctx.path(record_file), recorder.rows_written, master.time, network.summary(),
                              wall, engine, memory, failure, loop_cpu_time_s=cpu)
    return cell, pacer, granted
