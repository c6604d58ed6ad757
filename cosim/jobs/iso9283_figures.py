"""PNG figures of the ISO 9283 job, after the paper's Figure 2 (matplotlib, Agg backend).

* ``figure2a_lag_errors.png`` - lag errors ``q_d - q`` of axes 1-3 over the path time,
  standard against model-based (paper Figure 2a; also the cascade with the drives'
  speed feed-forward when that mode ran).
* ``figure2b_tcp_error.png`` - TCP error (measured vs commanded, true kinematics) along
  the path (arc length), standard against model-based (paper Figure 2b), log scale.
* ``tcp_error_vs_desired_path.png`` - the error against the programmed path, which
  adds the geometric error of the controller's (uncalibrated) kinematic model.
* ``vibration.png`` - the TCP error spectrum over the path (log-log) and the residual
  vibration after the motion ends (noise-free TCP error, settling band).

Each series has a point every 1 ms (12 000 per mode on the ISO path) and the axes are
about 800 pixels wide: a line is drawn through its extremes, the first minimum and the
first maximum of each of :data:`ENVELOPE_COLUMNS` columns of its x range (log x for the
spectrum), in their order (:func:`envelope`). The drawn line covers the same pixels - every
peak is kept, nothing is averaged - at a third of the points. Margins are fixed and legends
placed where matplotlib's "best" put them for the main job (its search counts the lines'
vertices; with ``tight_layout`` it measured every tick label's text: half of the drawing
time). The figures are drawn on matplotlib's object API with the Agg canvas (no pyplot).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Callable

import numpy as np

from cosim.results import figure_process

from cosim.results.panels import COLOURS, ENVELOPE_COLUMNS, LABELS, PANEL, envelope  # noqa: F401 - the one description

#: Fixed margins (figure fractions) of the 9 x 7.5 in and 9 x 4.5 in figures: what
#: ``tight_layout`` gives for the main job's figures plus a little room for longer tick
#: labels; ``tight_layout`` measured every tick label's text, a third of the drawing time.
MARGINS_TALL = {"left": 0.09, "right": 0.98, "bottom": 0.08, "top": 0.935}
MARGINS_WIDE = {"left": 0.09, "right": 0.98, "bottom": 0.13, "top": 0.915}
#: Title height (axes fraction) given explicitly: matplotlib then does not measure every tick
#: label of the axes to see whether the title must move up (it never must here: no ticks on
#: top), which was 40 % of the drawing time of the vibration figure. Same pixels.
TITLE_Y = 1.0
def _figure(**kwargs: Any) -> tuple[Any, Any]:
    """A figure on the Agg canvas and its axes (``Figure.subplots`` arguments)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    size = kwargs.pop("figsize")
    fig = Figure(figsize=size)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(**kwargs)


def warm_up(prepare: bool = True) -> None:
    """Import matplotlib's figure and Agg canvas and draw one small figure into memory (fonts
    loaded, text layout, log-scale tick machinery, PNG writer), so that :func:`write_figures`
    does not pay for them; with ``prepare``, also make the four figures' axes without their data
    (:data:`AXES`) and draw them once (their ticks, tick labels and text layout), kept for
    :func:`write_figures` (about a third of its drawing time). Run by the figure process forked
    at the start of ``cosim run`` (:mod:`cosim.results.figure_process`) while the command imports
    the cell, else by the job while the modes' worker processes run and its process only waits
    for them (:func:`cosim.execution.mode_pool.run_modes` ``while_waiting``). Nothing is written."""
    import io

    os.environ.setdefault("MPLBACKEND", "Agg")
    fig, ax = _figure(figsize=(2, 2))
    ax.plot([0.0, 1.0], [1.0, 2.0], lw=0.8, label="warm-up")
    ax.set_yscale("log")
    ax.set_xlabel("x")
    ax.set_title("warm-up")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    fig.savefig(io.BytesIO(), dpi=110)
    if prepare:
        for name, make in AXES.items():
            drawing = make()
            drawing[0].canvas.draw()
            _PREPARED[name] = drawing


#: The figures' axes without their data (labels, titles, scales, grids, margins), by figure.
AXES: dict[str, Callable[[], tuple[Any, Any]]] = {}
#: Axes :func:`warm_up` made and drew once, each taken by the first figure drawn of its kind.
_PREPARED: dict[str, tuple[Any, Any]] = {}


def _axes(name: str) -> tuple[Any, Any]:
    """The figure and axes ``name`` of :data:`AXES`: the ones :func:`warm_up` prepared if they are
    still there (their ticks, tick labels and text layout made once already), else new ones.
    The PNG is the same either way (tests/cosim/jobs/test_iso9283_figures.py)."""
    drawing = _PREPARED.pop(name, None)
    return drawing if drawing is not None else AXES[name]()


def write_figures(out_dir: Path, results: dict[str, Any], path: Any, processes: int = 2) -> list[Path]:
    """Write the figures for the modes in ``results`` (mode -> TrackingResult); return the files.

    With ``processes`` > 1, more than one usable core and no other thread in this process, the
    vibration figure is drawn by a forked process while this one draws the other three
    (:func:`_draw_all`); the files are the same either way."""
    # the built-in modes in their order, then any other run (a user's controller)
    modes = [m for m in [*COLOURS, *(r for r in results if r not in COLOURS)] if m in results and results[m].t.size]
    if not modes:
        figure_process.stop()
        return []
    helper = figure_process.current()
    if helper is not None:  # forked at the command's start, matplotlib warmed up there: it draws
        drawn, files = helper.call("cosim.jobs.iso9283_figures:_write_figures", out_dir,
                                   {m: figure_data(results[m]) for m in modes}, modes, figure_path(path), processes)
        if drawn:
            return files
    return _write_figures(out_dir, results, modes, path, processes)


#: The fields of a tracking result (cosim.tracking.metrics.TrackingResult) the figures draw.
FIGURE_FIELDS = ("t", "lag", "arc_length", "tcp_error", "path_error", "spectrum_hz", "spectrum_m", "residual_t",
                 "residual_error", "residual")


def figure_data(result: Any) -> SimpleNamespace:
    """What the figures read of a tracking result, as plain data (arrays, a dict): the figure
    process gets these, not the result (whose class would import the cell there)."""
    return SimpleNamespace(**{name: getattr(result, name) for name in FIGURE_FIELDS})


def figure_path(path: Any) -> SimpleNamespace:
    """What the figures read of the test path: each segment's start along the path (m)."""
    return SimpleNamespace(segments=[SimpleNamespace(arc_start=float(seg.arc_start)) for seg in path.segments])


def _write_figures(out_dir: Path, results: dict[str, Any], modes: list[str], path: Any,
                   processes: int = 2) -> list[Path]:
    """:func:`write_figures` in this process (with ``processes`` > 1 the vibration figure in a fork)."""
    os.environ.setdefault("MPLBACKEND", "Agg")
    jobs = [(_lag_figure, out_dir / "figure2a_lag_errors.png"), (_tcp_error_figure, out_dir / "figure2b_tcp_error.png"),
            (_path_error_figure, out_dir / "tcp_error_vs_desired_path.png"), (_vibration_figure, out_dir / "vibration.png")]
    return _draw_all([(draw, file, results, modes, path) for draw, file in jobs], fork=processes > 1)


def _draw_all(jobs: list[tuple], fork: bool = True) -> list[Path]:
    """Draw ``jobs`` (``(draw, file, results, modes, path)``); the last one (the vibration
    figure, about as long as the other three together) in a forked process when two cores
    are there to use. A child that fails leaves its figure to this process (drawn here after
    all); SIGINT/SIGTERM here end the child first."""
    import threading

    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: F401 - imported once, before the fork

    half = len(jobs) - 1
    forked = (fork and len(jobs) > 1 and hasattr(os, "fork") and threading.active_count() == 1
              and len(os.sched_getaffinity(0)) > 1)
    if not forked:
        return [draw(file, results, modes, path) for draw, file, results, modes, path in jobs]
    import signal

    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    pid = os.fork()
    if pid == 0:  # the child: draw the second half, exit without Python's shutdown
        code = 1
        try:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            for draw, file, results, modes, path in jobs[half:]:
                draw(file, results, modes, path)
            code = 0
        finally:
            os._exit(code)
    try:
        written = [draw(file, results, modes, path) for draw, file, results, modes, path in jobs[:half]]
        _, status = os.waitpid(pid, 0)
    except BaseException:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        raise
    if os.waitstatus_to_exitcode(status) == 0:
        return written + [file for _, file, *_ in jobs[half:]]
    return written + [draw(file, results, modes, path) for draw, file, results, modes, path in jobs[half:]]


def _lag_axes() -> tuple[Any, Any]:
    fig, axes = _figure(nrows=3, ncols=1, figsize=(9, 7.5), sharex=True)
    for j, ax in enumerate(axes):
        ax.set_ylabel(f"axis {j + 1} {PANEL['lag'].ylabel}")
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("path time [s]")
    fig.suptitle(PANEL["lag"].png_title)
    fig.subplots_adjust(**MARGINS_TALL, hspace=0.13)
    return fig, axes


def _lag_figure(file: Path, results: dict[str, Any], modes: list[str], path: Any) -> Path:
    fig, axes = _axes("lag")
    lag = PANEL["lag"].series[0]
    for j, ax in enumerate(axes):
        for mode in modes:
            r = results[mode]
            ax.plot(*envelope(r.t - r.t[0], getattr(r, lag.field)[:, j] * lag.field_scale),
                    color=COLOURS.get(mode, "tab:green"), lw=0.8,
                    label=LABELS.get(mode, mode))
    axes[0].legend(loc="upper right", fontsize=8)
    return _save(fig, file)


def _along_path_axes(ylabel: str, title: str, log: bool) -> tuple[Any, Any]:
    fig, ax = _figure(figsize=(9, 4.5))
    if log:
        ax.set_yscale("log")  # the modes differ by orders of magnitude (docs/explanation/main_job.md)
    ax.set_xlabel("path length [m]")
    ax.set_ylabel(ylabel)
    ax.set_title(title, y=TITLE_Y)
    ax.grid(True, alpha=0.3)
    fig.subplots_adjust(**MARGINS_WIDE)
    return fig, ax


def _tcp_error_axes() -> tuple[Any, Any]:
    panel = PANEL["tcp_error"]
    return _along_path_axes(panel.ylabel, panel.png_title, log=panel.log)


def _path_error_axes() -> tuple[Any, Any]:
    panel = PANEL["path_error"]
    return _along_path_axes(panel.ylabel, panel.png_title, log=panel.log)


def _tcp_error_figure(file: Path, results: dict[str, Any], modes: list[str], path: Any) -> Path:
    fig, ax = _axes("tcp_error")
    series = PANEL["tcp_error"].series[0]
    for mode in modes:
        r = results[mode]
        values = getattr(r, series.field) * series.field_scale
        ax.plot(*envelope(r.arc_length, values), color=COLOURS.get(mode, "tab:green"), lw=0.8,
                label=f"{LABELS.get(mode, mode)}: max {r.tcp_error.max() * 1e3:.3f} mm")
    _segment_marks(ax, path)
    ax.legend(fontsize=8, loc="lower center")
    return _save(fig, file)


def _path_error_figure(file: Path, results: dict[str, Any], modes: list[str], path: Any) -> Path:
    fig, ax = _axes("path_error")
    series = PANEL["path_error"].series[0]
    for mode in modes:
        r = results[mode]
        ax.plot(*envelope(r.arc_length, getattr(r, series.field) * series.field_scale),
                color=COLOURS.get(mode, "tab:green"), lw=0.8,
                label=f"{LABELS.get(mode, mode)}: max {r.path_error.max() * 1e3:.3f} mm")
    _segment_marks(ax, path)
    ax.legend(fontsize=8, loc="lower right")
    return _save(fig, file)


def _vibration_axes() -> tuple[Any, Any]:
    fig, (ax_f, ax_r) = _figure(nrows=2, ncols=1, figsize=(9, 7.5))
    ax_f.set_xscale("log")
    ax_f.set_yscale("log")
    ax_r.set_yscale("log")
    ax_f.set_xlabel("frequency [Hz]")
    ax_f.set_ylabel("TCP error amplitude [mm]")
    ax_f.set_title("Spectrum of the noise-free TCP error over the ISO 9283 path (Hann window)", y=TITLE_Y)
    ax_f.grid(True, which="both", alpha=0.3)
    ax_r.set_xlabel("time after the end of the motion [ms]")
    ax_r.set_ylabel("distance from the final pose [mm] (log)")
    ax_r.set_title("Residual vibration after the motion ends (noise-free TCP, about the attained final pose)", y=TITLE_Y)
    ax_r.grid(True, which="both", alpha=0.3)
    fig.subplots_adjust(**MARGINS_TALL, hspace=0.3)
    return fig, (ax_f, ax_r)


def _vibration_figure(file: Path, results: dict[str, Any], modes: list[str], path: Any) -> Path:
    fig, (ax_f, ax_r) = _axes("vibration")
    for mode in sorted(modes, key=lambda m: -float(results[m].tcp_error.max())):  # largest first: none hidden
        r = results[mode]
        if r.spectrum_hz.size > 1:
            ax_f.plot(*envelope(r.spectrum_hz[1:], r.spectrum_m[1:] * 1e3, log_x=True),
                      color=COLOURS.get(mode, "tab:green"), lw=0.8, label=LABELS.get(mode, mode))
        if r.residual_t.size:
            res = r.residual
            ax_r.plot(r.residual_t * 1e3, np.maximum(r.residual_error * 1e3, 1e-6),
                      color=COLOURS.get(mode, "tab:green"), lw=0.9,
                      label=f"{LABELS.get(mode, mode)}: peak {res.get('peak_mm', float('nan')):.4f} mm, settled "
                            f"{_ms(res.get('settling_time_s'))}, static offset "
                            f"{res.get('static_offset_mm', float('nan')):.3f} mm")
    band = next((results[m].residual.get("band_mm") for m in modes if results[m].residual), None)
    if band is not None:
        ax_r.axhline(band, color="0.4", lw=0.8, ls="--", label=f"settling band {band:.3f} mm")
    ax_f.legend(fontsize=8, loc="upper right")
    ax_r.legend(fontsize=8, loc="upper right")
    return _save(fig, file)


AXES.update(lag=_lag_axes, tcp_error=_tcp_error_axes, path_error=_path_error_axes, vibration=_vibration_axes)


def _ms(seconds: float | None) -> str:
    if seconds is None or not np.isfinite(seconds):
        return "not within the recording"
    return f"after {seconds * 1e3:.0f} ms"


def _segment_marks(ax: Any, path: Any) -> None:
    for seg in path.segments[1:]:
        ax.axvline(seg.arc_start, color="0.7", lw=0.5, ls=":")


def _save(fig: Any, file: Path) -> Path:
    fig.savefig(file, dpi=110)
    return file
