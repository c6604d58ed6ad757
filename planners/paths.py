"""Geometric Cartesian paths of the flange and their mapping to joint paths.

A :class:`CartesianPath` describes the ``tool0`` (flange) pose in ``base_link`` as a
function of the path parameter sigma in [0, 1] (the paper's z_E(sigma), eq. 31),
together with its first and second sigma-derivatives:

* position p(sigma) [m], p'(sigma) [m], p''(sigma) [m];
* rotation R(sigma), the angular rate per unit sigma w(sigma) = (R' R^T)^vee [rad]
  and its derivative w'(sigma) [rad], all in base-frame axes.

The twist derivative x' = (p', w') and x'' = (p'', w') feed the joint-path
derivatives (eq. 33-35): with the geometric Jacobian J(q) of robot.kinematics,

    q'  = J^-1 x'
    q'' = J^-1 (x'' - Jdot(q, q') q')

where Jdot(q, q') q' is the classical flange acceleration for joint velocity q' and
zero joint acceleration. :func:`joint_path` solves the inverse kinematics on a sigma
grid (warm-started, one consistent branch) and returns a :class:`JointPath` that
evaluates q, q', q'', q''' at any sigma (quintic Hermite in sigma through the grid
values; q''' from differences of the exact q'').

Paths: :class:`LinePath` (eq. 39: straight line, constant or slerped orientation),
:class:`CirclePath`, :class:`SplinePath` (C2 cubic spline through waypoints),
:class:`CompositePath` (segments in sequence, sigma split by length) and
:func:`rectangle_path` (four lines with sharp corners).
"""
from __future__ import annotations

import abc
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from robot.inverse_kinematics import AnalyticIK, UnreachablePoseError
from robot.kinematics import FlangeKinematics, KinematicsInputError, as_rotation_matrix, rotation_from_cardan
from robot.joints import N_JOINTS


class PathError(ValueError):
    """A path definition or a path request is malformed."""


class PathUnreachableError(PathError, UnreachablePoseError):
    """A path point is out of the arm's reach (or outside the joint limits)."""


class PathSingularError(PathError):
    """The path crosses (or comes too close to) a kinematic singularity."""


# -----------------------------------------------------------------------------
# Cartesian paths


@dataclass(frozen=True)
class PathPoints:
    """Flange path samples at ``sigma`` (n,): see module docstring for meaning and units.

    position, d_position, dd_position: (n, 3) m; rotation: (n, 3, 3);
    omega, d_omega: (n, 3) rad (angular rate per unit sigma and its sigma-derivative).
    """

    sigma: np.ndarray
    position: np.ndarray
    d_position: np.ndarray
    dd_position: np.ndarray
    rotation: np.ndarray
    omega: np.ndarray
    d_omega: np.ndarray

    @property
    def twist_derivative(self) -> np.ndarray:
        """x' = (p', w') of shape (n, 6)."""
        return np.concatenate([self.d_position, self.omega], axis=1)

    @property
    def twist_second_derivative(self) -> np.ndarray:
        """x'' = (p'', w') of shape (n, 6)."""
        return np.concatenate([self.dd_position, self.d_omega], axis=1)

    @property
    def transforms(self) -> np.ndarray:
        out = np.zeros((self.sigma.size, 4, 4))
        out[:, :3, :3] = self.rotation
        out[:, :3, 3] = self.position
        out[:, 3, 3] = 1.0
        return out


def _as_point(value: ArrayLike, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise PathError(f"{name}: expected 3 finite coordinates in m, got {np.asarray(value).tolist()!r}")
    return arr


def _as_rotation(value: ArrayLike, name: str) -> np.ndarray:
    """A 3x3 rotation matrix, or Cardan angles (alpha, beta, gamma) in rad."""
    arr = np.asarray(value, dtype=float)
    if arr.shape == (3,):
        return rotation_from_cardan(arr)
    try:
        return as_rotation_matrix(arr, name=name)
    except ValueError as exc:
        raise PathError(f"{name}: expected a 3x3 rotation matrix or 3 Cardan angles in rad: {exc}") from exc


def _as_sigma(sigma: ArrayLike) -> np.ndarray:
    s = np.atleast_1d(np.asarray(sigma, dtype=float))
    if s.ndim != 1 or not np.all(np.isfinite(s)) or np.any(s < -1e-12) or np.any(s > 1 + 1e-12):
        raise PathError(f"sigma: expected values in [0, 1], got min {np.min(s)!r}, max {np.max(s)!r}")
    return np.clip(s, 0.0, 1.0)


class CartesianPath(abc.ABC):
    """A flange pose path sigma in [0, 1] -> pose (see module docstring)."""

    @abc.abstractmethod
    def evaluate(self, sigma: ArrayLike) -> PathPoints:
        """Samples of the path and its sigma-derivatives at ``sigma`` (values in [0, 1])."""

    @property
    @abc.abstractmethod
    def length(self) -> float:
        """Length of the position curve in m."""

    @property
    def corners(self) -> np.ndarray:
        """Sigma values where the path has a sharp corner (direction jumps), ascending."""
        return np.zeros(0)

    def segment_index(self, sigma: ArrayLike) -> np.ndarray:
        """Index of the segment that holds each sigma (0 for a single-segment path)."""
        return np.zeros(np.size(sigma), dtype=int)


class _Orientation:
    """Constant orientation, or slerp from R0 to R1 at a constant rate along sigma."""

    def __init__(self, start: ArrayLike, end: ArrayLike | None, name: str) -> None:
        self.r0 = _as_rotation(start, f"{name} orientation")
        r1 = self.r0 if end is None else _as_rotation(end, f"{name} end orientation")
        self.rotvec = Rotation.from_matrix(r1 @ self.r0.T).as_rotvec()  # base-frame axis * angle

    def evaluate(self, u: np.ndarray, du: np.ndarray, ddu: np.ndarray) -> tuple[np.ndarray, ...]:
        """Rotation, omega and omega' for the slerp fraction u(sigma) and its derivatives."""
        rots = Rotation.from_rotvec(u[:, None] * self.rotvec[None, :]).as_matrix() @ self.r0
        return rots, du[:, None] * self.rotvec[None, :], ddu[:, None] * self.rotvec[None, :]


class LinePath(CartesianPath):
    """Straight line p0 -> p1 [m] at constant speed in sigma (paper eq. 39).

    ``orientation``: 3x3 rotation or Cardan angles (rad) of the flange, held constant
    unless ``end_orientation`` is given (then slerped along sigma).
    """

    def __init__(self, start: ArrayLike, end: ArrayLike, orientation: ArrayLike,
                 end_orientation: ArrayLike | None = None) -> None:
        self.start = _as_point(start, "LinePath start")
        self.end = _as_point(end, "LinePath end")
        if np.linalg.norm(self.end - self.start) < 1e-9 and end_orientation is None:
            raise PathError(f"LinePath: start and end coincide ({self.start.tolist()}), expected distinct points")
        self._orientation = _Orientation(orientation, end_orientation, "LinePath")

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end - self.start))

    def evaluate(self, sigma: ArrayLike) -> PathPoints:
        s = _as_sigma(sigma)
        delta = self.end - self.start
        pos = self.start + s[:, None] * delta
        rot, om, dom = self._orientation.evaluate(s, np.ones_like(s), np.zeros_like(s))
        return PathPoints(s, pos, np.tile(delta, (s.size, 1)), np.zeros_like(pos), rot, om, dom)


class CirclePath(CartesianPath):
    """Circle (or arc) about ``center`` [m] in the plane normal to ``normal``.

    The point at angle phi is center + radius (cos phi e1 + sin phi e2), where e1 is
    ``start_direction`` projected into the plane (default: the base x axis, or y if x
    is normal to the plane) and e2 = normal x e1. phi runs from ``start_angle`` by
    ``sweep`` rad (default a full turn, counter-clockwise about ``normal``) at
    constant speed in sigma. Orientation constant.
    """

    def __init__(self, center: ArrayLike, normal: ArrayLike, radius: float, orientation: ArrayLike,
                 start_angle: float = 0.0, sweep: float = 2.0 * math.pi,
                 start_direction: ArrayLike | None = None) -> None:
        self.center = _as_point(center, "CirclePath center")
        n = _as_point(normal, "CirclePath normal")
        if np.linalg.norm(n) < 1e-12:
            raise PathError("CirclePath normal: expected a non-zero vector")
        self.normal = n / np.linalg.norm(n)
        if not (math.isfinite(radius) and radius > 0.0):
            raise PathError(f"CirclePath radius: expected a positive length in m, got {radius!r}")
        if not (math.isfinite(sweep) and sweep != 0.0):
            raise PathError(f"CirclePath sweep: expected a non-zero angle in rad, got {sweep!r}")
        self.radius = float(radius)
        self.start_angle = float(start_angle)
        self.sweep = float(sweep)
        ref = np.array([1.0, 0.0, 0.0]) if start_direction is None else _as_point(start_direction, "start_direction")
        e1 = ref - self.normal * (ref @ self.normal)
        if np.linalg.norm(e1) < 1e-6:
            if start_direction is not None:
                raise PathError("CirclePath start_direction: expected a direction not parallel to the normal")
            ref = np.array([0.0, 1.0, 0.0])
            e1 = ref - self.normal * (ref @ self.normal)
        self.e1 = e1 / np.linalg.norm(e1)
        self.e2 = np.cross(self.normal, self.e1)
        self._orientation = _Orientation(orientation, None, "CirclePath")

    @property
    def length(self) -> float:
        return abs(self.sweep) * self.radius

    def evaluate(self, sigma: ArrayLike) -> PathPoints:
        s = _as_sigma(sigma)
        phi = self.start_angle + self.sweep * s
        c, si = np.cos(phi)[:, None], np.sin(phi)[:, None]
        r, w = self.radius, self.sweep
        pos = self.center + r * (c * self.e1 + si * self.e2)
        dpos = r * w * (-si * self.e1 + c * self.e2)
        ddpos = -r * w * w * (c * self.e1 + si * self.e2)
        rot, om, dom = self._orientation.evaluate(s, np.zeros_like(s), np.zeros_like(s))
        return PathPoints(s, pos, dpos, ddpos, rot, om, dom)


class SplinePath(CartesianPath):
    """C2 cubic spline through ``waypoints`` (k, 3) [m], parameterised by chord length.

    sigma is the normalised cumulative chord length (not exactly arc length);
    ``bc_type`` as scipy's CubicSpline ("natural", "not-a-knot", "clamped").
    Orientation constant, or slerped along sigma with ``end_orientation``.
    """

    def __init__(self, waypoints: ArrayLike, orientation: ArrayLike,
                 end_orientation: ArrayLike | None = None, bc_type: str = "natural") -> None:
        pts = np.asarray(waypoints, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 2 or not np.all(np.isfinite(pts)):
            raise PathError(f"SplinePath waypoints: expected (k >= 2, 3) finite points in m, got shape {pts.shape}")
        chords = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        if np.any(chords < 1e-9):
            raise PathError("SplinePath waypoints: consecutive waypoints must differ")
        knots = np.concatenate([[0.0], np.cumsum(chords)])
        self.waypoints = pts
        self.knots = knots / knots[-1]
        from scipy.interpolate import CubicSpline  # imported where used: the line and circle paths need none

        self._spline = CubicSpline(self.knots, pts, bc_type=bc_type)
        fine = np.linspace(0.0, 1.0, 2001)
        speed = np.linalg.norm(self._spline(fine, 1), axis=1)
        self._length = float(np.sum(0.5 * (speed[1:] + speed[:-1]) * np.diff(fine)))
        self._orientation = _Orientation(orientation, end_orientation, "SplinePath")

    @property
    def length(self) -> float:
        return self._length

    def evaluate(self, sigma: ArrayLike) -> PathPoints:
        s = _as_sigma(sigma)
        rot, om, dom = self._orientation.evaluate(s, np.ones_like(s), np.zeros_like(s))
        return PathPoints(s, self._spline(s), self._spline(s, 1), self._spline(s, 2), rot, om, dom)


class CompositePath(CartesianPath):
    """Segments traversed one after the other; sigma is split in proportion to length.

    Consecutive segments must meet (end of one = start of the next within 1e-6 m and
    1e-6 rad). Where the direction jumps the path has a sharp corner (see ``corners``);
    a CP time law must stop there (sigma-dot = 0).
    """

    def __init__(self, segments: Sequence[CartesianPath]) -> None:
        if len(segments) == 0:
            raise PathError("CompositePath segments: expected at least one segment")
        self.segments = list(segments)
        lengths = np.array([seg.length for seg in self.segments])
        if np.any(lengths <= 0.0):
            raise PathError(f"CompositePath segments: expected positive lengths, got {lengths.tolist()}")
        self.breaks = np.concatenate([[0.0], np.cumsum(lengths) / lengths.sum()])
        self._length = float(lengths.sum())
        corners = []
        for k in range(1, len(self.segments)):
            a = self.segments[k - 1].evaluate([1.0])
            b = self.segments[k].evaluate([0.0])
            gap = np.linalg.norm(a.position[0] - b.position[0])
            turn = np.linalg.norm(Rotation.from_matrix(a.rotation[0] @ b.rotation[0].T).as_rotvec())
            if gap > 1e-6 or turn > 1e-6:
                raise PathError(
                    f"CompositePath: segment {k - 1} ends {gap:.3g} m / {turn:.3g} rad away from the start "
                    f"of segment {k}, expected them to meet"
                )
            ta = a.d_position[0] / np.linalg.norm(a.d_position[0])
            tb = b.d_position[0] / np.linalg.norm(b.d_position[0])
            if np.linalg.norm(ta - tb) > 1e-6:
                corners.append(self.breaks[k])
        self._corners = np.array(corners)

    @property
    def length(self) -> float:
        return self._length

    @property
    def corners(self) -> np.ndarray:
        return self._corners

    def segment_index(self, sigma: ArrayLike) -> np.ndarray:
        s = _as_sigma(sigma)
        return np.clip(np.searchsorted(self.breaks, s, side="right") - 1, 0, len(self.segments) - 1)

    def evaluate(self, sigma: ArrayLike) -> PathPoints:
        s = _as_sigma(sigma)
        idx = self.segment_index(s)
        n = s.size
        out = {k: np.empty((n, 3)) for k in ("position", "d_position", "dd_position", "omega", "d_omega")}
        rot = np.empty((n, 3, 3))
        for k in np.unique(idx):
            mask = idx == k
            width = self.breaks[k + 1] - self.breaks[k]
            local = np.clip((s[mask] - self.breaks[k]) / width, 0.0, 1.0)
            pts = self.segments[k].evaluate(local)
            out["position"][mask] = pts.position
            out["d_position"][mask] = pts.d_position / width
            out["dd_position"][mask] = pts.dd_position / width**2
            out["omega"][mask] = pts.omega / width
            out["d_omega"][mask] = pts.d_omega / width**2
            rot[mask] = pts.rotation
        return PathPoints(s, out["position"], out["d_position"], out["dd_position"], rot, out["omega"], out["d_omega"])


def rectangle_path(corner: ArrayLike, edge_a: ArrayLike, edge_b: ArrayLike, orientation: ArrayLike) -> CompositePath:
    """Rectangle with sharp corners: corner -> +edge_a -> +edge_b -> -edge_a -> back [m].

    ``edge_a`` and ``edge_b`` are the two edge vectors (m) from ``corner``; they must be
    orthogonal. Four :class:`LinePath` segments at constant ``orientation``.
    """
    c = _as_point(corner, "rectangle corner")
    a = _as_point(edge_a, "rectangle edge_a")
    b = _as_point(edge_b, "rectangle edge_b")
    if min(np.linalg.norm(a), np.linalg.norm(b)) < 1e-9:
        raise PathError("rectangle edges: expected non-zero edge vectors")
    if abs(a @ b) > 1e-9 * np.linalg.norm(a) * np.linalg.norm(b):
        raise PathError(f"rectangle edges: expected orthogonal edge vectors, got {a.tolist()} and {b.tolist()}")
    pts = [c, c + a, c + a + b, c + b, c]
    return CompositePath([LinePath(pts[k], pts[k + 1], orientation) for k in range(4)])


# -----------------------------------------------------------------------------
# joint paths

DEFAULT_GRID_POINTS = 1001
"""Sigma grid of the inverse kinematics in :func:`joint_path` (quintic Hermite between)."""
DEFAULT_SINGULAR_TOLERANCE = 5e-3
"""Smallest accepted singular value of the geometric Jacobian along a path [m or rad
per rad]. Near the wrist singularity of this arm it is about 0.5 |q5|, so 5e-3
rejects paths that come closer than about 0.6 deg to q5 = 0."""
IK_TOLERANCE = 1e-10
"""Newton tolerance on the pose error [m and rad] of the grid points."""


@dataclass(frozen=True)
class JointPath:
    """Joint path q(sigma) of a Cartesian path, with sigma-derivatives (eq. 33-35).

    Grid values (``sigma`` (m,), ``q``, ``dq``, ``ddq``, ``dddq`` (m, 6): rad per
    sigma^k) are exact IK / Jacobian values except ``dddq`` (central differences of
    ``ddq``). :meth:`evaluate` interpolates with quintic Hermite polynomials in sigma.
    ``min_singular_value`` is the smallest singular value of J along the grid and
    ``cartesian`` the Cartesian path it came from (None for a path given in joints).
    """

    sigma: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    dddq: np.ndarray
    min_singular_value: float = math.nan
    cartesian: CartesianPath | None = None

    def evaluate(self, sigma: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(q, q', q'', q''') at ``sigma`` (values in [0, 1]); arrays (n, 6)."""
        from planners.trajectory import _quintic_hermite

        s = _as_sigma(sigma)
        i = np.clip(np.searchsorted(self.sigma, s, side="right") - 1, 0, self.sigma.size - 2)
        h = (self.sigma[i + 1] - self.sigma[i])[:, None]
        u = ((s - self.sigma[i]) / h[:, 0])[:, None]
        q, dq, ddq = _quintic_hermite(self.q[i], self.dq[i] * h, self.ddq[i] * h**2,
                                      self.q[i + 1], self.dq[i + 1] * h, self.ddq[i + 1] * h**2, u)
        dddq = self.dddq[i] + u * (self.dddq[i + 1] - self.dddq[i])
        return q, dq / h, ddq / h**2, dddq

    @property
    def start(self) -> np.ndarray:
        return self.q[0].copy()

    @property
    def end(self) -> np.ndarray:
        return self.q[-1].copy()

    @classmethod
    def from_samples(cls, sigma: ArrayLike, q: ArrayLike) -> "JointPath":
        """A joint path from joint samples q(sigma) (e.g. a PtP geometry), by a C2 spline."""
        s = np.asarray(sigma, dtype=float)
        qq = np.asarray(q, dtype=float)
        if s.ndim != 1 or s.size < 2 or abs(s[0]) > 1e-12 or abs(s[-1] - 1.0) > 1e-12 or np.any(np.diff(s) <= 0):
            raise PathError("JointPath.from_samples sigma: expected increasing values from 0 to 1")
        if qq.shape != (s.size, N_JOINTS) or not np.all(np.isfinite(qq)):
            raise PathError(f"JointPath.from_samples q: expected shape ({s.size}, 6) finite, got {qq.shape}")
        from scipy.interpolate import CubicSpline

        spline = CubicSpline(s, qq, bc_type="not-a-knot" if s.size > 3 else "natural")
        return cls(s, qq, spline(s, 1), spline(s, 2), spline(s, 3))


def _newton_ik(kin: FlangeKinematics, target: np.ndarray, q0: np.ndarray, max_iter: int = 30,
               max_step: float = 0.5) -> tuple[np.ndarray, float]:
    """Damped Newton on the pose error; returns (q, final error norm)."""
    q = q0.copy()
    err = np.inf
    for _ in range(max_iter):
        actual = kin.placement(q)
        e = np.concatenate([target[:3, 3] - actual.translation,
                            pin.log3(target[:3, :3] @ actual.rotation.T)])  # = robot.kinematics.pose_error
        err = float(np.linalg.norm(e))
        if err < IK_TOLERANCE:
            break
        jac = kin.jacobian(q)
        dq = np.linalg.lstsq(jac, e, rcond=1e-10)[0]
        norm = np.linalg.norm(dq)
        if norm > max_step:
            dq *= max_step / norm
        q = q + dq
    return q, err


def _twist_rate(kin: FlangeKinematics, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """Jdot(q, dq) dq: classical flange acceleration (linear, angular) for qdd = 0."""
    model, data = kin.model, kin.data
    pin.forwardKinematics(model, data, q, dq, np.zeros(N_JOINTS))
    acc = pin.getFrameClassicalAcceleration(model, data, kin.frame_id, pin.LOCAL_WORLD_ALIGNED)
    return np.concatenate([acc.linear, acc.angular])


def solve_start_configuration(path: CartesianPath, q_hint: ArrayLike,
                              kinematics: FlangeKinematics | None = None) -> np.ndarray:
    """Joint angles [rad] of the path start on the IK branch nearest ``q_hint`` (6,).

    Uses robot.inverse_kinematics.AnalyticIK on the nominal arm (all branches, the
    nearest to the hint), damped Newton from the hint on other models.
    """
    kin = kinematics or FlangeKinematics()
    start = path.evaluate([0.0])
    hint = np.asarray(q_hint, dtype=float)
    if hint.shape != (N_JOINTS,) or not np.all(np.isfinite(hint)):
        raise PathError(f"q_start: expected 6 finite joint angles in rad, got {np.asarray(q_hint).tolist()!r}")
    try:
        analytic = AnalyticIK(kin.model)
    except KinematicsInputError:
        analytic = None
    if analytic is not None:
        try:
            return analytic.nearest(start.transforms[0], hint)
        except UnreachablePoseError as exc:
            raise PathUnreachableError(f"path start {_where(0.0, start.position[0])}: {exc}") from exc
    q, err = _newton_ik(kin, start.transforms[0], hint, max_iter=200, max_step=0.2)
    if err > 1e-8:
        raise PathUnreachableError(
            f"path start {_where(0.0, start.position[0])}: inverse kinematics did not converge from "
            f"q_start {np.round(hint, 3).tolist()} (pose error {err:.3g}); the pose is out of reach or the "
            "hint is on no branch that reaches it"
        )
    return q


def _batch_pose_error(targets: np.ndarray, actual: np.ndarray) -> np.ndarray:
    """pose_error of robot.kinematics for batches (n, 4, 4): (n, 6) [m, rad]."""
    d_rot = targets[:, :3, :3] @ np.swapaxes(actual[:, :3, :3], 1, 2)
    return np.concatenate([targets[:, :3, 3] - actual[:, :3, 3], Rotation.from_matrix(d_rot).as_rotvec()], axis=1)


def joint_path(path: CartesianPath, q_start: ArrayLike, n_grid: int = DEFAULT_GRID_POINTS,
               kinematics: FlangeKinematics | None = None,
               singular_tolerance: float = DEFAULT_SINGULAR_TOLERANCE,
               check_limits: bool = True, n_track: int = 101) -> JointPath:
    """Map a Cartesian path to a joint path by inverse kinematics on a sigma grid.

    ``q_start`` (6,) [rad] selects the branch: the first point is solved from it (see
    :func:`solve_start_configuration`); ``n_track`` points are then tracked one after
    the other, each warm-started from the previous one plus q' dsigma, so the path
    stays on one branch; the ``n_grid`` points are finally refined together by batched
    Newton steps from the Hermite interpolation of the tracked points. Raises
    PathUnreachableError when a point is out of reach or outside the joint limits,
    PathSingularError when the smallest singular value of J drops below
    ``singular_tolerance`` or the branch jumps. q' and q'' come from the Jacobian
    (module docstring), the third derivative from central differences of q''.
    """
    kin = kinematics or FlangeKinematics()
    if int(n_grid) < 3 or int(n_track) < 3:
        raise PathError(f"n_grid, n_track: expected integers >= 3, got {n_grid!r}, {n_track!r}")
    # 1) sequential tracking on a coarse grid (branch continuity)
    coarse = np.linspace(0.0, 1.0, int(n_track))
    cpts = path.evaluate(coarse)
    ctargets = cpts.transforms
    qc = np.empty((coarse.size, N_JOINTS))
    dqc = np.empty((coarse.size, N_JOINTS))
    q_prev = solve_start_configuration(path, q_start, kin)
    dq_prev = np.zeros(N_JOINTS)
    step = coarse[1] - coarse[0]
    for k in range(coarse.size):
        guess = q_prev + dq_prev * (step if k else 0.0)
        qk, err = _newton_ik(kin, ctargets[k], guess, max_step=0.2)
        _check_point(kin, coarse[k], cpts.position[k], qk, err, singular_tolerance, check_limits)
        jump = float(np.max(np.abs(qk - guess)))
        if k and jump > max(0.05, 10.0 * step * np.max(np.abs(dq_prev))):
            raise PathSingularError(
                f"path point at {_where(coarse[k], cpts.position[k])}: the inverse kinematics branch jumps by "
                f"{jump:.3g} rad; the path passes (too) close to a singularity"
            )
        dq_prev = np.linalg.solve(kin.jacobian(qk), cpts.twist_derivative[k])
        qc[k], dqc[k] = qk, dq_prev
        q_prev = qk
    # 2) batched Newton on the fine grid from the Hermite interpolation of the tracked points
    sigma = np.linspace(0.0, 1.0, int(n_grid))
    pts = path.evaluate(sigma)
    targets = pts.transforms
    from scipy.interpolate import CubicHermiteSpline  # imported where used (not by the Cartesian paths)

    guess = CubicHermiteSpline(coarse, qc, dqc)(sigma)
    q = guess.copy()
    for _ in range(10):
        err = _batch_pose_error(targets, kin.transforms(q))
        if np.max(np.abs(err)) < IK_TOLERANCE:
            break
        q = q + np.linalg.solve(kin.jacobians(q), err[:, :, None])[:, :, 0]
    err_norm = np.linalg.norm(_batch_pose_error(targets, kin.transforms(q)), axis=1)
    jac = kin.jacobians(q)
    smin = np.linalg.svd(jac, compute_uv=False)[:, -1]
    moved = np.max(np.abs(q - guess), axis=1)
    for k in np.flatnonzero((err_norm > 1e-8) | (smin < singular_tolerance) | (moved > 0.05)):
        _check_point(kin, sigma[k], pts.position[k], q[k], float(err_norm[k]), singular_tolerance, False)
        raise PathSingularError(
            f"path point at {_where(sigma[k], pts.position[k])}: the inverse kinematics branch jumps by "
            f"{moved[k]:.3g} rad between tracking points; the path passes (too) close to a singularity "
            f"(or raise n_track above {n_track})"
        )
    if check_limits:
        for k in np.flatnonzero(np.any((q < kin.lower) | (q > kin.upper), axis=1))[:1]:
            _check_point(kin, sigma[k], pts.position[k], q[k], 0.0, 0.0, True)
    dq = np.linalg.solve(jac, pts.twist_derivative[:, :, None])[:, :, 0]
    rate = np.array([_twist_rate(kin, q[k], dq[k]) for k in range(sigma.size)])
    ddq = np.linalg.solve(jac, (pts.twist_second_derivative - rate)[:, :, None])[:, :, 0]
    dddq = np.gradient(ddq, sigma, axis=0, edge_order=2)
    return JointPath(sigma, q, dq, ddq, dddq, float(smin.min()), path)


def _where(sigma: float, position: np.ndarray) -> str:
    return f"sigma = {sigma:.4f} (flange at {np.round(position, 4).tolist()} m)"


def _check_point(kin: FlangeKinematics, sigma: float, position: np.ndarray, q: np.ndarray, err: float,
                 singular_tolerance: float, check_limits: bool) -> None:
    where = _where(sigma, position)
    if err > 1e-8:
        raise PathUnreachableError(
            f"path point at {where}: inverse kinematics did not converge (pose error {err:.3g}); "
            "the point is out of reach at the required orientation"
        )
    smin = float(np.linalg.svd(kin.jacobian(q), compute_uv=False)[-1])
    if smin < singular_tolerance:
        raise PathSingularError(
            f"path point at {where}: the arm is singular at q = {np.round(q, 4).tolist()} rad "
            f"(smallest singular value of J {smin:.3g} < singular_tolerance {singular_tolerance:g}); "
            "the path crosses a singularity at the required orientation"
        )
    if check_limits and (np.any(q < kin.lower) or np.any(q > kin.upper)):
        bad = int(np.argmax((q < kin.lower) | (q > kin.upper)))
        raise PathUnreachableError(
            f"path point at {where}: joint {bad + 1} at {q[bad]:.4f} rad is outside its range "
            f"[{kin.lower[bad]:.4f}, {kin.upper[bad]:.4f}] rad"
        )
