"""Planner summaries (summary.json ``planners.<name>``) and the paper's Figures 7 and 8.

``planner_summary`` gives the numbers each planner is compared by: duration_s, solve_time_s,
max_constraint_ratio (largest |value| / limit over velocity, acceleration, torque and
torque rate, resampled at 1 ms, torque recomputed by the robot's inverse dynamics),
energy (integral tau^T tau dt, N^2 m^2 s), plus status and the per-kind ratios.
Figures use matplotlib with the Agg backend (no display).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from planners.base import JointLimits, PlanResult
from planners.figure_file import save_figure
from planners.trajectory import RATIO_KINDS, Trajectory, constraint_ratios, energy
from robot.kinematics import FlangeKinematics

ACTIVE_THRESHOLD = 0.98
"""Normalised value above which a constraint counts as active in Figure 8."""


def planner_summary(result: PlanResult, limits: JointLimits, dynamics: Any = None,
                    dt: float = 1e-3) -> dict[str, Any]:
    """JSON-ready summary of one planner run (see module docstring); None values when no trajectory."""
    out: dict[str, Any] = {
        "status": result.status.value,
        "message": result.message,
        "solve_time_s": float(result.solve_time_s),
        "build_time_s": float(result.build_time_s),
        "duration_s": None,
        "max_constraint_ratio": None,
        "energy": None,
    }
    traj = result.trajectory
    if traj is None:
        return out
    ratios = constraint_ratios(traj, limits, dt, dynamics)
    finite = {k: float(np.max(v)) for k, v in ratios.items()}
    out.update({
        "duration_s": traj.duration,
        "max_constraint_ratio": max(finite[k] for k in RATIO_KINDS),
        "energy": energy(traj),
        "constraint_ratios": finite,
    })
    for key in ("iterations", "transcription", "constraint_rows"):
        if key in result.info:
            out[key] = result.info[key]
    return out


def tcp_speed(traj: Trajectory) -> np.ndarray:
    """Flange speed |v| [m/s] at the trajectory samples (geometric Jacobian times qd)."""
    kin = FlangeKinematics()
    jac = kin.jacobians(traj.q)
    return np.linalg.norm(np.einsum("nij,nj->ni", jac[:, :3, :], traj.qd), axis=1)


def plot_velocity_profile(trajectories: Mapping[str, Trajectory], path: str | Path,
                          title: str = "CP velocity profile (paper Figure 7)") -> Path:
    """Figure 7: flange speed over time and path speed sigma_dot over sigma, one line per planner."""
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    for name, traj in trajectories.items():
        ax1.plot(traj.t, tcp_speed(traj), label=f"{name} ({traj.duration:.3f} s)")
        if "sigma" in traj.cartesian and "sigma_dot" in traj.cartesian:
            ax2.plot(traj.cartesian["sigma"], traj.cartesian["sigma_dot"], label=name)
    ax1.set_xlabel("time [s]")
    ax1.set_ylabel("flange speed [m/s]")
    ax2.set_xlabel("path parameter sigma [-]")
    ax2.set_ylabel("sigma_dot [1/s]")
    for ax in (ax1, ax2):
        ax.grid(True, alpha=0.3)
        ax.legend()
    fig.suptitle(title)
    return save_figure(fig, path)


def normalised_signals(traj: Trajectory, limits: JointLimits, dynamics: Any = None,
                       dt: float = 1e-3) -> dict[str, np.ndarray]:
    """|value| / limit time series at ``dt`` per constraint and joint, e.g. "velocity 4".

    Keys "t" (s) and "<kind> <joint>" for velocity, acceleration, jerk, torque, torque_rate
    (finite limits only). Torques recomputed by inverse dynamics when ``dynamics`` is given;
    rate-type signals (jerk, torque_rate) are finite differences, one sample shorter,
    padded with their last value.
    """
    r = traj.resample(dt)
    if dynamics is not None:
        from planners.trajectory import _smooth_torque

        tau, tau_smooth = _smooth_torque(dynamics, r.q, r.qd, r.qdd)
    else:
        tau, tau_smooth = r.tau, r.tau
    step = np.diff(r.t)[:, None]

    def pad(x):
        return np.vstack([x, x[-1:]])

    values = {
        "velocity": np.abs(r.qd),
        "acceleration": np.abs(r.qdd),
        "jerk": pad(np.abs(np.diff(r.qdd, axis=0) / step)),
        "torque": np.abs(tau),
        "torque_rate": pad(np.abs(np.diff(tau_smooth, axis=0) / step)),
    }
    out: dict[str, np.ndarray] = {"t": r.t}
    for kind, val in values.items():
        lim = np.asarray(getattr(limits, kind))
        for j in range(6):
            if np.isfinite(lim[j]):
                out[f"{kind} {j + 1}"] = val[:, j] / lim[j]
    return out


def plot_active_constraints(traj: Trajectory, limits: JointLimits, path: str | Path, dynamics: Any = None,
                            threshold: float = ACTIVE_THRESHOLD,
                            title: str = "Normalised active constraints (paper Figure 8)") -> Path:
    """Figure 8: the normalised signals that reach ``threshold`` somewhere, and their maximum.

    A time-optimal solution has at least one active constraint at every instant; the
    black line (largest normalised value of all constraints) shows it.
    """
    import matplotlib.pyplot as plt

    sig = normalised_signals(traj, limits, dynamics)
    t = sig.pop("t")
    fig, ax = plt.subplots(figsize=(9, 4.5))
    for name, val in sig.items():
        if np.max(val) >= threshold:
            ax.plot(t, val, label=name, linewidth=1.2)
    ax.plot(t, np.max(np.vstack(list(sig.values())), axis=0), "k", linewidth=0.8, alpha=0.6,
            label="max of all")
    ax.set_ylim(0.0, 1.1)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("|value| / limit [-]")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="lower center", ncol=4, fontsize=8)
    ax.set_title(title)
    return save_figure(fig, path)


def energy_table(rows: Sequence[tuple[float, PlanResult]]) -> str:
    """Markdown table k2 | status | duration | energy for an energy-weighting sweep."""
    lines = ["| k2 | status | duration [s] | energy ∫τᵀτ dt [N²m²s] | solve [s] |", "|---|---|---|---|---|"]
    for k2, res in rows:
        if res.trajectory is None:
            lines.append(f"| {k2:g} | {res.status.value} | – | – | {res.solve_time_s:.3f} |")
        else:
            lines.append(f"| {k2:g} | {res.status.value} | {res.trajectory.duration:.4f} | "
                         f"{energy(res.trajectory):.4g} | {res.solve_time_s:.3f} |")
    return "\n".join(lines)
