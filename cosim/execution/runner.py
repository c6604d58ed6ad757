"""ONE runner for the robot cell: a :class:`~cosim.cell.description.CellDescription` run in
an execution mode given as a parameter, the way libcosim and Drake treat real time.

Modes (``mode`` of :func:`run_cell`):

``in_process``
    the master steps the FMUs as fast as it can; the controller runs as the bus-cycle task
    (:class:`cosim.cell.link.FieldbusLink`) in simulated time;
``paced``
    the same, held to the wall clock at the bus cycle (``cosim run --realtime``): every bus
    cycle waits for its wall deadline (:class:`cosim.execution.timing.network.PacedNetwork`), late
    cycles get the overrun policy; the CAN log is buffered until the end; the loop runs
    without cyclic GC, pinned and, when granted, under SCHED_FIFO;
``split``
    controller and managing node in this process, drives and plant in a spawned process,
    frames over UDP multicast (``cosim run --split``; paced too with ``--realtime``):
    :func:`cosim.execution.split.controller_side.run_split_cell`;
``serve``
    the cell side only, paced, for a controller that is another program on the bus
    (``cosim serve``): :func:`cosim.execution.cell_side.run_served_cell`; the job's controller
    is not run.

Without a ``mode`` the run follows ``ctx.execution`` (the ``cosim run`` options,
:class:`cosim.execution.cell_execution.CellExecution`, which also reports lateness), else
``in_process``. Every mode builds the cell from the same description, drives the
controller through the controller contract and returns a :class:`CellRun`; a
SimulationError (failing FMU, NaN output, failing or stopped controller) ends a run
with everything recorded so far written, the error in ``CellRun.failure``.
"""
from __future__ import annotations

import contextlib
import time
from pathlib import Path
from collections.abc import Mapping, Sequence
from typing import Any, Callable

from controller import CellController, ControllerInfo
from controller.contract import DEFAULT_COMPUTE_BUDGET_S
from controller.port import command_log_columns
from cosim.cell.description import CellDescription
from cosim.cell.link import FieldbusLink
from cosim.cell.protection import protection_events
from cosim.cell.run import CellRun
from cosim.cell.wiring import N_JOINTS, cell_variables, joint_scaling
from cosim.tracking.laser_tracker import TRACKER_VARIABLES, LaserTracker
from cosim.master import Master, MemorySink, Recorder, SimulationError
from cosim.execution.timing.pacer import no_cyclic_gc
from cosim.results.timeseries import SeriesFile
from cosim.scenario.context import RunContext
from cosim.scenario.cosim_tables import build_master
from fieldbus import FieldbusConfig, PowerlinkNetwork
from robot.parameters import load_parameters

MODES = ("in_process", "paced", "split", "serve")
"""The execution modes of :func:`run_cell`."""


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


def controller_info(controller: Any, fb_config: FieldbusConfig, *, label: str = "",
                    parameters: dict[str, Any] | None = None, source: str = "", reference: Any = None,
                    q_start: Any = None, kinematic_model: Any = None, dynamics: Any = None,
                    compute_budget_s: float | None = None) -> ControllerInfo:
    """The :class:`controller.ControllerInfo` of a cell run: the bus cycle and dead time of
    ``fb_config``, the arm's limits (robot/rx130l.urdf via robot/rx130l_params.toml), and the
    reference, start pose, models and budget given (else the built-in controller's own,
    where ``controller`` has them)."""
    p = load_parameters()
    config = getattr(controller, "config", None)
    budget = compute_budget_s if compute_budget_s is not None else getattr(config, "compute_budget_s", DEFAULT_COMPUTE_BUDGET_S)

    def pick(given: Any, name: str) -> Any:
        return given if given is not None else getattr(controller, name, None)

    return ControllerInfo(period_s=fb_config.cycle_time_s, n_joints=N_JOINTS,
                          dead_time_cycles=fb_config.dead_time_cycles,
                          lookahead_cycles=fb_config.planned_ahead_cycles, compute_budget_s=budget,
                          position_min=p.position_lower.copy(), position_max=p.position_upper.copy(),
                          velocity_max=p.velocity_limit.copy(), torque_max=p.effort_limit.copy(),
                          rated_torque=p.rated_torque.copy(), q_start=pick(q_start, "q_start"),
                          reference=pick(reference, "reference"),
                          kinematic_model=pick(kinematic_model, "kinematic_model"),
                          dynamics=pick(dynamics, "dynamics"), parameters=dict(parameters or {}), label=label,
                          source=source)


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


def run_cell(cell: CellDescription, controller: CellController, ctx: RunContext, *, mode: str | None = None,
             options: Any = None, pacer: Any = None,
             on_cycle: Callable[[int, Any], None] | None = None) -> CellRun:
    """Run ``cell`` with ``controller`` (a :class:`controller.CellController`) from 0 to its
    stop time in ``mode`` (:data:`MODES`; None: as ``ctx.execution`` says, else in process).

    ``options`` is a :class:`cosim.execution.config.ExecutionOptions` for ``paced``/``split``
    (default: the defaults); ``pacer`` a :class:`~cosim.execution.timing.pacer.Pacer` to use (tests:
    one on a virtual clock); ``on_cycle(cycle, session)`` a hook of split runs.

    In process, the recorder streams to ``cell.record_file`` in the results folder as the
    run goes (Parquet by default, bounded buffer, :class:`cosim.results.timeseries.ParquetSink`;
    the suffix follows the run's format) and ``CellRun.recording`` reads it back; paced and
    split runs sample into memory and write the file when the loop has ended (no file I/O
    inside a paced cycle).

    Whatever the mode, ``CellRun.protection_events`` holds the drives' and the plant's protection
    events of the run (:func:`cosim.cell.protection.protection_events`, from the recording).
    """
    if mode is None:
        execution = getattr(ctx, "execution", None)
        if execution is not None and execution.active:
            return execution.run_cell(cell, controller, ctx)  # run_cell again, with its mode
        mode = "in_process"
    run = _run_in_mode(cell, controller, ctx, mode, options, pacer, on_cycle)
    run.protection_events = protection_events(cell, run.recording)
    return run


def _run_in_mode(cell: CellDescription, controller: CellController, ctx: RunContext, mode: str, options: Any,
                 pacer: Any, on_cycle: Callable[[int, Any], None] | None) -> CellRun:
    """:func:`run_cell` in the execution mode ``mode`` (before its protection events)."""
    if mode not in MODES:
        raise ValueError(f"cell execution mode {mode!r}: expected one of {MODES}")
    if options is None:
        from cosim.execution.config import ExecutionOptions

        options = ExecutionOptions(mode="split" if mode == "split" else "in_process", realtime=(mode == "paced"))
    if mode == "serve":  # the cell side only: the controller is another program on the bus (cosim serve)
        from cosim.execution.cell_side import run_served_cell
        from cosim.execution.served import ServeSettings

        controller_close = getattr(controller, "close", None)
        if callable(controller_close):
            controller_close()  # the job's own controller does not run: the controller is elsewhere
        settings = getattr(options, "serve", None) or ServeSettings()
        return run_served_cell(cell, ctx, settings, pacer=pacer, start_on_first_frame_s=settings.wait_for_controller_s)
    if mode == "split":
        from cosim.execution.split.controller_side import run_split_cell

        return run_split_cell(cell, controller, ctx, options=options, pacer=pacer, on_cycle=on_cycle)
    return _run_on_master(cell, controller, ctx, paced=(mode == "paced"), settings=options.settings, pacer=pacer)


def _run_on_master(cell: CellDescription, controller: CellController, ctx: RunContext, *, paced: bool,
                   settings: Any, pacer: Any) -> CellRun:
    """The in-process and paced modes: the whole cell on one master in this process."""
    fb_config = cell.fieldbus
    if paced:
        from cosim.execution.timing.network import deferred_recording

        fb_config = deferred_recording(fb_config)
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
    network = PowerlinkNetwork(fb_config, joint_scaling(), log_path=cell.can_log)
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
            from cosim.execution.timing.network import PacedNetwork, auto_tolerance_s, lateness_thresholds
            from cosim.execution.timing.pacer import Pacer, realtime_scheduling

            tolerance = settings.tolerance_s if settings.tolerance_s is not None else auto_tolerance_s(network.layout)
            if pacer is None:
                pacer = Pacer(period, settings.spin_s, tolerance, capacity=int(stop_time / period) + 16)
            pacer.thresholds = lateness_thresholds(network.layout)
            bus = PacedNetwork(network, pacer, settings.overrun_policy, cycles=int(round(stop_time / period)) + 1)
            scheduling = realtime_scheduling(settings.scheduling, settings.fifo_priority, settings.cpu)
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
                   wall, engine, recording, failure, cpu, pacer=pacer if paced else None, scheduling=granted,
                   controller_timing=link.port.timing(), port_overhead=link.port.overhead(),
                   controller_record=ctx.path(controller_file) if controller_file else None,
                   drives_checked=True, drives_enabled_at_s=link.enabled_at_s,
                   controller_close_error=link.port.close_error)
