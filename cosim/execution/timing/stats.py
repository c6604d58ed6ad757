"""Lateness statistics of a paced run and the jitter histogram figure."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from cosim.execution.timing.pacer import LatenessLog

#: At most this many overrun cycle numbers are listed in a summary.
LISTED_OVERRUNS = 200


def load_average() -> list[float] | None:
    """1, 5 and 15 min load averages of the machine (None where unavailable)."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except (AttributeError, OSError):
        return None


def lateness_summary(log: LatenessLog, thresholds: dict[str, float] | None = None) -> dict[str, Any]:
    """``cycles``, ``overruns``, ``overrun_fraction``, ``lateness`` {p50_us, p99_us, max_us, mean_us},
    ``missed_ticks`` (wall ticks dropped after cycles late by whole periods),
    ``cycle_work`` {p50_us, p99_us, max_us} (wall time of a cycle's work before the next wait),
    ``overrun_cycles`` (the first :data:`LISTED_OVERRUNS`); with ``thresholds`` (name -> s) also
    ``late_fraction`` {name: fraction of cycles whose lateness exceeds it} and ``thresholds_us``."""
    lat = log.lateness_us
    cycles = int(lat.size)
    overruns = int(log.overrun[:cycles].sum())
    if cycles:
        p50, p99 = np.percentile(lat, [50.0, 99.0])
        lateness = {"p50_us": float(p50), "p99_us": float(p99), "max_us": float(lat.max()),
                    "mean_us": float(lat.mean())}
    else:
        lateness = {"p50_us": None, "p99_us": None, "max_us": None, "mean_us": None}
    work = log.work_us
    if work.size:
        w50, w99 = np.percentile(work, [50.0, 99.0])
        cycle_work = {"p50_us": float(w50), "p99_us": float(w99), "max_us": float(work.max())}
    else:
        cycle_work = {"p50_us": None, "p99_us": None, "max_us": None}
    extra: dict[str, Any] = {}
    if thresholds:
        extra["thresholds_us"] = {k: v * 1e6 for k, v in thresholds.items()}
        extra["late_fraction"] = {k: float((lat > v * 1e6).sum()) / cycles if cycles else 0.0
                                  for k, v in thresholds.items()}
    return {"cycles": cycles, "overruns": overruns, "overrun_fraction": overruns / cycles if cycles else 0.0,
            "missed_ticks": int(log.missed_ticks), "lateness": lateness, "cycle_work": cycle_work, **extra,
            "overrun_cycles": log.overrun_cycles[:LISTED_OVERRUNS]}


#: Columns of the per-cycle timing series ``lateness_<label>`` (docs/reference/output_files.md) and their units.
LATENESS_UNITS = {"t": "s", "cycle": "1", "lateness_us": "us", "work_us": "us", "overrun": "1", "tolerance_us": "us"}


def lateness_columns(log: LatenessLog, period_s: float, tolerance_s: float) -> dict[str, np.ndarray]:
    """The per-cycle timing series of a paced, split or served run: ``t`` (the cycle's simulated
    time, cycle x period, s), ``cycle``, ``lateness_us`` (wall start minus the cycle's wall
    deadline), ``work_us`` (wall time of the previous cycle's work; NaN for the first),
    ``overrun`` (1 when the lateness exceeded ``tolerance_us``) and ``tolerance_us`` (the
    overrun tolerance: the deadline the lateness is judged against)."""
    n = log.count
    cycles = log.cycles[:n]
    work = log.work_ns[:n].astype(float) * 1e-3
    work[log.work_ns[:n] < 0] = np.nan
    return {"t": cycles * float(period_s), "cycle": cycles.astype(float), "lateness_us": log.lateness_ns[:n] * 1e-3,
            "work_us": work, "overrun": log.overrun[:n].astype(float),
            "tolerance_us": np.full(n, float(tolerance_s) * 1e6)}


def combine(logs: list[LatenessLog]) -> LatenessLog:
    """One log holding the entries of several (e.g. the modes of a job)."""
    total = LatenessLog(sum(log.count for log in logs) + 16)
    for log in logs:
        n = log.count
        total.cycles[total.count:total.count + n] = log.cycles[:n]
        total.lateness_ns[total.count:total.count + n] = log.lateness_ns[:n]
        total.overrun[total.count:total.count + n] = log.overrun[:n]
        total.work_ns[total.count:total.count + n] = log.work_ns[:n]
        total.count += n
        total.missed_ticks += log.missed_ticks
    return total


def write_histogram(path: str | Path, log: LatenessLog, *, period_s: float, tolerance_s: float, bins: int = 60,
                    title: str = "") -> Path:
    """Histogram of the per-cycle lateness (µs, log axes) with p50, p99, the overrun tolerance and
    the cycle time marked; PNG at ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lat = log.lateness_us
    path = Path(path)
    floor_us = 0.01  # lateness below 10 ns is shown in the first bin (log axis)
    fig, ax = plt.subplots(figsize=(7.0, 4.0))
    if lat.size:
        top = max(float(lat.max()), tolerance_s * 1e6 * 2.0, period_s * 1e6 * 1.5)
        edges = np.geomspace(floor_us, top * 1.01, bins + 1)
        ax.hist(np.clip(lat, floor_us, None), bins=edges, color="tab:blue", alpha=0.85)
        p50, p99 = np.percentile(lat, [50.0, 99.0])
        for value, name, style in ((p50, "p50", ":"), (p99, "p99", "--")):
            ax.axvline(max(value, floor_us), color="k", linestyle=style, linewidth=1,
                       label=f"{name} = {value:.2f} µs")
    ax.axvline(max(tolerance_s * 1e6, floor_us), color="tab:red", linewidth=1.2,
               label=f"overrun above {tolerance_s * 1e6:.1f} µs")
    ax.axvline(period_s * 1e6, color="tab:gray", linewidth=1.0, linestyle="-.",
               label=f"one cycle = {period_s * 1e6:.0f} µs")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("cycle lateness vs wall deadline [µs]")
    ax.set_ylabel("cycles")
    overruns = int(log.overrun[:log.count].sum())
    ax.set_title(title or f"{log.count} cycles of {period_s * 1e6:.0f} µs, {overruns} overruns")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
