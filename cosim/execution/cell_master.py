"""The robot cell on one co-simulation master, shared by every execution mode: the master
built from the cell's description, the cell's tasks (bus cycle + controller, laser tracker,
recorder), the units and files of the recording, and the run of the whole cell on one master
in this process (:func:`run_on_master`: the simulated and the paced modes). The served cell
side and the split run's drive process build their master here too.
"""
from __future__ import annotations

import contextlib
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from controller import CellController, ControllerInfo
from controller.port import command_log_columns
from cosim.cell.description import CellDescription
from cosim.cell.drive_objects import DriveParameterWriter, cell_object_dictionaries
from cosim.cell.link import FieldbusLink
from cosim.cell.run import CellRun
from cosim.cell.wiring import N_JOINTS, cell_variables, joint_scaling
from cosim.execution.timing.pacer import no_cyclic_gc
from cosim.master import Master, MemorySink, Recorder, SimulationError
from cosim.results.timeseries import SeriesFile
from cosim.scenario.context import RunContext
from cosim.scenario.cosim_tables import build_master
from cosim.tracking.laser_tracker import TRACKER_VARIABLES, LaserTracker
from fieldbus import PowerlinkNetwork


def master_units(master: Master, signals: Sequence[str]) -> dict[str, str]:
    """The unit of each recorded signal the FMUs declare (``unit`` or declared type's unit)."""
    units = {"time": "s", **{name: "m" for name in TRACKER_VARIABLES}}
    for signal in signals:
        try:
            unit = master.unit(signal)
        except (AttributeError, KeyError, ValueError):
            continue
        if unit:
            units[signal] = unit
    return units


def write_recording(memory: MemorySink, sink: Any) -> None:
    """Write what a MemorySink holds to another sink (e.g. ``ctx.csv_sink(name)``) and close it."""
    sink.open(memory.columns, memory.kinds)
    data = memory.data
    if len(data):
        sink.write(data)
    sink.close()


def controller_log_of(controller: Any) -> Any:
    """The :class:`controller.ControllerLog` of a built-in controller (or of a wrapper that
    delegates to one, as the identification job's recorder), else None."""
    from controller import ControllerLog

    try:
        log = getattr(controller, "log", None)
    except Exception:  # a user's controller with a property that fails: it has no built-in log
        return None
    return log if isinstance(log, ControllerLog) else None


def controller_record_name(cell: CellDescription) -> str:
    """``controller_<name>`` for the cell's ``timeseries_<name>`` record file (the label otherwise)."""
    stem = Path(cell.record_file).stem
    return "controller_" + (stem[len("timeseries_"):] if stem.startswith("timeseries_") else cell.label)


def add_cell_tasks(master: Master, network: Any, controller: CellController, period_s: float, laser: LaserTracker,
                   signals: Sequence[str], record_period_s: float, sink: Any, info: ControllerInfo | None = None,
                   stop_grace_s: float = 0.5) -> tuple[Recorder, FieldbusLink]:
    """Add the cell's tasks to ``master`` (before initialize): the :class:`FieldbusLink` of
    ``network`` and ``controller`` every ``period_s`` (priority 0; the controller's
    ``setup(info)`` at master initialisation), the laser tracker at its period (priority 1)
    and the recorder of ``signals`` every ``record_period_s`` into ``sink``; returns the
    recorder and the link (``link.port.close()`` when the run ends)."""
    link = FieldbusLink(network, controller, period_s, stop_grace_s=stop_grace_s, info=info)
    master.add_task(link, period_s, priority=0, name="fieldbus+controller", setup=link.setup)
    master.add_task(laser, laser.config.period_s, priority=1, name="laser_tracker", setup=laser.setup)
    return master.add_recorder(signals, record_period_s, sink, name="cell"), link


def build_cell_master(cell: CellDescription | Mapping[str, Any]) -> Master:
    """The master of a cell (a :class:`CellDescription`, or its ``master_document()`` as the split
    run's drive process gets it): its FMUs with their start values, the cell's master variables
    (``bus.*``, ``tracker.*``) and its connections (not initialized, no tasks yet)."""
    document = cell.master_document() if isinstance(cell, CellDescription) else dict(cell)
    return build_master(document, master_variables=cell_variables())



def run_on_master(cell: CellDescription, controller: CellController, ctx: RunContext, *,
                  pacing: Any = None) -> CellRun:
    """The whole cell on one master in this process, to its stop time: the simulated mode
    (``pacing`` None: as fast as it goes, the recording streamed to its file) and the paced one
    (``pacing`` a :class:`cosim.execution.timing.network.Pacing`: every bus cycle held to the wall
    clock, everything recorded in memory and written when the loop has ended)."""
    paced = pacing is not None
    fb_config = pacing.fieldbus(cell.fieldbus) if paced else cell.fieldbus
    period, stop_time = cell.period_s, cell.stop_time_s
    laser = LaserTracker(cell.true_robot.kinematic_model(), cell.tracker)
    master = build_cell_master(cell)
    memory = MemorySink()
    record_file = ctx.series_name(cell.record_file)
    units = master_units(master, cell.signals)
    sink = memory if paced else ctx.series_sink(record_file, units)
    engine = ""
    granted = "normal"
    failure: SimulationError | None = None
    wall0 = time.perf_counter()
    cpu0 = time.process_time()
    ods = cell_object_dictionaries(fb_config)
    writer = DriveParameterWriter(ods, lambda instance, name, value: master.fmus[instance].set_value(name, value))
    network = PowerlinkNetwork(fb_config, joint_scaling(), log_path=cell.can_log, canopen=ods, on_write=writer)
    link = None
    log = None if paced else controller_log_of(controller)  # paced: no file I/O in the loop
    command_log = None
    controller_file = None
    try:
        if log is not None:  # the controller's log streams beside the recording (bounded memory)
            from cosim.cell.evaluation import series_units
            from controller.controller import LOG_COLUMNS

            controller_file = ctx.series_name(controller_record_name(cell))
            log.stream_to(ctx.series_sink(controller_file, series_units(LOG_COLUMNS)))
        bus: Any = network
        scheduling: Any = contextlib.nullcontext("normal")
        if paced:
            bus, scheduling = pacing.bus(network, period, stop_time)
        recorder, link = add_cell_tasks(master, bus, controller, period, laser, cell.signals, cell.record_period_s,
                                        sink, cell.controller, cell.stop_grace_s)
        if log is None and controller_log_of(controller) is None:
            # a user's controller: the port logs what it commanded, streamed (in memory when paced)
            controller_file = ctx.series_name(controller_record_name(cell))
            command_log = link.port.start_log(None if paced else ctx.series_sink(
                controller_file, command_log_columns(N_JOINTS)[2]))
        if paced:
            ctx.label = cell.label  # no summary heartbeat in a paced loop
        else:
            ctx.attach(master, stop_time, label=cell.label)
        with master:
            try:
                master.initialize(stop_time)
                engine = master.engine.name
                with scheduling as granted, no_cyclic_gc():
                    ctx.execute(master, stop_time)
            except SimulationError as exc:
                failure = exc
    finally:
        if link is not None:
            link.port.close()
        network.close()
        wall = time.perf_counter() - wall0
        cpu = time.process_time() - cpu0
        if paced and memory.columns:
            write_recording(memory, ctx.series_sink(record_file, units))
        elif not paced:
            sink.close()  # the master closed its recorder (footer written); again is a no-op
        if log is not None:
            log.close_stream()
        if command_log is not None:
            command_log.close(ctx.series_sink(controller_file, command_log.units) if paced else None)
    recording = memory if paced else SeriesFile(ctx.path(record_file))
    return CellRun(cell.label, ctx.path(record_file), recorder.rows_written, master.time, network.summary(),
                   wall, engine, recording, failure, cpu, pacer=pacing.pacer if paced else None, scheduling=granted,
                   controller_timing=link.port.timing(), port_overhead=link.port.overhead(),
                   controller_record=ctx.path(controller_file) if controller_file else None,
                   drives_checked=True, drives_enabled_at_s=link.enabled_at_s,
                   controller_close_error=link.port.close_error)
