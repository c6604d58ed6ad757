"""The EN ISO 9283 test path of the RX130L-class arm and its smooth time law.

Geometry (robot-data.md, ISO section; check details against the standard):

* **Cube.** Edges parallel to base_link, centred in front of the robot on the x axis
  (y = 0), at the constant flange orientation ``ISO_ORIENTATION_CARDAN`` (tool z axis
  pointing down, Cardan angles (pi, 0, 0)). ``ISO_CUBE_CENTER`` and ``ISO_CUBE_EDGE``
  come from :func:`search_largest_cube`: over centres x in [0.50, 1.50] m, z in
  [-0.30, 1.60] m (5 cm grid), bisect the largest edge such that 11 points on each
  of the 12 edges and the centre have an analytic IK solution on ONE branch
  (``ISO_IK_BRANCH`` = 0: shoulder in front, elbow up, q5 > 0), keep joints 2, 3 and 5
  at least ``CUBE_JOINT_MARGIN`` = 0.1 rad inside their ranges and the smallest
  singular value of the Jacobian at least ``CUBE_MIN_SINGULAR_VALUE`` = 0.05. The
  best centre was (0.90, 0, 0.50) m with a 0.943 m edge; the edge is rounded down to
  0.90 m for margin (run ``search_largest_cube()`` to reproduce, about 30 s).
* **Test plane.** The diagonal plane through the upper cube edge nearer to the robot
  and the lower edge farther away (a table tilted 45 deg towards the robot). Its
  corners C1..C4 (in order around the rectangle, a x a*sqrt(2)): C1 = (x-, y-, z+),
  C2 = (x-, y+, z+), C3 = (x+, y+, z-), C4 = (x+, y-, z-).
* **Poses.** P1 = cube centre; P2..P5 on the plane diagonals 10 % of the diagonal
  length in from C1..C4 (P = P1 + 0.8 (C - P1)).
* **Path** (segments in this order, each traversed rest to rest, stopping at every
  junction, in particular at the sharp rectangle corners): rectangle P2-P3-P4-P5-P2,
  straight line P2 -> P4, transfer to the large circle, large circle about P1 in the
  test plane (diameter 0.8 x cube edge, one turn), transfer, small circle (diameter
  0.1 x the large one), transfer back to P1.

Time law per segment: arc length s(t) with a sin^2 acceleration ramp (acceleration
continuous, jerk bounded: a_t pi / T_ramp), cruise speed ``ISO_SPEED`` = 1 m/s and
peak tangential acceleration ``ISO_ACCELERATION`` = 5 m/s^2 (paper sec. 2.3.3). On
circles the total acceleration must stay within 5 m/s^2 too: the tangential peak is
0.8 x 5 m/s^2 and the cruise speed is capped so that v^2 / r <= 0.6 x 5 m/s^2
(sqrt(0.8^2 + 0.6^2) = 1); the small circle therefore runs at about 0.33 m/s.
Orientation is constant, so angular velocity and acceleration are zero.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from planners.paths import CartesianPath, CirclePath, LinePath, joint_path
from planners.trajectory import Trajectory, uniform_times
from robot.kinematics import cardan_from_rotation, rotation_from_cardan

ISO_ORIENTATION_CARDAN: tuple[float, float, float] = (math.pi, 0.0, 0.0)
"""Constant flange orientation of the test (Cardan x-y-z, rad): tool z axis down."""
ISO_CUBE_CENTER: tuple[float, float, float] = (0.90, 0.0, 0.50)
"""Cube centre in base_link [m] (see module docstring for the search)."""
ISO_CUBE_EDGE: float = 0.90
"""Cube edge [m]: largest found 0.943 m at ISO_CUBE_CENTER, rounded down."""
ISO_SPEED: float = 1.0
"""TCP cruise speed [m/s] (paper sec. 2.3.3)."""
ISO_ACCELERATION: float = 5.0
"""TCP acceleration limit [m/s^2] (paper sec. 2.3.3)."""
ISO_IK_BRANCH: int = 0
"""robot.inverse_kinematics.AnalyticIK branch of the test (shoulder front, elbow up, q5 > 0)."""
ISO_Q_HINT: tuple[float, ...] = (0.0, 0.4, 1.8, 0.0, 0.9, math.pi)
"""Joint angles [rad] near the test path on ISO_IK_BRANCH (joint-path branch seed)."""
CUBE_JOINT_MARGIN: float = 0.1
"""Least distance [rad] of joints 2, 3, 5 from their limits inside the cube."""
CUBE_MIN_SINGULAR_VALUE: float = 0.05
"""Least smallest-singular-value of the Jacobian inside the cube."""
LARGE_CIRCLE_DIAMETER_FRACTION: float = 0.8
"""Large circle diameter / cube edge (robot-data.md)."""
SMALL_CIRCLE_FRACTION: float = 0.1
"""Small circle diameter / large circle diameter (robot-data.md)."""
CIRCLE_TANGENTIAL_SHARE: float = 0.8
"""On circles: peak tangential acceleration / ISO_ACCELERATION (normal share 0.6)."""

SEGMENT_KINDS = ("rectangle", "line", "transfer", "circle_large", "circle_small")


class IsoPathError(ValueError):
    """An ISO 9283 path request is malformed (bad speed, acceleration, time, ...)."""


# -----------------------------------------------------------------------------
# rest-to-rest sin^2 time law along one segment


@dataclass(frozen=True)
class SegmentTimeLaw:
    """Arc length s(t) on [0, duration] from rest to rest [m, s].

    Acceleration ramps a(t) = a_peak sin^2(pi t / ramp_time) up to cruise_speed, a cruise,
    and the mirrored ramp down.
    """

    length: float
    cruise_speed: float
    peak_acceleration: float
    ramp_time: float
    cruise_time: float

    @classmethod
    def create(cls, length: float, speed: float, acceleration: float) -> "SegmentTimeLaw":
        if not (length > 0 and speed > 0 and acceleration > 0):
            raise IsoPathError(
                f"segment time law: expected positive length, speed, acceleration, got {length}, {speed}, {acceleration}"
            )
        ramp = 2.0 * speed / acceleration
        if speed * ramp > length:  # no cruise: the two ramps meet
            speed = math.sqrt(length * acceleration / 2.0)
            ramp = 2.0 * speed / acceleration
        cruise = (length - speed * ramp) / speed
        return cls(length, speed, acceleration, ramp, max(cruise, 0.0))

    @property
    def duration(self) -> float:
        return 2.0 * self.ramp_time + self.cruise_time

    @property
    def peak_jerk(self) -> float:
        """Largest |d^3 s / dt^3| [m/s^3]."""
        return self.peak_acceleration * math.pi / self.ramp_time

    def _ramp(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        a, tr = self.peak_acceleration, self.ramp_time
        w = 2.0 * math.pi / tr
        s = 0.5 * a * (0.5 * tau**2 + (np.cos(w * tau) - 1.0) / w**2)
        v = 0.5 * a * (tau - np.sin(w * tau) / w)
        acc = 0.5 * a * (1.0 - np.cos(w * tau))
        return s, v, acc

    def evaluate(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s [m], ds/dt [m/s], d2s/dt2 [m/s^2]) at local times t (clamped to [0, duration])."""
        tt = np.clip(np.asarray(t, dtype=float), 0.0, self.duration)
        s = np.empty_like(tt)
        v = np.empty_like(tt)
        a = np.empty_like(tt)
        tr, tc = self.ramp_time, self.cruise_time
        up = tt <= tr
        down = tt >= tr + tc
        mid = ~up & ~down
        s[up], v[up], a[up] = self._ramp(tt[up])
        s_ramp = 0.5 * self.cruise_speed * tr
        s[mid] = s_ramp + self.cruise_speed * (tt[mid] - tr)
        v[mid] = self.cruise_speed
        a[mid] = 0.0
        sd, vd, ad = self._ramp(self.duration - tt[down])
        s[down], v[down], a[down] = self.length - sd, vd, -ad
        return s, v, a


# -----------------------------------------------------------------------------
# the test path


@dataclass(frozen=True)
class IsoSegment:
    """One rest-to-rest element of the test path (sigma of ``path`` is arc length / length)."""

    index: int
    name: str
    kind: str
    path: CartesianPath
    law: SegmentTimeLaw
    t_start: float
    arc_start: float

    @property
    def t_end(self) -> float:
        return self.t_start + self.law.duration


@dataclass(frozen=True)
class FlangeReference:
    """Desired flange motion at time(s) t: arrays with a leading sample axis (m,).

    position (m, 3) m, rotation (m, 3, 3), velocity (m, 3) m/s, angular_velocity (m, 3)
    rad/s, acceleration (m, 3) m/s^2, angular_acceleration (m, 3) rad/s^2 (base_link
    axes); segment (m,) index into IsoTestPath.segments; arc_length (m,) m along the
    whole path; speed (m,) m/s.
    """

    t: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    velocity: np.ndarray
    angular_velocity: np.ndarray
    acceleration: np.ndarray
    angular_acceleration: np.ndarray
    segment: np.ndarray
    arc_length: np.ndarray
    speed: np.ndarray

    def columns(self) -> dict[str, np.ndarray]:
        """Flat CSV-ready columns: x, y, z, alpha, beta, gamma, vx.., ax.., wx.., segment, arc_length, speed."""
        cardan = cardan_from_rotation(self.rotation)
        out: dict[str, np.ndarray] = {}
        for k, axis in enumerate("xyz"):
            out[axis] = self.position[:, k]
        for k, name in enumerate(("alpha", "beta", "gamma")):
            out[name] = cardan[:, k]
        for prefix, arr in (("v", self.velocity), ("a", self.acceleration), ("w", self.angular_velocity),
                            ("dw", self.angular_acceleration)):
            for k, axis in enumerate("xyz"):
                out[f"{prefix}{axis}"] = arr[:, k]
        out["segment"] = self.segment.astype(float)
        out["arc_length"] = self.arc_length
        out["speed"] = self.speed
        return out

    def write_csv(self, path: str | Path) -> Path:
        """CSV with a header ``t, x, y, z, alpha, ...`` (SI units, base_link)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        cols = {"t": self.t, **self.columns()}
        np.savetxt(path, np.column_stack(list(cols.values())), delimiter=",", header=",".join(cols), comments="")
        return path


@dataclass
class IsoTestPath:
    """The ISO 9283 test path with its time law (see module docstring).

    Build with :func:`iso9283_test_path`. ``reference(t)`` gives the desired flange pose,
    twist and acceleration at any time (the 400 us controller samples it and solves the
    IK itself); ``cartesian_trajectory(dt)`` samples it on a grid; ``joint_trajectory``
    maps it to a joint :class:`Trajectory` by IK with inverse-dynamics torques.
    """

    cube_center: np.ndarray
    cube_edge: float
    rotation: np.ndarray
    plane_corners: np.ndarray
    poses: dict[str, np.ndarray]
    segments: list[IsoSegment]
    speed: float
    acceleration: float
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def duration(self) -> float:
        return self.segments[-1].t_end

    @property
    def length(self) -> float:
        last = self.segments[-1]
        return last.arc_start + last.law.length

    @property
    def segment_names(self) -> list[str]:
        return [seg.name for seg in self.segments]

    @property
    def cube_corners(self) -> np.ndarray:
        """The 8 cube corners (8, 3) m."""
        signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=float)
        return self.cube_center + 0.5 * self.cube_edge * signs

    def segment_at(self, t: ArrayLike) -> np.ndarray:
        """Segment index at time(s) t [s]."""
        starts = np.array([seg.t_start for seg in self.segments])
        tt = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.duration)
        return np.clip(np.searchsorted(starts, tt, side="right") - 1, 0, len(self.segments) - 1)

    def reference(self, t: ArrayLike) -> FlangeReference:
        """Desired flange pose, twist and acceleration at time(s) t [s] (clamped to [0, duration])."""
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        if tt.ndim != 1 or not np.all(np.isfinite(tt)):
            raise IsoPathError(f"IsoTestPath.reference t: expected finite times in s, got {t!r}")
        tt = np.clip(tt, 0.0, self.duration)
        idx = self.segment_at(tt)
        m = tt.size
        pos, vel, acc = np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3))
        om, dom = np.empty((m, 3)), np.empty((m, 3))
        rot = np.empty((m, 3, 3))
        arc, speed = np.empty(m), np.empty(m)
        for k in np.unique(idx):
            seg = self.segments[k]
            mask = idx == k
            s, sd, sdd = seg.law.evaluate(tt[mask] - seg.t_start)
            length = seg.law.length
            sigma = np.clip(s / length, 0.0, 1.0)
            sig_d, sig_dd = sd / length, sdd / length
            pts = seg.path.evaluate(sigma)
            pos[mask] = pts.position
            vel[mask] = pts.d_position * sig_d[:, None]
            acc[mask] = pts.d_position * sig_dd[:, None] + pts.dd_position * (sig_d**2)[:, None]
            om[mask] = pts.omega * sig_d[:, None]
            dom[mask] = pts.omega * sig_dd[:, None] + pts.d_omega * (sig_d**2)[:, None]
            rot[mask] = pts.rotation
            arc[mask] = seg.arc_start + s
            speed[mask] = sd
        return FlangeReference(tt, pos, rot, vel, om, acc, dom, idx, arc, speed)

    def progress(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """(segment index, arc length [m]) at time(s) t [s] (clamped to [0, duration]): the
        ``segment`` and ``arc_length`` of :meth:`reference`, the same numbers, without the poses."""
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        if tt.ndim != 1 or not np.all(np.isfinite(tt)):
            raise IsoPathError(f"IsoTestPath.progress t: expected finite times in s, got {t!r}")
        tt = np.clip(tt, 0.0, self.duration)
        idx = self.segment_at(tt)
        arc = np.empty(tt.size)
        for k in np.unique(idx):
            seg = self.segments[k]
            mask = idx == k
            arc[mask] = seg.arc_start + seg.law.evaluate(tt[mask] - seg.t_start)[0]
        return idx, arc

    def cartesian_trajectory(self, dt: float = 1e-3) -> FlangeReference:
        """The reference sampled every ``dt`` s from 0 to the end (last sample exact)."""
        if not (dt > 0.0 and math.isfinite(dt)):
            raise IsoPathError(f"cartesian_trajectory dt: expected a positive time step in s, got {dt!r}")
        return self.reference(uniform_times(0.0, self.duration, dt))

    def joint_trajectory(self, dt: float = 1e-3, dynamics: Any = None, q_hint: ArrayLike = ISO_Q_HINT,
                         n_grid: int = 401) -> Trajectory:
        """The test path as a joint :class:`Trajectory` sampled every ``dt`` s.

        Each segment is mapped to a joint path by :func:`planners.paths.joint_path`
        (warm-started from the previous segment's end, ``q_hint`` for the first), then
        q_dot = q' sigma_dot, q_ddot = q' sigma_ddot + q'' sigma_dot^2; torques by
        ``dynamics.inverse_dynamics`` (default: the nominal robot.dynamics.RobotDynamics).
        Cartesian columns x, y, z, speed, segment and arc_length are attached.
        """
        from robot.dynamics import RobotDynamics

        dyn = dynamics or RobotDynamics()
        started = time.perf_counter()
        ref = self.cartesian_trajectory(dt)
        q = np.empty((ref.t.size, 6))
        qd = np.empty_like(q)
        qdd = np.empty_like(q)
        seed = np.asarray(q_hint, dtype=float)
        for seg in self.segments:
            jp = joint_path(seg.path, seed, n_grid=n_grid)
            seed = jp.end
            mask = ref.segment == seg.index
            s, sd, sdd = seg.law.evaluate(ref.t[mask] - seg.t_start)
            length = seg.law.length
            qq, dq, ddq, _ = jp.evaluate(np.clip(s / length, 0.0, 1.0))
            q[mask] = qq
            qd[mask] = dq * (sd / length)[:, None]
            qdd[mask] = dq * (sdd / length)[:, None] + ddq * ((sd / length) ** 2)[:, None]
        tau = np.array([dyn.inverse_dynamics(q[k], qd[k], qdd[k]) for k in range(q.shape[0])])
        cart = {"x": ref.position[:, 0], "y": ref.position[:, 1], "z": ref.position[:, 2], "speed": ref.speed,
                "segment": ref.segment.astype(float), "arc_length": ref.arc_length}
        meta = {"planner": "iso9283", "status": "feasible", "solve_time_s": time.perf_counter() - started,
                "segments": self.segment_names}
        return Trajectory(ref.t, q, qd, qdd, tau, cart, meta)


def diagonal_plane_frame(center: ArrayLike, edge: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corners C1..C4 (4, 3) m of the diagonal test plane and its unit axes e_u (along
    y, C1 -> C2) and e_v (C2 -> C3, down and away from the robot)."""
    c = np.asarray(center, dtype=float)
    h = 0.5 * edge
    corners = c + np.array([[-h, -h, h], [-h, h, h], [h, h, -h], [h, -h, -h]])
    e_u = np.array([0.0, 1.0, 0.0])
    e_v = (corners[2] - corners[1]) / np.linalg.norm(corners[2] - corners[1])
    return corners, e_u, e_v


def iso9283_test_path(
    center: ArrayLike = ISO_CUBE_CENTER,
    edge: float = ISO_CUBE_EDGE,
    orientation: ArrayLike = ISO_ORIENTATION_CARDAN,
    speed: float = ISO_SPEED,
    acceleration: float = ISO_ACCELERATION,
) -> IsoTestPath:
    """Build the ISO 9283 test path (module docstring) for a cube ``center`` [m], ``edge`` [m]."""
    c = np.asarray(center, dtype=float)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise IsoPathError(f"center: expected 3 finite coordinates in m, got {center!r}")
    for name, value in (("edge", edge), ("speed", speed), ("acceleration", acceleration)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
            raise IsoPathError(f"{name}: expected a positive finite number, got {value!r}")
    rot = rotation_from_cardan(np.asarray(orientation, dtype=float))
    corners, e_u, e_v = diagonal_plane_frame(c, edge)
    normal = np.cross(e_u, e_v)
    poses = {"P1": c.copy()}
    for k in range(4):
        poses[f"P{k + 2}"] = c + 0.8 * (corners[k] - c)
    r_large = 0.5 * LARGE_CIRCLE_DIAMETER_FRACTION * edge
    r_small = SMALL_CIRCLE_FRACTION * r_large
    start_large = c + r_large * e_u
    start_small = c + r_small * e_u
    p = poses
    elements: list[tuple[str, str, CartesianPath]] = [
        ("rectangle P2-P3", "rectangle", LinePath(p["P2"], p["P3"], rot)),
        ("rectangle P3-P4", "rectangle", LinePath(p["P3"], p["P4"], rot)),
        ("rectangle P4-P5", "rectangle", LinePath(p["P4"], p["P5"], rot)),
        ("rectangle P5-P2", "rectangle", LinePath(p["P5"], p["P2"], rot)),
        ("line P2-P4", "line", LinePath(p["P2"], p["P4"], rot)),
        ("transfer P4-large circle", "transfer", LinePath(p["P4"], start_large, rot)),
        ("circle large", "circle_large",
         CirclePath(c, normal, r_large, rot, start_angle=0.0, start_direction=e_u)),
        ("transfer large-small circle", "transfer", LinePath(start_large, start_small, rot)),
        ("circle small", "circle_small",
         CirclePath(c, normal, r_small, rot, start_angle=0.0, start_direction=e_u)),
        ("transfer small circle-P1", "transfer", LinePath(start_small, c, rot)),
    ]
    segments: list[IsoSegment] = []
    t0 = 0.0
    arc0 = 0.0
    for k, (name, kind, path) in enumerate(elements):
        if isinstance(path, CirclePath):
            a_t = CIRCLE_TANGENTIAL_SHARE * acceleration
            a_n = math.sqrt(1.0 - CIRCLE_TANGENTIAL_SHARE**2) * acceleration
            v = min(speed, math.sqrt(a_n * path.radius))
        else:
            a_t, v = acceleration, speed
        law = SegmentTimeLaw.create(path.length, v, a_t)
        segments.append(IsoSegment(k, name, kind, path, law, t0, arc0))
        t0 += law.duration
        arc0 += law.length
    return IsoTestPath(c, float(edge), rot, corners, poses, segments, float(speed), float(acceleration),
                       {"large_circle_radius_m": r_large, "small_circle_radius_m": r_small,
                        "plane_normal": normal, "plane_axes": (e_u, e_v)})


# -----------------------------------------------------------------------------
# how the cube was chosen


def _cube_sample_points(n_per_edge: int = 11) -> np.ndarray:
    corners = np.array([[i, j, k] for i in (-0.5, 0.5) for j in (-0.5, 0.5) for k in (-0.5, 0.5)])
    edges = [(a, b) for a in range(8) for b in range(a + 1, 8) if np.sum(np.abs(corners[a] - corners[b])) == 1]
    u = np.linspace(0.0, 1.0, n_per_edge)
    pts = [corners[a] + (corners[b] - corners[a]) * u[:, None] for a, b in edges]
    return np.vstack(pts + [np.zeros((1, 3))])


def cube_is_workable(center: ArrayLike, edge: float, orientation: ArrayLike = ISO_ORIENTATION_CARDAN,
                     branch: int = ISO_IK_BRANCH, joint_margin: float = CUBE_JOINT_MARGIN,
                     min_singular_value: float = CUBE_MIN_SINGULAR_VALUE) -> bool:
    """True when the cube's edges and centre meet the criteria of the module docstring."""
    from robot.inverse_kinematics import AnalyticIK

    ik = AnalyticIK()
    kin = ik.kinematics
    rot = rotation_from_cardan(np.asarray(orientation, dtype=float))
    pts = np.asarray(center, dtype=float) + edge * _cube_sample_points()
    q, valid = ik.solve_batch(pts, np.repeat(rot[None], len(pts), axis=0))
    if not np.all(valid[:, branch]):
        return False
    qb = q[:, branch]
    margin = np.minimum(qb - kin.lower, kin.upper - qb)[:, [1, 2, 4]]
    if margin.min() < joint_margin:
        return False
    smin = np.linalg.svd(kin.jacobians(qb), compute_uv=False)[:, -1]
    return bool(smin.min() >= min_singular_value)


def largest_cube_edge(center: ArrayLike, orientation: ArrayLike = ISO_ORIENTATION_CARDAN,
                      upper: float = 1.6, iterations: int = 12) -> float:
    """Largest workable cube edge [m] at ``center`` by bisection (0 if none)."""
    if not cube_is_workable(center, 0.05, orientation):
        return 0.0
    lo, hi = 0.05, upper
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        if cube_is_workable(center, mid, orientation):
            lo = mid
        else:
            hi = mid
    return lo


def search_largest_cube(orientation: ArrayLike = ISO_ORIENTATION_CARDAN,
                        x_range: tuple[float, float] = (0.5, 1.5), z_range: tuple[float, float] = (-0.3, 1.6),
                        step: float = 0.05) -> tuple[np.ndarray, float]:
    """Grid search (y = 0) for the centre [m] with the largest workable cube edge [m]."""
    best = (np.zeros(3), 0.0)
    for x in np.arange(x_range[0], x_range[1] + 1e-9, step):
        for z in np.arange(z_range[0], z_range[1] + 1e-9, step):
            center = np.array([x, 0.0, z])
            edge = largest_cube_edge(center, orientation)
            if edge > best[1]:
                best = (center, edge)
    return best
