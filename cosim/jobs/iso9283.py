"""Job ``iso9283``: the paper's section 2 experiment, end to end (the testbed's main job).

The EN ISO 9283 test path (``planners.iso9283``: cube, diagonal plane, rectangle,
line, circles at 1 m/s and 5 m/s^2, constant orientation) is driven through the
400 µs controller, the POWERLINK-timed CiA 402 fieldbus, six servo-drive FMUs and
the plant FMU, once per mode in ``[controller] modes`` (:data:`JOB_MODES`), on the
SAME seeded true robot (inertial, friction and rotor deviations, geometric errors,
payload). The modes follow the paper (section 2.3, Figure 1, eq. 7):

* ``standard``: position set-points only, the drives' P-PI cascade (drive speed
  feed-forward gain 0, no torque offset);
* ``standard_speed_ff`` (optional): the cascade plus the drives' own speed
  feed-forward from target differences, no torque offset;
* ``model_based``: eq. 7, ``Q_M = M(q_d) qdd_d + g(q_d, qd_d) + K_p (q_d - q) + K_d (qd_d - qd)``:
  the velocity reference enters through the drives' speed feed-forward (gain 1), the
  model torque as torque offset, plus the drive set-point shaping.

The drive speed feed-forward is the servo-drive FMU parameter ``speed_feedforward_gain``,
set by the job per mode (``[controller.<mode>] drive_speed_feedforward`` overrides the
mode's default). A laser tracker samples the true flange every 1 ms. See docs/main_job.md.

Results (``results/<name>/`` or ``--out``): ``summary.json``; per mode
``timeseries_<mode>.csv`` (1 ms: plant q, qd, drive torques and currents, drive
following errors, tracker), ``controller_<mode>.csv`` (400 µs: set-points, feed-forward,
compute times), ``tcp_<mode>.csv`` (1 ms: programmed, commanded and measured TCP,
TCP and path errors, joint set-points and lag errors), ``can_<mode>.blf`` (every frame
on the bus); figures ``figure2a_lag_errors.png``, ``figure2b_tcp_error.png``,
``tcp_error_vs_desired_path.png``.
"""
from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from controller import Controller, ControllerConfig, Phase, TcpTrajectory
from controller.elastic import make_controller
from cosim.jobs import robot_cell
from cosim.jobs.cell_checks import check_cell, fill_defaults
from cosim.jobs.columns_csv import write_columns_csv
from cosim.jobs.laser_tracker import DEFAULT_POSITION_SIGMA_M, TrackerConfig
from cosim.jobs.tracking_metrics import TrackingResult, desired_joints, evaluate
from cosim.scenario.context import RunContext
from cosim.scenario.cosim_tables import COSIM_FIELDS
from cosim.scenario.loader import SCENARIO_FIELD, Scenario
from cosim.scenario.registry import register_job
from cosim.scenario.schema import (AnyValue, Boolean, Field, FilePath, Integer, List, Number, String, Table, Where)

JOB_NAME = "iso9283"


@dataclass(frozen=True)
class JobMode:
    """One mode of the job.

    controller_mode: the :class:`controller.ControllerConfig` mode (``"standard"``: zero
        torque offset, target = q_d; ``"model_based"``: eq. 7 torque offset + set-point shaping).
    drive_speed_feedforward: default of ``[controller.<mode>] drive_speed_feedforward``:
        True = the drives' ``speed_feedforward_gain`` of fmus/servo_drive/drive_params.toml
        (1.0), False = 0 (pure P position loop).
    description: one line for summary.json.
    """

    controller_mode: str
    drive_speed_feedforward: bool
    description: str


JOB_MODES: dict[str, JobMode] = {
    "standard": JobMode("standard", False, "position set-points only: the drives' P position / PI speed / PI current "
                                           "cascade, no speed or torque feed-forward (paper section 2.3, Figure 1)"),
    "standard_speed_ff": JobMode("standard", True, "position set-points, the drives' own speed feed-forward from "
                                                   "target differences, no torque feed-forward"),
    "model_based": JobMode("model_based", True, "eq. 7: velocity reference through the drives' speed feed-forward, "
                                                "torque feed-forward M(q_d) qdd_d + g(q_d, qd_d) as torque offset, "
                                                "drive set-point shaping"),
    "model_based_elastic": JobMode("model_based_elastic", True,
                                   "flatness-based feed-forward for elastic gears: motor reference q_d + K^-1 tau_g "
                                   "(from q_d and its derivatives up to the 4th) as target, motor torque as torque "
                                   "offset, drive set-point shaping (controller/elastic.py)"),
}
"""The job's modes (``[controller] modes``), in the order they are reported."""

SPEED_FEEDFORWARD_PARAMETER = "speed_feedforward_gain"
"""The servo-drive FMU parameter the job sets per mode."""


def _mode_table(mode: str) -> Table:
    default = JOB_MODES[mode].drive_speed_feedforward
    return Table({
        "drive_speed_feedforward": Field(
            Boolean(), default=default,
            doc=f"true: the drives add their speed feed-forward from target differences (gain of "
                f"fmus/servo_drive/drive_params.toml), false: gain 0; default for {mode!r}: "
                f"{str(default).lower()}"),
    }, doc=f"the [controller.{mode}] table")

#: Largest accepted |x|, |y|, |z| of the payload's centre of mass in tool0, m: load diagrams of 10 kg-class
#: arms end at a few hundred mm of offset; 1 m leaves room for long tools and refuses unit slips (mm for m).
MAX_PAYLOAD_COM_M = 1.0

TRUE_ROBOT_TABLE = Table({
    "seed": Field(Integer(min=0), default=1, doc="the seed of the true robot's deviations: an integer >= 0"),
    "payload_mass": Field(Number(unit="kg", min=0, max=10), default=0.0,
                          doc="the payload on tool0: a number in kg in [0, 10] (rated load 10 kg)"),
    "payload_com": Field(List(Number(unit="m", min=-MAX_PAYLOAD_COM_M, max=MAX_PAYLOAD_COM_M), length=3),
                         default=[0.0, 0.0, 0.0],
                         doc="the payload's centre of mass in tool0: 3 numbers in m"),
    "dynamic_deviations": Field(Boolean(), default=True),
    "geometric_errors": Field(Boolean(), default=True),
}, doc="the [true_robot] table")

CONTROLLER_TABLE = Table({
    "modes": Field(List(String(choices=tuple(JOB_MODES)), min_len=1, unique=True),
                   default=["standard", "model_based"]),
    "period": Field(Number(unit="s", gt=0), default=400e-6, doc="the controller cycle: a number in s > 0"),
    "kinematics": Field(String(choices=("nominal", "true")), default="nominal",
                        doc="the controller's IK model: 'nominal' (URDF) or 'true' (perfectly calibrated)"),
    "calibrated_urdf": Field(FilePath(must_exist=True, suffix=".urdf"),
                             doc="a calibrated URDF for the controller's IK (overrides kinematics)"),
    "dynamics": Field(String(choices=("nominal", "true")), default="nominal",
                      doc="the feed-forward model: 'nominal' (URDF + parameter file) or 'true' (ideal)"),
    "payload_known": Field(Boolean(), default=True,
                           doc="true: the controller's model includes the [true_robot] payload (declared tool load)"),
    "drive_compensation": Field(Boolean(), default=True,
                                doc="model_based: shape the targets for the drives' speed feed-forward and filter"),
    "compute_budget": Field(Number(unit="s", gt=0), default=100e-6),
    "settle_time": Field(Number(unit="s", min=0), default=0.2),
    **{mode: Field(_mode_table(mode)) for mode in JOB_MODES},
}, doc="the [controller] table")

PATH_TABLE = Table({
    "speed": Field(Number(unit="m/s", gt=0, max=2.0), default=1.0),
    "acceleration": Field(Number(unit="m/s^2", gt=0, max=20.0), default=5.0),
}, doc="the [path] table")

TRACKER_TABLE = Table({
    "period": Field(Number(unit="s", gt=0), default=1e-3),
    "noise_sigma": Field(Number(unit="m", min=0, max=1e-3), default=DEFAULT_POSITION_SIGMA_M),
    "seed": Field(Integer(min=0), default=0),
}, doc="the [tracker] table")

RESULTS_TABLE = Table({
    "can_log": Field(Boolean(), default=True, doc="write the CAN log can_<mode>.blf"),
    "figures": Field(Boolean(), default=True, doc="write the PNG figures"),
}, doc="the [results] table")

SCHEMA = Table({
    "scenario": SCENARIO_FIELD,
    **COSIM_FIELDS,
    "true_robot": Field(TRUE_ROBOT_TABLE, default={}),
    "controller": Field(CONTROLLER_TABLE, default={}),
    "path": Field(PATH_TABLE, default={}),
    "tracker": Field(TRACKER_TABLE, default={}),
    "fieldbus": Field(Table({}, extra=AnyValue(), doc="a [fieldbus] table (fieldbus/powerlink_defaults.toml keys)"),
                      default={}),
    "results": Field(RESULTS_TABLE, default={}),
}, doc="an iso9283 scenario document")


# ---------------------------------------------------------------------------------------- checks
def fill_table_defaults(doc: dict[str, Any]) -> None:
    """Give the job's tables ([true_robot], [controller], [path], [tracker], [results]) their
    fields' defaults where the document leaves them out (the jobs built on this schema call it too)."""
    fill_defaults(doc, SCHEMA, ("true_robot", "controller", "path", "tracker", "results"))


def check(doc: dict[str, Any], where: Where) -> None:
    """Everything that can be checked before running (raises ScenarioError at the key)."""
    fill_table_defaults(doc)
    check_cell(doc, where, job_set_drive_parameters={
        SPEED_FEEDFORWARD_PARAMETER: "no speed_feedforward_gain here: the job sets it per mode "
                                     "([controller.<mode>] drive_speed_feedforward = true/false)"},
        run_length_s=doc["simulation"]["stop_time"])


# ---------------------------------------------------------------------------------------- set-up
def make_true_robot(table: dict[str, Any]):
    """The seeded true robot of the [true_robot] table."""
    from robot.geometric_errors import ErrorMagnitudes
    from robot.true_robot import DeviationMagnitudes, make_true_robot as draw

    payload = [table["payload_mass"], *table["payload_com"]]
    dyn = DeviationMagnitudes() if table["dynamic_deviations"] else DeviationMagnitudes(
        **{k: 0.0 for k in DeviationMagnitudes.__dataclass_fields__})
    geo = None if table["geometric_errors"] else _zero_error_magnitudes(ErrorMagnitudes)
    return draw(table["seed"], payload, dyn, geometric_magnitudes=geo)


def _zero_error_magnitudes(cls):
    fields = cls.__dataclass_fields__
    return cls(**{k: 0.0 for k in fields})


def controller_models(ctrl: dict[str, Any], true_robot) -> tuple[Any, Any, str, str]:
    """(kinematic model, dynamics, kinematics label, dynamics label) of the controller."""
    from robot.description import load_model
    from robot.dynamics import RobotDynamics

    if ctrl.get("calibrated_urdf") is not None:
        kin, kin_label = load_model(ctrl["calibrated_urdf"]), f"calibrated URDF {ctrl['calibrated_urdf']}"
    elif ctrl["kinematics"] == "true":
        kin, kin_label = true_robot.kinematic_model(), "true (ideal calibration)"
    else:
        kin, kin_label = load_model(), "nominal URDF"
    payload = true_robot.payload if ctrl["payload_known"] else np.zeros(4)
    if ctrl["dynamics"] == "true":
        dyn, dyn_label = true_robot.dynamics(), "true robot (ideal identification)"
    else:
        dyn, dyn_label = RobotDynamics(payload=payload, model=kin), "nominal (URDF + rx130l_params.toml)"
    return kin, dyn, kin_label, dyn_label


def drive_speed_feedforward(ctrl: dict[str, Any], mode: str) -> bool:
    """Whether the drives' speed feed-forward is on in ``mode`` ([controller.<mode>] or the mode's default)."""
    table = ctrl.get(mode) or {}
    return bool(table.get("drive_speed_feedforward", JOB_MODES[mode].drive_speed_feedforward))


def mode_fmus(doc_fmus: list[dict[str, Any]], speed_feedforward: bool) -> list[dict[str, Any]]:
    """A copy of the scenario's ``[[fmus]]`` with every drive's ``speed_feedforward_gain`` set:
    the drive parameter file's value (1.0) when ``speed_feedforward``, else 0."""
    from fmus.servo_drive.params import drive_start_values

    fmus = copy.deepcopy(doc_fmus)
    for fmu in fmus:
        if fmu["name"] in robot_cell.DRIVES:
            axis = robot_cell.DRIVES.index(fmu["name"]) + 1
            gain = drive_start_values(axis)[SPEED_FEEDFORWARD_PARAMETER] if speed_feedforward else 0.0
            fmu["parameters"] = {**fmu["parameters"], SPEED_FEEDFORWARD_PARAMETER: float(gain)}
    return fmus


# ---------------------------------------------------------------------------------------- running
@dataclass
class JobSetup:
    """Everything the modes of one scenario share (built once by :func:`prepare`).

    doc: the validated scenario document; true_robot; path (planners.iso9283 test path);
    reference (:class:`TcpTrajectory` on the controller grid); kinematics/dynamics of the
    controller and their labels; tracker; fieldbus (FieldbusConfig); capacity (controller
    log rows); mode_settings (per mode: controller_mode, drive_speed_feedforward,
    torque_feedforward, description).
    """

    doc: dict[str, Any]
    true_robot: Any
    path: Any
    reference: TcpTrajectory
    kinematics: Any
    dynamics: Any
    kinematics_label: str
    dynamics_label: str
    tracker: TrackerConfig
    fieldbus: Any
    capacity: int
    mode_settings: dict[str, dict[str, Any]]

    def summary_fields(self) -> dict[str, Any]:
        """summary.json fields describing the set-up (true robot, controller model, path, definitions)."""
        tr, ctrl_t = self.true_robot, self.doc["controller"]
        return {
            "true_robot": {"seed": tr.seed, "payload_mass_kg": float(tr.payload[0]),
                           "payload_com_m": tr.payload[1:].tolist(),
                           "dynamic_deviations": self.doc["true_robot"]["dynamic_deviations"],
                           "geometric_errors": self.doc["true_robot"]["geometric_errors"]},
            "controller_model": {"kinematics": self.kinematics_label, "dynamics": self.dynamics_label,
                                 "payload_known": ctrl_t["payload_known"],
                                 "drive_compensation": ctrl_t["drive_compensation"], "modes": self.mode_settings},
            "path": {"duration_s": self.path.duration, "length_m": self.path.length, "speed_m_s": self.path.speed,
                     "acceleration_m_s2": self.path.acceleration, "segments": self.path.segment_names},
            "definitions": DEFINITIONS,
        }


def prepare(doc: dict[str, Any], source: str) -> JobSetup:
    """Build the shared set-up of a validated iso9283-style document (``source``: the file, for messages)."""
    from fieldbus import FieldbusConfig
    from planners.iso9283 import iso9283_test_path

    fill_table_defaults(doc)
    ctrl_t = doc["controller"]
    period = ctrl_t["period"]
    true_robot = make_true_robot(doc["true_robot"])
    path = iso9283_test_path(speed=doc["path"]["speed"], acceleration=doc["path"]["acceleration"])
    reference = TcpTrajectory.from_reference(path.reference, path.duration, period)
    kin, dyn, kin_label, dyn_label = controller_models(ctrl_t, true_robot)
    tracker = TrackerConfig(doc["tracker"]["period"], doc["tracker"]["noise_sigma"], doc["tracker"]["seed"])
    fb = FieldbusConfig.from_dict(doc["fieldbus"], source=source)
    mode_settings = {mode: {"controller_mode": JOB_MODES[mode].controller_mode,
                            "drive_speed_feedforward": drive_speed_feedforward(ctrl_t, mode),
                            "torque_feedforward": JOB_MODES[mode].controller_mode in ("model_based",
                                                                                      "model_based_elastic"),
                            "description": JOB_MODES[mode].description} for mode in ctrl_t["modes"]}
    return JobSetup(doc, true_robot, path, reference, kin, dyn, kin_label, dyn_label, tracker, fb,
                    int(doc["simulation"]["stop_time"] / period) + 16, mode_settings)


def mode_controller(setup: JobSetup, mode: str) -> tuple[dict[str, Any], Controller]:
    """The scenario document and the controller of one mode: the document's drives get the
    mode's ``speed_feedforward_gain`` (:func:`mode_fmus`); the controller runs the mode's
    controller mode at ``[controller] period`` (s) with the set-up's models, set-points
    ``1 + dead_time_cycles`` cycles ahead of the fieldbus, and the drives' position loops
    (:func:`cosim.jobs.robot_cell.drive_loop_model`) when it feeds torque forward with
    ``drive_compensation``."""
    from planners.iso9283 import ISO_Q_HINT

    doc, ctrl_t = setup.doc, setup.doc["controller"]
    period = ctrl_t["period"]
    settings = setup.mode_settings[mode]
    mode_doc = {**doc, "fmus": mode_fmus(doc["fmus"], settings["drive_speed_feedforward"])}
    drive_model = (robot_cell.drive_loop_model(mode_doc["fmus"], period)
                   if ctrl_t["drive_compensation"] and settings["torque_feedforward"] else None)
    config = ControllerConfig(mode=settings["controller_mode"], period_s=period,
                              lead_cycles=1 + setup.fieldbus.dead_time_cycles,
                              compute_budget_s=ctrl_t["compute_budget"], settle_time_s=ctrl_t["settle_time"])
    controller = make_controller(setup.reference, config, kinematic_model=setup.kinematics, dynamics=setup.dynamics,
                                 q_hint=np.array(ISO_Q_HINT), drive_model=drive_model, capacity=setup.capacity)
    return mode_doc, controller


def run_mode(ctx: RunContext, setup: JobSetup, mode: str, extra_signals: Sequence[str] = ()
             ) -> tuple[dict[str, Any], TrackingResult, robot_cell.CellRun, Controller]:
    """Run one mode on the cell and evaluate it: (summary entry, tracking result, cell run, controller).

    The drives get the mode's ``speed_feedforward_gain``; ``extra_signals`` are recorded
    besides the scenario's [record] signals. A failure of the run is in ``cell.failure``
    (not raised); everything recorded up to it is evaluated and written.
    """
    doc = setup.doc
    settings = setup.mode_settings[mode]
    mode_doc, controller = mode_controller(setup, mode)
    if extra_signals:
        record = dict(doc.get("record") or {"period": setup.tracker.period_s, "signals": []})
        record["signals"] = list(record["signals"]) + [s for s in extra_signals if s not in record["signals"]]
        mode_doc["record"] = record
    can_log = ctx.path(f"can_{mode}.blf") if doc["results"]["can_log"] else None
    cell = robot_cell.run_cell(mode_doc, controller, setup.true_robot, ctx, label=mode,
                               stop_time=doc["simulation"]["stop_time"], fieldbus=setup.fieldbus,
                               tracker=setup.tracker, record_file=f"timeseries_{mode}.csv", can_log=can_log)
    entry, result = evaluate_run(ctx, mode, cell, controller, setup.reference, setup.path, setup.true_robot)
    entry = {"drive_speed_feedforward": settings["drive_speed_feedforward"],
             "torque_feedforward": settings["torque_feedforward"], **entry}
    return entry, result, cell, controller


def run(scenario: Scenario, ctx: RunContext) -> dict[str, Any]:
    """Run every mode of the scenario on the same true robot; write results; return summary fields."""
    setup = prepare(scenario.data, str(scenario.path))
    path = setup.path
    ctx.summary.update(**setup.summary_fields(), modes={})
    modes: dict[str, Any] = {}
    results: dict[str, TrackingResult] = {}
    for mode in setup.doc["controller"]["modes"]:
        entry, result, cell, _ = run_mode(ctx, setup, mode)
        modes[mode] = entry
        results[mode] = result
        ctx.summary.update(modes=modes)
        if cell.failure is not None:
            raise cell.failure
    fields: dict[str, Any] = {"modes": modes}
    if "standard" in modes and "model_based" in modes:
        fields["improvement_factor"] = _ratio(modes["standard"]["tcp_error_max_mm"],
                                              modes["model_based"]["tcp_error_max_mm"])
        fields["improvement_factor_rms"] = _ratio(modes["standard"]["tcp_error_rms_mm"],
                                                  modes["model_based"]["tcp_error_rms_mm"])
        fields["improvement_factor_noise_free"] = _ratio(modes["standard"]["tcp_error_max_noise_free_mm"],
                                                         modes["model_based"]["tcp_error_max_noise_free_mm"])
    if "standard_speed_ff" in modes and "model_based" in modes:
        fields["improvement_factor_vs_standard_speed_ff"] = _ratio(modes["standard_speed_ff"]["tcp_error_max_mm"],
                                                                   modes["model_based"]["tcp_error_max_mm"])
    if "model_based_elastic" in modes:
        for base in ("standard", "model_based"):
            if base in modes:
                fields[f"improvement_factor_elastic_vs_{base}"] = _ratio(
                    modes[base]["tcp_error_max_mm"], modes["model_based_elastic"]["tcp_error_max_mm"])
    if setup.doc["results"]["figures"]:
        from cosim.jobs.iso9283_figures import write_figures

        fields["figures"] = [p.name for p in write_figures(ctx.out_dir, results, path)]
    return fields


DEFINITIONS = {
    "tcp_error": "|measured - commanded| of the flange position, commanded = TRUE kinematics at the joint "
                 "set-points q_d(t) the drives apply (pure dynamic tracking error, paper Figure 2b)",
    "tcp_error_noise_free": "as tcp_error with the true flange instead of the tracker reading (no noise)",
    "tcp_path_error": "|measured - programmed| (programmed = desired Cartesian path): tcp_error plus the "
                      "geometric error of the controller's kinematic model",
    "path_accuracy_AT": "EN ISO 9283 AT per segment: max distance of a measured point to the commanded path in "
                        "the plane normal to the path (one run, no averaging over repetitions)",
    "joint_lag": "q_d(t) - q(t) per joint, rad (paper Figure 2a)",
    "window": "from the motion start (drives apply trajectory time 0) to the end of the trajectory",
    "cycle_compute_us": "wall time of the controller's own work per cycle (interpolation, IK, derivatives, "
                        "feed-forward), perf_counter_ns; deadline miss = above compute_budget",
    "cycle_compute_cpu_us": "the same as thread CPU time (thread_time_ns): without the time other processes "
                            "took the core",
}


def _ratio(a: float, b: float) -> float:
    return a / b if (b and math.isfinite(a) and math.isfinite(b)) else float("nan")


def evaluate_run(ctx: RunContext, mode: str, cell: robot_cell.CellRun, controller: Controller,
                 reference: TcpTrajectory, path, true_robot) -> tuple[dict[str, Any], TrackingResult]:
    """Post-process one run of the ISO 9283 path on the cell (also after a failure): write
    ``controller_<mode>.csv`` (the controller log), ``tcp_<mode>.csv`` (programmed, commanded
    and measured TCP in m, base_link; TCP and path errors in mm; joint set-points and lag
    errors in rad) and return (the summary entry of the run, the tracking result).

    ``mode`` names the run in the file names; ``reference`` is the controller's TCP
    trajectory, ``path`` the planners.iso9283 test path, ``true_robot`` the plant's robot
    (its kinematics turn joint angles into the commanded and true flange positions)."""
    from robot.kinematics import FlangeKinematics

    log = controller.log.columns()
    write_columns_csv(ctx.path(f"controller_{mode}.csv"), log)
    rec = cell.recording
    cols = rec.columns
    data = rec.data
    t = data[:, 0]
    q = data[:, [cols.index(f"plant.q[{i}]") for i in range(1, 7)]]
    measured = data[:, [cols.index(s) for s in ("tracker.x", "tracker.y", "tracker.z")]]
    t_apply = log["t_apply"]
    stack = [np.column_stack([log[f"{g}{j}"] for j in range(1, 7)]) for g in ("q_d", "qd_d", "qdd_d")]
    ok = np.isfinite(stack[0]).all(axis=1)
    q_d = desired_joints(t, t_apply[ok], stack[0][ok], stack[1][ok], stack[2][ok]) if ok.any() else q.copy()
    true_kinematics = FlangeKinematics(true_robot.kinematic_model())
    commanded = true_kinematics.transforms(q_d)[:, :3, 3] if t.size else measured
    actual = true_kinematics.transforms(q)[:, :3, 3] if t.size else measured
    start = controller.motion_start_s
    tau = np.clip(t - (start if start is not None else np.inf), 0.0, path.duration)
    programmed = reference.positions(reference.t_start + tau)
    ref = path.reference(tau)
    segment = ref.segment
    t_end = (start + path.duration) if start is not None else -1.0
    window = (start if start is not None else np.inf, min(t_end, float(t[-1]) if t.size else -1.0))
    result = evaluate(t, q, measured, q_d, commanded, programmed, segment, window, ref.arc_length, actual)
    lag = q_d - q
    series = {"t": t, "tau": tau, "segment": segment.astype(float), "arc_length": ref.arc_length}
    for name, arr in (("programmed", programmed), ("commanded", commanded), ("measured", measured)):
        for k, axis in enumerate("xyz"):
            series[f"{axis}_{name}"] = arr[:, k]
    series["tcp_error_mm"] = np.linalg.norm(measured - commanded, axis=1) * 1e3
    series["path_error_mm"] = np.linalg.norm(measured - programmed, axis=1) * 1e3
    for j in range(6):
        series[f"q_d{j + 1}"] = q_d[:, j]
    for j in range(6):
        series[f"q{j + 1}"] = q[:, j]
    for j in range(6):
        series[f"lag{j + 1}"] = lag[:, j]
    write_columns_csv(ctx.path(f"tcp_{mode}.csv"), series)
    timing = controller.timing()
    entry: dict[str, Any] = {
        "status": "ok" if cell.failure is None else "failed",
        **result.metrics(path.segment_names),
        "cycle_compute_us": {"p50": timing.p50_us, "p99": timing.p99_us, "max": timing.max_us,
                             "mean": timing.mean_us},
        "cycle_compute_cpu_us": {"p50": timing.cpu_p50_us, "p99": timing.cpu_p99_us, "max": timing.cpu_max_us},
        "deadline_misses": timing.deadline_misses,
        "compute_budget_us": timing.budget_us,
        "controller_cycles_timed": timing.cycles,
        "sim_time_s": cell.reached_s,
        "loop_wall_time_s": cell.loop_wall_time_s,
        "loop_realtime_factor": cell.reached_s / cell.loop_wall_time_s if cell.loop_wall_time_s > 0 else None,
        "engine": cell.engine,
        "motion_start_s": start,
        "enabled_at_s": controller.enabled_at_s,
        "path_completed": bool(start is not None and t.size and t[-1] >= t_end - 1e-9),
        "controller_phase": controller.phase.name.lower(),
        "stop_reason": controller.stop_reason,
        "ik_iterations_max": float(np.nanmax(log["ik_iterations"])) if log["ik_iterations"].size else None,
        "compiled_kernel": controller.kernel_note, "kernel_cycles": controller.kernel_cycles,
        "fallback_cycles": controller.fallback_cycles,
        "fieldbus": {k: cell.fieldbus[k] for k in ("cycles_run", "frames_sent", "frames_dropped", "frames_recorded",
                                                   "log_path", "dead_time_cycles", "node_fault", "comm_fault",
                                                   "scaling_saturations", "event_tally")},
        "files": {"timeseries": f"timeseries_{mode}.csv", "controller": f"controller_{mode}.csv",
                  "tcp": f"tcp_{mode}.csv", "can_log": Path(cell.fieldbus["log_path"]).name
                  if cell.fieldbus.get("log_path") else None},
    }
    if cell.failure is not None:
        entry["failure"] = str(cell.failure)
    if controller.phase is Phase.STOPPED:
        entry["stopped_at_s"] = controller.stopped_at_s
    return entry, result


register_job(JOB_NAME, run, SCHEMA, check,
             "ISO 9283 path through controller, fieldbus, drive and plant FMUs: standard vs model-based")
