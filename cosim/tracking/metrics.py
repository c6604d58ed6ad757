"""Tracking metrics of a cell run: lag errors, TCP errors, ISO 9283 path accuracy AT.

Inputs are the 1 ms recording (plant joint angles, tracker measurement) and the
controller's per-cycle log (the joint set-points it computed, with the time each acts).

Definitions (all positions of the flange origin in base_link):

* ``q_d(t)``: the joint set-point the drives apply at time t: the controller's q_d of
  the cycle whose set-point acts at t (``t_apply``), interpolated between cycles with
  the quintic Hermite polynomial through q_d, qd_d, qdd_d (exact at the cycles).
* **lag error** ``e_q(t) = q_d(t) - q(t)`` per joint (rad), q the plant's joint angle.
* **commanded TCP** ``c(t) = f_DK,true(q_d(t))``: where the TRUE arm's flange would be if
  the joints followed the set-points exactly.
* **measured TCP** ``m(t)``: the laser tracker's reading of the true flange.
* **TCP error** ``|m(t) - c(t)|``: the dynamic tracking error the controller and the
  drives make (the paper's Figure 2b quantity). It holds no static geometric error:
  both sides use the true kinematics.
* **noise-free TCP error** ``|f_DK,true(q(t)) - c(t)|``: the same without the tracker
  noise (what the tracker would read with a perfect instrument).
* **path error** ``|m(t) - p_d(t)|``, ``p_d`` the programmed (desired) path: TCP error
  plus the geometric error of an uncalibrated controller model (mm level); reported
  separately.
* **residual vibration** (after the motion ends at ``t_end``, the commanded TCP at
  rest), from the noise-free TCP error: ``static offset`` = distance of the attained
  final pose (mean of the last 20 ms) from the commanded one; ``peak`` = largest distance
  from the final pose over ``t >= t_end``; ``settling time`` = time from ``t_end`` until
  that distance stays inside ``band`` (ISO 9283's position stabilisation time with the
  band given; NaN if it does not within the recording).
* **TCP error spectrum**: one-sided amplitude spectrum (Hann window, mean removed) of
  the noise-free TCP error vector over the path, combined over x, y, z
  (``sqrt(|X_x|^2 + |X_y|^2 + |X_z|^2)``); its largest peak above ``SPECTRUM_MIN_HZ``
  is reported (frequency, amplitude).
* **AT** (EN ISO 9283 path accuracy): per path segment, the largest distance from a
  measured point to the commanded path in the plane normal to the path through that
  point, i.e. the distance to the commanded polyline (1 ms samples, chord error below
  1 µm here) of the same segment; ``AT`` is the maximum over segments. ISO averages n
  repeated runs point by point before this; the simulation is deterministic up to the
  tracker noise, so one run is evaluated. ``AT_vs_programmed`` uses ``p_d``.
"""
from __future__ import annotations

import ctypes
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from controller import quintic_hermite
from robot.joints import N_JOINTS

AT_WINDOW_SAMPLES = 150
"""Half-width (samples) of the window of commanded points searched for the foot of the
normal plane of a measured point: 150 ms at 1 ms, far above any lag."""


VIBRATION_BAND_M = 20e-6
"""Settling band of the residual vibration (m): 20 um, well inside the +-0.03..0.05 mm
pose repeatability of arms of this class, above the tracker's 2 um noise."""

SPECTRUM_MIN_HZ = 2.0
"""Lowest frequency (Hz) searched for the dominant peak of the TCP error spectrum: below
it the error follows the path's own motion (quasi-static lag), not a vibration."""


FINAL_POSE_WINDOW_S = 0.02
"""Length (s) of the last stretch of the recording averaged as the attained final pose."""


def residual_vibration(t: np.ndarray, error: np.ndarray, t_end: float,
                       band: float = VIBRATION_BAND_M) -> dict[str, float]:
    """Residual vibration after the motion ends at ``t_end`` (s) from the TCP error vectors
    ``error`` (m, 3) in m at ``t`` (m,) s. The attained final pose is the mean error over the
    last ``FINAL_POSE_WINDOW_S`` of the samples; its distance from the commanded pose is
    ``static_offset_mm`` (e.g. gear sag under gravity). ``peak_mm``: largest distance from the
    final pose after ``t_end``; ``settling_time_s``: time from ``t_end`` until the distance
    stays inside ``band`` (ISO 9283 position stabilisation time; NaN if it does not within
    the samples); ``band_mm``; ``window_s``: length of the observed stretch."""
    nan = float("nan")
    after = t >= t_end - 1e-9
    if after.sum() < 2:
        return {"peak_mm": nan, "settling_time_s": nan, "static_offset_mm": nan, "band_mm": band * 1e3,
                "window_s": 0.0}
    ta, ea = t[after], error[after]
    final = ea[ta >= ta[-1] - FINAL_POSE_WINDOW_S].mean(axis=0)
    distance = np.linalg.norm(ea - final, axis=1)
    outside = np.flatnonzero(distance > band)
    if outside.size == 0:
        settling = 0.0
    elif ta[outside[-1]] >= ta[-1] - FINAL_POSE_WINDOW_S:
        settling = nan
    else:
        settling = float(ta[outside[-1] + 1] - t_end)
    return {"peak_mm": float(distance.max() * 1e3), "settling_time_s": settling,
            "static_offset_mm": float(np.linalg.norm(final) * 1e3), "band_mm": band * 1e3,
            "window_s": float(ta[-1] - t_end)}


def error_spectrum(t: np.ndarray, error: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(frequencies Hz, amplitude m) of the TCP error vectors ``error`` (m, 3) sampled
    uniformly at ``t`` (m,) s: one-sided amplitude spectrum, Hann window, mean removed,
    combined over the three axes."""
    if t.size < 16:
        return np.zeros(0), np.zeros(0)
    dt = float(np.median(np.diff(t)))
    window = np.hanning(t.size)
    spectra = np.fft.rfft((error - error.mean(axis=0)) * window[:, None], axis=0)
    amplitude = np.sqrt((np.abs(spectra) ** 2).sum(axis=1)) * 2.0 / window.sum()
    return np.fft.rfftfreq(t.size, dt), amplitude


def dominant_peak(freq: np.ndarray, amplitude: np.ndarray, min_hz: float = SPECTRUM_MIN_HZ) -> tuple[float, float]:
    """(frequency Hz, amplitude m) of the largest spectral line above ``min_hz``."""
    mask = freq >= min_hz
    if not mask.any():
        return float("nan"), float("nan")
    k = int(np.argmax(np.where(mask, amplitude, -1.0)))
    return float(freq[k]), float(amplitude[k])


def desired_joints(t: np.ndarray, t_apply: np.ndarray, q_d: np.ndarray, qd_d: np.ndarray,
                   qdd_d: np.ndarray) -> np.ndarray:
    """q_d at times ``t`` (m,) from per-cycle set-points acting at ``t_apply`` (n,) (see module doc).

    Before the first cycle's ``t_apply`` the first set-point holds; after the last, the last.
    """
    t = np.asarray(t, dtype=float)
    if t_apply.size == 1:
        return np.repeat(q_d[:1], t.size, axis=0)
    k = np.clip(np.searchsorted(t_apply, t, side="right") - 1, 0, t_apply.size - 2)
    h = (t_apply[k + 1] - t_apply[k])[:, None]
    s = np.clip((t - t_apply[k])[:, None] / h, 0.0, 1.0)
    q, _, _ = quintic_hermite(q_d[k], qd_d[k], qdd_d[k], q_d[k + 1], qd_d[k + 1], qdd_d[k + 1], h, s)
    before = t < t_apply[0]
    q[before] = q_d[0]
    return q


def _pair_distance2(points: np.ndarray, a: np.ndarray, ab: np.ndarray, ab2: np.ndarray, i: np.ndarray,
                    j: np.ndarray) -> np.ndarray:
    """Squared distance of ``points[i]`` to the segments ``a[j] + [0, 1] ab[j]`` (pairwise)."""
    ap = np.take(points, i, axis=0) - np.take(a, j, axis=0)
    abj = np.take(ab, j, axis=0)
    u = np.clip(np.einsum("ij,ij->i", ap, abj) / ab2.take(j), 0.0, 1.0)
    d = ap - u[:, None] * abj
    return np.einsum("ij,ij->i", d, d)


_COARSE_SEGMENTS = 16
"""Segments per coarse ball of :func:`distance_to_polyline` (16 of 1 ms: about 16 mm at 1 m/s)."""
_FINE_SEGMENTS = 4
"""Segments per fine ball (a quarter of a coarse one)."""
_INFLATE = 1.0 + 1e-9
"""Relative margin on every bound of :func:`distance_to_polyline` (far above float64 rounding)."""


def _balls(mid: np.ndarray, half: np.ndarray, size: int) -> tuple[list[np.ndarray], np.ndarray]:
    """Balls holding each run of ``size`` consecutive segments (midpoints ``mid``, half lengths
    ``half``) whole: (centre x, y, z arrays, radius). Segments with a non-finite midpoint are left
    out (no bound ever admits them); a run of only such segments gets a NaN radius (never admitted)."""
    count = mid.shape[0]
    balls = -(-count // size)
    fill = balls * size - count
    finite = bool(np.isfinite(mid).all() and np.isfinite(half).all())
    if finite:  # the last run padded with copies of the last segment: the same ball
        if fill:
            mid = np.concatenate([mid, np.repeat(mid[-1:], fill, axis=0)])
            half = np.concatenate([half, np.repeat(half[-1:], fill)])
        runs = mid.reshape(balls, size, 3)
        center = runs.mean(axis=1)
        spread = runs - center[:, None, :]
        radius = (np.sqrt(np.einsum("ijk,ijk->ij", spread, spread)) + half.reshape(balls, size)).max(axis=1)
        return [np.ascontiguousarray(center[:, k]) for k in range(3)], radius * _INFLATE + 1e-12
    keep = np.isfinite(mid).all(axis=1) & np.isfinite(half)
    runs = np.concatenate([np.where(keep[:, None], mid, 0.0), np.zeros((fill, 3))]).reshape(balls, size, 3)
    weight = np.concatenate([keep, np.zeros(fill, dtype=bool)]).reshape(balls, size)
    members = weight.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        center = runs.sum(axis=1) / members[:, None]
        spread = runs - center[:, None, :]
        extent = np.sqrt(np.einsum("ijk,ijk->ij", spread, spread)) + np.concatenate(
            [np.where(keep, half, 0.0), np.zeros(fill)]).reshape(balls, size)
        radius = np.where(weight, extent, -np.inf).max(axis=1) * _INFLATE + 1e-12
    radius[members == 0] = np.nan
    return [np.ascontiguousarray(center[:, k]) for k in range(3)], radius


def _squared(p: list[np.ndarray], i: np.ndarray, c: list[np.ndarray], j: np.ndarray) -> np.ndarray:
    """|p[i] - c[j]|^2 elementwise (``p``, ``c``: x, y, z arrays; ``i``, ``j``: index arrays)."""
    dx = p[0].take(i) - c[0].take(j)
    dy = p[1].take(i) - c[1].take(j)
    dz = p[2].take(i) - c[2].take(j)
    return dx * dx + dy * dy + dz * dz


KERNEL_SOURCE = Path(__file__).with_name("polyline_kernel.c")
"""The candidate search of :func:`distance_to_polyline` in C (built by :mod:`native`)."""
_KERNEL: list = []


def candidate_kernel():
    """The compiled candidate search (``polyline_candidates`` of :data:`KERNEL_SOURCE`), or None
    when it cannot be built (``$COSIM_NATIVE``: the numpy search runs, same numbers)."""
    if not _KERNEL:
        from native import load_library

        library = load_library(KERNEL_SOURCE, what="path accuracy kernel")
        fn = None
        if library is not None:
            fn = library.polyline_candidates
            p, n = ctypes.c_void_p, ctypes.c_longlong
            fn.argtypes = [p, n, p, p, n, p, p, n, n, n, p, p, p, n]
            fn.restype = n
        _KERNEL.append(fn)
    return _KERNEL[0]


def distance_to_polyline(points: np.ndarray, polyline: np.ndarray, window: int = AT_WINDOW_SAMPLES,
                         compiled: bool | None = None) -> np.ndarray:
    """Distance (m,) of each point to the polyline (n, 3), searching the segments within
    ``window`` samples of the point's own index (points and polyline are sampled at the
    same times, ``m == n``).

    Exact and pruned: the answer is the minimum of :func:`_pair_distance2` over the point's
    window, and only segments that can reach it are evaluated (about five of 2 window + 1).
    Bounds on the answer: the distance to the point's own segment, and that to the nearest
    midpoint of the segments in the nearest ball of 16 (a midpoint lies on its segment).
    A segment whose midpoint is farther than a bound plus its half length cannot be closer;
    a ball of 16, then of 4 consecutive segments farther than the bound plus its radius holds
    none that can. Every bound has a 1e-9 relative margin; the segments kept get the same
    arithmetic as in a search over the whole window, so the minimum is the same number
    (tests/cosim/tracking/test_path_accuracy_pruned.py). The search for those segments runs
    in C (:func:`candidate_kernel`, balls of 16 only) when it is built and ``compiled`` is not
    False (True: it must be); the distances are always numpy's."""
    n = polyline.shape[0]
    if n == 1:
        return np.linalg.norm(points - polyline[0], axis=1)
    m = points.shape[0]
    last = n - 2  # the last segment
    a = polyline[:-1]
    ab = polyline[1:] - a
    ab2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    idx = np.arange(m)
    best = _pair_distance2(points, a, ab, ab2, idx, np.minimum(idx, last))  # own segment: in every window
    with np.errstate(invalid="ignore"):
        reach = np.sqrt(best) * _INFLATE + 1e-12
        mid = a + 0.5 * ab
        half = 0.5 * np.sqrt(ab2) * _INFLATE
        coarse, coarse_r = _balls(mid, half, _COARSE_SEGMENTS)
    kernel = candidate_kernel() if compiled is not False else None
    if compiled and kernel is None:
        raise RuntimeError("the path accuracy kernel is not built (see $COSIM_NATIVE)")
    if kernel is not None:
        i, j = _candidates_compiled(kernel, points, mid, half, coarse, coarse_r, window, reach)
    else:
        i, j = _candidates(points, mid, half, coarse, coarse_r, window, reach)
    if i.size:  # ascending in i
        d2 = _pair_distance2(points, a, ab, ab2, i, j)
        start = np.flatnonzero(np.concatenate(([True], i[1:] != i[:-1])))
        rows = i[start]
        best[rows] = np.minimum(best[rows], np.minimum.reduceat(d2, start))
    return np.sqrt(best)


def _candidates_compiled(kernel, points: np.ndarray, mid: np.ndarray, half: np.ndarray, coarse: list[np.ndarray],
                         coarse_r: np.ndarray, window: int, reach: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(point, segment) index pairs to evaluate, ascending in the point, from the C search."""
    m = points.shape[0]
    f64 = np.float64
    points, mid, half, reach = (np.ascontiguousarray(x, dtype=f64) for x in (points, mid, half, reach))
    centre = np.ascontiguousarray(np.column_stack(coarse), dtype=f64)
    radius = np.ascontiguousarray(coarse_r, dtype=f64)
    capacity = 16 * m + 64
    while True:
        out_i = np.empty(capacity, dtype=np.int64)
        out_j = np.empty(capacity, dtype=np.int64)
        count = kernel(points.ctypes.data, m, mid.ctypes.data, half.ctypes.data, mid.shape[0], centre.ctypes.data,
                       radius.ctypes.data, radius.size, _COARSE_SEGMENTS, int(window), reach.ctypes.data,
                       out_i.ctypes.data, out_j.ctypes.data, capacity)
        if count <= capacity:
            return out_i[:count], out_j[:count]
        capacity = int(count)


def _candidates(points: np.ndarray, mid: np.ndarray, half: np.ndarray, coarse: list[np.ndarray],
                coarse_r: np.ndarray, window: int, reach: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(point, segment) index pairs to evaluate, ascending in the point (the numpy search)."""
    m = points.shape[0]
    last = mid.shape[0] - 1
    idx = np.arange(m)
    with np.errstate(invalid="ignore"):
        p = [np.ascontiguousarray(points[:, k]) for k in range(3)]
        mids = [np.ascontiguousarray(mid[:, k]) for k in range(3)]
        lo = np.maximum(np.minimum(idx - window, last), 0)  # the window: segments clip(i + k, 0, last), |k| <= window
        hi = np.minimum(idx + window, last)
        fine, fine_r = _balls(mid, half, _FINE_SEGMENTS)
        # every coarse ball touching the window, (m, count)
        first, final = lo // _COARSE_SEGMENTS, hi // _COARSE_SEGMENTS
        ball = first[:, None] + np.arange(int((final - first).max()) + 1)
        outside = ball > final[:, None]
        np.minimum(ball, coarse_r.size - 1, out=ball)
        ball_d2 = _squared(p, idx[:, None], coarse, ball)
        ball_d2[outside] = np.inf
        # the second bound: the nearest midpoint among the segments of the nearest ball (inside the window)
        seg = ball[idx, np.argmin(np.where(np.isnan(ball_d2), np.inf, ball_d2), axis=1)][:, None] * _COARSE_SEGMENTS \
            + np.arange(_COARSE_SEGMENTS)
        beyond = (seg < lo[:, None]) | (seg > hi[:, None])
        np.minimum(seg, last, out=seg)
        mid_d2 = _squared(p, idx[:, None], mids, seg)
        mid_d2[beyond | np.isnan(mid_d2)] = np.inf
        reach = np.minimum(reach, np.sqrt(mid_d2.min(axis=1)) * _INFLATE + 1e-12)
        # coarse balls that can hold a closer segment -> their fine balls -> their segments
        limit = reach[:, None] + coarse_r.take(ball)
        i, k = np.nonzero(ball_d2 <= limit * limit)
        per = _COARSE_SEGMENTS // _FINE_SEGMENTS
        i, b = np.repeat(i, per), (ball[i, k][:, None] * per + np.arange(per)).ravel()
        keep = b < fine_r.size
        i, b = i[keep], b[keep]
        limit = reach.take(i) + fine_r.take(b)
        keep = _squared(p, i, fine, b) <= limit * limit
        i, j = np.repeat(i[keep], _FINE_SEGMENTS), (b[keep][:, None] * _FINE_SEGMENTS + np.arange(_FINE_SEGMENTS)).ravel()
        keep = (j >= lo.take(i)) & (j <= hi.take(i))
        i, j = i[keep], j[keep]
        limit = reach.take(i) + half.take(j)
        keep = _squared(p, i, mids, j) <= limit * limit
    return i[keep], j[keep]


def path_accuracy(measured: np.ndarray, commanded: np.ndarray, segment: np.ndarray) -> dict[int, float]:
    """ISO 9283 AT (m) per segment id: max distance from the measured points to the
    commanded polyline of the same segment (points sampled at common times)."""
    out: dict[int, float] = {}
    for seg in np.unique(segment):
        mask = segment == seg
        out[int(seg)] = float(distance_to_polyline(measured[mask], commanded[mask]).max())
    return out


@dataclass
class TrackingResult:
    """Per-sample series (over the evaluation window) and the scalar metrics of one run."""

    t: np.ndarray
    q: np.ndarray
    q_d: np.ndarray
    lag: np.ndarray
    commanded: np.ndarray
    measured: np.ndarray
    programmed: np.ndarray
    tcp_error: np.ndarray
    path_error: np.ndarray
    segment: np.ndarray
    arc_length: np.ndarray
    at_per_segment: dict[int, float]
    at_vs_programmed_per_segment: dict[int, float]
    tcp_error_noise_free: np.ndarray
    residual: dict[str, float] = field(default_factory=dict)
    spectrum_hz: np.ndarray = field(default_factory=lambda: np.zeros(0))
    spectrum_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    residual_t: np.ndarray = field(default_factory=lambda: np.zeros(0))  # s after the motion's end
    residual_error: np.ndarray = field(default_factory=lambda: np.zeros(0))  # m, noise-free TCP error

    def metrics(self, segment_names: list[str] | None = None) -> dict[str, object]:
        """summary.json fields (mm, rad)."""
        names = segment_names or []

        def name(k: int) -> str:
            return names[k] if k < len(names) else str(k)

        empty = self.t.size == 0
        nan = float("nan")
        return {
            "tcp_error_max_mm": nan if empty else float(self.tcp_error.max() * 1e3),
            "tcp_error_rms_mm": nan if empty else float(np.sqrt(np.mean(self.tcp_error ** 2)) * 1e3),
            "path_accuracy_AT_mm": nan if empty else float(max(self.at_per_segment.values()) * 1e3),
            "path_accuracy_AT_per_segment_mm": {name(k): v * 1e3 for k, v in self.at_per_segment.items()},
            "joint_lag_max_rad": [nan] * N_JOINTS if empty else np.abs(self.lag).max(axis=0).tolist(),
            "tcp_error_max_noise_free_mm": nan if empty else float(self.tcp_error_noise_free.max() * 1e3),
            "tcp_error_rms_noise_free_mm": (nan if empty else
                                            float(np.sqrt(np.mean(self.tcp_error_noise_free ** 2)) * 1e3)),
            "tcp_path_error_max_mm": nan if empty else float(self.path_error.max() * 1e3),
            "tcp_path_error_rms_mm": nan if empty else float(np.sqrt(np.mean(self.path_error ** 2)) * 1e3),
            "path_accuracy_AT_vs_programmed_mm": (nan if empty else
                                                  float(max(self.at_vs_programmed_per_segment.values()) * 1e3)),
            "residual_vibration": {k: v for k, v in self.residual.items()},
            "tcp_error_spectrum_peak_hz": dominant_peak(self.spectrum_hz, self.spectrum_m)[0],
            "tcp_error_spectrum_peak_mm": dominant_peak(self.spectrum_hz, self.spectrum_m)[1] * 1e3,
            "evaluated_samples": int(self.t.size),
            "evaluated_from_s": nan if empty else float(self.t[0]),
            "evaluated_to_s": nan if empty else float(self.t[-1]),
        }


def evaluate(t: np.ndarray, q: np.ndarray, measured: np.ndarray, q_d: np.ndarray, commanded: np.ndarray,
             programmed: np.ndarray, segment: np.ndarray, window: tuple[float, float],
             arc_length: np.ndarray | None = None, actual: np.ndarray | None = None,
             band: float = VIBRATION_BAND_M) -> TrackingResult:
    """Metrics over the samples with ``window[0] <= t <= window[1]`` (s); the residual
    vibration over ``t >= window[1]`` (the motion's end) with settling ``band`` (m).

    ``t`` (m,) s; ``q``, ``q_d`` (m, 6) rad; ``measured``, ``commanded``, ``programmed``
    (m, 3) m; ``segment`` (m,) path segment ids; ``arc_length`` (m,) m along the path
    (kept for plots; zeros when not given); ``actual`` (m, 3) m the true flange without
    tracker noise (for ``tcp_error_noise_free``; the measured points when not given).
    """
    if actual is None:
        actual = measured
    if arc_length is None:
        arc_length = np.zeros(t.shape)
    residual = residual_vibration(t, actual - commanded, window[1], band)
    after = t >= window[1] - 1e-9
    residual_t = t[after] - window[1]
    final = (actual - commanded)[after][residual_t >= residual_t[-1] - FINAL_POSE_WINDOW_S].mean(axis=0) \
        if residual_t.size else np.zeros(3)
    residual_error = np.linalg.norm(actual[after] - commanded[after] - final, axis=1)
    mask = (t >= window[0] - 1e-9) & (t <= window[1] + 1e-9)
    t, q, measured, q_d = t[mask], q[mask], measured[mask], q_d[mask]
    commanded, programmed, segment, arc_length = commanded[mask], programmed[mask], segment[mask], arc_length[mask]
    actual = actual[mask]
    lag = q_d - q
    tcp_error = np.linalg.norm(measured - commanded, axis=1)
    path_error = np.linalg.norm(measured - programmed, axis=1)
    at = path_accuracy(measured, commanded, segment) if t.size else {}
    at_prog = path_accuracy(measured, programmed, segment) if t.size else {}
    freq, amplitude = error_spectrum(t, actual - commanded)
    return TrackingResult(t, q, q_d, lag, commanded, measured, programmed, tcp_error, path_error, segment,
                          arc_length, at, at_prog, np.linalg.norm(actual - commanded, axis=1), residual,
                          freq, amplitude, residual_t, residual_error)
