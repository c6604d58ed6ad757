"""The sweep figure of ``[report]``: a metric against an axis parameter (PNG, matplotlib Agg).

``kind = "points"``: every ok variant as a dot, and the mean over the other axes (e.g.
the Monte Carlo draws) per x value as a line; ``kind = "box"``: a box plot per x value
(median, quartiles, 1.5 IQR whiskers), the x values as evenly spaced categories. With
``group``, one series per value of that axis. For points, numeric parameters are placed
at their values (SI, as in the table); other values (strings, lists such as
``["standard"]``) are categories in sweep order. The metric may be a glob
(``modes.*.tcp_error_max_mm``): each row uses its first matching metric.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from cosim.sweep.loader import Report
from cosim.sweep.table import metric_pattern


def label_of(value: Any) -> str:
    """Legend/tick text of a parameter value (``["standard"]`` -> ``standard``)."""
    if isinstance(value, list):
        return ", ".join(label_of(v) for v in value)
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def report_points(rows: Sequence[dict[str, Any]], report: Report) -> tuple[list[tuple[Any, Any, float]], int, str]:
    """(x value, group value, metric) of every ok row with the metric; count of rows left out; metric name."""
    rx = metric_pattern(report.metric)
    points = []
    names: list[str] = []
    left_out = 0
    for row in rows:
        match = next((k for k in row.get("metrics", {}) if rx.match(k)), None) if row["status"] == "ok" else None
        value = row["metrics"].get(match) if match is not None else None
        if not _is_number(value) or not math.isfinite(value):
            left_out += 1
            continue
        if match not in names:
            names.append(match)
        group = row["values"].get(report.group) if report.group else None
        points.append((row["values"].get(report.parameter), group, float(value)))
    return points, left_out, (names[0] if len(names) == 1 else report.metric)


def plot_report(rows: Sequence[dict[str, Any]], report: Report, path: str | Path,
                sweep_name: str = "") -> tuple[Path | None, str | None]:
    """Write the figure to ``path``; return (path or None, a note on rows left out / no data)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    points, left_out, metric_name = report_points(rows, report)
    note = (f"figure: {left_out} variant(s) without an ok value of {report.metric!r} left out"
            if left_out else None)
    if not points:
        return None, f"figure not written: no ok variant has a numeric metric matching {report.metric!r}"
    numeric_x = report.kind != "box" and all(_is_number(x) for x, _, _ in points)
    categories: list[str] = []
    if not numeric_x:
        for x, _, _ in points:
            if label_of(x) not in categories:
                categories.append(label_of(x))
    groups: list[str] = []
    for _, g, _ in points:
        if label_of(g) not in groups:
            groups.append(label_of(g))

    def position(x: Any) -> float:
        return float(x) if numeric_x else float(categories.index(label_of(x)))

    fig, ax = plt.subplots(figsize=(7.5, 4.5), dpi=120)
    xs_all = sorted({position(x) for x, _, _ in points})
    spacing = min(np.diff(xs_all)) if len(xs_all) > 1 else 1.0
    for gi, group in enumerate(groups):
        by_x: dict[float, list[float]] = {}
        for x, g, y in points:
            if label_of(g) == group:
                by_x.setdefault(position(x), []).append(y)
        xs = sorted(by_x)
        label = f"{report.group} = {group}" if report.group else None
        if report.kind == "box":
            width = 0.6 * spacing / max(1, len(groups))
            offset = (gi - (len(groups) - 1) / 2) * width
            parts = ax.boxplot([by_x[x] for x in xs], positions=[x + offset for x in xs], widths=width * 0.9,
                               manage_ticks=False, patch_artist=True)
            color = f"C{gi}"
            for box in parts["boxes"]:
                box.set(facecolor=color, alpha=0.5)
            ax.plot([], [], color=color, lw=6, alpha=0.5, label=label)
        else:
            color = f"C{gi}"
            ax.scatter([x for x in xs for _ in by_x[x]], [y for x in xs for y in by_x[x]], s=14, alpha=0.45,
                       color=color)
            ax.plot(xs, [float(np.mean(by_x[x])) for x in xs], "-o", color=color, lw=1.5, ms=4,
                    label=(label + " (mean)") if label else "mean")
    ax.set_xscale(report.x_scale if numeric_x else "linear")    # (resets the ticks: set them after)
    if not numeric_x:
        ax.set_xticks(range(len(categories)), categories)
    ax.set_yscale(report.y_scale)
    ax.set_xlabel(report.parameter + (" (SI units)" if all(_is_number(x) for x, _, _ in points) else ""))
    ax.set_ylabel(metric_name)
    title = report.title or f"sweep {sweep_name}: {metric_name} vs {report.parameter}"
    if left_out:
        title += f"\n({left_out} variant(s) without a value not shown)"
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    if report.group or report.kind == "points":
        ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path)
    plt.close(fig)
    return path, note


__all__ = ["label_of", "plot_report", "report_points"]
