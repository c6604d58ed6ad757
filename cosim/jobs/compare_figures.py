"""Figures of the ``compare`` job: every entry readable, whatever the spread of the values.

* ``compare_metrics.png``: one panel per metric of the table, one horizontal bar per entry
  (grouped by trajectory, one colour per controller), each bar labelled with its value;
  an entry whose verdict is not ``ok`` is labelled with it and "not ranked" and shows no
  value (its metrics are not comparable);
  a panel whose positive values span more than :data:`LOG_SPAN` uses a logarithmic axis
  (symmetric-log when some values are 0, e.g. no deadline miss).
* ``compare_tcp_error.png``: per trajectory, the TCP error over the motion of every
  controller on a logarithmic axis; the curves are drawn from the largest error to the
  smallest, each thinner than the one before, so none hides another.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

LOG_SPAN = 30.0
"""Ratio of the largest to the smallest positive value above which an axis is logarithmic."""
LINE_STYLES = ("-", "--", "-.", ":")


def _pyplot():
    os.environ.setdefault("MPLBACKEND", "Agg")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _colours(names: list[str]) -> dict[str, Any]:
    import matplotlib

    cmap = matplotlib.colormaps["tab10"]
    return {n: cmap(k % 10) for k, n in enumerate(names)}


def axis_scale(values: list[float]) -> str:
    """'linear', 'log' or 'symlog' for these values (see module docstring)."""
    finite = [v for v in values if v is not None and math.isfinite(v)]
    positive = [v for v in finite if v > 0]
    if len(positive) < 2 or max(positive) / min(positive) <= LOG_SPAN:
        return "linear"
    return "symlog" if any(v <= 0 for v in finite) else "log"


def write_figures(out_dir: Path, rows: list[dict[str, Any]], results: dict[tuple[str, str], Any],
                  rank_by: str, metric_labels: dict[str, str]) -> list[Path]:
    """Write both figures from the table ``rows`` and the tracking results ((trajectory, controller) ->
    TrackingResult); ``metric_labels``: the table's metrics, column -> label with unit
    (:data:`cosim.jobs.compare.METRICS`, which passes them down); return the files written."""
    plt = _pyplot()
    written: list[Path] = []
    controllers = list(dict.fromkeys(r["controller"] for r in rows))
    colour = _colours(controllers)
    labels = [f"{r['controller']} / {r['trajectory']}" + (f"  #{r['rank']}" if r["rank"] else
                                                            f"  [{r['status']}: not ranked]") for r in rows]
    metrics = list(metric_labels)
    ncols = 3
    nrows = math.ceil(len(metrics) / ncols)
    height = max(2.2, 0.28 * len(rows) + 1.0)
    fig, axes = plt.subplots(nrows, ncols, figsize=(5.2 * ncols, height * nrows), squeeze=False)
    y = list(range(len(rows)))[::-1]
    for ax, key in zip(axes.flat, metrics):
        values = [r[key] if r[key] is not None else float("nan") for r in rows]
        scale = axis_scale(values)
        shown = [v if math.isfinite(v) else 0.0 for v in values]
        ax.barh(y, shown, color=[colour[r["controller"]] for r in rows], height=0.7)
        positive = [v for v in values if math.isfinite(v) and v > 0]
        if scale == "log":
            ax.set_xscale("log")
            ax.set_xlim(min(positive) / 3.0, max(positive) * 8.0)
        elif scale == "symlog":
            ax.set_xscale("symlog", linthresh=min(positive))
            ax.set_xlim(0.0, max(positive) * 8.0)
        else:
            top = max([v for v in values if math.isfinite(v)] or [1.0])
            ax.set_xlim(0.0, (top if top > 0 else 1.0) * 1.35)
            ax.ticklabel_format(axis="x", style="sci", scilimits=(-3, 4))
        for yy, v in zip(y, values):
            text = "n/a" if not math.isfinite(v) else (f"{v:.3g}" if abs(v) < 1e4 else f"{v:.3e}")
            anchor = v if math.isfinite(v) and (v > 0 or scale == "linear") else ax.get_xlim()[0]
            ax.text(anchor, yy, " " + text, va="center", ha="left", fontsize=7)
        ax.set_yticks(y)
        ax.set_yticklabels(labels, fontsize=7)
        ax.set_title(metric_labels[key] + (" (log)" if scale != "linear" else "") + ("  - ranked by" if key == rank_by
                                                                              else ""), fontsize=9)
        ax.grid(True, axis="x", alpha=0.3, which="both")
    for ax in list(axes.flat)[len(metrics):]:
        ax.axis("off")
    fig.suptitle(f"Comparison: {len(controllers)} controllers x {len(set(r['trajectory'] for r in rows))} "
                 f"trajectories on one seeded robot (rank: {rank_by}, per trajectory)", fontsize=11)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 0.45 / fig.get_figheight()))   # room for the title
    written.append(_save(fig, out_dir / "compare_metrics.png", plt))

    trajectories = list(dict.fromkeys(r["trajectory"] for r in rows))
    with_data = [t for t in trajectories if any((t, c) in results and results[(t, c)] is not None
                                                and results[(t, c)].t.size for c in controllers)]
    if with_data:
        fig, axes = plt.subplots(len(with_data), 1, figsize=(10, 3.4 * len(with_data)), squeeze=False)
        for ax, traj in zip(axes[:, 0], with_data):
            curves = [(c, results[(traj, c)]) for c in controllers
                      if (traj, c) in results and results[(traj, c)] is not None and results[(traj, c)].t.size]
            curves.sort(key=lambda cr: -float(cr[1].tcp_error.max()))
            verdict = {r["controller"]: r["status"] for r in rows if r["trajectory"] == traj}
            for k, (ctrl, res) in enumerate(curves):
                err = res.tcp_error * 1e3
                mark = "" if verdict.get(ctrl, "ok") == "ok" else f" [{verdict[ctrl]}: not ranked]"
                ax.plot(res.t - res.t[0], err, color=colour[ctrl], ls=LINE_STYLES[k % len(LINE_STYLES)],
                        lw=max(0.6, 2.2 - 0.45 * k), label=f"{ctrl}{mark}: max {err.max():.3g} mm, "
                                                           f"RMS {math.sqrt(float((err ** 2).mean())):.3g} mm")
            ax.set_yscale("log")
            ax.set_ylabel("TCP error [mm] (log)")
            ax.set_title(f"trajectory {traj}: |measured - commanded| over the motion", fontsize=10)
            ax.grid(True, alpha=0.3, which="both")
            ax.legend(fontsize=8, loc="best")
        axes[-1, 0].set_xlabel("time since motion start [s]")
        fig.tight_layout()
        written.append(_save(fig, out_dir / "compare_tcp_error.png", plt))
    return written


def _save(fig: Any, file: Path, plt: Any) -> Path:
    fig.savefig(file, dpi=110)
    plt.close(fig)
    return file
