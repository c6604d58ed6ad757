"""The robot cell on the co-simulation master: plant + six drives + fieldbus + controller + tracker.

Shared by the robot jobs (ISO 9283 now; identification and planner scenarios later).
A cell is:

* the FMUs of the scenario: ``plant`` (``rx130l_plant``) and ``drive1`` ... ``drive6``
  (``servo_drive``), coupled by the scenario's connections (:func:`cell_connections`
  lists the ones a cell needs);
* the master variables ``bus.target_position[i]``, ``bus.torque_offset[i]`` (Real) and
  ``bus.controlword[i]``, ``bus.fault_code[i]`` (Integer), i = 1..6, written by the
  fieldbus task and connected to the drives' inputs;
* one periodic task per controller cycle (:class:`FieldbusLink`, priority 0): read the
  drives' actual values at ``t_k`` -> ``fieldbus.PowerlinkNetwork.run_cycle`` (the
  set-points the controller computed in the previous cycle travel; the drives get what
  the network applies from ``t_k``) -> ``Controller.step`` with what the controller
  observes in cycle ``k``;
* the laser tracker task (:class:`cosim.jobs.laser_tracker.LaserTracker`, priority 1):
  the true flange position from ``plant.q`` into ``tracker.x/y/z``;
* a recorder of the ``[record]`` signals plus :data:`RECORDED_SIGNALS`.

The plant is set to the TRUE robot (``robot.true_robot.make_true_robot``): its 78
dynamic parameters and payload as FMU start values, its start configuration ``q0`` =
the controller's start set-point (the arm starts at rest there). Drive parameters
are :func:`fmus.servo_drive.params.drive_start_values` of each axis, overridden by the
scenario's ``[fmus.parameters]``.
"""
from __future__ import annotations

import copy
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from controller import CellController, Controller, ControllerInfo, DriveLoopModel, speed_comparison_lead
from controller.port import ControllerFailure, ControllerPort
from cosim.jobs.laser_tracker import TRACKER_VARIABLES, LaserTracker, TrackerConfig
from cosim.master import Master, MemorySink, Recorder, SimulationError
from cosim.realtime.pacer import no_cyclic_gc
from cosim.scenario.context import RunContext
from cosim.scenario.cosim_tables import build_master
from fieldbus import AppliedSetpoints, DriveActuals, FieldbusConfig, JointScaling, PowerlinkNetwork
from fmus.servo_drive.params import drive_start_values
from robot.parameters import RobotParameters, load_parameters
from robot.true_robot import TrueRobot

N_JOINTS = 6
PLANT = "plant"
DRIVES: tuple[str, ...] = tuple(f"drive{i}" for i in range(1, N_JOINTS + 1))
PLANT_FMU = "rx130l_plant"
DRIVE_FMU = "servo_drive"

BUS_REAL = ("target_position", "torque_offset")
BUS_INTEGER = ("controlword", "fault_code")


def bus_variables() -> dict[str, tuple[str, object]]:
    """Master variables of the fieldbus task: name -> (type, start), declared in this order
    (so each group of six is one contiguous writable view)."""
    out: dict[str, tuple[str, object]] = {}
    for name in BUS_REAL:
        for i in range(1, N_JOINTS + 1):
            out[f"bus.{name}[{i}]"] = ("Real", 0.0)
    for name in BUS_INTEGER:
        for i in range(1, N_JOINTS + 1):
            out[f"bus.{name}[{i}]"] = ("Integer", 0)
    return out


def tracker_variables() -> dict[str, tuple[str, object]]:
    """Master variables of the laser tracker (m, base_link)."""
    return {name: ("Real", 0.0) for name in TRACKER_VARIABLES}


def cell_variables() -> dict[str, tuple[str, object]]:
    """All master variables of a cell (fieldbus + tracker)."""
    return {**bus_variables(), **tracker_variables()}


def cell_connections() -> list[str]:
    """The connections a cell needs (the scenario must list each of them)."""
    out = []
    for i, drive in enumerate(DRIVES, start=1):
        out += [f"{drive}.tau_out -> {PLANT}.tau[{i}]", f"{PLANT}.q_motor[{i}] -> {drive}.q_meas",
                f"{PLANT}.qd_motor[{i}] -> {drive}.qd_meas"]
        out += [f"bus.{name}[{i}] -> {drive}.{name}" for name in BUS_REAL + BUS_INTEGER]
    return out


RECORDED_SIGNALS: tuple[str, ...] = (
    tuple(f"{PLANT}.q[{i}]" for i in range(1, 7)) + tuple(f"{PLANT}.qd[{i}]" for i in range(1, 7))
    + tuple(f"{d}.tau_out" for d in DRIVES) + tuple(f"{d}.current_actual" for d in DRIVES)
    + tuple(f"{d}.following_error" for d in DRIVES) + TRACKER_VARIABLES
)
"""What every cell records (besides the scenario's [record] signals): joint angles and
speeds of the plant, joint torques and motor currents of the drives, the drives' own
following errors, the tracker's measurement."""

JOB_SET_PLANT_PARAMETERS = ("q0[", "qd0[", "p[", "payload_mass", "payload_com[")
"""Plant parameters the cell sets itself (from the true robot and the start pose)."""


def plant_start_values(true_robot: TrueRobot, q0: Sequence[float]) -> dict[str, float]:
    """Start values of the plant FMU: the true robot's 78 parameters and payload, at rest at ``q0`` (rad)."""
    values: dict[str, float] = {}
    for i, q in enumerate(q0, start=1):
        values[f"q0[{i}]"] = float(q)
        values[f"qd0[{i}]"] = 0.0
    for k, p in enumerate(true_robot.dynamic_parameters, start=1):
        values[f"p[{k}]"] = float(p)
    values["payload_mass"] = float(true_robot.payload[0])
    for i, c in enumerate(true_robot.payload[1:], start=1):
        values[f"payload_com[{i}]"] = float(c)
    return values


def joint_scaling(parameters: RobotParameters | None = None) -> JointScaling:
    """CiA 402 scaling of the arm's joints (gear ratios, encoder counts, rated torques)."""
    p = parameters or load_parameters()
    return JointScaling(p.gear_ratio, p.encoder_counts_per_motor_rev, p.rated_torque)


def cell_fmus(doc_fmus: list[dict[str, Any]], true_robot: TrueRobot, q0: Sequence[float]) -> list[dict[str, Any]]:
    """A copy of the scenario's ``[[fmus]]`` with the plant's and drives' start values filled in
    (drive defaults first, then the scenario's own parameters on top)."""
    fmus = copy.deepcopy(doc_fmus)
    for fmu in fmus:
        if fmu["name"] == PLANT:
            fmu["parameters"] = {**fmu["parameters"], **plant_start_values(true_robot, q0)}
        elif fmu["name"] in DRIVES:
            axis = DRIVES.index(fmu["name"]) + 1
            fmu["parameters"] = {**drive_start_values(axis), **fmu["parameters"]}
    return fmus


def drive_parameters(doc_fmus: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each drive's effective parameters (defaults of its axis + the scenario's), axis 1..6."""
    by_name = {fmu["name"]: fmu for fmu in doc_fmus}
    return [{**drive_start_values(axis), **by_name[d]["parameters"]} for axis, d in enumerate(DRIVES, start=1)]


def drive_loop_model(doc_fmus: list[dict[str, Any]], period_s: float) -> DriveLoopModel:
    """What the model-based controller knows of the drives' position loops (their Kv,
    speed feed-forward gain and speed-comparison lead), from the effective parameters."""
    params = drive_parameters(doc_fmus)
    for axis, p in enumerate(params, start=1):
        if abs(p["position_sample_time"] - period_s) > 1e-12:
            raise ValueError(f"drive{axis}: position_sample_time = {p['position_sample_time']!r} s, expected the "
                             f"controller period {period_s!r} s for set-point shaping")
    return DriveLoopModel(
        position_kv=np.array([p["position_kv"] for p in params]),
        speed_feedforward_gain=np.array([p["speed_feedforward_gain"] for p in params]),
        lead_s=np.array([speed_comparison_lead(p["position_sample_time"], p["speed_sample_time"],
                                               p["speed_filter_time"]) for p in params]),
        period_s=period_s)


class FieldbusLink:
    """The controller cycle task: drives -> fieldbus -> controller -> fieldbus -> drives.

    At cycle ``k`` (time ``t_k``): the drives' outputs at ``t_k`` are the actual values
    the controlled nodes latch; ``run_cycle(k, setpoints, actuals)`` carries the
    set-points the controller returned in cycle ``k - 1``; what the network applies
    from ``t_k`` (quantised target, torque offset, controlword, fault code of a tripped
    controlled node) is written to the ``bus.*`` master variables (the network writes
    into views of them, ``PowerlinkNetwork.bind_applied``); then the controller
    computes the set-points for cycle ``k + 1`` from what it observed in cycle ``k``.
    ``stop_grace_s`` after the controller stopped (drive fault, node fault) the task
    ends the run with a SimulationError naming the reason.
    """

    def __init__(self, network: PowerlinkNetwork, controller: CellController | ControllerPort, period_s: float,
                 stop_grace_s: float = 0.5, info: ControllerInfo | None = None) -> None:
        self.network = network
        self.info = info
        self.port = controller if isinstance(controller, ControllerPort) else ControllerPort(
            controller, N_JOINTS, q_start=getattr(controller, "q_start", None))
        self.controller = self.port.controller
        self.period_s = period_s
        self.stop_grace_s = stop_grace_s
        self.cycle = 0
        self.actuals = DriveActuals.zeros(N_JOINTS)
        self.setpoints = self.port.setpoints
        self._real = self._integer = None
        self._real_out = self._integer_out = None
        self._copy_applied = True
        self._paced = hasattr(network, "last_late")

    def setup(self, master: Master) -> None:
        """Bind one reader per bus type for the drives' actual values and one writable
        view per bus type for the ``bus.*`` variables (end of master.initialize); then the
        controller's ``setup(info)`` (a failure there ends the run as a SimulationError)."""
        if self.info is not None:
            try:
                self.port.setup(self.info)
            except ControllerFailure as exc:
                raise SimulationError("controller", 0.0, exc.reason) from exc
        self._real = master.reader([f"{d}.{name}" for name in ("position_actual", "velocity_actual", "torque_actual")
                                    for d in DRIVES])
        self._integer = master.reader([f"{d}.{name}" for name in ("statusword", "error_code") for d in DRIVES])
        self._real_out = master.view([f"bus.{name}[{i}]" for name in BUS_REAL for i in range(1, N_JOINTS + 1)],
                                     writable=True)
        self._integer_out = master.view([f"bus.{name}[{i}]" for name in BUS_INTEGER
                                         for i in range(1, N_JOINTS + 1)], writable=True)
        # the actual values are views of the readers' reused buffers: read() refreshes them
        n = N_JOINTS
        real, integer = self._real.read(), self._integer.read()
        self.actuals = DriveActuals(statusword=integer[:n], position=real[:n], velocity=real[n:2 * n],
                                    torque=real[2 * n:], error_code=integer[n:])
        # a PowerlinkNetwork writes what the drives apply straight into the bus.* variables;
        # other networks (e.g. cosim.realtime's PacedNetwork wrapper) get it copied each cycle
        bind = getattr(self.network, "bind_applied", None)
        self._copy_applied = bind is None
        if bind is not None:
            bind(AppliedSetpoints(controlword=self._integer_out[:n], position=self._real_out[:n],
                                  torque_offset=self._real_out[n:], fresh=np.zeros(n, dtype=bool),
                                  comm_fault=np.zeros(n, dtype=bool), fault_code=self._integer_out[n:]))

    def __call__(self, t: float) -> None:
        self._real.read()
        self._integer.read()
        result = self.network.run_cycle(self.cycle, self.setpoints, self.actuals)
        if self._copy_applied:
            n, applied = N_JOINTS, result.applied
            self._real_out[:n] = applied.position
            self._real_out[n:] = applied.torque_offset
            self._integer_out[:n] = applied.controlword
            self._integer_out[n:] = applied.fault_code
        try:
            if self._paced:  # a wall-clock network (cosim.realtime.network.PacedNetwork) says whether it was late
                network = self.network
                self.setpoints = self.port.step(self.cycle, t, result.observed, network.last_late, network.last_lost)
            else:
                self.setpoints = self.port.step(self.cycle, t, result.observed)
        except ControllerFailure as exc:
            raise SimulationError("controller", exc.time_s, exc.reason) from exc
        self.cycle += 1
        stopped_at = self.port.stopped_at_s
        if stopped_at is not None and t - stopped_at >= self.stop_grace_s - 1e-12:
            raise SimulationError("controller", stopped_at, f"motion stopped: {self.port.stop_reason}")


@dataclass
class CellRun:
    """What one cell run produced: the recorder file and its rows (also in memory), the
    simulated time reached (s), the fieldbus summary, the wall time of the run (s), the
    stepping engine, the SimulationError that ended it (None: ran to the end) and the CPU
    time of this process over the same span as the wall time (s, process_time)."""

    label: str
    record_path: Path | None
    rows_recorded: int
    reached_s: float
    fieldbus: dict[str, Any]
    loop_wall_time_s: float
    engine: str
    recording: MemorySink
    failure: SimulationError | None = None
    loop_cpu_time_s: float = float("nan")


def write_recording(memory: MemorySink, sink: Any) -> None:
    """Write what a MemorySink holds to another sink (e.g. ``ctx.csv_sink(name)``) and close it."""
    sink.open(memory.columns, memory.kinds)
    data = memory.data
    if len(data):
        sink.write(data)
    sink.close()


def cell_fieldbus_config(fieldbus: FieldbusConfig | dict[str, Any] | None, controller: Any) -> FieldbusConfig:
    """The cell's fieldbus configuration (a FieldbusConfig, a [fieldbus] table, or None for the
    defaults); ValueError when its cycle time differs from the built-in controller's period (s)."""
    config = fieldbus if isinstance(fieldbus, FieldbusConfig) else FieldbusConfig.from_dict(fieldbus or {})
    period = config.cycle_time_s
    if isinstance(controller, Controller) and abs(period - controller.config.period_s) > 1e-12:
        raise ValueError(f"controller period {controller.config.period_s} s differs from the fieldbus cycle "
                         f"time {period} s")
    return config


def cell_document(doc: dict[str, Any], true_robot: TrueRobot, q0: Sequence[float]) -> dict[str, Any]:
    """A shallow copy of the scenario document whose ``[[fmus]]`` carry the cell's start values
    (:func:`cell_fmus`: the true robot at rest at ``q0``, rad)."""
    cell_doc = dict(doc)
    cell_doc["fmus"] = cell_fmus(doc["fmus"], true_robot, q0)
    return cell_doc


def cell_signals(doc: dict[str, Any], laser: LaserTracker) -> tuple[list[str], float]:
    """What the cell records and how often (s): the ``[record]`` signals plus
    :data:`RECORDED_SIGNALS`, every ``[record] period`` (default: the tracker period)."""
    record = doc.get("record") or {"period": laser.config.period_s, "signals": []}
    signals = list(record["signals"]) + [s for s in RECORDED_SIGNALS if s not in record["signals"]]
    return signals, record["period"]


def add_cell_tasks(master: Master, network: Any, controller: CellController, period_s: float, laser: LaserTracker,
                   signals: Sequence[str], record_period_s: float, sink: Any,
                   info: ControllerInfo | None = None) -> tuple[Recorder, FieldbusLink]:
    """Add the cell's tasks to ``master`` (before initialize): the :class:`FieldbusLink` of
    ``network`` and ``controller`` every ``period_s`` (priority 0; the controller's
    ``setup(info)`` at master initialisation), the laser tracker at its period (priority 1)
    and the recorder of ``signals`` every ``record_period_s`` into ``sink``; returns the
    recorder and the link (``link.port.close()`` when the run ends)."""
    link = FieldbusLink(network, controller, period_s, info=info)
    master.add_task(link, period_s, priority=0, name="fieldbus+controller", setup=link.setup)
    master.add_task(laser, laser.config.period_s, priority=1, name="laser_tracker", setup=laser.setup)
    return master.add_recorder(signals, record_period_s, sink, name="cell"), link


def controller_info(controller: Any, fb_config: FieldbusConfig, *, label: str = "",
                    parameters: dict[str, Any] | None = None, source: str = "", reference: Any = None,
                    q_start: Any = None, kinematic_model: Any = None, dynamics: Any = None,
                    compute_budget_s: float | None = None) -> ControllerInfo:
    """The :class:`controller.ControllerInfo` of a cell run: the bus cycle and dead time of
    ``fb_config``, the arm's limits (robot/rx130l_params.toml), and the reference, start pose,
    models and budget given (else the built-in controller's own, where ``controller`` has them)."""
    p = load_parameters()
    config = getattr(controller, "config", None)
    budget = compute_budget_s if compute_budget_s is not None else getattr(config, "compute_budget_s", 100e-6)
    pick = (lambda given, name: given if given is not None else getattr(controller, name, None))
    return ControllerInfo(period_s=fb_config.cycle_time_s, n_joints=N_JOINTS,
                          dead_time_cycles=fb_config.dead_time_cycles, compute_budget_s=budget,
                          position_min=p.position_lower.copy(), position_max=p.position_upper.copy(),
                          velocity_max=p.velocity_limit.copy(), torque_max=p.effort_limit.copy(),
                          rated_torque=p.rated_torque.copy(), q_start=pick(q_start, "q_start"),
                          reference=pick(reference, "reference"),
                          kinematic_model=pick(kinematic_model, "kinematic_model"),
                          dynamics=pick(dynamics, "dynamics"), parameters=dict(parameters or {}), label=label,
                          source=source)


def run_cell(doc: dict[str, Any], controller: CellController, true_robot: TrueRobot, ctx: RunContext, *,
             label: str, stop_time: float, fieldbus: FieldbusConfig | dict[str, Any] | None = None,
             tracker: TrackerConfig | None = None, record_file: str = "timeseries.csv",
             can_log: Path | None = None, info: ControllerInfo | None = None) -> CellRun:
    """Co-simulate one cell run from 0 to ``stop_time`` s and return what it produced.

    ``doc`` is the validated scenario (its [simulation], [[fmus]], connections, [record]);
    the recorder samples the ``[record]`` signals plus :data:`RECORDED_SIGNALS` every
    ``[record] period`` (default: the tracker period) into memory (``CellRun.recording``),
    written to ``record_file`` in the results folder when the loop has ended (formatting
    CSV text costs about 50 µs per row-millisecond, as much as the bus; it is output, not
    loop work, and stays out of ``loop_wall_time_s``); ``can_log`` is the CAN log
    (.blf/.asc) or None. A SimulationError (failing FMU, NaN output, stopped controller)
    ends the run: everything recorded is written and the error is returned in
    ``CellRun.failure``.

    With ``ctx.execution`` active (``cosim run --realtime`` / ``--split``) the run is handed
    to it (:mod:`cosim.realtime`, :mod:`cosim.split`): paced and/or split over two processes.
    """
    execution = getattr(ctx, "execution", None)
    if execution is not None and execution.active:
        return execution.run_cell(doc, controller, true_robot, ctx, label=label, stop_time=stop_time,
                                  fieldbus=fieldbus, tracker=tracker, record_file=record_file, can_log=can_log,
                                  info=info)
    fb_config = cell_fieldbus_config(fieldbus, controller)
    if info is None:
        info = controller_info(controller, fb_config, label=label)
    period = fb_config.cycle_time_s
    laser = LaserTracker(true_robot.kinematic_model(), tracker)
    signals, record_period = cell_signals(doc, laser)
    master = build_master(cell_document(doc, true_robot, info.q_start), master_variables=cell_variables())
    memory = MemorySink()
    engine = ""
    failure: SimulationError | None = None
    wall0 = time.perf_counter()
    cpu0 = time.process_time()
    network = PowerlinkNetwork(fb_config, joint_scaling(), log_path=can_log)
    link = None
    try:
        recorder, link = add_cell_tasks(master, network, controller, period, laser, signals, record_period, memory,
                                        info)
        ctx.attach(master, stop_time, label=label)
        with master:
            try:
                master.initialize(stop_time)
                engine = master.engine.name
                with no_cyclic_gc():
                    ctx.execute(master, stop_time)
            except SimulationError as exc:
                failure = exc
    finally:
        if link is not None:
            link.port.close()
        network.close()
        wall = time.perf_counter() - wall0
        cpu = time.process_time() - cpu0
        if memory.columns:
            write_recording(memory, ctx.csv_sink(record_file))
    return CellRun(label, ctx.path(record_file), recorder.rows_written, master.time, network.summary(), wall,
                   engine, memory, failure, cpu)
