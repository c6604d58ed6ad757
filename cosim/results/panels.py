"""What a run's plots show: one description read by the PNG figures and by ``report.html``.

The matplotlib figures of the ISO 9283 job (:mod:`cosim.jobs.iso9283_figures`) and the
interactive report (:mod:`cosim.results.report`) both take their titles, axis labels,
scales, units, colours and mode labels from :data:`PANELS`, :data:`COLOURS` and
:data:`LABELS` here, and both thin their lines with :func:`envelope` (the first minimum and
the first maximum of every column of the x range: every peak kept, nothing averaged), so
the two cannot disagree on what a curve is or how it was decimated.

A :class:`Panel` is a list of :class:`Series`; a series names where its values come from
twice, for the two readers: ``column`` in a results file (``tcp_<mode>``,
``timeseries_<mode>``, ``controller_<mode>``, ``lateness_<mode>``; ``{j}`` is the joint number) times ``scale``,
and ``field`` of the in-memory tracking result the figures draw (``None``: not drawn
in a PNG) times ``field_scale``. This module imports nothing heavy (numpy only when
:func:`envelope` is called).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

#: Colour of each built-in mode (matplotlib names; the report maps them to the same RGB).
COLOURS = {"standard": "tab:red", "standard_speed_ff": "tab:orange", "model_based": "tab:blue",
           "model_based_elastic": "tab:green"}
#: Colours of other runs (a user's controller, compare entries), in turn.
OTHER_COLOURS = ("tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan", "tab:gray")
#: The RGB of matplotlib's "tab" colours (its tab10 palette), for the browser.
TAB_RGB = {"tab:blue": "#1f77b4", "tab:orange": "#ff7f0e", "tab:green": "#2ca02c", "tab:red": "#d62728",
           "tab:purple": "#9467bd", "tab:brown": "#8c564b", "tab:pink": "#e377c2", "tab:gray": "#7f7f7f",
           "tab:olive": "#bcbd22", "tab:cyan": "#17becf"}
LABELS = {"standard": "standard (drive cascade, position set-points)",
          "standard_speed_ff": "cascade + drive speed feed-forward",
          "model_based": "model-based (eq. 7 feed-forward)",
          "model_based_elastic": "model-based, elastic gears (flatness feed-forward)"}

#: Columns of a line's x range in which its extremes are kept: about 2.6 per pixel of the
#: ~770-pixel-wide PNG axes, so a column never straddles more than two pixels
#: (tests/cosim/jobs/test_iso9283_figures.py: under 1 % of the inked pixels change); the
#: report uses the same for its overview of a whole run.
ENVELOPE_COLUMNS = 2000


@dataclass(frozen=True)
class Series:
    """One curve (per joint when its names hold ``{j}``): ``column`` of file ``source``
    (``"tcp"``, ``"timeseries"``, ``"controller"``, ``"lateness"``) times ``scale`` is the value in the panel's
    unit; ``field`` of a tracking result times ``field_scale`` is the same for the PNG figures."""

    source: str
    column: str
    scale: float = 1.0
    label: str = ""
    field: str | None = None
    field_scale: float = 1.0


@dataclass(frozen=True)
class Panel:
    """One plot: ``title``, ``ylabel`` (with the unit), ``unit``, ``log`` (log y), the curves,
    ``joints`` (the joints a ``{j}`` series is drawn for), ``limit`` (a per-joint limit drawn
    as a dashed line: ``"current_limit"`` from the robot's drive-train parameters),
    ``limit_column`` (a per-run limit drawn as a dashed line: this column of the series' file,
    constant over the run, e.g. the overrun tolerance of the lateness) with ``limit_label``."""

    key: str
    title: str
    ylabel: str
    unit: str
    series: tuple[Series, ...]
    log: bool = False
    joints: tuple[int, ...] = ()
    limit: str | None = None
    limit_column: str | None = None
    limit_label: str = ""
    png_title: str | None = None
    png_joints: tuple[int, ...] = ()
    extra: dict[str, Any] = field(default_factory=dict)


PANELS: tuple[Panel, ...] = (
    Panel("tcp_error", "TCP error |measured - commanded| (laser tracker, 1 ms)", "TCP error [mm] (log scale)", "mm",
          (Series("tcp", "tcp_error_mm", 1.0, "TCP error", "tcp_error", 1e3),), log=True,
          png_title="TCP error along the ISO 9283 path, laser tracker at 1 ms (cf. paper Fig. 2b)"),
    Panel("path_error", "Measured TCP vs programmed path (dynamic + geometric error of the controller's model)",
          "error to the programmed path [mm]", "mm",
          (Series("tcp", "path_error_mm", 1.0, "path error", "path_error", 1e3),),
          png_title="Measured TCP vs programmed path (dynamic + geometric error of the controller's model)"),
    Panel("lag", "Lag errors q_d - q per joint", "lag [mrad]", "mrad",
          (Series("tcp", "lag{j}", 1e3, "axis {j}", "lag", 1e3),), joints=(1, 2, 3, 4, 5, 6),
          png_title="Lag errors q_d - q of axes 1-3 on the ISO 9283 path (cf. paper Fig. 2a)", png_joints=(1, 2, 3)),
    Panel("current", "Motor current per drive against its limit", "motor current [A]", "A",
          (Series("timeseries", "drive{j}.current_actual", 1.0, "axis {j}"),), joints=(1, 2, 3, 4, 5, 6),
          limit="current_limit"),
    Panel("following_error", "Drive following error (position demand - actual, drive side)",
          "following error [mrad]", "mrad",
          (Series("timeseries", "drive{j}.following_error", 1e3, "axis {j}"),), joints=(1, 2, 3, 4, 5, 6)),
    Panel("compute", "Controller compute time per 400 us cycle (wall clock)", "compute time [us] (log scale)", "us",
          (Series("controller", "compute_us", 1.0, "compute time"),), log=True),
    Panel("lateness", "Cycle start lateness vs its wall deadline (paced, split and served runs)",
          "cycle start lateness [us] (log scale)", "us",
          (Series("lateness", "lateness_us", 1.0, "lateness"),), log=True,
          limit_column="tolerance_us", limit_label="overrun tolerance",
          png_title="Cycle start lateness vs its wall deadline"),
)
PANEL = {p.key: p for p in PANELS}


def colour_of(name: str, others: list[str] | None = None) -> str:
    """A run's matplotlib colour: the mode's, else the next of :data:`OTHER_COLOURS` by its place in ``others``."""
    if name in COLOURS:
        return COLOURS[name]
    index = (others or [name]).index(name) if name in (others or [name]) else 0
    return OTHER_COLOURS[index % len(OTHER_COLOURS)]


def label_of(name: str) -> str:
    return LABELS.get(name, name)


def joint_names(text: str, joint: int) -> str:
    return text.replace("{j}", str(joint))


def envelope(x: Any, y: Any, columns: int = ENVELOPE_COLUMNS, log_x: bool = False):
    """The points of the line ``(x, y)`` to draw: in each of ``columns`` equal columns of the x
    range (of log10 x with ``log_x``) the first minimum and the first maximum of y, with the
    line's first and last point, in their original order. The line is returned whole when it
    has few points, its x is not non-decreasing or anything is not finite (a NaN is a gap)."""
    import numpy as np

    index = envelope_index(x, y, columns, log_x)
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    return (x, y) if index is None else (x[index], y[index])


def envelope_index(x: Any, y: Any, columns: int = ENVELOPE_COLUMNS, log_x: bool = False, finite_only: bool = False):
    """The indices :func:`envelope` keeps (sorted), or None when it keeps every point. With
    ``finite_only``, non-finite y values are left out of the extremes instead of keeping the
    whole line (the report: a run that stopped early has NaN rows)."""
    import numpy as np

    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if x.size <= 2 * columns or x.shape != y.shape:
        return None
    u = np.log10(x) if log_x and np.all(x > 0) else (None if log_x else x)
    if u is None or not np.all(np.isfinite(u)) or np.any(np.diff(u) < 0):
        return None
    finite = np.isfinite(y)
    if not finite.all():
        if not finite_only:
            return None
        keep_rows = np.flatnonzero(finite)
        if keep_rows.size <= 2 * columns:
            return keep_rows
        sub = envelope_index(u[keep_rows] if not log_x else x[keep_rows], y[keep_rows], columns, log_x)
        return keep_rows if sub is None else keep_rows[sub]
    span = u[-1] - u[0]
    if not span > 0:
        return None
    column = np.minimum(((u - u[0]) * (columns / span)).astype(np.int64), columns - 1)
    starts = np.flatnonzero(np.r_[True, column[1:] != column[:-1]])  # x sorted: each column is one run
    segment = np.repeat(np.arange(starts.size), np.diff(np.r_[starts, x.size]))
    keep = np.zeros(x.size, dtype=bool)  # sorted and unique without sorting
    keep[[0, x.size - 1]] = True
    for extreme in (np.minimum.reduceat(y, starts), np.maximum.reduceat(y, starts)):
        hit = np.flatnonzero(y == extreme[segment])
        first = np.r_[True, segment[hit[1:]] != segment[hit[:-1]]]
        keep[hit[first]] = True
    return np.flatnonzero(keep)
