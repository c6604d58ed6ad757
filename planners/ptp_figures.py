"""Figure 9 of the paper: PtP joint torques and velocities normalised to their limits.

``plot_ptp_torques_velocities`` draws two panels over time: (a) tau_j / tau_max_j and
(b) qd_j / qd_max_j, signed, for the joints whose normalised torque or velocity reaches
``threshold`` somewhere (the paper shows "the most interesting signals"), or for the
joints given. Torques are recomputed by the inverse dynamics when ``dynamics`` is given.
Matplotlib with the Agg backend (no display).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from planners.base import JointLimits, PlannerInputError
from planners.figure_file import save_figure
from planners.trajectory import Trajectory

FIGURE9_THRESHOLD = 0.9
"""Normalised level a joint's torque or velocity must reach to be drawn by default."""


def normalised_torques_velocities(traj: Trajectory, limits: JointLimits, dynamics: Any = None,
                                  dt: float = 1e-3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t (n,), tau / tau_max (n, 6), qd / qd_max (n, 6)) resampled every ``dt`` s, signed.

    Infinite limits give 0. With ``dynamics`` (robot.dynamics.RobotDynamics) the torque
    is ``dynamics.inverse_dynamics`` of the resampled (q, qd, qdd).
    """
    r = traj.resample(dt)
    if dynamics is not None:
        tau = np.array([dynamics.inverse_dynamics(r.q[k], r.qd[k], r.qdd[k]) for k in range(r.t.size)])
    else:
        tau = r.tau
    with np.errstate(divide="ignore"):
        tau_n = np.where(np.isfinite(limits.torque), tau / limits.torque, 0.0)
        qd_n = np.where(np.isfinite(limits.velocity), r.qd / limits.velocity, 0.0)
    return r.t, tau_n, qd_n


def plot_ptp_torques_velocities(traj: Trajectory, limits: JointLimits, path: str | Path, dynamics: Any = None,
                                joints: Sequence[int] | None = None, threshold: float = FIGURE9_THRESHOLD,
                                title: str = "PtP trajectory (paper Figure 9)") -> Path:
    """Write Figure 9 (PNG) to ``path`` and return the path.

    ``joints``: 1-based joint numbers to draw (default: those reaching ``threshold``;
    all joints if none does).
    """
    import matplotlib.pyplot as plt

    t, tau_n, qd_n = normalised_torques_velocities(traj, limits, dynamics)
    if joints is None:
        peak = np.maximum(np.max(np.abs(tau_n), axis=0), np.max(np.abs(qd_n), axis=0))
        chosen = [j + 1 for j in range(6) if peak[j] >= threshold] or list(range(1, 7))
    else:
        chosen = list(joints)
        if not chosen or any(j not in range(1, 7) for j in chosen):
            raise PlannerInputError(f"joints: expected joint numbers 1..6, got {list(joints)!r}")
    fig, (ax_tau, ax_qd) = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True)
    for j in chosen:
        ax_tau.plot(t, tau_n[:, j - 1], label=f"axis {j}", linewidth=1.2)
        ax_qd.plot(t, qd_n[:, j - 1], label=f"axis {j}", linewidth=1.2)
    for ax, label in ((ax_tau, "(a) torque / limit [-]"), (ax_qd, "(b) velocity / limit [-]")):
        ax.axhline(1.0, color="k", linestyle="--", linewidth=0.8)
        ax.axhline(-1.0, color="k", linestyle="--", linewidth=0.8)
        ax.set_ylim(-1.15, 1.15)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="lower right", ncol=len(chosen), fontsize=8)
    ax_qd.set_xlabel("time [s]")
    ax_tau.set_title(f"{title}, duration {traj.duration:.3f} s")
    return save_figure(fig, path)
