"""Zero-phase filtering, differentiation and period averaging of measured joint signals.

Identification needs ``qd`` and ``qdd`` that are not delayed with respect to the
measured torque: a phase lag between ``tau`` and ``Theta(q, qd, qdd)`` biases the
estimate (a delayed ``qdd`` looks like extra damping). Two ways, both without phase:

* **any record** (:func:`zero_phase_derivatives`): a Butterworth low-pass run forwards
  and backwards (``scipy.signal.sosfiltfilt``, zero phase, squared magnitude; the
  record is padded at both ends by a cubic fitted to its last samples, so the
  filter's start-up does not distort q, qd, qdd near the edges), then
  second-order central differences (``numpy.gradient``, symmetric, zero phase) for
  ``qd`` and again for ``qdd``. The torques get the same low-pass
  (:func:`zero_phase_lowpass`), so both sides of ``tau = Theta p`` see the same filter.
* **a periodic record** (:func:`periodic_derivatives`): after averaging whole periods
  (:func:`average_periods`, which also divides uncorrelated noise by sqrt(periods)),
  the period is expanded in its discrete Fourier series; harmonics above the cut-off
  are dropped and ``qd``, ``qdd`` are the exact derivatives of the remaining series
  (multiplication by ``i w`` per harmonic). Exact for a band-limited periodic signal,
  no edge effects.

Units: time in s, frequencies in Hz, signals in whatever unit they come in (rad, N m).
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from identification.defaults import DEFAULT_CUTOFF_HZ
from identification.errors import IdentificationDataError

FILTER_ORDER = 4
"""Butterworth order of the zero-phase low-pass (applied twice by filtfilt: 8th-order magnitude)."""
EDGE_PAD_CUTOFF_PERIODS = 3.0
"""Length of the extrapolated padding at each end, in periods of the cut-off frequency (the
filter's transient has died out well within it)."""
EDGE_FIT_CUTOFF_PERIODS = 0.5
"""Samples at each end the padding polynomial is fitted to, in periods of the cut-off."""
EDGE_POLYNOMIAL_DEGREE = 3
"""Degree of the extrapolating polynomial at the ends (cubic: continuous acceleration, so the
second derivative has no step at the record's edges; scipy's default odd padding flips it)."""
SAMPLING_JITTER = 0.01
"""Largest accepted deviation of a time step from the median step, relative."""


def sample_time_of(t: ArrayLike, name: str = "t") -> float:
    """The uniform sample time (s) of a time axis; raises on NaN, non-increasing or irregular steps."""
    t = np.asarray(t, dtype=float).reshape(-1)
    if t.size < 2:
        raise IdentificationDataError(f"column {name!r}: {t.size} sample(s), expected at least 2 time samples")
    if not np.all(np.isfinite(t)):
        bad = int(np.flatnonzero(~np.isfinite(t))[0])
        raise IdentificationDataError(f"column {name!r}: value {t[bad]!r} at sample {bad}, expected finite times in s")
    steps = np.diff(t)
    if np.any(steps <= 0.0):
        k = int(np.flatnonzero(steps <= 0.0)[0])
        raise IdentificationDataError(
            f"column {name!r}: time goes from {t[k]!r} to {t[k + 1]!r} s at sample {k + 1}, expected strictly "
            "increasing times (non-monotonic sampling)")
    dt = float(np.median(steps))
    deviation = np.abs(steps - dt)
    if np.any(deviation > SAMPLING_JITTER * dt):
        k = int(np.argmax(deviation))
        raise IdentificationDataError(
            f"column {name!r}: time step {steps[k]!r} s at sample {k + 1} differs from the median step {dt!r} s by "
            f"more than {SAMPLING_JITTER:.0%}, expected uniform sampling (resample the record first)")
    return dt


def _check_cutoff(sample_time: float, cutoff_hz: float) -> None:
    nyquist = 0.5 / sample_time
    if not (isinstance(cutoff_hz, (int, float)) and math.isfinite(cutoff_hz) and 0.0 < cutoff_hz < nyquist):
        raise IdentificationDataError(
            f"cutoff_hz = {cutoff_hz!r}, expected a frequency in (0, {nyquist:g}) Hz (below the Nyquist frequency of "
            f"the {sample_time:g} s sampling)")


def _sos(sample_time: float, cutoff_hz: float) -> np.ndarray:
    _check_cutoff(sample_time, cutoff_hz)
    import scipy.signal  # here, not at import: scipy.signal costs seconds to import

    return scipy.signal.butter(FILTER_ORDER, cutoff_hz, btype="low", output="sos", fs=1.0 / sample_time)


def minimum_samples(sample_time: float, cutoff_hz: float) -> int:
    """Fewest samples the zero-phase filter accepts: its padding plus one cut-off period."""
    return 3 * (2 * FILTER_ORDER + 1) + int(math.ceil(1.0 / (cutoff_hz * sample_time)))


def zero_phase_lowpass(x: ArrayLike, sample_time: float, cutoff_hz: float = DEFAULT_CUTOFF_HZ) -> np.ndarray:
    """Butterworth low-pass forwards and backwards along axis 0 (zero phase)."""
    x = np.asarray(x, dtype=float)
    need = minimum_samples(sample_time, cutoff_hz)
    if x.shape[0] < need:
        raise IdentificationDataError(
            f"record too short: {x.shape[0]} samples, expected at least {need} for a {cutoff_hz:g} Hz zero-phase "
            f"filter at {sample_time:g} s")
    pad = min(x.shape[0] - 1, int(math.ceil(EDGE_PAD_CUTOFF_PERIODS / (cutoff_hz * sample_time))))
    fit = min(x.shape[0], max(8, int(math.ceil(EDGE_FIT_CUTOFF_PERIODS / (cutoff_hz * sample_time)))))
    extended = np.concatenate((_extrapolate(x[:fit][::-1], pad)[::-1], x, _extrapolate(x[-fit:], pad)), axis=0)
    import scipy.signal

    y = scipy.signal.sosfiltfilt(_sos(sample_time, cutoff_hz), extended, axis=0, padtype=None)
    return y[pad:pad + x.shape[0]]


def _extrapolate(tail: np.ndarray, count: int) -> np.ndarray:
    """``count`` samples continuing ``tail`` (its last sample is the edge) by a least-squares
    cubic in the sample index: keeps the value, slope and curvature at the edge smooth."""
    m = tail.shape[0]
    k = np.arange(m, dtype=float) - (m - 1)
    degree = min(EDGE_POLYNOMIAL_DEGREE, m - 1)
    vander = np.vander(k, degree + 1)
    coef = np.linalg.lstsq(vander, tail.reshape(m, -1), rcond=None)[0]
    ahead = np.vander(np.arange(1, count + 1, dtype=float), degree + 1) @ coef
    return ahead.reshape((count,) + tail.shape[1:])


def zero_phase_derivatives(q: ArrayLike, sample_time: float,
                           cutoff_hz: float = DEFAULT_CUTOFF_HZ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Filtered q, and qd, qdd by central differences of the filtered signal (all (n, ...))."""
    qf = zero_phase_lowpass(q, sample_time, cutoff_hz)
    qd = np.gradient(qf, sample_time, axis=0, edge_order=2)
    qdd = np.gradient(qd, sample_time, axis=0, edge_order=2)
    return qf, qd, qdd


def average_periods(x: ArrayLike, samples_per_period: int, periods: int | None = None,
                    skip_periods: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation over whole periods of a periodic record along axis 0.

    ``x[skip_periods * n : (skip_periods + periods) * n]`` is cut into ``periods`` blocks
    of ``n = samples_per_period``; returns (mean block, std block) of shape (n, ...).
    ``periods`` defaults to all complete periods after the skipped ones.
    """
    x = np.asarray(x, dtype=float)
    n = samples_per_period
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise IdentificationDataError(f"samples_per_period = {n!r}, expected an integer >= 2")
    available = x.shape[0] // n - skip_periods
    periods = available if periods is None else periods
    if periods < 1 or periods > available:
        raise IdentificationDataError(
            f"record of {x.shape[0]} samples holds {max(available, 0)} complete period(s) of {n} samples after "
            f"skipping {skip_periods}, expected at least {max(periods, 1)}")
    blocks = x[skip_periods * n:(skip_periods + periods) * n].reshape((periods, n) + x.shape[1:])
    std = blocks.std(axis=0, ddof=1) if periods > 1 else np.zeros(blocks.shape[1:])
    return blocks.mean(axis=0), std


def _harmonic_mask(n: int, sample_time: float, cutoff_hz: float) -> np.ndarray:
    freqs = np.fft.rfftfreq(n, sample_time)
    return freqs <= cutoff_hz


def periodic_lowpass(x: ArrayLike, sample_time: float, cutoff_hz: float) -> np.ndarray:
    """One period (n, ...) with the harmonics above ``cutoff_hz`` removed (ideal, zero phase)."""
    x = np.asarray(x, dtype=float)
    _check_cutoff(sample_time, cutoff_hz)
    spectrum = np.fft.rfft(x, axis=0)
    mask = _harmonic_mask(x.shape[0], sample_time, cutoff_hz).reshape((-1,) + (1,) * (x.ndim - 1))
    return np.fft.irfft(spectrum * mask, n=x.shape[0], axis=0)


def periodic_derivatives(q: ArrayLike, sample_time: float,
                         cutoff_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Band-limited q, qd, qdd of ONE period (n, ...) by Fourier-domain differentiation."""
    q = np.asarray(q, dtype=float)
    _check_cutoff(sample_time, cutoff_hz)
    n = q.shape[0]
    spectrum = np.fft.rfft(q, axis=0)
    shape = (-1,) + (1,) * (q.ndim - 1)
    mask = _harmonic_mask(n, sample_time, cutoff_hz).reshape(shape)
    if n % 2 == 0:  # the Nyquist bin has no well-defined derivative
        mask = mask.copy()
        mask[-1] = False
    iw = (2j * np.pi * np.fft.rfftfreq(n, sample_time)).reshape(shape)
    kept = spectrum * mask
    return (np.fft.irfft(kept, n=n, axis=0), np.fft.irfft(kept * iw, n=n, axis=0),
            np.fft.irfft(kept * iw**2, n=n, axis=0))


def periodic_evaluate(x: ArrayLike, sample_time: float, cutoff_hz: float, times: ArrayLike,
                      derivative: int = 0) -> np.ndarray:
    """The band-limited Fourier series of ONE period ``x`` (n, ...) sampled every ``sample_time``
    s from phase 0, or its ``derivative``-th time derivative, at arbitrary ``times`` (s, taken
    modulo the period): exact interpolation of the periodic signal up to ``cutoff_hz``."""
    x = np.asarray(x, dtype=float)
    _check_cutoff(sample_time, cutoff_hz)
    n = x.shape[0]
    spectrum = np.fft.rfft(x, axis=0)
    freqs = np.fft.rfftfreq(n, sample_time)
    keep = freqs <= cutoff_hz
    if n % 2 == 0:
        keep[-1] = False
    weights = np.where(np.arange(freqs.size) == 0, 1.0, 2.0)[keep] / n
    omega = 2.0 * np.pi * freqs[keep]
    coef = spectrum[keep].reshape(int(keep.sum()), -1) * (weights * (1j * omega) ** derivative)[:, None]
    phase = np.exp(1j * np.outer(np.asarray(times, dtype=float), omega))
    return (phase @ coef).real.reshape((-1,) + x.shape[1:])
