"""Figures of the identification campaign (paper Figure 5): excitation path, torque verification."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from robot.textfiles import csv_rows


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def figure_excitation_path(path: Path, excitation: Any, samples: int = 2000) -> Path:
    """Figure 5(a): the flange path of one period of the exciting trajectory (3D, m) with
    the allowed TCP box, and the optimised versus random condition numbers."""
    from robot.kinematics import FlangeKinematics

    plt = _pyplot()
    traj = excitation.trajectory
    s = traj.sample(np.arange(samples) * traj.period / samples)
    kin = FlangeKinematics()
    r = np.array([kin.position(q) for q in s.q])
    speed = np.linalg.norm(np.gradient(r, s.t, axis=0), axis=1)
    fig = plt.figure(figsize=(11, 5))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    points = ax.scatter(r[:, 0], r[:, 1], r[:, 2], c=speed, s=2, cmap="viridis")
    lo, hi = excitation.limits.tcp_lower, excitation.limits.tcp_upper
    for x in (lo[0], hi[0]):
        for y in (lo[1], hi[1]):
            ax.plot([x, x], [y, y], [lo[2], hi[2]], color="0.7", lw=0.5)
    ax.set_xlabel("x in m")
    ax.set_ylabel("y in m")
    ax.set_zlabel("z in m")
    ax.set_title(f"flange path, one period ({traj.period:.2f} s)\nmax flange speed {speed.max():.2f} m/s", fontsize=10)
    fig.colorbar(points, ax=ax, shrink=0.6, label="flange speed in m/s")
    ax2 = fig.add_subplot(1, 2, 2)
    ax2.semilogy(np.arange(len(excitation.history)), excitation.history, label="SLSQP iterate")
    for k, c in enumerate(excitation.random_condition_numbers):
        ax2.axhline(c, color="0.8", lw=0.6, label="random feasible series" if k == 0 else None)
    ax2.set_xlabel("iteration")
    ax2.set_ylabel("condition number of the normalised base regressor")
    ax2.set_title(f"optimised {excitation.condition_number:.3g} vs random median {excitation.random_median:.3g}",
                  fontsize=10)
    ax2.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def figure_torques(path: Path, csv_path: Path) -> Path:
    """Figure 5(b): measured (fieldbus) and predicted joint torques on the ISO 9283 path."""
    plt = _pyplot()
    rows = csv_rows(csv_path)
    header = rows[0]
    data = np.array(rows[1:], dtype=float)
    col = {name: k for k, name in enumerate(header)}
    t = data[:, col["t"]]
    fig, axes = plt.subplots(3, 2, figsize=(12, 9), sharex=True)
    for j, ax in enumerate(axes.T.reshape(-1)):
        ax.plot(t, data[:, col[f"tau_measured{j + 1}"]], color="0.8", lw=0.5, label="measured (torque actual)")
        ax.plot(t, data[:, col[f"tau_measured_filtered{j + 1}"]], color="0.3", lw=0.8, label="measured, low-pass")
        ax.plot(t, data[:, col[f"tau_identified{j + 1}"]], color="C0", lw=1.0, label="identified model")
        ax.plot(t, data[:, col[f"tau_nominal{j + 1}"]], color="C3", lw=0.8, ls="--", label="nominal model")
        ax.set_ylabel(f"joint {j + 1} torque in N m")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("time in s (ISO 9283 path)")
    fig.suptitle("Figure 5(b): measured vs predicted joint torques along the EN ISO 9283 path")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def figure_parameter_errors(path: Path, identification: dict[str, Any]) -> Path:
    """Every identified parameter against the true robot: the rotor inertias and (elastic plant)
    the gear stiffness and damping per axis in % with the +-10 % acceptance band
    (identification.campaign.WITHIN_PERCENT), and every base parameter's error in standard
    deviations with the +-3 sigma band."""
    plt = _pyplot()
    gears = identification.get("gear_stiffness")
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(13, 8.5), gridspec_kw={"height_ratios": [1, 1.2]})
    axes = np.arange(1, 7)
    rotors = identification["rotor_inertias"]
    width = 0.27 if gears else 0.5
    top.bar(axes - (width if gears else 0), [rotors[f"Ia{j}"]["error_percent"] for j in axes], width,
            label="rotor inertia (Ia1 in Izz1R, Ia2 in Iyy2R)", color="C0")
    if gears:
        k_err = [np.nan if e is None else e for e in gears["stiffness_error_percent"]]
        top.bar(axes, k_err, width, label="gear stiffness", color="C1")
        for x, e in zip(axes, k_err):
            top.annotate("k: not identifiable" if not np.isfinite(e) else f"k {e:+.2f} %", (x, 0), xytext=(0, -14),
                         textcoords="offset points", ha="center", fontsize=7, color="C1")
        prior = gears.get("nominal_stiffness_error_percent")
        if prior is not None:
            top.plot(axes, prior, "o", mfc="none", color="C1", label="catalogue stiffness (the prior)")
        b_err = [np.nan if e is None else e for e in (gears.get("damping_error_percent") or [None] * 6)]
        top.bar(axes + width, np.clip(b_err, -60, 60), width, label="gear damping (clipped at +-60 %)", color="C2",
                alpha=0.6)
    top.axhspan(-10, 10, color="0.9", zorder=0, label="+-10 % acceptance band")
    top.axhline(0, color="0.3", lw=0.6)
    top.set_xticks(axes, [f"axis {j}" for j in axes])
    top.set_ylabel("identified / true - 1 in %")
    top.legend(fontsize=8, ncol=3)
    top.set_title("rotor inertias" + (", gear stiffness and damping" if gears else "") + " against the true robot",
                  fontsize=10)
    rows = identification["parameter_errors"]
    sigma = [r["error_in_std"] if r["error_in_std"] is not None else np.nan for r in rows]
    k = np.arange(len(rows))
    bottom.bar(k, sigma, color=["C3" if abs(s) > 3 else "C0" for s in sigma])
    bottom.axhspan(-3, 3, color="0.9", zorder=0)
    bottom.set_xticks(k, [r["name"] for r in rows], rotation=90, fontsize=7)
    bottom.set_ylabel("(identified - true) / std")
    within = sum(abs(s) <= 3 for s in sigma)
    bottom.set_title(f"{len(rows)} base parameters: {within} within 3 std of the true value; median relative "
                     f"error {100 * identification.get('median_relative_error_vs_true', np.nan):.2f} %", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
