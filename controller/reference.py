"""Planned references the controller follows, sampled once on its own time grid.

The controller never calls a planner inside its 400 µs cycle. Before motion it samples
the planned trajectory on a uniform grid (``dt``, normally the controller period, so
every cycle reads one knot) and then, each cycle, *interpolates* it at the time the
set-point will be applied:

* :class:`TcpTrajectory` - the desired flange (``tool0``) motion in ``base_link``:
  position (m), rotation matrix, linear velocity (m/s), angular velocity (rad/s),
  linear acceleration (m/s^2, second time derivative of the position) and angular
  acceleration (rad/s^2), all in base-frame axes. Between knots: quintic Hermite
  polynomial of the position through (p, v, a) at both knots, and the rotation
  ``R(t) = Exp(w tau + dw tau^2 / 2) R_k`` (second-order expansion from knot k,
  base-frame angular velocity ``w``); at a knot the values are returned exactly.
* :class:`JointTrajectory` - a joint-space reference (q rad, qd rad/s, qdd rad/s^2,
  shape (6,) per sample), e.g. a planner's :class:`planners.trajectory.Trajectory`;
  between knots a quintic Hermite polynomial per joint.

Sources are duck-typed so that this middle-floor package imports no planner:
``TcpTrajectory.from_reference(fn, ...)`` takes any ``fn(times) -> obj`` whose ``obj``
has the arrays ``position (m, 3)``, ``rotation (m, 3, 3)``, ``velocity``,
``angular_velocity``, ``acceleration``, ``angular_acceleration`` (m, 3) - e.g.
``planners.iso9283.IsoTestPath.reference``; ``JointTrajectory.from_sampler(fn, ...)``
takes any ``fn(times) -> obj`` with ``q, qd, qdd`` arrays (m, 6) - e.g.
``Trajectory.sample``. Times before the start or after the end are clamped (the
reference is at rest there for rest-to-rest trajectories).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin
from robot.joints import N_JOINTS

_KNOT_TOLERANCE = 1e-9
"""Relative distance (in grid steps) below which a time is taken as a knot."""


class ReferenceError(ValueError):
    """A reference trajectory or a sampling request is malformed."""


def _grid(t_start: float, t_end: float, dt: float, what: str) -> np.ndarray:
    for name, value in (("t_start", t_start), ("t_end", t_end), ("dt", dt)):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ReferenceError(f"{what}: {name} = {value!r}, expected a finite number of seconds")
    if not dt > 0.0:
        raise ReferenceError(f"{what}: dt = {dt!r}, expected a grid step > 0 s")
    if not t_end > t_start:
        raise ReferenceError(f"{what}: t_end = {t_end!r}, expected a time after t_start = {t_start!r} s")
    n = int(math.ceil((t_end - t_start) / dt - _KNOT_TOLERANCE)) + 1
    return t_start + dt * np.arange(n)


def _array(obj: Any, name: str, shape: tuple[int, ...], what: str) -> np.ndarray:
    value = getattr(obj, name, None)
    if value is None:
        raise ReferenceError(f"{what}: the sampled reference has no attribute {name!r}")
    arr = np.array(value, dtype=float)
    if arr.shape != shape:
        raise ReferenceError(f"{what}: {name} has shape {arr.shape}, expected {shape}")
    if not np.all(np.isfinite(arr)):
        raise ReferenceError(f"{what}: {name} holds NaN or Inf values")
    return arr


class _Grid:
    """Uniform knot grid t_k = t_start + k dt, k = 0..n-1 (the last knot is t_end)."""

    def __init__(self, times: np.ndarray, dt: float) -> None:
        self.times = times
        self.t_start = float(times[0])
        self.t_end = float(times[-1])
        self.dt = float(dt)
        self.n = int(times.size)

    @property
    def duration(self) -> float:
        """t_end - t_start in s."""
        return self.t_end - self.t_start

    def locate(self, t: float) -> tuple[int, float]:
        """(knot index k, offset tau = t - t_k in s, 0 <= tau < dt) with t clamped to the grid."""
        if t <= self.t_start:
            return 0, 0.0
        if t >= self.t_end:
            return self.n - 1, 0.0
        x = (t - self.t_start) / self.dt
        k = round(x)
        if abs(x - k) <= _KNOT_TOLERANCE:
            return min(int(k), self.n - 1), 0.0
        k = int(math.floor(x))
        return k, t - float(self.times[k])


class _OnGrid:
    """What both trajectory kinds say of their knot grid ``self.grid``."""

    grid: _Grid

    @property
    def t_start(self) -> float:
        """Time of the first knot in s."""
        return self.grid.t_start

    @property
    def duration(self) -> float:
        """Length of the trajectory in s."""
        return self.grid.duration


def quintic_hermite(p0: np.ndarray, v0: np.ndarray, a0: np.ndarray, p1: np.ndarray, v1: np.ndarray, a1: np.ndarray,
              h: float, s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quintic Hermite through (p, v, a) at s = 0 and 1 over an interval of ``h`` s: value,
    first and second time derivatives at ``s`` in [0, 1]. Works on scalars and on numpy
    arrays that broadcast (e.g. rows (m, 6) with ``s`` (m, 1) and ``h`` scalar or (m, 1))."""
    s2, s3 = s * s, s * s * s
    s4, s5 = s3 * s, s3 * s2
    h0 = 1 - 10 * s3 + 15 * s4 - 6 * s5
    h1 = s - 6 * s3 + 8 * s4 - 3 * s5
    h2 = 0.5 * (s2 - 3 * s3 + 3 * s4 - s5)
    h3 = 1 - h0
    h4 = -4 * s3 + 7 * s4 - 3 * s5
    h5 = 0.5 * (s3 - 2 * s4 + s5)
    d0 = -30 * s2 + 60 * s3 - 30 * s4
    d1 = 1 - 18 * s2 + 32 * s3 - 15 * s4
    d2 = 0.5 * (2 * s - 9 * s2 + 12 * s3 - 5 * s4)
    d4 = -12 * s2 + 28 * s3 - 15 * s4
    d5 = 0.5 * (3 * s2 - 8 * s3 + 5 * s4)
    e0 = -60 * s + 180 * s2 - 120 * s3
    e1 = -36 * s + 96 * s2 - 60 * s3
    e2 = 0.5 * (2 - 18 * s + 36 * s2 - 20 * s3)
    e4 = -24 * s + 84 * s2 - 60 * s3
    e5 = 0.5 * (6 * s - 24 * s2 + 20 * s3)
    hv0, hv1, ha0, ha1 = v0 * h, v1 * h, a0 * h * h, a1 * h * h
    pos = h0 * p0 + h1 * hv0 + h2 * ha0 + h3 * p1 + h4 * hv1 + h5 * ha1
    vel = (d0 * (p0 - p1) + d1 * hv0 + d2 * ha0 + d4 * hv1 + d5 * ha1) / h
    acc = (e0 * (p0 - p1) + e1 * hv0 + e2 * ha0 + e4 * hv1 + e5 * ha1) / (h * h)
    return pos, vel, acc


@dataclass(frozen=True)
class TcpSample:
    """The desired flange motion at one time (base_link, SI): ``target`` placement,
    ``twist`` (6,) = (v m/s, w rad/s) and ``acceleration`` (6,) = (a m/s^2, dw rad/s^2)."""

    target: pin.SE3
    twist: np.ndarray
    acceleration: np.ndarray


class TcpTrajectory(_OnGrid):
    """A planned flange trajectory sampled on a uniform grid (see module docstring).

    Arrays: ``times`` (n,) s; ``position`` (n, 3) m; ``rotation`` (n, 3, 3);
    ``twist`` (n, 6) = (v m/s, w rad/s); ``acceleration`` (n, 6) = (a m/s^2, dw rad/s^2);
    ``packed`` (n, 24): per knot the rotation (column-major), position, twist and
    acceleration in one row (:meth:`packed_sample`).
    """

    kind = "tcp"

    def __init__(self, times: np.ndarray, position: np.ndarray, rotation: np.ndarray, twist: np.ndarray,
                 acceleration: np.ndarray, dt: float) -> None:
        self.grid = _Grid(np.asarray(times, dtype=float), dt)
        n = self.grid.n
        self.position = np.ascontiguousarray(position, dtype=float).reshape(n, 3)
        self.rotation = np.ascontiguousarray(rotation, dtype=float).reshape(n, 3, 3)
        self.twist = np.ascontiguousarray(twist, dtype=float).reshape(n, 6)
        self.acceleration = np.ascontiguousarray(acceleration, dtype=float).reshape(n, 6)
        self._placement_list: list[pin.SE3] | None = None  # made on first use (:attr:`_placements`)
        # one contiguous row per knot for compiled consumers: R (9, column-major), p (3), twist (6), acc (6)
        self.packed = np.ascontiguousarray(np.hstack([self.rotation.transpose(0, 2, 1).reshape(n, 9), self.position,
                                                      self.twist, self.acceleration]))

    @property
    def _placements(self) -> list[pin.SE3]:
        """Every knot's placement (pin.SE3), made on first use (30 520 on the ISO path, about
        40 ms: not in the job's serial set-up, which builds this trajectory once for every mode,
        since the compiled cycles read :attr:`packed`); the Python paths that walk the knots
        (IK knot by knot) use it."""
        if self._placement_list is None:
            self._placement_list = [pin.SE3(self.rotation[k], self.position[k]) for k in range(self.grid.n)]
        return self._placement_list

    @classmethod
    def from_reference(cls, reference: Callable[[np.ndarray], Any], t_end: float, dt: float,
                       t_start: float = 0.0) -> "TcpTrajectory":
        """Sample ``reference(times)`` on ``t_start, t_start + dt, ..., t_end`` (s)."""
        what = "TcpTrajectory.from_reference"
        times = _grid(t_start, t_end, dt, what)
        ref = reference(times)
        n = times.size
        rotation = _array(ref, "rotation", (n, 3, 3), what)
        orth = np.abs(rotation @ np.swapaxes(rotation, 1, 2) - np.eye(3)).max()
        if orth > 1e-6:
            raise ReferenceError(f"{what}: rotation is not orthonormal (max |R R^T - I| = {orth:.3g})")
        twist = np.hstack([_array(ref, "velocity", (n, 3), what), _array(ref, "angular_velocity", (n, 3), what)])
        acc = np.hstack([_array(ref, "acceleration", (n, 3), what),
                         _array(ref, "angular_acceleration", (n, 3), what)])
        return cls(times, _array(ref, "position", (n, 3), what), rotation, twist, acc, dt)

    def sample(self, t: float) -> TcpSample:
        """The desired flange motion at time ``t`` (s, clamped to the trajectory).

        At a knot the stored values (no copy of the placement: do not modify it);
        between knots the interpolation of the module docstring.
        """
        k, tau = self.grid.locate(t)
        if tau == 0.0:  # the knot's placement: the made one when they are made, else a new one (equal)
            placements = self._placement_list
            target = placements[k] if placements is not None else pin.SE3(self.rotation[k], self.position[k])
            return TcpSample(target, self.twist[k], self.acceleration[k])
        h = self.grid.dt
        pos, vel, acc = quintic_hermite(self.position[k], self.twist[k, :3], self.acceleration[k, :3],
                                  self.position[k + 1], self.twist[k + 1, :3], self.acceleration[k + 1, :3],
                                  h, tau / h)
        s = tau / h
        w = self.twist[k, 3:] + tau * self.acceleration[k, 3:]
        dw = (1.0 - s) * self.acceleration[k, 3:] + s * self.acceleration[k + 1, 3:]
        rot = pin.exp3(self.twist[k, 3:] * tau + 0.5 * tau * tau * self.acceleration[k, 3:]) @ self.rotation[k]
        return TcpSample(pin.SE3(rot, pos), np.concatenate([vel, w]), np.concatenate([acc, dw]))

    def packed_sample(self, t: float, scratch: np.ndarray) -> np.ndarray:
        """The sample at ``t`` as one row of 24 (layout of ``packed``): a row of ``packed``
        at a knot (no copy), else ``scratch`` (24,) filled with the interpolation."""
        k, tau = self.grid.locate(t)
        if tau == 0.0:
            return self.packed[k]
        sample = self.sample(t)
        scratch[:9] = sample.target.rotation.ravel(order="F")
        scratch[9:12] = sample.target.translation
        scratch[12:18] = sample.twist
        scratch[18:] = sample.acceleration
        return scratch

    def positions(self, times: np.ndarray) -> np.ndarray:
        """Desired flange positions (m, 3) in m at ``times`` (m,) s (clamped), the same
        interpolation as :meth:`sample`, vectorised (for evaluation, not for the cycle)."""
        t = np.clip(np.asarray(times, dtype=float), self.grid.t_start, self.grid.t_end)
        x = (t - self.grid.t_start) / self.grid.dt
        k = np.clip(np.floor(x + _KNOT_TOLERANCE).astype(int), 0, self.grid.n - 2)
        s = np.clip(x - k, 0.0, 1.0)[:, None]
        pos, _, _ = quintic_hermite(self.position[k], self.twist[k, :3], self.acceleration[k, :3],
                                    self.position[k + 1], self.twist[k + 1, :3], self.acceleration[k + 1, :3],
                                    self.grid.dt, s)
        return pos


@dataclass(frozen=True)
class JointSample:
    """Joint references at one time: q (6,) rad, qd (6,) rad/s, qdd (6,) rad/s^2."""

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray


class JointTrajectory(_OnGrid):
    """A planned joint trajectory sampled on a uniform grid (see module docstring).

    Arrays ``times`` (n,) s and ``q``, ``qd``, ``qdd`` (n, 6) in rad, rad/s, rad/s^2.
    """

    kind = "joint"

    def __init__(self, times: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, dt: float) -> None:
        self.grid = _Grid(np.asarray(times, dtype=float), dt)
        n = self.grid.n
        self.q = np.ascontiguousarray(q, dtype=float).reshape(n, N_JOINTS)
        self.qd = np.ascontiguousarray(qd, dtype=float).reshape(n, N_JOINTS)
        self.qdd = np.ascontiguousarray(qdd, dtype=float).reshape(n, N_JOINTS)

    @classmethod
    def from_sampler(cls, sampler: Callable[[np.ndarray], Any], t_end: float, dt: float,
                     t_start: float = 0.0) -> "JointTrajectory":
        """Sample ``sampler(times)`` (an object with q, qd, qdd arrays (m, 6)) on the grid.

        The grid starts at ``t_start`` (s); ``t_end`` is the planner's end time.
        """
        what = "JointTrajectory.from_sampler"
        times = _grid(t_start, t_end, dt, what)
        ref = sampler(times)
        n = times.size
        return cls(times, _array(ref, "q", (n, N_JOINTS), what), _array(ref, "qd", (n, N_JOINTS), what),
                   _array(ref, "qdd", (n, N_JOINTS), what), dt)

    @classmethod
    def from_planner_trajectory(cls, trajectory: Any, dt: float) -> "JointTrajectory":
        """From an object with ``t`` (n,) and ``sample(times)`` (a planners ``Trajectory``),
        re-timed so that its first sample is at time 0."""
        t = np.asarray(getattr(trajectory, "t", None), dtype=float)
        if t.ndim != 1 or t.size < 2:
            raise ReferenceError("JointTrajectory.from_planner_trajectory: expected an object with times t (n >= 2,)")
        t0 = float(t[0])
        return cls.from_sampler(lambda times: trajectory.sample(times + t0), float(t[-1]) - t0, dt)

    def sample(self, t: float) -> JointSample:
        """Joint references at ``t`` (s, clamped); at a knot the stored rows (views)."""
        k, tau = self.grid.locate(t)
        if tau == 0.0:
            return JointSample(self.q[k], self.qd[k], self.qdd[k])
        h = self.grid.dt
        q, qd, qdd = quintic_hermite(self.q[k], self.qd[k], self.qdd[k], self.q[k + 1], self.qd[k + 1], self.qdd[k + 1],
                               h, tau / h)
        return JointSample(q, qd, qdd)


def higher_derivatives(qdd: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Jerk and snap (each (n, 6); rad/s^3, rad/s^4) of a joint motion from its exact
    accelerations ``qdd`` (n, 6) on a uniform grid of step ``dt`` (s): second-order central
    differences inside, one-sided at the ends (where rest-to-rest references are at rest).
    Error O(dt^2) times the 5th / 6th derivative; where the acceleration has a kink (e.g.
    the start of a sin^2 ramp) the snap is spread over one grid step."""
    qdd = np.asarray(qdd, dtype=float)
    if qdd.ndim != 2 or qdd.shape[0] < 3:
        raise ReferenceError(f"higher_derivatives: qdd has shape {qdd.shape}, expected (n >= 3, joints)")
    if not (math.isfinite(dt) and dt > 0):
        raise ReferenceError(f"higher_derivatives: dt = {dt!r}, expected a grid step > 0 s")
    jerk = np.gradient(qdd, dt, axis=0, edge_order=2)
    snap = np.empty_like(qdd)
    snap[1:-1] = (qdd[2:] - 2.0 * qdd[1:-1] + qdd[:-2]) / (dt * dt)
    snap[0], snap[-1] = snap[1], snap[-2]
    return jerk, snap
