"""Inverse dynamics for the point-to-point planners: CasADi functions and batched checks.

One object, :class:`PtPDynamics`, turns a ``robot.dynamics.RobotDynamics`` (default: the
nominal arm) and a friction model ("full", "coulomb", "none"; see
``planners.base.CPProblem``) into

* ``torque`` : CasADi ``tau(q, qd, qdd)`` [N m] (the arm's RNEA of ``robot.symbolic``
  with the parameters as constants and the unused friction terms set to zero);
* ``smooth_torque_rate`` : CasADi ``dtau_s/dt(q, qd, qdd, qddd)`` [N m/s], the exact
  time derivative of the torque WITHOUT the Coulomb term along a motion with jerk
  ``qddd``. The Coulomb term ``fc tanh(qd / v_s)`` jumps by 2 fc whenever a joint
  reverses, which no smooth trajectory avoids; ``planners.trajectory.constraint_ratios``
  therefore leaves it out of the torque rate, and so do the planners here;
* batched numeric evaluation (joint arrays of shape (n, 6)) and the constraint ratios
  of a sampled motion, computed like ``planners.trajectory.constraint_ratios`` with
  ``dynamics`` given, but with this friction model and without a Python loop.

Units: rad, rad/s, rad/s^2, rad/s^3, N m, N m/s (joint side).
"""
from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from planners.base import JointLimits, N_JOINTS, PlannerInputError
from robot.dynamics import COULOMB_SLICE, VISCOUS_SLICE, RobotDynamics
from robot.symbolic import numeric_inverse_dynamics_function

FRICTION_MODELS: tuple[str, ...] = ("full", "coulomb", "none")


class PtPDynamics:
    """Inverse dynamics of one arm with one friction model, as CasADi functions and numbers.

    ``dynamics``: a ``robot.dynamics.RobotDynamics`` (None: the nominal arm).
    ``friction``: "full" (viscous + Coulomb), "coulomb" (Coulomb only) or "none".
    """

    def __init__(self, dynamics: RobotDynamics | None = None, friction: str = "full") -> None:
        if friction not in FRICTION_MODELS:
            raise PlannerInputError(f"friction: expected one of {FRICTION_MODELS}, got {friction!r}")
        self.dynamics: RobotDynamics = dynamics if dynamics is not None else _nominal_dynamics()
        self.friction = friction
        p = self.dynamics.parameter_vector()
        if friction in ("coulomb", "none"):
            p[VISCOUS_SLICE] = 0.0
        if friction == "none":
            p[COULOMB_SLICE] = 0.0
        self.parameter_vector: np.ndarray = p
        self.coulomb: np.ndarray = p[COULOMB_SLICE].copy()
        self.smoothing_velocity: float = float(self.dynamics.coulomb_smoothing_velocity)
        self.torque: ca.Function = numeric_inverse_dynamics_function(
            p, np.asarray(self.dynamics.payload), name="ptp_tau")
        q, qd, qdd, qddd = (ca.SX.sym(n, N_JOINTS) for n in ("q", "qd", "qdd", "qddd"))
        tau = self.torque(q, qd, qdd)
        smooth = tau - self.coulomb * ca.tanh(qd / self.smoothing_velocity)
        rate = ca.jtimes(smooth, ca.vertcat(q, qd, qdd), ca.vertcat(qd, qdd, qddd))
        self.smooth_torque_rate: ca.Function = ca.Function(
            "ptp_tau_rate", [q, qd, qdd, qddd], [rate], ["q", "qd", "qdd", "qddd"], ["tau_rate"], {"cse": True})
        self.smooth_torque: ca.Function = ca.Function(
            "ptp_tau_smooth", [q, qd, qdd], [smooth], ["q", "qd", "qdd"], ["tau_smooth"], {"cse": True})

    @property
    def key(self) -> tuple:
        """Hashable identity (parameters, payload, friction) for caching built problems."""
        return (self.parameter_vector.tobytes(), np.asarray(self.dynamics.payload).tobytes(),
                self.smoothing_velocity, self.friction)

    # -- numbers ------------------------------------------------------------------
    def torques(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """tau [N m], (n, 6), for joint arrays (n, 6) (one CasADi call for all rows)."""
        return _rows(self.torque, q, qd, qdd)

    def smooth_torques(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """tau minus the Coulomb term [N m], (n, 6)."""
        return _rows(self.smooth_torque, q, qd, qdd)

    def ratios(self, t: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
               limits: JointLimits) -> dict[str, np.ndarray]:
        """Per joint, the largest |value| / limit of a sampled motion (times ``t`` (n,) in s).

        Kinds: velocity, acceleration, jerk and torque_rate (finite differences between
        samples; the torque rate without the Coulomb term), torque, position (as in
        ``planners.trajectory.constraint_ratios``: 1 + excursion beyond the range /
        half range). Sample at 1 ms for ``max_constraint_ratio`` (docs/explanation/planners.md).
        """
        step = np.diff(t)[:, None]
        tau = self.torques(q, qd, qdd)
        smooth = tau - self.coulomb * np.tanh(qd / self.smoothing_velocity)
        values = {
            "velocity": np.abs(qd),
            "acceleration": np.abs(qdd),
            "jerk": np.abs(np.diff(qdd, axis=0) / step),
            "torque": np.abs(tau),
            "torque_rate": np.abs(np.diff(smooth, axis=0) / step),
        }
        out = {kind: np.max(val, axis=0) / getattr(limits, kind) for kind, val in values.items()}
        lower, upper = limits.position_lower, limits.position_upper
        bounded = np.isfinite(lower) & np.isfinite(upper)
        half = np.where(bounded, 0.5 * (upper - lower), 1.0)
        mid = np.where(bounded, 0.5 * (upper + lower), 0.0)
        out["position"] = np.where(bounded, np.max(np.abs(q - mid), axis=0) / half, 0.0)
        return out


def _rows(function: ca.Function, *arrays: np.ndarray) -> np.ndarray:
    cols = [np.ascontiguousarray(np.asarray(a, dtype=float).T) for a in arrays]
    return np.asarray(function(*cols)).T.reshape(-1, N_JOINTS)


_NOMINAL: list[RobotDynamics] = []


def _nominal_dynamics() -> RobotDynamics:
    if not _NOMINAL:
        _NOMINAL.append(RobotDynamics())
    return _NOMINAL[0]


_CACHE: dict[tuple, PtPDynamics] = {}


def ptp_dynamics(dynamics: Any = None, friction: str = "full") -> PtPDynamics:
    """A cached :class:`PtPDynamics` (building the CasADi functions costs ~0.1 s)."""
    base = dynamics if dynamics is not None else _nominal_dynamics()
    key = (id(base), friction)
    cached = _CACHE.get(key)
    if cached is None or cached.dynamics is not base:
        if len(_CACHE) >= 8:
            _CACHE.clear()
        cached = PtPDynamics(base, friction)
        _CACHE[key] = cached
    return cached


def boundary_violation(problem: Any) -> str | None:
    """Why the boundary states of a ``PtPProblem`` break its limits, or None if they do not.

    Checks q0, qe against the position range and qd0, qde against the velocity limit
    (a PtP request from or to such a state cannot be met by any planner).
    """
    limits: JointLimits = problem.limits
    reasons = []
    for name in ("q0", "qe"):
        q = getattr(problem, name)
        bad = np.flatnonzero((q < limits.position_lower) | (q > limits.position_upper))
        for j in bad:
            reasons.append(f"{name}[joint {j + 1}] = {q[j]:.6g} rad is outside the position range "
                           f"[{limits.position_lower[j]:.6g}, {limits.position_upper[j]:.6g}] rad")
    for name in ("qd0", "qde"):
        qd = getattr(problem, name)
        bad = np.flatnonzero(np.abs(qd) > limits.velocity)
        for j in bad:
            reasons.append(f"{name}[joint {j + 1}] = {qd[j]:.6g} rad/s exceeds the velocity limit "
                           f"{limits.velocity[j]:.6g} rad/s")
    return "; ".join(reasons) if reasons else None


def boundary_torque_violation(problem: Any, dyn: PtPDynamics) -> str | None:
    """Why the torque at the boundary states (qdd = 0 there) breaks the torque limit, or None.

    Both PtP planners start and end with zero acceleration (continuous torque with holding
    the boundary state), so tau(0) = ID(q0, qd0, 0) and tau(T) = ID(qe, qde, 0) are fixed.
    """
    limits: JointLimits = problem.limits
    reasons = []
    for label, q, qd in (("start", problem.q0, problem.qd0), ("end", problem.qe, problem.qde)):
        tau = dyn.torques(q[None, :], qd[None, :], np.zeros((1, N_JOINTS)))[0]
        for j in np.flatnonzero(np.abs(tau) > limits.torque):
            reasons.append(f"holding torque at the {label} state, joint {j + 1}: {tau[j]:.6g} N m exceeds the "
                           f"torque limit {limits.torque[j]:.6g} N m")
    return "; ".join(reasons) if reasons else None
