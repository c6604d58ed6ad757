"""Job ``planners``: the paper's section 5 side by side, optionally executed on the cell.

A scenario names the planners to run (``[planners] run``, names of :data:`PLANNERS`) and
the problem (``[problem]``: the paper's straight line, ``planners.paper_line``; weights
k1, k2 of eq. 36/38/40; interval counts; the robot's limits, optionally scaled). CP
planners (``own_cp``, ``toppra``) get the CP problem along the line; PtP planners
(``own_ptp``, ``ruckig``, ``ruckig_feasible``) get the PtP problem between its end
points. Each plan is summarised (``planners.report.planner_summary``: status, duration_s,
solve_time_s, max_constraint_ratio at 1 ms with the torque recomputed by the nominal
inverse dynamics, energy = integral tau^T tau dt) and written as ``trajectory_<name>.csv``.

With ``[planners] execute = true`` each trajectory is driven through the co-simulated
cell (:mod:`cosim.cell`: the same wiring and tables as the iso9283 job, controller in ``model_based`` mode with the
joint trajectory as reference, POWERLINK-timed fieldbus, servo-drive FMUs, plant =
the seeded true robot or, with ``[planners] plant = "nominal"``, the nominal robot):
``tcp_error_max_mm`` (tracker reading vs TRUE kinematics at the applied set-points, as
the iso9283 job), ``tcp_error_max_noise_free_mm`` and ``drive_saturated`` (some drive's
current set-point ``current_demand`` reached its clamp min(current_limit, torque_limit /
(gear_ratio torque_constant))).

Results: ``summary.json`` (updated after every planner), ``trajectory_<name>.csv``,
``timeseries_<name>.parquet`` (or .csv on request) when executed, figures ``figure7_velocity_profile.png`` (CP
planners), ``figure8_active_constraints.png`` (own_cp), ``figure9_ptp.png`` (own_ptp).
See docs/explanation/planners.md.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from cosim.cell import wiring
from cosim.cell.description import describe_cell
from cosim.cell.parts import (BUILTIN_MODES, CELL_FIELDS, can_log_path, check_cell_scenario, controller_models,
                              drive_speed_feedforward, fill_cell_defaults, make_true_robot, mode_fmus,
                              tracker_config)
from cosim.cell.evaluation import controller_log_columns
from cosim.cell.info import controller_info
from cosim.execution import run_cell
from cosim.scenario.cosim_tables import COSIM_FIELDS
from cosim.scenario.loader import SCENARIO_FIELD
from cosim.tracking.metrics import desired_joints, residual_vibration
from cosim.scenario.context import RunContext
from cosim.scenario.loader import Scenario
from cosim.scenario.job_type import JobType
from cosim.scenario.schema import AnyValue, Boolean, Field, Integer, List, Number, Spec, String, Table, Where
from cosim.scenario.user_class import (SPEC_FORM, class_spec_file, instantiate, is_class_spec, load_user_class,
                                      with_class_file)

JOB_NAME = "planners"

CP_PLANNERS: tuple[str, ...] = ("own_cp", "toppra")
PTP_PLANNERS: tuple[str, ...] = ("own_ptp", "ruckig", "ruckig_feasible")
PLANNERS: tuple[str, ...] = CP_PLANNERS + PTP_PLANNERS
"""Built-in planner names a scenario may list in ``[planners] run`` (besides user planner classes)."""
USER_NAME_PATTERN = r"[A-Za-z0-9_.-]+"
"""What a user planner's ``name`` may contain (it names result files)."""

SATURATION_FRACTION = 1.0 - 1e-6
"""A drive counts as saturated when |current_demand| >= this fraction of its current clamp."""

SCALE_KINDS: tuple[str, ...] = ("velocity", "acceleration", "jerk", "torque", "torque_rate")



class PlannerEntry(Spec):
    """A built-in planner name or a user planner class (``file.py:Class`` / ``module:Class``)."""

    expected = f"one of {', '.join(repr(p) for p in PLANNERS)} or a planner class as {SPEC_FORM}"

    def check(self, value: Any, where: Where) -> str:
        if isinstance(value, str) and (value in PLANNERS or is_class_spec(value)):
            return value
        raise where.error(self.expected, value)

    # the file of a 'file.py:Class' entry travels with a sweep's tasks (cosim.scenario.keypath.referenced_files)
    def referenced_file(self, value: Any) -> str | None:
        return class_spec_file(value)

    def relocated(self, value: str, path: str) -> str:
        return with_class_file(value, path)


PLANNERS_TABLE = Table({
    "run": Field(List(PlannerEntry(), min_len=1, unique=True), required=True,
                 doc=f"the planners to run: names among {list(PLANNERS)} or user classes as {SPEC_FORM}"),
    "execute": Field(Boolean(), default=False,
                     doc="true: drive each planned trajectory through the co-simulated cell"),
    "execute_only": Field(List(PlannerEntry(), unique=True),
                          doc="with execute = true: only these planners (default: all of run)"),
    "plant": Field(String(choices=("true", "nominal")), default="true",
                   doc="the executing plant: 'true' (the [true_robot] table) or 'nominal' (no deviations)"),
    "figures": Field(Boolean(), default=True, doc="write Figures 7, 8, 9"),
    "parameters": Field(Table({}, extra=Table({}, extra=AnyValue(), doc="keyword arguments of the planner class"),
                              doc="per user planner entry of run: a table of its constructor's keyword arguments"),
                        default={}),
}, doc="the [planners] table")

SCALE_TABLE = Table({kind: Field(Number(gt=0, max=1.0), default=1.0,
                                 doc=f"factor on the robot's {kind} limits: a number in (0, 1]")
                     for kind in SCALE_KINDS}, doc="the [problem.limit_scale] table")

PROBLEM_TABLE = Table({
    "path": Field(String(choices=("paper_line",)), default="paper_line",
                  doc="the motion: 'paper_line' (planners.paper_line, eq. 39)"),
    "k1": Field(Number(min=0), default=1.0, doc="time weight of eq. 36: a number >= 0"),
    "k2": Field(Number(min=0), default=0.0, doc="energy weight of eq. 36 (tau^T tau): a number >= 0"),
    "n_intervals": Field(Integer(min=2, max=5000), default=200, doc="CP transcription intervals: an integer >= 2"),
    "ptp_intervals": Field(Integer(min=4, max=1000), default=100, doc="PtP transcription intervals: an integer >= 4"),
    "friction": Field(String(choices=("full", "coulomb", "none")), default="full",
                      doc="friction in the planners' torque model: 'full' (viscous and Coulomb), 'coulomb' or 'none'"),
    "cp_limits": Field(String(choices=("eq38", "all")), default="eq38",
                       doc="CP limits: 'eq38' (velocity, acceleration, torque: what TOPP-RA can represent) "
                           "or 'all' (plus jerk and torque rate)"),
    "ptp_limits": Field(String(choices=("eq40", "all")), default="eq40",
                        doc="PtP limits: 'eq40' (torque, torque rate, velocity, position) or 'all'"),
    "limit_scale": Field(SCALE_TABLE, default={}, doc="factors <= 1 on the robot's limits, per kind of limit"),
}, doc="the [problem] table")

SCHEMA = Table({"scenario": SCENARIO_FIELD, **COSIM_FIELDS, **CELL_FIELDS,
                "planners": Field(PLANNERS_TABLE, required=True,
                                  doc="the [planners] table: which planners run and are compared"),
                "problem": Field(PROBLEM_TABLE, default={},
                                 doc="the planning problem: motion, weights, transcription, friction, limits")},
               doc="a planners scenario document")


def _fill(doc: dict[str, Any]) -> None:
    for key in ("problem",):
        if not doc.get(key):
            doc[key] = SCHEMA.fields[key].spec.check({}, Where(None) / key)
    if not doc["problem"].get("limit_scale"):
        doc["problem"]["limit_scale"] = SCALE_TABLE.check({}, Where(None) / "problem" / "limit_scale")


def check(doc: dict[str, Any], where: Where) -> None:
    """The cell's checks (:func:`cosim.cell.parts.check_cell_scenario`) plus the planners' and problem's consistency."""
    check_cell_scenario(doc, where)
    _fill(doc)
    problem, planners = doc["problem"], doc["planners"]
    if problem["k1"] + problem["k2"] <= 0.0:
        raise (where / "problem" / "k2").error("k1 + k2 > 0 (k1 = 1, k2 = 0 is time-optimal)", problem["k2"],
                                               problem="both weights are 0")
    user_planners(planners, where / "planners")
    only = planners.get("execute_only")
    if only is not None:
        if not planners["execute"]:
            raise (where / "planners" / "execute_only").error("no execute_only unless execute = true", only)
        missing = [n for n in only if n not in planners["run"]]
        if missing:
            raise (where / "planners" / "execute_only").error(
                f"names among [planners] run = {planners['run']}", only, problem=f"{missing} not run")


# ------------------------------------------------------------------------------------- problems
def _limits(problem_t: dict[str, Any]):
    from planners.base import JointLimits

    lim = JointLimits.from_robot()
    scale = problem_t["limit_scale"]
    return lim.replace(**{k: getattr(lim, k) * scale[k] for k in SCALE_KINDS})


def _cp_problem(problem_t: dict[str, Any], dynamics: Any):
    from planners.paper_line import paper_cp_problem

    return paper_cp_problem(_limits(problem_t), dynamics, k1=problem_t["k1"], k2=problem_t["k2"],
                            friction=problem_t["friction"], n_intervals=problem_t["n_intervals"],
                            kinematic_only_limits=problem_t["cp_limits"] == "eq38")


def _ptp_problem(problem_t: dict[str, Any], dynamics: Any):
    from planners.ptp_optimal import paper_ptp_problem

    return paper_ptp_problem(_limits(problem_t), dynamics, k1=problem_t["k1"], k2=problem_t["k2"],
                             friction=problem_t["friction"], n_intervals=problem_t["ptp_intervals"],
                             paper_limits=problem_t["ptp_limits"] == "eq40")


def user_planners(planners_t: dict[str, Any], where: Where) -> dict[str, Any]:
    """The user planners of ``[planners] run`` (entry -> instance), loaded, instantiated with their
    ``[planners.parameters."<entry>"]`` and checked against the :class:`planners.base.Planner`
    contract; ScenarioError at the entry otherwise (also for a name clash)."""
    import re

    from planners.base import Planner

    params = planners_t.get("parameters") or {}
    for key in params:
        if key not in planners_t["run"] or key in PLANNERS:
            raise (where / "parameters" / key).error("a user planner entry of [planners] run",
                                                      problem="no such user planner in run")
    out: dict[str, Any] = {}
    names = {n: n for n in planners_t["run"] if n in PLANNERS}
    for k, entry in enumerate(planners_t["run"]):
        if entry in PLANNERS:
            continue
        at = (where / "run")[k]
        cls = load_user_class(entry, at, "planner class")
        planner = instantiate(cls, dict(params.get(entry) or {}), (where / "parameters" / entry), "planner class")
        missing = [m for m in ("name", "kind", "plan") if not hasattr(planner, m)]
        if missing or not callable(getattr(planner, "plan", None)):
            raise at.error("a class satisfying planners.base.Planner (name, kind, plan(problem) -> PlanResult)",
                           entry, problem=f"{cls.__name__} lacks {missing or ['a callable plan']}")
        if not isinstance(planner, Planner):
            raise at.error("a class satisfying planners.base.Planner", entry)
        if planner.kind not in ("cp", "ptp"):
            raise at.error("a planner whose kind is 'cp' or 'ptp'", entry, problem=f"kind = {planner.kind!r}")
        name = planner.name
        if not (isinstance(name, str) and re.fullmatch(USER_NAME_PATTERN, name)):
            raise at.error(f"a planner whose name matches {USER_NAME_PATTERN}", entry, problem=f"name = {name!r}")
        if name in names:
            raise at.error("a planner name not used by another entry of run", entry,
                           problem=f"name {name!r} is also {names[name]!r}")
        names[name] = entry
        out[entry] = planner
    return out


def _planner(name: str):
    """A fresh planner instance for ``name`` (one of :data:`PLANNERS`)."""
    if name == "own_cp":
        from planners.cp_optimal import OwnCPPlanner
        return OwnCPPlanner()
    if name == "toppra":
        from planners.toppra_baseline import ToppraPlanner
        return ToppraPlanner()
    if name == "own_ptp":
        from planners.ptp_optimal import OptimalPtPPlanner
        return OptimalPtPPlanner()
    if name == "ruckig":
        from planners.ruckig_baseline import RuckigPlanner
        return RuckigPlanner()
    if name == "ruckig_feasible":
        from planners.ruckig_baseline import FeasibleRuckigPlanner
        return FeasibleRuckigPlanner()
    raise ValueError(f"planner name {name!r}: expected one of {list(PLANNERS)}")


def ratios(entries: dict[str, dict[str, Any]]) -> dict[str, float]:
    """Duration ratios between the planners run (only pairs with both durations)."""
    pairs = {"own_cp_over_toppra": ("own_cp", "toppra"), "own_ptp_over_own_cp": ("own_ptp", "own_cp"),
             "own_ptp_over_ruckig_feasible": ("own_ptp", "ruckig_feasible"),
             "own_ptp_over_toppra": ("own_ptp", "toppra"), "ruckig_feasible_over_ruckig": ("ruckig_feasible", "ruckig")}
    out: dict[str, float] = {}
    for key, (a, b) in pairs.items():
        da = (entries.get(a) or {}).get("duration_s")
        db = (entries.get(b) or {}).get("duration_s")
        if da is not None and db:
            out[key] = float(da / db)
    return out


# ------------------------------------------------------------------------------------- execution
def _execute(ctx: RunContext, doc: dict[str, Any], name: str, traj: Any, true_robot: Any,
             fieldbus: Any) -> dict[str, Any]:
    """Drive ``traj`` (a planners Trajectory) through the cell; the summary fields of the run."""
    from controller import Controller, ControllerConfig, JointTrajectory
    from robot.kinematics import FlangeKinematics

    ctrl_t = doc["controller"]
    period = ctrl_t["period"]
    settings = BUILTIN_MODES["model_based"]
    speed_ff = drive_speed_feedforward(ctrl_t, "model_based")
    run_doc = {**doc, "fmus": mode_fmus(doc["fmus"], speed_ff)}
    demand = [f"{d}.current_demand" for d in wiring.DRIVES]
    kin, dyn, kin_label, dyn_label = controller_models(ctrl_t, true_robot)
    drive_model = wiring.drive_loop_model(run_doc["fmus"], period) if ctrl_t["drive_compensation"] else None
    reference = JointTrajectory.from_planner_trajectory(traj, period)
    stop_time = 0.02 + ctrl_t["settle_time"] + reference.duration + 0.2
    config = ControllerConfig(mode=settings.controller_mode, period_s=period, lead_cycles=fieldbus.lead_cycles,
                              compute_budget_s=ctrl_t["compute_budget"], settle_time_s=ctrl_t["settle_time"])
    controller = Controller(reference, config, kinematic_model=kin, dynamics=dyn, drive_model=drive_model,
                            capacity=int(stop_time / period) + 16)
    description = describe_cell(run_doc, true_robot, controller_info(controller, fieldbus, label=name), label=name,
                                stop_time=stop_time, fieldbus=fieldbus, tracker=tracker_config(doc["tracker"]),
                                record_file=f"timeseries_{name}.csv", extra_signals=demand,
                                can_log=can_log_path(ctx, doc["results"], name))
    cell = run_cell(description, controller, ctx)
    rec = cell.recording
    cols, data = rec.columns, rec.data
    t = data[:, 0]
    q = data[:, [cols.index(f"{wiring.PLANT}.q[{i}]") for i in range(1, 7)]]
    measured = data[:, [cols.index(s) for s in ("tracker.x", "tracker.y", "tracker.z")]]
    # the run's length is the trajectory's (stop_time above): its rows and log are held whole
    log = controller_log_columns(ctx, f"controller_{name}", cell, controller)
    stack = [np.column_stack([log[f"{g}{j}"] for j in range(1, 7)]) for g in ("q_d", "qd_d", "qdd_d")]
    ok = np.isfinite(stack[0]).all(axis=1)
    q_d = desired_joints(t, log["t_apply"][ok], stack[0][ok], stack[1][ok], stack[2][ok]) if ok.any() else q
    true_kin = FlangeKinematics(true_robot.kinematic_model())
    commanded = true_kin.positions(q_d)
    actual = true_kin.positions(q)
    start = controller.motion_start_s
    window = (t >= start) & (t <= start + reference.duration) if start is not None else np.zeros(t.size, bool)
    err = np.linalg.norm(measured - commanded, axis=1) * 1e3
    err_free = np.linalg.norm(actual - commanded, axis=1) * 1e3
    params = wiring.drive_parameters(run_doc["fmus"])
    clamp = np.array([min(p["current_limit"], p["torque_limit"] / (p["gear_ratio"] * p["torque_constant"]))
                      for p in params])
    current = np.abs(data[:, [cols.index(s) for s in demand]])
    peak_ratio = current.max(axis=0) / clamp if t.size else np.zeros(6)
    entry: dict[str, Any] = {
        "status": "ok" if cell.failure is None else "failed",
        "plant": doc["planners"]["plant"],
        "controller": {"mode": settings.controller_mode, "drive_speed_feedforward": speed_ff,
                       "kinematics": kin_label, "dynamics": dyn_label},
        "motion_start_s": start,
        "path_completed": bool(start is not None and t.size and t[-1] >= start + reference.duration - 1e-9),
        "tcp_error_max_mm": float(err[window].max()) if window.any() else None,
        "tcp_error_rms_mm": float(np.sqrt(np.mean(err[window] ** 2))) if window.any() else None,
        "tcp_error_max_noise_free_mm": float(err_free[window].max()) if window.any() else None,
        "joint_lag_max_rad": (np.abs(q_d - q)[window].max(axis=0).tolist() if window.any() else None),
        # after the trajectory's end (0.2 s of standstill): cosim.tracking.metrics.residual_vibration
        "residual_vibration": (residual_vibration(t, actual - commanded, start + reference.duration)
                               if start is not None else None),
        "drive_saturated": bool(np.any(current >= SATURATION_FRACTION * clamp)),
        "current_demand_peak_ratio": peak_ratio.tolist(),
        "sim_time_s": cell.reached_s,
        "loop_wall_time_s": cell.loop_wall_time_s,
        "files": {"timeseries": ctx.series_name(f"timeseries_{name}")},
    }
    if cell.failure is not None:
        entry["failure"] = str(cell.failure)
    from cosim.cell.verdict import record

    from cosim.cell.evaluation import deadline_basis

    record(entry, cell, controller.timing().judged_on(deadline_basis(cell)))
    ctx.note_verdict(name, entry)
    return entry


# ------------------------------------------------------------------------------------- run
def plan_checked(planner: Any, problem: Any, entry: str):
    """``planner.plan(problem)``, its result checked against the contract: a PlanResult whose
    trajectory is a planners Trajectory when its status has one. A user planner that raises
    or returns something else gives a PlanResult with status FAILED and the reason as message
    (the scenario goes on with the other planners)."""
    import time

    from planners.base import PlanResult, PlanStatus
    from planners.trajectory import Trajectory

    start = time.perf_counter()
    try:
        result = planner.plan(problem)
    except Exception as exc:  # a user's planner: record, do not crash the scenario
        return PlanResult(getattr(planner, "name", entry), PlanStatus.FAILED, None, time.perf_counter() - start,
                          message=f"{entry}: plan() raised {type(exc).__name__}: {exc}")
    if not isinstance(result, PlanResult):
        return PlanResult(getattr(planner, "name", entry), PlanStatus.FAILED, None, time.perf_counter() - start,
                          message=f"{entry}: plan() returned {type(result).__name__}, expected a "
                                  "planners.base.PlanResult")
    if result.status.has_trajectory and not isinstance(result.trajectory, Trajectory):
        return PlanResult(result.planner, PlanStatus.FAILED, None, result.solve_time_s,
                          message=f"{entry}: status {result.status.value} but trajectory is "
                                  f"{type(result.trajectory).__name__}, expected a planners.trajectory.Trajectory")
    return result


def refusal(entry: str, result: Any, problem: Any) -> Any:
    """Check a user planner's plan (``entry``: its class spec) before it runs, with the limit checker
    of trajectory files (:func:`planners.trajectory_file.check_planned_trajectory`: the robot's
    limits, and that it ends at the problem's goal): the :class:`~planners.trajectory_file.PlanLimitError`
    that refuses it, or None. Built-in planners are not refused here (their report gives
    ``max_constraint_ratio``; the drives judge what runs)."""
    from planners.trajectory_file import PlanLimitError, check_planned_trajectory

    if entry in PLANNERS or not result.ok or result.trajectory is None:
        return None
    goal = getattr(problem, "qe", None)
    if goal is None:
        path_q = getattr(getattr(problem, "path", None), "q", None)
        goal = None if path_q is None else np.asarray(path_q)[-1]
    try:
        check_planned_trajectory(result.trajectory, entry, goal=goal)
    except PlanLimitError as exc:
        return exc
    return None


def refused_fields(exc: Any) -> dict[str, Any]:
    """A refused plan's summary fields: ``status: "refused"``, the one-line reason and the violation
    (kind ``refused``: planner, joint, limit and time), verdict ``failed``."""
    from cosim.cell.verdict import Verdict, violation

    unit = {"position": "rad", "velocity": "rad/s", "acceleration": "rad/s^2", "torque": "N.m",
            "goal": "rad"}.get(exc.kind)
    limit = exc.limit if not isinstance(exc.limit, tuple) else (exc.limit[1] if exc.value > exc.limit[1]
                                                                  else exc.limit[0])
    if exc.kind == "goal":  # the plan ends short of the goal: no limit to quote
        v = violation("refused", exc.time, str(exc), joint=exc.joint, value=float(exc.value), unit=unit)
    else:
        v = violation("refused", exc.time, str(exc), joint=exc.joint, value=float(exc.value), limit=float(limit),
                      unit=unit)
    return {"status": "refused", "refused": str(exc), **Verdict("failed", [v], v, 1).fields()}


def run(scenario: Scenario, ctx: RunContext) -> dict[str, Any]:
    """Plan with every listed planner, summarise, write CSVs and figures, optionally execute."""
    from fieldbus import FieldbusConfig
    from planners.report import planner_summary
    from robot.dynamics import RobotDynamics

    doc = scenario.data
    fill_cell_defaults(doc)
    _fill(doc)
    problem_t, planners_t = doc["problem"], doc["planners"]
    dynamics = RobotDynamics()
    users = user_planners(planners_t, Where(scenario.path) / "planners")
    instances = {entry: users.get(entry) or _planner(entry) for entry in planners_t["run"]}
    kinds = {entry: p.kind for entry, p in instances.items()}
    cp = _cp_problem(problem_t, dynamics) if "cp" in kinds.values() else None
    ptp = _ptp_problem(problem_t, dynamics) if "ptp" in kinds.values() else None
    executed = (planners_t.get("execute_only") or planners_t["run"]) if planners_t["execute"] else []
    true_robot = fieldbus = None
    if executed:
        table = dict(doc["true_robot"])
        if planners_t["plant"] == "nominal":
            table.update(dynamic_deviations=False, geometric_errors=False)
        true_robot = make_true_robot(table)
        fieldbus = FieldbusConfig.from_dict(doc["fieldbus"], source=str(scenario.path))
    ctx.summary.update(problem={**problem_t, "cp_limits_note": "eq38: velocity, acceleration, torque",
                                "ptp_limits_note": "eq40: torque, torque rate, velocity, position"},
                       planners={})
    entries: dict[str, dict[str, Any]] = {}
    trajectories: dict[str, Any] = {}
    for run_entry in planners_t["run"]:
        planner = instances[run_entry]
        name = planner.name if run_entry in users else run_entry
        problem = cp if kinds[run_entry] == "cp" else ptp
        result = plan_checked(planner, problem, run_entry)
        entry = planner_summary(result, problem.limits, dynamics)
        entry["kind"] = kinds[run_entry]
        if run_entry in users:
            entry["class"] = run_entry
        extras = {k: v for k, v in result.info.items() if isinstance(v, (bool, int, float, str))}
        if extras:
            entry["info"] = extras      # planner-specific scalars (e.g. ruckig_feasible's limit scale)
        refused = refusal(run_entry, result, problem)
        if result.ok:
            if refused is None:
                trajectories[name] = result.trajectory
            result.trajectory.write_csv(ctx.path(f"trajectory_{name}.csv"))  # kept, refused or not
            entry["files"] = {"trajectory": f"trajectory_{name}.csv"}
        if refused is not None:  # beyond the robot's limits: not run, not drawn; the job ends failed
            entry.update(refused_fields(refused))
            ctx.note_verdict(name, entry)
        entries[name] = entry
        ctx.summary.update(planners=entries, ratios=ratios(entries))
        if run_entry in executed and result.ok and refused is None:
            entry["execution"] = _execute(ctx, doc, name, result.trajectory, true_robot, fieldbus)
            entry["tcp_error_max_mm"] = entry["execution"]["tcp_error_max_mm"]
            entry["drive_saturated"] = entry["execution"]["drive_saturated"]
            entry["residual_vibration_peak_mm"] = (entry["execution"]["residual_vibration"] or {}).get("peak_mm")
            ctx.summary.update(planners=entries)
    fields: dict[str, Any] = {"planners": entries, "ratios": ratios(entries)}
    if planners_t["figures"]:
        cp_names = {(instances[e].name if e in users else e) for e, k in kinds.items() if k == "cp"}
        fields["figures"] = _figures(ctx, trajectories, cp, ptp, dynamics, cp_names)
    return fields


def _figures(ctx: RunContext, trajectories: dict[str, Any], cp: Any, ptp: Any, dynamics: Any,
             cp_names: set[str] = set(CP_PLANNERS)) -> list[str]:
    from planners.ptp_figures import plot_ptp_torques_velocities
    from planners.report import plot_active_constraints, plot_velocity_profile

    written = []
    cp_trajs = {n: t for n, t in trajectories.items() if n in cp_names}
    if cp_trajs:
        written.append(plot_velocity_profile(cp_trajs, ctx.path("figure7_velocity_profile.png")))
    if "own_cp" in trajectories:
        written.append(plot_active_constraints(trajectories["own_cp"], cp.limits,
                                               ctx.path("figure8_active_constraints.png"), dynamics))
    if "own_ptp" in trajectories:
        written.append(plot_ptp_torques_velocities(trajectories["own_ptp"], ptp.limits, ctx.path("figure9_ptp.png"),
                                                   dynamics))
    return [p.name for p in written]


JOB = JobType(JOB_NAME, run, SCHEMA, check,
              "time/energy-optimal CP and PtP planners vs TOPP-RA and Ruckig, optionally executed on the cell")
