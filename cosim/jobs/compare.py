"""Job ``compare``: N controllers x M trajectories on the same seeded true robot, one ranked table.

A scenario lists the controllers and the trajectories (``[compare]``, docs/how-to/own_controller.md):

* controllers: the built-in modes of the main job (``standard``, ``standard_speed_ff``,
  ``model_based``, :data:`cosim.cell.parts.BUILTIN_MODES`) and users' controllers;
* trajectories: ``iso9283`` (the EN ISO 9283 test path of ``[path]``, a Cartesian
  reference the controller follows by IK, exactly as the main job), a built-in planner
  (``own_cp``, ``toppra``, ``own_ptp``, ``ruckig``, ``ruckig_feasible``) or a user planner
  class (``file.py:Class``) planning the ``[problem]`` of the planners job (the paper line),
  or a user trajectory file (joint or Cartesian CSV, :mod:`planners.trajectory_file`),
  checked against the robot's limits before anything runs.

Every pair runs through the same robot cell (:mod:`cosim.cell`: the
``[true_robot]`` drawn once from its seed, POWERLINK-timed fieldbus, drive FMUs, plant
FMU, laser tracker) and is evaluated the same way (:mod:`cosim.tracking.metrics`:
TCP error measured vs commanded with the TRUE kinematics, ISO 9283 AT, joint lag);
a ``model_based`` x ``iso9283`` entry is the main job's ``model_based`` run, to the last
digit. Added per entry: the peak ratio of the drives' current set-point to its clamp,
the mechanical energy at the joints (integral of sum |tau_j qd_j| dt over the motion, J),
the paper's torque measure (integral of tau^T tau dt), the motion's duration, the
controller's deadline misses.

Results: ``compare.csv`` and ``compare.json`` (the table, one row per entry, ranked per
trajectory by ``[compare] rank_by``), ``summary.json`` (the table plus every entry's full
record, updated after each entry), per entry ``timeseries_<label>``,
``tcp_<label>``, ``controller_<label>`` (Parquet, or CSV on request) (label ``<controller>__<trajectory>``),
per planned or file trajectory ``trajectory_<name>.csv``; figures
``compare_metrics.png`` (every metric for every entry, log axes where values span
decades) and ``compare_tcp_error.png`` (TCP error over the motion per trajectory).
"""
from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from controller import ControllerLog
from cosim.cell import wiring
from cosim.cell.description import describe_cell
from cosim.cell.evaluation import (controller_log_columns, deadline_basis, evaluate_run, recording_chunks,
                                   timing_fields)
from cosim.execution.mode_runs import CellSetup, mode_cell, prepare
from cosim.cell.parts import (BUILTIN_MODES, CELL_FIELDS, TORQUE_FEEDFORWARD_MODES, can_log_path, check_cell_scenario,
                              drive_speed_feedforward, fill_cell_defaults, mode_fmus)
from cosim.cell.run import CellRun
from cosim.cell.info import controller_info
from cosim.execution import run_cell
from cosim.jobs import planners as planners_job
from cosim.tracking.metrics import desired_joints, evaluate
from cosim.scenario.context import RunContext
from cosim.scenario.cosim_tables import COSIM_FIELDS
from cosim.scenario.loader import SCENARIO_FIELD, Scenario
from cosim.scenario.job_type import JobType
from cosim.scenario.schema import (AnyValue, Boolean, Field, List, Number, Spec, String, Table, Where)
from cosim.scenario.user_class import (SPEC_FORM, class_spec_file, instantiate, is_class_spec, load_user_class,
                                      with_class_file)

JOB_NAME = "compare"
ISO_TRAJECTORY = "iso9283"
NAME_PATTERN = r"[A-Za-z0-9_.-]+"
"""What an entry's name may contain (it names result files)."""
ENABLE_MARGIN_S = 0.02
"""Time [s] allowed for enabling the drives before the settle time starts (joint trajectories)."""
TAIL_S = 0.2
"""Standstill [s] recorded after the end of a joint trajectory."""
SATURATION_FRACTION = planners_job.SATURATION_FRACTION

METRICS: dict[str, str] = {
    "tcp_error_max_mm": "max TCP error [mm]",
    "tcp_error_rms_mm": "RMS TCP error [mm]",
    "path_accuracy_AT_mm": "ISO 9283 AT [mm]",
    "joint_lag_max_mrad": "max joint lag [mrad]",
    "current_peak_ratio": "peak current / clamp [-]",
    "energy_J": "mechanical energy [J]",
    "tau_squared_integral": "integral tau^T tau dt [N^2 m^2 s]",
    "duration_s": "motion duration [s]",
    "deadline_misses": "deadline misses [-]",
}
"""The table's metrics (column -> label with unit); all: smaller is better except none."""
TABLE_COLUMNS: tuple[str, ...] = ("trajectory", "controller", "rank", "status", *METRICS, "first_violation")
"""compare.csv's columns: ``status`` is the entry's verdict (``ok``, ``limit``, ``fault``,
``failed``, ``refused``, ``planner_<status>``); only ``ok`` entries are ranked and carry metrics
in the table; the others follow the ranked rows with an empty rank, empty metric cells and
their first violation (their metrics are in compare.json under ``unranked_metrics``)."""
UNRANKED_NOTE = ("not ranked: the run did not end ok; its metrics cover the run up to its stop or with the "
                 "violation in, and are not comparable")

# ------------------------------------------------------------------------------------- schema


class ControllerEntry(Spec):
    """A controller of the comparison: a built-in mode name, a user controller class or FMU, or a table."""

    expected = (f"a built-in mode ({', '.join(repr(m) for m in BUILTIN_MODES)}), a controller class as {SPEC_FORM}, "
                "a controller FMU 'path.fmu', or a table with one of the keys mode, class, fmu, fmu_source")
    TABLE = Table({
        "name": Field(String(pattern=NAME_PATTERN, pattern_doc="of letters, digits, _ - ."),
                      doc="the entry's name in the table and file names"),
        "mode": Field(String(choices=tuple(BUILTIN_MODES)), doc="a built-in mode of the main job"),
        "class": Field(String(), doc=f"a user controller class (controller.CellController) as {SPEC_FORM}"),
        "fmu": Field(String(), doc="an FMI 2.0 co-simulation controller FMU (relative to the scenario file)"),
        "fmu_source": Field(String(), doc="a folder with the controller FMU's modelDescription.xml and C files: "
                                          "built with the system C compiler (fmus.source_fmu)"),
        "parameters": Field(Table({}, extra=AnyValue(), doc="keyword arguments of the class / FMU parameters"),
                            default={}),
        "fmu_inputs": Field(Table({}, extra=String(), doc="FMU input = controller input field, e.g. "
                                                          "q1 = 'position[1]'"), default={}),
        "fmu_outputs": Field(Table({}, extra=String(), doc="FMU output = controller output field, e.g. "
                                                           "tau1 = 'torque_offset[1]'"), default={}),
        "drive_speed_feedforward": Field(Boolean(), doc="the drives' own speed feed-forward from target "
                                                        "differences (default: the mode's; false for user "
                                                        "controllers)"),
    }, one_of=[("mode", "class", "fmu", "fmu_source")], doc="a controller table")

    def check(self, value: Any, where: Where) -> dict[str, Any]:
        if isinstance(value, str):
            if value in BUILTIN_MODES:
                return {"name": value, "kind": "mode", "mode": value, "parameters": {}}
            if value.lower().endswith(".fmu"):
                value = {"fmu": value}
            elif is_class_spec(value):
                value = {"class": value}
            else:
                raise where.error(self.expected, value)
        if not isinstance(value, dict):
            raise where.error(self.expected, value)
        table = self.TABLE.check(value, where)
        if "mode" in table:
            return {"kind": "mode", "name": table["mode"], **table}
        if "class" in table:
            table["kind"] = "class"
            table.setdefault("name", table["class"].rpartition(":")[2].split(".")[-1])
            return table
        key = "fmu" if "fmu" in table else "fmu_source"
        path = Path(table[key]).expanduser()
        table[key] = path if path.is_absolute() else where.base_dir / path
        table["kind"] = "fmu"
        table.setdefault("name", table[key].stem if key == "fmu" else table[key].name)
        return table

    # the class file or FMU of an entry travels with a sweep's tasks (a source folder, like
    # [[fmus]] source, does not: a shipped sweep needs the built FMU, fmu = "...")
    def referenced_file(self, value: Any) -> str | None:
        if isinstance(value, dict):
            if isinstance(value.get("fmu"), str):
                return value["fmu"]
            return class_spec_file(value.get("class"))
        if isinstance(value, str) and value.lower().endswith(".fmu"):
            return value
        return class_spec_file(value) if isinstance(value, str) and value not in BUILTIN_MODES else None

    def relocated(self, value: Any, path: str) -> Any:
        if isinstance(value, dict):
            if isinstance(value.get("fmu"), str):
                return {**value, "fmu": path}
            return {**value, "class": with_class_file(value["class"], path)}
        return path if value.lower().endswith(".fmu") else with_class_file(value, path)


def user_controller_table(entry: dict[str, Any]) -> dict[str, Any]:
    """The entry as a ``[controller]``-like table for :mod:`cosim.cell.user_controller` (FMU built from
    its source folder first when ``fmu_source`` is given)."""
    ctrl = {"parameters": dict(entry.get("parameters") or {}), "fmu_inputs": dict(entry.get("fmu_inputs") or {}),
            "fmu_outputs": dict(entry.get("fmu_outputs") or {})}
    if entry["kind"] == "class":
        ctrl["class"] = entry["class"]
    else:
        ctrl["fmu"] = entry.get("fmu") or entry["fmu_built"]
    return ctrl


class TrajectoryEntry(Spec):
    """A trajectory of the comparison: ``iso9283``, a planner, a user planner class, a CSV file, or a table."""

    expected = (f"'iso9283', a planner name ({', '.join(repr(p) for p in planners_job.PLANNERS)}), a planner "
                f"class as {SPEC_FORM}, a trajectory file 'path.csv', or a table with one of the keys path, "
                "planner, file")
    TABLE = Table({
        "name": Field(String(pattern=NAME_PATTERN, pattern_doc="of letters, digits, _ - ."),
                      doc="the entry's name in the table and file names"),
        "path": Field(String(choices=(ISO_TRAJECTORY,)), doc="'iso9283': the EN ISO 9283 test path of [path]"),
        "planner": Field(String(), doc=f"a built-in planner name or a planner class as {SPEC_FORM}"),
        "parameters": Field(Table({}, extra=AnyValue(), doc="the planner class's keyword arguments"), default={}),
        "file": Field(String(), doc="a trajectory CSV file (relative to the scenario file's folder)"),
        "kind": Field(String(choices=("auto", "joint", "cartesian")), default="auto",
                      doc="the file's kind: 'auto' (Cartesian when it has x, y, z), 'joint' or 'cartesian'"),
        "smoothing": Field(Number(unit="rad", min=0), default=0.0,
                           doc="0: interpolating quintic spline through q; sigma > 0: smoothing spline, RMS "
                               "deviation <= sigma (rad)"),
        "boundary": Field(String(choices=("rest", "free")), default="rest",
                          doc="'rest': qd = qdd = 0 at both ends of the derived spline; 'free': not-a-knot"),
        "q_seed": Field(List(Number(unit="rad"), length=6),
                        doc="Cartesian files: the IK branch of the first sample is the one nearest to these 6 "
                            "angles (default: planners.iso9283.ISO_Q_HINT)"),
    }, one_of=[("path", "planner", "file")], doc="a trajectory table")

    # the trajectory file or planner file of an entry travels with a sweep's tasks
    # (cosim.scenario.keypath.referenced_files)
    def referenced_file(self, value: Any) -> str | None:
        if isinstance(value, dict):
            if isinstance(value.get("file"), str):
                return value["file"]
            return class_spec_file(value.get("planner"))
        if isinstance(value, str) and value.lower().endswith(".csv"):
            return value
        return class_spec_file(value)

    def relocated(self, value: Any, path: str) -> Any:
        if isinstance(value, dict):
            key = "file" if isinstance(value.get("file"), str) else "planner"
            return {**value, key: path if key == "file" else with_class_file(value[key], path)}
        return path if value.lower().endswith(".csv") else with_class_file(value, path)

    def check(self, value: Any, where: Where) -> dict[str, Any]:
        if isinstance(value, str):
            if value == ISO_TRAJECTORY:
                value = {"path": value}
            elif value in planners_job.PLANNERS or is_class_spec(value) and not value.endswith(".csv"):
                value = {"planner": value}
            elif value.lower().endswith(".csv"):
                value = {"file": value}
            else:
                raise where.error(self.expected, value)
        if not isinstance(value, dict):
            raise where.error(self.expected, value)
        table = self.TABLE.check(value, where)
        if "path" in table:
            table.update(kind_of="iso9283", name=table.get("name", ISO_TRAJECTORY))
        elif "planner" in table:
            spec = table["planner"]
            if not (spec in planners_job.PLANNERS or is_class_spec(spec)):
                raise (where / "planner").error(f"a planner name among {list(planners_job.PLANNERS)} or a planner "
                                                f"class as {SPEC_FORM}", spec)
            table["kind_of"] = "planner"
            if "name" not in table and spec in planners_job.PLANNERS:
                table["name"] = spec
        else:
            path = Path(table["file"]).expanduser()
            table["file"] = path if path.is_absolute() else where.base_dir / path
            table["kind_of"] = "file"
            table.setdefault("name", table["file"].stem)
        return table


COMPARE_TABLE = Table({
    "controllers": Field(List(ControllerEntry(), min_len=1), required=True,
                         doc="the controllers to compare: built-in mode names or controller tables"),
    "trajectories": Field(List(TrajectoryEntry(), min_len=1), default=[ISO_TRAJECTORY],
                          doc="the trajectories: 'iso9283', planner names or classes, trajectory CSV files"),
    "rank_by": Field(String(choices=tuple(k for k in METRICS if k != "duration_s")), default="tcp_error_max_mm",
                     doc="the metric the table ranks by (per trajectory, smaller first)"),
    "figures": Field(Boolean(), default=True, doc="write compare_metrics.png and compare_tcp_error.png"),
}, doc="the [compare] table")

SCHEMA = Table({"scenario": SCENARIO_FIELD, **COSIM_FIELDS, **CELL_FIELDS,
                "compare": Field(COMPARE_TABLE, required=True,
                                 doc="the [compare] table: the controllers and trajectories compared, the ranking"),
                "problem": Field(planners_job.PROBLEM_TABLE, default={},
                                 doc="the planning problem of planned trajectories (as in the planners job)")},
               doc="a compare scenario document")


# ------------------------------------------------------------------------------------- checks
def check(doc: dict[str, Any], where: Where) -> None:
    """The cell's checks (as the main job), unique entry names, every user planner loaded and every
    trajectory file read and checked against the robot's limits - before anything runs."""
    check_cell_scenario(doc, where)
    planners_job._fill(doc)
    cmp_t = doc["compare"]
    for k, entry in enumerate(cmp_t["controllers"]):
        _check_user_controller(doc, entry, (where / "compare" / "controllers")[k])
    _unique_names(cmp_t["controllers"], where / "compare" / "controllers")
    for k, entry in enumerate(cmp_t["trajectories"]):
        at = (where / "compare" / "trajectories")[k]
        if entry["kind_of"] == "planner" and entry["planner"] not in planners_job.PLANNERS:
            planner = _load_planner(entry, at)
            entry.setdefault("name", planner.name)
        elif entry["kind_of"] == "file":
            _load_file(doc, entry, at, check_only=True)
    _unique_names(cmp_t["trajectories"], where / "compare" / "trajectories")


def _check_user_controller(doc: dict[str, Any], entry: dict[str, Any], at: Where) -> None:
    """A user controller entry loaded and checked against the contract (FMU: built, its mapping checked)."""
    from cosim.cell.user_controller import check_user_controller
    from cosim.scenario.cosim_tables import resolve_source

    if entry["kind"] == "mode":
        return
    if entry["kind"] == "fmu":
        if "fmu_source" in entry:
            entry["fmu_built"] = resolve_source(str(entry["fmu_source"]), at / "fmu_source")
        elif not Path(entry["fmu"]).is_file():
            raise (at / "fmu").error("a controller FMU file (relative to the scenario file's folder)",
                                     str(entry["fmu"]), problem="no such file")
    check_user_controller(user_controller_table(entry), at)


def _unique_names(entries: list[dict[str, Any]], where: Where) -> None:
    seen: dict[str, int] = {}
    for k, entry in enumerate(entries):
        name = entry["name"]
        if not re.fullmatch(NAME_PATTERN, name):
            raise where[k].error(f"a name matching {NAME_PATTERN} (set name = ...)", name)
        if name in seen:
            raise where[k].error(f"a name not used by entry [{seen[name]}] (set name = ...)", name,
                                 problem=f"name {name!r} twice")
        seen[name] = k


def _load_planner(entry: dict[str, Any], at: Where):
    """A user planner instance, checked against the contract (errors at ``at.planner``)."""
    from planners.base import Planner

    cls = load_user_class(entry["planner"], at / "planner", "planner class")
    planner = instantiate(cls, dict(entry.get("parameters") or {}), at / "parameters", "planner class")
    if not isinstance(planner, Planner) or not callable(getattr(planner, "plan", None)):
        raise (at / "planner").error("a class satisfying planners.base.Planner (name, kind, plan(problem))",
                                     entry["planner"])
    if planner.kind not in ("cp", "ptp"):
        raise (at / "planner").error("a planner whose kind is 'cp' or 'ptp'", entry["planner"],
                                     problem=f"kind = {planner.kind!r}")
    if not (isinstance(planner.name, str) and re.fullmatch(NAME_PATTERN, planner.name)):
        raise (at / "planner").error(f"a planner whose name matches {NAME_PATTERN}", entry["planner"],
                                     problem=f"name = {planner.name!r}")
    return planner


def _controller_dynamics(doc: dict[str, Any]):
    """The nominal dynamics the controller knows (with the declared payload when payload_known)."""
    from robot.dynamics import RobotDynamics

    ctrl_t, tr = doc["controller"], doc["true_robot"]
    payload = [tr["payload_mass"], *tr["payload_com"]] if ctrl_t["payload_known"] else [0.0, 0.0, 0.0, 0.0]
    return RobotDynamics(payload=payload)


def _load_file(doc: dict[str, Any], entry: dict[str, Any], at: Where, check_only: bool = False,
               kinematic_model: Any = None):
    """The entry's trajectory file, loaded and checked (TrajectoryFileError -> ScenarioError at ``at.file``)."""
    from planners.iso9283 import ISO_Q_HINT
    from planners.trajectory_file import TrajectoryFileError, load_trajectory_file

    try:
        return load_trajectory_file(entry["file"], kind=entry["kind"], smoothing=entry["smoothing"],
                                    boundary=entry["boundary"], dynamics=_controller_dynamics(doc),
                                    kinematic_model=kinematic_model,
                                    q_seed=entry.get("q_seed") or list(ISO_Q_HINT))
    except TrajectoryFileError as exc:
        raise (at / "file").error("a trajectory file within the robot's limits (docs/how-to/own_controller.md)",
                                  str(entry["file"]), problem=str(exc)) from None


# ------------------------------------------------------------------------------------- trajectories
class _Motion:
    """One trajectory entry, ready to run: either the ISO path (Cartesian) or a planned/file joint trajectory."""

    def __init__(self, name: str, kind_of: str, trajectory: Any = None, status: str = "ok", message: str = "",
                 info: dict[str, Any] | None = None) -> None:
        self.name, self.kind_of, self.trajectory = name, kind_of, trajectory
        self.status, self.message, self.info = status, message, info or {}


def _motions(ctx: RunContext, doc: dict[str, Any], setup: CellSetup, source: Path | None) -> list[_Motion]:
    """Every trajectory entry planned or loaded (planner failures are entries with a status, not errors)."""
    from planners.report import planner_summary
    from robot.dynamics import RobotDynamics

    out: list[_Motion] = []
    problems: dict[str, Any] = {}
    dynamics = RobotDynamics()
    where = Where(source) / "compare" / "trajectories"
    for k, entry in enumerate(doc["compare"]["trajectories"]):
        name = entry["name"]
        if entry["kind_of"] == "iso9283":
            out.append(_Motion(name, "iso9283", info={"duration_s": setup.path.duration}))
            continue
        if entry["kind_of"] == "file":
            traj = _load_file(doc, entry, where[k], kinematic_model=setup.kinematics)
            traj.write_csv(ctx.path(f"trajectory_{name}.csv"))
            info = {"file": str(entry["file"]), "duration_s": traj.duration,
                    **{key: traj.metadata[key] for key in ("kind", "derivation", "torque", "limit_ratios")}}
            out.append(_Motion(name, "file", traj, info=info))
            continue
        spec = entry["planner"]
        planner = planners_job._planner(spec) if spec in planners_job.PLANNERS else _load_planner(entry, where[k])
        if planner.kind not in problems:
            problems[planner.kind] = (planners_job._cp_problem if planner.kind == "cp" else
                                      planners_job._ptp_problem)(doc["problem"], dynamics)
        problem = problems[planner.kind]
        result = planners_job.plan_checked(planner, problem, spec)
        summary = planner_summary(result, problem.limits, dynamics)
        info = {"planner": spec, "kind": planner.kind,
                **{key: summary[key] for key in ("status", "duration_s", "solve_time_s", "max_constraint_ratio")}}
        refused = planners_job.refusal(spec, result, problem)
        if refused is not None:  # beyond the robot's limits: not run (the other entries still run)
            result.trajectory.write_csv(ctx.path(f"trajectory_{name}.csv"))
            info.update(planners_job.refused_fields(refused))
            out.append(_Motion(name, "planner", None, status="refused", message=str(refused), info=info))
        elif result.ok:
            result.trajectory.write_csv(ctx.path(f"trajectory_{name}.csv"))
            out.append(_Motion(name, "planner", result.trajectory, info=info))
        else:
            out.append(_Motion(name, "planner", None, status=f"planner_{result.status.value}",
                               message=result.message, info=info))
    return out


# ------------------------------------------------------------------------------------- running
def _controller_for(setup: CellSetup, ctrl: dict[str, Any], motion: _Motion, stop_time: float):
    """(document for the run, Controller) of a built-in mode on ``motion``."""
    from controller import ControllerConfig, JointTrajectory
    from controller.elastic import make_controller

    mode = ctrl["mode"]
    ctrl_t = setup.doc["controller"]
    speed_ff = ctrl.get("drive_speed_feedforward")
    if speed_ff is None:
        speed_ff = drive_speed_feedforward(ctrl_t, mode)
    settings = {"controller_mode": BUILTIN_MODES[mode].controller_mode, "drive_speed_feedforward": speed_ff,
                "torque_feedforward": BUILTIN_MODES[mode].controller_mode in TORQUE_FEEDFORWARD_MODES,
                "description": BUILTIN_MODES[mode].description}
    run_doc = {**setup.doc, "fmus": mode_fmus(setup.doc["fmus"], speed_ff)}
    if motion.kind_of == "iso9283":
        setup.mode_settings[mode] = settings
        return run_doc, mode_cell(setup, mode)[1]
    period = ctrl_t["period"]
    drive_model = (wiring.drive_loop_model(run_doc["fmus"], period)
                   if ctrl_t["drive_compensation"] and settings["torque_feedforward"] else None)
    reference = JointTrajectory.from_planner_trajectory(motion.trajectory, period)
    config = ControllerConfig(mode=settings["controller_mode"], period_s=period,
                              lead_cycles=setup.fieldbus.lead_cycles,
                              compute_budget_s=ctrl_t["compute_budget"], settle_time_s=ctrl_t["settle_time"])
    # the elastic mode inverts the flexible-joint model along the joint reference (controller/elastic.py):
    # jerk and snap from the reference's accelerations on the controller grid, as on the ISO path
    controller = make_controller(reference, config, kinematic_model=setup.kinematics, dynamics=setup.dynamics,
                                 drive_model=drive_model, capacity=int(stop_time / period) + 16)
    return run_doc, controller


def _stop_time(doc: dict[str, Any], motion: _Motion) -> float:
    if motion.kind_of == "iso9283":
        return doc["simulation"]["stop_time"]
    macro = doc["simulation"]["macro_step"]
    raw = ENABLE_MARGIN_S + doc["controller"]["settle_time"] + motion.trajectory.duration + TAIL_S
    return math.ceil(raw / macro - 1e-9) * macro


def _evaluate_joint(ctx: RunContext, label: str, cell: CellRun, controller: Any, motion: _Motion,
                    setup: CellSetup):
    """Metrics of a joint-trajectory run (the main job's definitions; programmed = the planned flange
    by the controller's kinematic model; one segment); writes tcp_<label> and controller_<label> (Parquet, or CSV on request)."""
    from cosim.cell.evaluation import series_units
    from robot.kinematics import FlangeKinematics

    rec = cell.recording
    cols, data = rec.columns, rec.data
    t = data[:, 0]
    q = data[:, [cols.index(f"{wiring.PLANT}.q[{i}]") for i in range(1, 7)]]
    measured = data[:, [cols.index(s) for s in ("tracker.x", "tracker.y", "tracker.z")]]
    start = getattr(controller, "motion_start_s", None)
    traj = motion.trajectory
    tau = np.clip(t - (start if start is not None else np.inf), 0.0, traj.duration)
    planned_q = traj.sample(traj.t[0] + tau).q
    builtin = isinstance(getattr(controller, "log", None), ControllerLog)
    if builtin:  # a joint trajectory's run: stop_time follows the trajectory, its rows and log are held whole
        log = controller_log_columns(ctx, f"controller_{label}", cell, controller)
        stack = [np.column_stack([log[f"{g}{j}"] for j in range(1, 7)]) for g in ("q_d", "qd_d", "qdd_d")]
        ok = np.isfinite(stack[0]).all(axis=1)
        q_d = (desired_joints(t, log["t_apply"][ok], stack[0][ok], stack[1][ok], stack[2][ok]) if ok.any()
               else q.copy())
    else:  # a user's controller: the reference itself, aligned at its motion start (the start pose before)
        q_d = planned_q.copy()
    true_kin = FlangeKinematics(setup.true_robot.kinematic_model())
    commanded = true_kin.positions(q_d) if t.size else measured
    actual = true_kin.positions(q) if t.size else measured
    programmed = FlangeKinematics(setup.kinematics).positions(planned_q) if t.size else measured
    t_end = start + traj.duration if start is not None else -1.0
    window = (start if start is not None else np.inf, min(t_end, float(t[-1]) if t.size else -1.0))
    result = evaluate(t, q, measured, q_d, commanded, programmed, np.zeros(t.size, dtype=int), window, tau, actual)
    series = {"t": t, "tau": tau, "tcp_error_mm": np.linalg.norm(measured - commanded, axis=1) * 1e3}
    for name, arr in (("programmed", programmed), ("commanded", commanded), ("measured", measured)):
        for k, axis in enumerate("xyz"):
            series[f"{axis}_{name}"] = arr[:, k]
    for j in range(6):
        series[f"lag{j + 1}"] = q_d[:, j] - q[:, j]
    tcp_file = ctx.write_series(f"tcp_{label}", series, series_units(series))
    timing = controller.timing() if builtin else cell.controller_timing
    if timing is not None:
        timing = timing.judged_on(deadline_basis(cell))
    entry = {"status": "ok" if cell.failure is None else "failed", **result.metrics([motion.name]),
             **timing_fields(timing),
             "motion_start_s": start, "sim_time_s": cell.reached_s, "loop_wall_time_s": cell.loop_wall_time_s,
             "path_completed": bool(start is not None and t.size and t[-1] >= t_end - 1e-9),
             "stop_reason": getattr(controller, "stop_reason", None),
             "files": {"timeseries": ctx.series_name(f"timeseries_{label}"), "tcp": tcp_file,
                       "controller": ctx.series_name(f"controller_{label}") if builtin else (
                           Path(cell.controller_record).name if cell.controller_record is not None else None)}}
    if cell.failure is not None:
        entry["failure"] = str(cell.failure)
    from cosim.cell.verdict import record

    record(entry, cell, timing)
    ctx.note_verdict(label, entry)
    return entry, result


def _drive_metrics(cell: CellRun, doc_fmus: list[dict[str, Any]], window: tuple[float, float]
                   ) -> dict[str, Any]:
    """Over the motion window: the peak of |current set-point| / its clamp min(current_limit, torque_limit /
    (gear_ratio torque_constant)) (also over the whole run, which includes the enable transient),
    the mechanical energy and the tau^T tau integral; ``drive_saturated``: the clamp reached anywhere.
    The recording is read chunk by chunk; only the motion window's rows are held."""
    rec = cell.recording
    params = wiring.drive_parameters(doc_fmus)
    clamp = np.array([min(p["current_limit"], p["torque_limit"] / (p["gear_ratio"] * p["torque_constant"]))
                      for p in params])
    columns = ([rec.columns[0]] + [f"{d}.current_demand" for d in wiring.DRIVES]
               + [f"{d}.tau_out" for d in wiring.DRIVES] + [f"{wiring.PLANT}.qd[{i}]" for i in range(1, 7)])
    whole = np.full(6, -np.inf)
    saturated = False
    rows = 0
    kept: list[np.ndarray] = []
    for block in recording_chunks(rec, columns):
        current = np.abs(block[:, 1:7])
        whole = np.maximum(whole, current.max(axis=0))
        saturated = saturated or bool(np.any(current >= SATURATION_FRACTION * clamp))
        t = block[:, 0]
        mask = (t >= window[0] - 1e-9) & (t <= window[1] + 1e-9)
        if mask.any():
            kept.append(block[mask])
        rows += t.size
    inside = np.concatenate(kept) if kept else np.zeros((0, 19))
    tm, current, torque, qd = inside[:, 0], np.abs(inside[:, 1:7]), inside[:, 7:13], inside[:, 13:19]
    whole = whole / clamp if rows else np.full(6, np.nan)
    ratio = current.max(axis=0) / clamp if tm.size else np.full(6, np.nan)
    if tm.size >= 2:
        power = np.abs(torque * qd).sum(axis=1)
        tau2 = (torque ** 2).sum(axis=1)
        energy = float(np.sum(0.5 * (power[1:] + power[:-1]) * np.diff(tm)))
        tau_sq = float(np.sum(0.5 * (tau2[1:] + tau2[:-1]) * np.diff(tm)))
    else:
        energy = tau_sq = float("nan")
    return {"current_peak_ratio": float(np.max(ratio)), "current_peak_ratio_per_axis": ratio.tolist(),
            "current_peak_ratio_whole_run": float(np.max(whole)),
            "drive_saturated": saturated,
            "energy_J": energy, "tau_squared_integral": tau_sq}


def _user_description(ctx: RunContext, setup: CellSetup, ctrl: dict[str, Any], motion: _Motion, controller: Any,
                      label: str, stop_time: float, extra_signals: list[str]):
    """(document, cell description) of a user controller on ``motion``: told the motion's reference (the ISO
    path's TCP trajectory or the joint trajectory), the start pose, the controller's models and the entry's
    parameters; the drives run their plain cascade unless the entry sets drive_speed_feedforward."""
    from controller import JointTrajectory, start_configuration
    from planners.iso9283 import ISO_Q_HINT

    doc, ctrl_t = setup.doc, setup.doc["controller"]
    if motion.kind_of == "iso9283":
        reference = setup.reference
        q_start = start_configuration(setup.reference, setup.kinematics, np.array(ISO_Q_HINT))
    else:
        reference = JointTrajectory.from_planner_trajectory(motion.trajectory, ctrl_t["period"])
        q_start = np.array(motion.trajectory.q[0])
    info = controller_info(controller, setup.fieldbus, label=label, parameters=ctrl.get("parameters"),
                           source=setup.source, reference=reference, q_start=q_start,
                           kinematic_model=setup.kinematics, dynamics=setup.dynamics,
                           compute_budget_s=ctrl_t["compute_budget"])
    run_doc = {**doc, "fmus": mode_fmus(doc["fmus"], bool(ctrl.get("drive_speed_feedforward", False)))}
    can_log = can_log_path(ctx, doc["results"], label)
    return run_doc, describe_cell(run_doc, setup.true_robot, info, label=label, stop_time=stop_time,
                                  fieldbus=setup.fieldbus, tracker=setup.tracker,
                                  record_file=f"timeseries_{label}.csv", can_log=can_log,
                                  extra_signals=extra_signals)


def _largest(values: Any) -> float:
    """The largest finite value of ``values`` (nan when there is none)."""
    arr = np.asarray(values if values is not None else [], dtype=float)
    finite = arr[np.isfinite(arr)]
    return float(finite.max()) if finite.size else float("nan")


def run_entry(ctx: RunContext, setup: CellSetup, ctrl: dict[str, Any], motion: _Motion, where: Where
              ) -> tuple[dict[str, Any], Any]:
    """Run one controller on one motion through the cell and evaluate it: (record, TrackingResult or None).

    A user controller that cannot be made (its constructor raises) gives a failed entry, not an error."""
    from cosim.scenario.errors import ScenarioError

    doc = setup.doc
    label = f"{ctrl['name']}__{motion.name}"
    ctx.begin(label)  # an error before the cell runs names this entry, not the previous one
    stop_time = _stop_time(doc, motion)
    demand = [f"{d}.current_demand" for d in wiring.DRIVES]
    if ctrl["kind"] == "mode":
        run_doc, controller = _controller_for(setup, ctrl, motion, stop_time)
        can_log = can_log_path(ctx, doc["results"], label)
        description = describe_cell(run_doc, setup.true_robot,
                                    controller_info(controller, setup.fieldbus, label=label), label=label,
                                    stop_time=stop_time, fieldbus=setup.fieldbus, tracker=setup.tracker,
                                    record_file=f"timeseries_{label}.csv", can_log=can_log, extra_signals=demand)
    else:
        from cosim.cell.user_controller import make_user_controller

        table = {**user_controller_table(ctrl), "settle_time": doc["controller"]["settle_time"]}
        try:
            controller = make_user_controller(table, where)
        except ScenarioError as exc:
            from cosim.cell.verdict import apply, failed_verdict

            entry = apply({"status": "failed", "failure": str(exc), "trajectory": motion.name,
                           "controller": {"kind": ctrl["kind"]}}, failed_verdict(f"the controller could not be made: "
                                                                                 f"{exc}"))
            ctx.note_verdict(label, entry)
            return entry, None
        run_doc, description = _user_description(ctx, setup, ctrl, motion, controller, label, stop_time, demand)
    cell = run_cell(description, controller, ctx)
    if motion.kind_of == "iso9283":
        user = {} if ctrl["kind"] == "mode" else {"kinematic_model": setup.kinematics,
                                                  "q_start": description.controller.q_start,
                                                  "port_timing": cell.controller_timing}
        entry, result = evaluate_run(ctx, label, cell, controller, setup.reference, setup.path, setup.true_robot,
                                     **user)
        duration = setup.path.duration
    else:
        entry, result = _evaluate_joint(ctx, label, cell, controller, motion, setup)
        duration = motion.trajectory.duration
    start = getattr(controller, "motion_start_s", None)
    window = (start, start + duration) if start is not None else (math.inf, -math.inf)
    entry.update(_drive_metrics(cell, run_doc["fmus"], window))
    entry.update(controller={"kind": ctrl["kind"], "mode": ctrl.get("mode"), "class": ctrl.get("class"),
                             "fmu": str(ctrl.get("fmu") or ctrl.get("fmu_source") or "") or None},
                 trajectory=motion.name, duration_s=duration,
                 joint_lag_max_mrad=_largest(entry.get("joint_lag_max_rad")) * 1e3, stop_time_s=stop_time)
    if cell.failure is not None:
        entry.setdefault("failure", str(cell.failure))
    return entry, result


# ------------------------------------------------------------------------------------- table
def _row(ctrl: str, motion: _Motion, entry: dict[str, Any] | None) -> dict[str, Any]:
    """The table row of an entry: only an entry whose verdict is ``ok`` shows its metrics; the
    others keep them under ``unranked_metrics`` (marked, never ranked) with their first violation."""
    from cosim.cell.verdict import describe_violation

    if entry:
        status = entry.get("verdict") or entry["status"]
        first = entry.get("first_violation")
    else:
        status = motion.status
        first = motion.info.get("first_violation")
    row: dict[str, Any] = {"trajectory": motion.name, "controller": ctrl, "rank": None, "status": status}
    metrics: dict[str, Any] = {}
    for key in METRICS:
        value = entry.get(key) if entry else None
        if key == "duration_s" and value is None:
            value = motion.info.get("duration_s")
        metrics[key] = None if value is None or (isinstance(value, float) and not math.isfinite(value)) else value
    if status == "ok":
        row.update(metrics)
        row["first_violation"] = None
    else:
        row.update({key: None for key in METRICS})
        row["first_violation"] = (describe_violation(first) if first else
                                  (motion.message or (entry or {}).get("failure") or status))
        row["unranked_metrics"] = metrics
        row["note"] = UNRANKED_NOTE
    return row


def rank_rows(rows: list[dict[str, Any]], rank_by: str) -> list[dict[str, Any]]:
    """Rank the ``ok`` rows per trajectory by ``rank_by`` (smaller first); returns the ranked rows
    (by trajectory as listed, then rank), then every row that is not ``ok`` or has no value of
    ``rank_by`` (unranked, in the order given) below them."""
    order = list(dict.fromkeys(r["trajectory"] for r in rows))
    ranked: list[dict[str, Any]] = []
    for traj in order:
        group = [r for r in rows if r["trajectory"] == traj]
        good = sorted((r for r in group if r["status"] == "ok" and r[rank_by] is not None), key=lambda r: r[rank_by])
        for k, r in enumerate(good, start=1):
            r["rank"] = k
        ranked += good
    return ranked + [r for r in rows if not any(r is g for g in ranked)]


def write_table(out_dir: Path, rows: list[dict[str, Any]], rank_by: str) -> tuple[Path, Path]:
    """compare.csv (one row per entry, :data:`TABLE_COLUMNS`) and compare.json (rows, units, ranking key)."""
    csv_path, json_path = out_dir / "compare.csv", out_dir / "compare.json"
    with open(csv_path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(TABLE_COLUMNS)
        for r in rows:
            writer.writerow(["" if r[c] is None else (repr(float(r[c])) if isinstance(r[c], float) else r[c])
                             for c in TABLE_COLUMNS])
    json_path.write_text(json.dumps({"rank_by": rank_by, "columns": {k: METRICS.get(k, k) for k in TABLE_COLUMNS},
                                     "ranking_rule": "only entries whose verdict is ok are ranked (per trajectory, "
                                                     "smaller first); the others follow, unranked, with their "
                                                     "verdict, first violation and unranked_metrics",
                                     "rows": rows}, indent=2, default=_json_default), encoding="utf-8")
    return csv_path, json_path


def _json_default(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    return str(value)


def console_table(rows: list[dict[str, Any]], rank_by: str) -> list[str]:
    """The ranking for the console: per trajectory the ranked entries with their ``rank_by``
    value, then the entries not ranked with their verdict and first violation."""
    lines = [f"ranking by {rank_by} ({METRICS[rank_by]}, smaller first; only entries whose verdict is ok):"]
    for traj in dict.fromkeys(r["trajectory"] for r in rows):
        ranked = [r for r in rows if r["trajectory"] == traj and r["rank"] is not None]
        text = "  ".join(f"{r['rank']}. {r['controller']} {r[rank_by]:.6g}" for r in ranked) or "(none ranked)"
        lines.append(f"  {traj}: {text}")
    unranked = [r for r in rows if r["rank"] is None]
    if unranked:
        lines.append("not ranked:")
        lines += [f"  {r['controller']} / {r['trajectory']}: {r['status']}: {r['first_violation']}" for r in unranked]
    return lines


# ------------------------------------------------------------------------------------- run
def run(scenario: Scenario, ctx: RunContext) -> dict[str, Any]:
    """Every controller on every trajectory, same true robot; the ranked table, files and figures."""
    doc = scenario.data
    fill_cell_defaults(doc)
    planners_job._fill(doc)
    cmp_t = doc["compare"]
    doc["controller"]["modes"] = [c["mode"] for c in cmp_t["controllers"] if c["kind"] == "mode"] or ["model_based"]
    doc["controller"]["modes"] = list(dict.fromkeys(doc["controller"]["modes"]))
    setup = prepare(doc, str(scenario.path))
    ctx.summary.update(**setup.summary_fields(), entries={}, table=[])
    motions = _motions(ctx, doc, setup, scenario.path)
    ctx.summary.update(trajectories={m.name: {"status": m.status, "message": m.message, **m.info} for m in motions})
    entries: dict[str, dict[str, Any]] = {}
    results: dict[tuple[str, str], Any] = {}
    rows: list[dict[str, Any]] = []
    for motion in motions:
        for ctrl in cmp_t["controllers"]:
            label = f"{ctrl['name']}__{motion.name}"
            entry = None
            if motion.trajectory is not None or motion.kind_of == "iso9283":
                at = (Where(scenario.path) / "compare" / "controllers")[cmp_t["controllers"].index(ctrl)]
                entry, result = run_entry(ctx, setup, ctrl, motion, at)
                entries[label] = entry
                results[(motion.name, ctrl["name"])] = result
            else:  # its trajectory was refused or not planned: the entry did not run
                from cosim.cell.verdict import Verdict, violation

                first = motion.info.get("first_violation") or violation(motion.status, None, motion.message)
                ctx.note_verdict(label, Verdict("failed", [first], first, 1).fields())
            rows.append(_row(ctrl["name"], motion, entry))
            ctx.summary.update(entries=entries, table=rank_rows([dict(r) for r in rows], cmp_t["rank_by"]))
    rows = rank_rows(rows, cmp_t["rank_by"])
    write_table(ctx.out_dir, rows, cmp_t["rank_by"])
    import sys

    print("\n".join(console_table(rows, cmp_t["rank_by"])), file=sys.stderr)
    fields: dict[str, Any] = {"entries": entries, "table": rows, "rank_by": cmp_t["rank_by"],
                              "files": {"table_csv": "compare.csv", "table_json": "compare.json"}}
    if cmp_t["figures"]:
        from cosim.jobs.compare_figures import write_figures

        fields["figures"] = [p.name for p in write_figures(ctx.out_dir, rows, results, cmp_t["rank_by"], METRICS)]
    failed = [label for label, e in entries.items() if e["status"] != "ok"]
    if failed:
        fields["failed_entries"] = failed  # every entry whose verdict is not ok (the job's status says the worst)
    unranked = [f"{r['controller']}__{r['trajectory']}" for r in rows if r["rank"] is None]
    if unranked:
        fields["unranked_entries"] = unranked
    return fields


JOB = JobType(JOB_NAME, run, SCHEMA, check,
              "N controllers x M trajectories (built-in modes, planners, trajectory files) on one seeded robot: "
              "one ranked table")
