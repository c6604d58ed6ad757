"""``fieldbus_fault.png``: joint speeds, drive torques and the fault timeline of a fieldbus_fault run.

Top: joint speeds (rad/s) around the fault; middle: joint torques to the plant (N m,
motor + holding brake); bottom: each drive's CiA 402 state. Vertical lines: the threshold
trips (red) and the controller's stop (black). Matplotlib, Agg backend.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

#: CiA 402 state (statusword & 0x6F) -> (row label, level in the state plot)
STATE_LEVELS = {0x40: ("switch on disabled", 0), 0x21: ("ready", 1), 0x23: ("switched on", 2),
                0x27: ("operation enabled", 3), 0x07: ("quick stop active", 4),
                0x0F: ("fault reaction active", 5), 0x08: ("fault", 6)}


def _state_level(statusword: np.ndarray) -> np.ndarray:
    masked = statusword.astype(int) & 0x6F
    return np.array([STATE_LEVELS.get(int(s), ("?", np.nan))[1] for s in masked], dtype=float)


def write_figure(file: Path, cell: Any, trips: list[dict[str, Any]], controller: Any,
                 before_s: float = 0.05) -> Path:
    """Write the figure for ``cell`` (a cosim.cell.CellRun with drive statuswords recorded); return the file."""
    os.environ.setdefault("MPLBACKEND", "Agg")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cosim.cell.evaluation import recording_chunks

    rec = cell.recording
    cols = [rec.columns[0]] + [f"{name}{i}{suffix}" for name, suffix in (("plant.qd[", "]"), ("drive", ".tau_out"),
                                                                         ("drive", ".statusword")) for i in range(1, 7)]
    first = min((tr["time_s"] for tr in trips), default=None)
    kept = []
    for block in recording_chunks(rec, cols):  # only the plotted columns from the first trip on are held
        if first is None:
            first = block[0, 0] + before_s
        kept.append(block[block[:, 0] >= first - before_s])
    data = np.concatenate(kept) if kept else np.zeros((0, len(cols)))
    t = data[:, 0]
    shown = np.ones(t.size, dtype=bool)
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for i in range(1, 7):
        axes[0].plot(t[shown], data[shown, cols.index(f"plant.qd[{i}]")], lw=0.9, label=f"axis {i}")
        axes[1].plot(t[shown], data[shown, cols.index(f"drive{i}.tau_out")], lw=0.9, label=f"axis {i}")
        axes[2].plot(t[shown], _state_level(data[shown, cols.index(f"drive{i}.statusword")]) + 0.05 * (i - 3.5),
                     lw=1.2, label=f"drive {i}")
    axes[0].set_ylabel("joint speed [rad/s]")
    axes[1].set_ylabel("joint torque [N m]\n(motor + brake)")
    axes[2].set_yticks([level for _, level in STATE_LEVELS.values()])
    axes[2].set_yticklabels([name for name, _ in STATE_LEVELS.values()], fontsize=7)
    axes[2].set_xlabel("time [s]")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        for tr in trips:
            ax.axvline(tr["time_s"], color="tab:red", lw=0.8, ls="--")
        if controller.stopped_at_s is not None:
            ax.axvline(controller.stopped_at_s, color="k", lw=0.8, ls=":")
    axes[0].legend(fontsize=7, ncol=6, loc="upper right")
    nodes = sorted({tr["node"] for tr in trips})
    fig.suptitle(f"Fieldbus fault: threshold trip on node(s) {nodes} (red), controller stop (black)")
    fig.tight_layout()
    fig.savefig(file, dpi=110)
    plt.close(fig)
    return file
