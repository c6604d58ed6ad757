"""Evaluation of a cell run along a programmed TCP path (the ISO 9283 path of the main job and of
the identification job's validation): the controller log, the recorded joint angles and the
tracker's measurement turned into TCP errors, ISO 9283 path accuracy, joint lags and the
run's summary entry."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from controller import Controller, ControllerLog
from cosim.cell.runner import CellRun
from cosim.tracking.metrics import TrackingResult, desired_joints, evaluate
from cosim.scenario.context import RunContext

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


SERIES_UNITS = (("t_apply", "s"), ("tau_ff", "N.m"), ("qdd_d", "rad/s2"), ("qd_d", "rad/s"), ("q_d", "rad"),
                ("q_obs", "rad"), ("target", "rad"), ("compute_us", "us"), ("lag", "rad"), ("arc_length", "m"),
                ("x_", "m"), ("y_", "m"), ("z_", "m"), ("q", "rad"), ("t", "s"), ("tau", "s"))
"""Units of the controller log and TCP series columns by name prefix (first match; ``*_mm`` are mm)."""


def series_units(columns) -> dict[str, str]:
    """Units of the columns of ``controller_<mode>`` and ``tcp_<mode>`` (see :data:`SERIES_UNITS`)."""
    units = {}
    for name in columns:
        if name.endswith("_mm"):
            units[name] = "mm"
            continue
        for prefix, unit in SERIES_UNITS:
            if name == prefix or (name.startswith(prefix) and (prefix.endswith("_") or name[len(prefix):].isdigit()
                                                               or prefix in ("t_apply", "compute_us", "arc_length"))):
                units[name] = unit
                break
    return units


def evaluate_run(ctx: RunContext, mode: str, cell: CellRun, controller: Any, reference, path, true_robot,
                 kinematic_model: Any = None, q_start: Any = None,
                 port_timing: Any = None) -> tuple[dict[str, Any], TrackingResult]:
    """Post-process one run of the ISO 9283 path on the cell (also after a failure): write
    ``controller_<mode>`` (the controller log), ``tcp_<mode>`` (Parquet, or CSV on request; programmed, commanded
    and measured TCP in m, base_link; TCP and path errors in mm; joint set-points and lag
    errors in rad) and return (the summary entry of the run, the tracking result).

    ``mode`` names the run in the file names; ``reference`` is the controller's TCP
    trajectory, ``path`` the planners.iso9283 test path, ``true_robot`` the plant's robot
    (its kinematics turn joint angles into the commanded and true flange positions).

    For a user's controller (not :class:`controller.Controller`) the joint set-points are the
    reference's IK with ``kinematic_model`` from ``q_start``, aligned at the controller's
    ``motion_start_s``; its compute times are ``port_timing`` (the cell's
    :meth:`controller.port.ControllerPort.timing`)."""
    from robot.kinematics import FlangeKinematics

    builtin = isinstance(controller, Controller) or isinstance(getattr(controller, "log", None), ControllerLog)
    rec = cell.recording
    cols = rec.columns
    data = rec.data
    t = data[:, 0]
    q = data[:, [cols.index(f"plant.q[{i}]") for i in range(1, 7)]]
    measured = data[:, [cols.index(s) for s in ("tracker.x", "tracker.y", "tracker.z")]]
    start = getattr(controller, "motion_start_s", None)
    if builtin:
        log = controller.log.columns()
        controller_file = ctx.write_series(f"controller_{mode}", log, series_units(log))
        t_apply = log["t_apply"]
        stack = [np.column_stack([log[f"{g}{j}"] for j in range(1, 7)]) for g in ("q_d", "qd_d", "qdd_d")]
        ok = np.isfinite(stack[0]).all(axis=1)
        q_d = desired_joints(t, t_apply[ok], stack[0][ok], stack[1][ok], stack[2][ok]) if ok.any() else q.copy()
    else:  # a user's controller: the reference's joint motion through the controller's IK, offline
        q_d = _reference_joints(t, start, reference, kinematic_model, q_start) if t.size else q.copy()
    true_kinematics = FlangeKinematics(true_robot.kinematic_model())
    commanded = true_kinematics.transforms(q_d)[:, :3, 3] if t.size else measured
    actual = true_kinematics.transforms(q)[:, :3, 3] if t.size else measured
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
    tcp_file = ctx.write_series(f"tcp_{mode}", series, series_units(series))
    timing = controller.timing() if builtin else port_timing
    entry: dict[str, Any] = {
        "status": "ok" if cell.failure is None else "failed",
        **result.metrics(path.segment_names),
        "cycle_compute_us": None if timing is None else {"p50": timing.p50_us, "p99": timing.p99_us,
                                                         "max": timing.max_us, "mean": timing.mean_us},
        "cycle_compute_cpu_us": None if timing is None else {"p50": timing.cpu_p50_us, "p99": timing.cpu_p99_us,
                                                             "max": timing.cpu_max_us},
        "deadline_misses": None if timing is None else timing.deadline_misses,
        "compute_budget_us": None if timing is None else timing.budget_us,
        "controller_cycles_timed": None if timing is None else timing.cycles,
        "sim_time_s": cell.reached_s,
        "loop_wall_time_s": cell.loop_wall_time_s,
        "loop_realtime_factor": cell.reached_s / cell.loop_wall_time_s if cell.loop_wall_time_s > 0 else None,
        "engine": cell.engine,
        "motion_start_s": start,
        "enabled_at_s": getattr(controller, "enabled_at_s", None),
        "path_completed": bool(start is not None and t.size and t[-1] >= t_end - 1e-9),
        "stop_reason": getattr(controller, "stop_reason", None),
        "fieldbus": {k: cell.fieldbus[k] for k in ("cycles_run", "frames_sent", "frames_dropped", "frames_recorded",
                                                   "log_path", "dead_time_cycles", "node_fault", "comm_fault",
                                                   "scaling_saturations", "event_tally")},
        "files": {"timeseries": ctx.series_name(f"timeseries_{mode}"), "controller": controller_file if builtin else None,
                  "tcp": tcp_file, "can_log": Path(cell.fieldbus["log_path"]).name
                  if cell.fieldbus.get("log_path") else None},
    }
    if builtin:
        entry.update(controller_phase=controller.phase.name.lower(),
                     ik_iterations_max=float(np.nanmax(log["ik_iterations"])) if log["ik_iterations"].size else None,
                     compiled_kernel=controller.kernel_note, kernel_cycles=controller.kernel_cycles,
                     fallback_cycles=controller.fallback_cycles)
    else:
        entry["controller"] = type(controller).__name__
        entry["contract_overhead_us"] = getattr(cell, "port_overhead", None)
        if start is None:
            entry["note"] = ("the controller gives no motion_start_s: the reference is not aligned with the run, "
                             "tracking figures are not evaluated")
    if cell.failure is not None:
        entry["failure"] = str(cell.failure)
    stopped_at = getattr(controller, "stopped_at_s", None)
    if stopped_at is not None:
        entry["stopped_at_s"] = stopped_at
    elif cell.failure is not None and cell.failure.component == "controller":
        entry["stopped_at_s"] = cell.failure.time
    return entry, result


def _reference_joints(t: np.ndarray, start: float | None, reference: Any, kinematic_model: Any,
                      q_start: Any) -> np.ndarray:
    """The joint motion (rad) of a TCP ``reference`` at times ``t`` with trajectory time 0 at
    ``start`` (s): the IK of ``kinematic_model`` along it, warm started from ``q_start``."""
    from controller import CartesianToJoint, JointTrajectory

    if start is None:
        return np.tile(np.asarray(q_start, dtype=float), (t.size, 1))
    tau = np.clip(t - start, 0.0, reference.duration)
    if isinstance(reference, JointTrajectory):
        return np.array([reference.sample(reference.t_start + x).q for x in tau])
    ik = CartesianToJoint(kinematic_model)
    ik.reset(np.asarray(q_start, dtype=float))
    out = np.empty((t.size, 6))
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1e-3
    for k, x in enumerate(tau):
        sample = reference.sample(reference.t_start + x)
        out[k] = ik.solve(sample.target, sample.twist, sample.acceleration, dt)[0]
    return out
