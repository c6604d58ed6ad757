"""Campaign report: the paper's Table 2 side by side, and the chosen configurations (Figure 4).

Error convention of Table 2 (paper section 3.4): at each validation pose the flange
pose measured on the real (here: true, simulated) robot minus the pose the model
predicts at the same joint angles; positions in mm (base frame), orientations as
differences of the Cardan angles (alpha, beta, gamma) in deg. "Maximum" is the
largest absolute value over the poses, "peak-to-peak" the spread max - min (the
paper prints it as +- half the spread).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from robot.kinematics import FlangeKinematics, cardan_from_rotation

COMPONENTS = ("e_x", "e_y", "e_z", "e_alpha", "e_beta", "e_gamma")
UNITS = ("mm", "mm", "mm", "deg", "deg", "deg")

PAPER_TABLE2 = {
    # component: (max uncal, max cal, +-p2p/2 uncal, +-p2p/2 cal); Springer et al. 2013, Table 2
    "e_x": (7.779, 0.272, 6.171, 0.271),
    "e_y": (19.026, 0.310, 4.267, 0.303),
    "e_z": (12.614, 0.414, 1.402, 0.376),
    "e_alpha": (1.140, 0.128, 0.272, 0.109),
    "e_beta": (1.817, 0.191, 0.335, 0.182),
    "e_gamma": (1.160, 0.131, 0.514, 0.116),
}


def pose_errors_table2(actual: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """Errors (n, 6) of ``actual`` vs ``predicted`` flange transforms (n, 4, 4):
    position difference in mm, Cardan-angle differences (wrapped to +-180) in deg."""
    dp = (actual[:, :3, 3] - predicted[:, :3, 3]) * 1e3
    da = cardan_from_rotation(actual[:, :3, :3]) - cardan_from_rotation(predicted[:, :3, :3])
    da = (da + np.pi) % (2.0 * np.pi) - np.pi
    return np.concatenate([dp, np.degrees(da)], axis=1)


def error_statistics(errors: np.ndarray) -> dict:
    """``{component: {"max": max |e|, "peak_to_peak": max - min, "unit": ...}}``."""
    out = {}
    for c, (name, unit) in enumerate(zip(COMPONENTS, UNITS)):
        v = errors[:, c]
        out[name] = {"max": float(np.max(np.abs(v))), "peak_to_peak": float(np.ptp(v)), "unit": unit}
    return out


def table2_markdown(uncal: dict, cal: dict, title: str = "") -> str:
    """Markdown table: the paper's Table 2 beside this campaign's figures."""
    lines = []
    if title:
        lines += [title, ""]
    lines += [
        "| error | max uncal. (paper) | max uncal. (ours) | max cal. (paper) | max cal. (ours) "
        "| p-p uncal. (paper) | p-p uncal. (ours) | p-p cal. (paper) | p-p cal. (ours) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, unit in zip(COMPONENTS, UNITS):
        pu, pc, ppu, ppc = PAPER_TABLE2[name]
        lines.append(
            f"| {name} in {unit} | {pu:.3f} | {uncal[name]['max']:.3f} | {pc:.3f} | {cal[name]['max']:.3f} "
            f"| ±{ppu:.3f} | ±{uncal[name]['peak_to_peak'] / 2:.3f} | ±{ppc:.3f} | ±{cal[name]['peak_to_peak'] / 2:.3f} |"
        )
    lines += [
        "",
        "Peak-to-peak printed as ± half the spread (max − min), as in the paper.",
    ]
    return "\n".join(lines) + "\n"


def plot_table2(uncal: dict, cal: dict, path: str | Path, subtitle: str = "") -> Path:
    """Bar chart (log scale) of the maximum errors, paper vs ours, uncalibrated and calibrated."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, group, unit in ((axes[0], COMPONENTS[:3], "mm"), (axes[1], COMPONENTS[3:], "deg")):
        x = np.arange(len(group))
        width = 0.2
        series = [
            ("paper uncal.", [PAPER_TABLE2[g][0] for g in group], "#c44e52"),
            ("ours uncal.", [uncal[g]["max"] for g in group], "#f2a0a0"),
            ("paper cal.", [PAPER_TABLE2[g][1] for g in group], "#4c72b0"),
            ("ours cal.", [cal[g]["max"] for g in group], "#a0c0f0"),
        ]
        for i, (label, values, color) in enumerate(series):
            ax.bar(x + (i - 1.5) * width, values, width, label=label, color=color)
        ax.set_xticks(x, [g.replace("e_", "e_") for g in group])
        ax.set_yscale("log")
        ax.set_ylabel(f"maximum |error| ({unit})")
        ax.grid(True, axis="y", which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("Table 2: errors before and after geometric calibration (paper vs this testbed)"
                 + (f"\n{subtitle}" if subtitle else ""), fontsize=10)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def plot_configurations(kinematics: FlangeKinematics, q_selected: np.ndarray, q_candidates: np.ndarray,
                        tracker_position: np.ndarray, path: str | Path, n_sticks: int = 6) -> Path:
    """Figure 4: stick figures of ``n_sticks`` chosen configurations and the flange
    positions of all chosen ones among the candidates, with the tracker."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frames = kinematics.chain_frames(q_selected)
    cand_pos = kinematics.transforms(q_candidates)[:, :3, 3]
    fig = plt.figure(figsize=(13, 7))
    pick = np.unique(np.round(np.linspace(0, len(q_selected) - 1, n_sticks)).astype(int))
    for s, i in enumerate(pick):
        ax = fig.add_subplot(2, 4, s + 1 if s < 3 else s + 2, projection="3d")
        pts = np.vstack([[0.0, 0.0, 0.0], frames.joint_origins[i], frames.flange_position[i]])
        ax.plot(pts[:, 0], pts[:, 1], pts[:, 2], "-o", color="#333333", markersize=3, linewidth=2)
        tip = frames.flange_position[i]
        z_axis = frames.flange_rotation[i][:, 2] * 0.2
        ax.quiver(*tip, *z_axis, color="#c44e52")
        ax.set_xlim(-1.5, 2.0)
        ax.set_ylim(-1.75, 1.75)
        ax.set_zlim(0.0, 2.5)
        ax.set_title("q = [" + ", ".join(f"{math.degrees(v):.0f}" for v in q_selected[i]) + "] deg", fontsize=7)
        ax.tick_params(labelsize=6)
    ax = fig.add_subplot(1, 4, 4, projection="3d")
    ax.scatter(cand_pos[:, 0], cand_pos[:, 1], cand_pos[:, 2], s=1, color="#bbbbbb", label="visible candidates")
    sel = frames.flange_position
    ax.scatter(sel[:, 0], sel[:, 1], sel[:, 2], s=18, color="#c44e52", label=f"{len(sel)} chosen")
    ax.scatter(*tracker_position, s=60, marker="^", color="#4c72b0", label="tracker")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.legend(fontsize=7, loc="upper left")
    ax.tick_params(labelsize=6)
    fig.suptitle("Figure 4: optimal measurement configurations (stick figures: base, joint origins, flange; "
                 "red arrow: flange z)", fontsize=10)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
