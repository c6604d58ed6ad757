"""Inverse kinematics of the flange: analytic (nominal arm) and numeric (any model).

Targets are flange poses (``tool0`` in ``base_link``) given as a 4x4 homogeneous
transform (m) or a pinocchio ``SE3``; joint vectors are (6,) arrays in rad. Use
:func:`robot.kinematics.transform_from_pose` to build a target from a Cardan pose.

* :class:`AnalyticIK` -- every solution (up to 8) of the nominal spherical-wrist arm:
  wrist centre from the flange pose, two shoulder branches (q1, q1 + pi), two elbow
  branches (+-q3), two wrist branches (+-q5). At the wrist singularity (q5 = 0) only
  q4 + q6 is defined: q4 is then taken from the seed (0 without seed). At the
  shoulder singularity (wrist centre on axis 1) q1 is taken from the seed (0 without).
* :class:`NumericIK` -- Newton / Levenberg-Marquardt on the full pinocchio model
  (nominal or with geometric errors), warm-started from a seed; the 400 us
  controller's IK. A reusable object: it holds its pinocchio Data.

Both raise :class:`UnreachablePoseError` when the pose is out of reach or has no
solution inside the joint limits.
"""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike
from scipy.linalg import lapack

from robot.description import load_model
from robot.kinematics import (
    N_JOINTS,
    ROTATION_TOLERANCE,
    FlangeKinematics,
    KinematicsInputError,
    as_joint_vector,
    as_transform,
)

WRIST_SINGULARITY_TOLERANCE = 1e-10
"""|sin q5| below which the analytic IK treats the wrist as singular (q5 = 0 or pi)."""
SHOULDER_SINGULARITY_TOLERANCE = 1e-10
"""Distance (m) of the wrist centre from axis 1 below which q1 is taken from the seed."""
REACH_TOLERANCE = 1e-10
"""Slack on cos(q3) beyond +-1 (elbow stretched / folded) still treated as reachable."""
LIMIT_TOLERANCE = 1e-12
"""Slack (rad) on the joint position limits when a solution is filtered."""
_GEOMETRY_TOLERANCE = 1e-12
_TWO_PI = 2.0 * math.pi


class UnreachablePoseError(ValueError):
    """The flange pose is out of reach, or no IK solution lies within the joint limits."""


def wrap_angle(angle: ArrayLike) -> np.ndarray:
    """Angles (rad) wrapped into (-pi, pi]."""
    a = np.asarray(angle, dtype=float)
    return np.pi - np.mod(np.pi - a, _TWO_PI)


def _target_arrays(target: ArrayLike | pin.SE3, name: str = "target") -> tuple[np.ndarray, np.ndarray]:
    t = as_transform(target, name=name)
    return t[:3, 3].copy(), t[:3, :3].copy()


def closest_equivalent(
    q: np.ndarray, seed: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> np.ndarray:
    """Per joint, the angle ``q + 2 pi k`` within [lower, upper] closest to ``seed``.

    ``q`` has shape (..., 6); joints with no shifted copy inside the limits keep ``q``.
    """
    k = np.round((seed - q) / _TWO_PI)
    best = q + k * _TWO_PI
    for step in (-1.0, 1.0):  # the rounded shift may fall just outside the limits
        alt = best + step * _TWO_PI
        inside_best = (best >= lower - LIMIT_TOLERANCE) & (best <= upper + LIMIT_TOLERANCE)
        inside_alt = (alt >= lower - LIMIT_TOLERANCE) & (alt <= upper + LIMIT_TOLERANCE)
        best = np.where(inside_alt & ~inside_best, alt, best)
    inside = (best >= lower - LIMIT_TOLERANCE) & (best <= upper + LIMIT_TOLERANCE)
    return np.where(inside, best, q)


def _nearest_row(solutions: np.ndarray, seed: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    shifted = closest_equivalent(solutions, seed, lower, upper)
    distance = np.sum((shifted - seed) ** 2, axis=1)
    return shifted[int(np.argmin(distance))].copy()


# ---------------------------------------------------------------------------
# analytic IK of the nominal arm


class AnalyticIK:
    """Closed-form IK of the nominal spherical-wrist arm (no error parameters).

    The geometry is read from ``model`` (default: the nominal URDF): it must be the
    arm's nominal structure (axes z, y, y, z, y, z; all joint origins on the local z
    axis, no rotations), otherwise KinematicsInputError is raised -- use
    :class:`NumericIK` for models with geometric errors.
    """

    def __init__(self, model: pin.Model | None = None) -> None:
        self.model: pin.Model = load_model() if model is None else model
        self.kinematics = FlangeKinematics(self.model)
        self.lower = self.kinematics.lower
        self.upper = self.kinematics.upper
        offsets = self._check_nominal_structure()
        self.shoulder_height = offsets[0] + offsets[1]  # base to axis 2 (m)
        self.upper_arm = offsets[2]  # axis 2 to axis 3 (m)
        self.forearm = offsets[3] + offsets[4]  # axis 3 to wrist centre (m)
        self.wrist_to_flange = offsets[5] + offsets[6]  # wrist centre to flange (m)

    def _check_nominal_structure(self) -> list[float]:
        kin = self.kinematics
        expected_axes = np.array([[0, 0, 1], [0, 1, 0], [0, 1, 0], [0, 0, 1], [0, 1, 0], [0, 0, 1]])
        rotations = list(kin._placement_rotations) + [kin._flange_rotation]
        translations = list(kin._placement_translations) + [kin._flange_translation]
        ok = np.allclose(kin._axes, expected_axes, atol=_GEOMETRY_TOLERANCE, rtol=0.0)
        ok &= all(np.allclose(r, np.eye(3), atol=_GEOMETRY_TOLERANCE, rtol=0.0) for r in rotations)
        ok &= all(np.allclose(t[:2], 0.0, atol=_GEOMETRY_TOLERANCE, rtol=0.0) for t in translations)
        if not ok:
            raise KinematicsInputError(
                "argument 'model': analytic IK needs the nominal spherical-wrist geometry (axes "
                "z, y, y, z, y, z, joint origins on the local z axes, no rotations); got a model "
                "with other placements (e.g. geometric errors) -- use NumericIK"
            )
        return [float(t[2]) for t in translations]

    # batched core ----------------------------------------------------------------
    def solve_batch(
        self,
        positions: ArrayLike,
        rotations: ArrayLike,
        seeds: ArrayLike | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """All 8 branches for n flange poses, without any input checks.

        positions (n, 3) m, rotations (n, 3, 3), seeds (n, 6) rad or None (only q1 and
        q4 of the seed are used, at the singularities). Returns ``(q, valid)`` with q of
        shape (n, 8, 6) (angles in (-pi, pi]) and valid (n, 8) bool: reachable, inside
        the joint limits and not a duplicate of an earlier branch. Branch index =
        4 * shoulder + 2 * elbow + wrist (0 = first, 1 = flipped).
        """
        p = np.asarray(positions, dtype=float)
        rot = np.asarray(rotations, dtype=float)
        n = p.shape[0]
        seed = np.zeros((n, N_JOINTS)) if seeds is None else np.asarray(seeds, dtype=float)
        a2, a3 = self.upper_arm, self.forearm

        wrist = p - self.wrist_to_flange * rot[:, :, 2]
        rho = np.hypot(wrist[:, 0], wrist[:, 1])
        q1_first = np.where(
            rho < SHOULDER_SINGULARITY_TOLERANCE,
            wrap_angle(seed[:, 0]),
            np.arctan2(wrist[:, 1], wrist[:, 0]),
        )
        q1 = np.stack([q1_first, wrap_angle(q1_first + np.pi)], axis=1)  # (n, 2)
        r = np.stack([rho, -rho], axis=1)  # signed horizontal distance along q1
        h = wrist[:, 2] - self.shoulder_height
        cos3 = (rho**2 + h**2 - a2**2 - a3**2) / (2.0 * a2 * a3)
        reachable = np.abs(cos3) <= 1.0 + REACH_TOLERANCE
        elbow = np.arccos(np.clip(cos3, -1.0, 1.0))
        q3 = np.stack([elbow, -elbow], axis=1)[:, None, :] * np.ones((1, 2, 1))  # (n, 2, 2)
        q2 = np.arctan2(r, h[:, None])[:, :, None] - np.arctan2(
            a3 * np.sin(q3), a2 + a3 * np.cos(q3)
        )
        q1b = np.broadcast_to(q1[:, :, None], q2.shape)

        # wrist: M = R03^T R with R03 = Rz(q1) Ry(q2 + q3); M = Rz(q4) Ry(q5) Rz(q6)
        c1, s1 = np.cos(q1b), np.sin(q1b)
        c23, s23 = np.cos(q2 + q3), np.sin(q2 + q3)
        r03 = np.empty(q2.shape + (3, 3))
        r03[..., 0, 0] = c1 * c23
        r03[..., 0, 1] = -s1
        r03[..., 0, 2] = c1 * s23
        r03[..., 1, 0] = s1 * c23
        r03[..., 1, 1] = c1
        r03[..., 1, 2] = s1 * s23
        r03[..., 2, 0] = -s23
        r03[..., 2, 1] = 0.0
        r03[..., 2, 2] = c23
        m = np.swapaxes(r03, -1, -2) @ rot[:, None, None, :, :]
        sin5 = np.hypot(m[..., 0, 2], m[..., 1, 2])
        singular = sin5 < WRIST_SINGULARITY_TOLERANCE
        q4_first = np.where(
            singular, wrap_angle(seed[:, 3])[:, None, None], np.arctan2(m[..., 1, 2], m[..., 0, 2])
        )
        q4 = np.stack([q4_first, wrap_angle(q4_first + np.pi)], axis=-1)  # (n, 2, 2, 2)
        q4 = np.where(singular[..., None], q4_first[..., None], q4)
        q5_first = np.arctan2(np.where(singular, 0.0, sin5), m[..., 2, 2])
        q5 = np.stack([q5_first, -q5_first], axis=-1)
        # q6 from the full matrix, so q4 and q6 stay consistent near the singularity
        c4, s4 = np.cos(q4), np.sin(q4)
        c5, s5 = np.cos(q5), np.sin(q5)
        m00, m10, m20 = (m[..., k, 0][..., None] for k in range(3))
        q6 = np.arctan2(-s4 * m00 + c4 * m10, c5 * (c4 * m00 + s4 * m10) - s5 * m20)

        shape = q4.shape  # (n, 2, 2, 2)
        q = np.empty(shape + (N_JOINTS,))
        q[..., 0] = q1[:, :, None, None]
        q[..., 1] = wrap_angle(q2)[..., None]
        q[..., 2] = q3[..., None]
        q[..., 3] = q4
        q[..., 4] = q5
        q[..., 5] = wrap_angle(q6)
        q = q.reshape(n, 8, N_JOINTS)

        valid = np.broadcast_to(reachable[:, None], (n, 8)).copy()
        valid &= np.all(q >= self.lower - LIMIT_TOLERANCE, axis=2)
        valid &= np.all(q <= self.upper + LIMIT_TOLERANCE, axis=2)
        # duplicates: elbow stretched (q3 = 0 twice), wrist singular (flip = same)
        for j in range(1, 8):
            same = np.all(np.abs(q[:, :j, :] - q[:, j : j + 1, :]) < 1e-12, axis=2)
            valid[:, j] &= ~np.any(same & valid[:, :j], axis=1)
        return q, valid

    # single pose -----------------------------------------------------------------
    def solutions(self, target: ArrayLike | pin.SE3, seed: ArrayLike | None = None) -> np.ndarray:
        """All distinct solutions (k, 6) in rad, k <= 8, inside the joint limits.

        Angles are in (-pi, pi] (unless ``seed`` is given: then each joint is the
        2-pi-equivalent inside the limits closest to the seed, and rows are sorted by
        distance to the seed). Raises UnreachablePoseError when k would be 0.
        """
        position, rotation = _target_arrays(target)
        seed_v = None if seed is None else as_joint_vector(seed, "seed")
        q, valid = self.solve_batch(
            position[None], rotation[None], None if seed_v is None else seed_v[None]
        )
        found = q[0][valid[0]]
        if found.shape[0] == 0:
            raise UnreachablePoseError(self._why_unreachable(position, rotation, q[0]))
        if seed_v is None:
            return found
        shifted = closest_equivalent(found, seed_v, self.lower, self.upper)
        order = np.argsort(np.sum((shifted - seed_v) ** 2, axis=1), kind="stable")
        return shifted[order]

    def nearest(self, target: ArrayLike | pin.SE3, seed: ArrayLike) -> np.ndarray:
        """The solution (6,) rad closest to ``seed`` (Euclidean in joint space, taking
        the 2-pi-equivalent of each joint inside the limits)."""
        return self.solutions(target, seed)[0].copy()

    def _why_unreachable(self, position: np.ndarray, rotation: np.ndarray, q: np.ndarray) -> str:
        wrist = position - self.wrist_to_flange * rotation[:, 2]
        shoulder = np.array([0.0, 0.0, self.shoulder_height])
        distance = float(np.linalg.norm(wrist - shoulder))
        lo, hi = abs(self.upper_arm - self.forearm), self.upper_arm + self.forearm
        where = f"flange position {np.round(position, 6).tolist()} m"
        if not lo - REACH_TOLERANCE <= distance <= hi + REACH_TOLERANCE:
            return (
                f"pose out of reach: {where}, wrist centre {distance:.6f} m from the shoulder, "
                f"expected {lo:.3f} ... {hi:.3f} m"
            )
        return (
            f"no IK solution within the joint limits for {where}: the 8 branches "
            f"{np.round(q, 4).tolist()} rad violate limits "
            f"lower={np.round(self.lower, 4).tolist()}, upper={np.round(self.upper, 4).tolist()}"
        )


# ---------------------------------------------------------------------------
# numeric IK on any model


def _is_rotation(rows: list[list[float]]) -> bool:
    """True when the upper-left 3x3 of ``rows`` is orthonormal with det +1 within
    ROTATION_TOLERANCE (plain floats: a few times cheaper than numpy on a 3x3;
    NaN fails every comparison)."""
    (a0, a1, a2, *_), (b0, b1, b2, *_), (c0, c1, c2, *_) = rows[0], rows[1], rows[2]
    tol = ROTATION_TOLERANCE
    det = a0 * (b1 * c2 - b2 * c1) - a1 * (b0 * c2 - b2 * c0) + a2 * (b0 * c1 - b1 * c0)
    return (
        abs(a0 * a0 + a1 * a1 + a2 * a2 - 1.0) <= tol
        and abs(b0 * b0 + b1 * b1 + b2 * b2 - 1.0) <= tol
        and abs(c0 * c0 + c1 * c1 + c2 * c2 - 1.0) <= tol
        and abs(a0 * b0 + a1 * b1 + a2 * b2) <= tol
        and abs(a0 * c0 + a1 * c1 + a2 * c2) <= tol
        and abs(b0 * c0 + b1 * c1 + b2 * c2) <= tol
        and abs(det - 1.0) <= tol
    )


class NumericIK:
    """Warm-started numeric IK of the flange for any pinocchio model of the arm.

    Newton steps on the flange's SE(3) error ``log6(M(q)^-1 M_target)`` with the
    local frame Jacobian (pinocchio), LAPACK ``dgesv`` for the 6x6 solve; a step small
    enough to leave an error far below ``tolerance`` is accepted without another FK
    (see :meth:`_acceptance_bound`). A warm start with seed = last cycle's solution
    takes 2 steps on a 400 us trajectory; the extrapolated seed ``2 q[k-1] - q[k-2]``
    usually takes 1 (``benchmarks/bench_ik.py``). When Newton fails
    (no convergence within ``newton_iterations``, singular Jacobian, solution out of
    the limits) the solver polishes every analytic branch of the nominal arm with
    Levenberg-Marquardt on ``model`` and returns the one nearest to the seed.

    ``tolerance``: convergence when ``|log6|`` (m and rad mixed) <= tolerance; this
    bounds both the flange position error (m) and the rotation error (rad).
    """

    def __init__(
        self,
        model: pin.Model | None = None,
        *,
        tolerance: float = 1e-10,
        newton_iterations: int = 8,
        max_step: float = 0.5,
        lm_iterations: int = 60,
    ) -> None:
        self.model: pin.Model = load_model() if model is None else model
        self.kinematics = FlangeKinematics(self.model)
        self.data: pin.Data = self.kinematics.data
        self.frame_id: int = self.kinematics.frame_id
        self.lower = self.kinematics.lower
        self.upper = self.kinematics.upper
        for name, value in (("tolerance", tolerance), ("max_step", max_step)):
            if not (math.isfinite(value) and value > 0.0):
                raise KinematicsInputError(f"argument {name!r}: expected a number > 0, got {value!r}")
        for name, count in (("newton_iterations", newton_iterations), ("lm_iterations", lm_iterations)):
            if not (isinstance(count, int) and count >= 1):
                raise KinematicsInputError(f"argument {name!r}: expected an int >= 1, got {count!r}")
        self.tolerance = float(tolerance)
        self._tol2 = self.tolerance**2
        self._accept2 = self._acceptance_bound()
        self._max_step2 = float(max_step) ** 2
        self.newton_iterations = newton_iterations
        self.lm_iterations = lm_iterations
        self._analytic: AnalyticIK | None = None
        self._lower_list = (self.lower - LIMIT_TOLERANCE).tolist()
        self._upper_list = (self.upper + LIMIT_TOLERANCE).tolist()
        self.last_iterations = 0
        """Newton steps taken by the last :meth:`solve` (-1: fell back to all branches)."""

    def _acceptance_bound(self) -> float:
        """Squared size below which a Newton step is accepted without a final FK check.

        A Newton step solves ``J dq = e`` with ``e = log6(M^-1 M_target)``, so the flange
        after the step is ``M exp(J dq)`` up to the second-order terms of the product of
        exponentials, ``1/2 sum_ij [xi_i, xi_j] dq_i dq_j``; with joint twists of unit
        axis and lever arm <= ``reach`` this is at most ``6 * reach * |dq|^2`` (the 6
        from ``|dq|_1^2 <= 6 |dq|^2``). Accepting only when ``|dq|^2`` (and ``|e|^2``) is
        below ``0.1 * tolerance / (6 * max(reach, 1 m))`` keeps the remaining error
        below a tenth of ``tolerance``. ``reach`` is the sum of the model's link vectors.
        """
        kin = self.kinematics
        reach = float(
            np.linalg.norm(kin._placement_translations, axis=1).sum()
            + np.linalg.norm(kin._flange_translation)
        )
        return 0.1 * self.tolerance / (6.0 * max(reach, 1.0))

    # input ----------------------------------------------------------------------
    def _as_se3(self, target: ArrayLike | pin.SE3) -> pin.SE3:
        """Target as SE3, checked with plain-float arithmetic (cheap on the hot path);
        anything suspicious goes through :func:`as_transform` for the detailed error."""
        if isinstance(target, pin.SE3):
            rows = target.rotation.tolist()
            if _is_rotation(rows) and math.isfinite(sum(target.translation.tolist())):
                return target
            as_transform(target)  # raises with the detailed message
            return target
        t = np.asarray(target, dtype=float)
        if t.shape == (4, 4):
            rows = t.tolist()
            if (
                _is_rotation(rows)
                and rows[3] == [0.0, 0.0, 0.0, 1.0]
                and math.isfinite(rows[0][3] + rows[1][3] + rows[2][3])
            ):
                return pin.SE3(t)
        t = as_transform(target)
        return pin.SE3(t[:3, :3], t[:3, 3])

    # solving --------------------------------------------------------------------
    def solve(self, target: ArrayLike | pin.SE3, seed: ArrayLike) -> np.ndarray:
        """Joint angles (6,) rad placing the flange at ``target`` (4x4 or SE3, m).

        Newton from ``seed`` (6,) rad; on failure the nearest of all branches (see the
        class doc). Raises UnreachablePoseError when no solution inside the limits
        exists, KinematicsInputError for malformed input.
        """
        goal = self._as_se3(target)
        q = np.array(seed, dtype=float)
        if q.shape != (N_JOINTS,):
            as_joint_vector(seed, "seed")  # raises with the detailed message
        # a non-finite seed makes Newton fail; solve_nearest then reports it
        model, data, fid = self.model, self.data, self.frame_id
        for step in range(self.newton_iterations + 1):
            pin.forwardKinematics(model, data, q)
            err = pin.log6(pin.updateFramePlacement(model, data, fid).actInv(goal)).vector
            err2 = err.dot(err)
            if err2 <= self._tol2:
                if all(lo <= x <= hi for lo, x, hi in zip(self._lower_list, q.tolist(), self._upper_list)):
                    self.last_iterations = step
                    return q
                break
            if step == self.newton_iterations:
                break
            jac = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL)
            _, _, dq, info = lapack.dgesv(jac, err)
            if info != 0:
                break
            if err2 <= self._accept2:
                # quadratic convergence: when both the error and the step are this small,
                # the error after the step is below the tolerance (see _acceptance_bound)
                if dq.dot(dq) <= self._accept2:
                    q += dq
                    if all(lo <= x <= hi for lo, x, hi in zip(self._lower_list, q.tolist(), self._upper_list)):
                        self.last_iterations = step + 1
                        return q
                    break
            elif err2 > 1e-4:  # far from the target (> ~1 cm / 0.6 deg): limit the step
                size2 = dq.dot(dq)
                if size2 > self._max_step2:
                    dq *= math.sqrt(self._max_step2 / size2)
            q += dq
        self.last_iterations = -1
        return self.solve_nearest(goal, seed)

    def solve_all(self, target: ArrayLike | pin.SE3) -> np.ndarray:
        """Every solution (k, 6) of this model, k <= 8, inside the limits: each analytic
        branch of the nominal arm polished with Levenberg-Marquardt on ``model``.
        Raises UnreachablePoseError when there is none."""
        goal = self._as_se3(target)
        analytic = self._analytic_ik()
        position, rotation = np.array(goal.translation), np.array(goal.rotation)
        q, _ = analytic.solve_batch(position[None], rotation[None])
        # start from all 8 branches, also those just outside the limits or the reach
        # of the nominal arm: the model's own solution may lie inside
        found: list[np.ndarray] = []
        for k, start in enumerate(q[0]):
            if any(np.array_equal(start, q[0][j]) for j in range(k)):
                continue
            sol = self._levenberg_marquardt(goal, start)
            if sol is None:
                continue
            sol = closest_equivalent(sol, wrap_angle(sol), self.lower, self.upper)
            if np.any(sol < self.lower - LIMIT_TOLERANCE) or np.any(sol > self.upper + LIMIT_TOLERANCE):
                continue
            if any(np.abs(wrap_angle(sol - other)).max() < 1e-8 for other in found):
                continue
            found.append(sol)
        if not found:
            try:
                analytic.solutions(goal)
            except UnreachablePoseError as exc:
                raise UnreachablePoseError(f"numeric IK: {exc}") from None
            raise UnreachablePoseError(
                f"numeric IK: no solution within the joint limits for flange position "
                f"{np.round(position, 6).tolist()} m"
            )
        return np.array(found)

    def solve_nearest(self, target: ArrayLike | pin.SE3, seed: ArrayLike) -> np.ndarray:
        """The solution (6,) of :meth:`solve_all` nearest to ``seed`` (6,) rad."""
        seed_v = as_joint_vector(seed, "seed")
        return _nearest_row(self.solve_all(target), seed_v, self.lower, self.upper)

    def _analytic_ik(self) -> AnalyticIK:
        if self._analytic is None:
            self._analytic = AnalyticIK()  # nominal arm: start values for any error model
        return self._analytic

    def _jacobian_and_error(self, q: np.ndarray, goal: pin.SE3) -> tuple[np.ndarray, np.ndarray]:
        """Local frame Jacobian (6, 6) and SE(3) error log6(M(q)^-1 M_goal) (6,) at q."""
        model, data, fid = self.model, self.data, self.frame_id
        pin.forwardKinematics(model, data, q)
        err = pin.log6(pin.updateFramePlacement(model, data, fid).actInv(goal)).vector
        return pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL), err

    def _levenberg_marquardt(self, goal: pin.SE3, start: np.ndarray) -> np.ndarray | None:
        q = start.copy()
        damping = 1e-6
        jac, err = self._jacobian_and_error(q, goal)
        cost = err.dot(err)
        for _ in range(self.lm_iterations):
            if cost <= self._tol2:
                return q
            jtj = jac.T @ jac
            dq = np.linalg.solve(jtj + damping * np.diag(np.diag(jtj) + 1e-9), jac.T @ err)
            trial = q + dq
            jac_t, err_t = self._jacobian_and_error(trial, goal)
            cost_t = err_t.dot(err_t)
            if cost_t < cost:
                q, jac, err, cost = trial, jac_t, err_t, cost_t
                damping = max(damping * 0.1, 1e-12)
            else:
                damping *= 10.0
                if damping > 1e6:
                    return None
        return q if cost <= self._tol2 else None
