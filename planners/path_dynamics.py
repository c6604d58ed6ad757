"""Robot dynamics along a joint path (eq. 35) and time-law reconstruction.

Along a joint path q(sigma) with sigma_dot = s, sigma_ddot = a, b = s^2 (eq. 32-35):

    qd   = q' s
    qdd  = q' a + q'' b
    tau  = m(sigma) a + c(sigma) b + g(sigma) + v(sigma) s + f_c(sigma)

    m = M(q) q',   c = M(q) q'' + C(q, q') q',   g = g(q)        (rigid body + rotor)
    v = F_v q'                                                      (viscous friction)
    f_c = F_c sign(q')                                              (Coulomb; sigma_dot >= 0)

so the rigid-body torque is linear in (a, b) and the viscous torque is linear in s.
:func:`path_dynamics` evaluates these coefficients (and their sigma-derivatives, for
torque-rate limits) on a sigma grid through ``robot.dynamics.RobotDynamics``'s
pinocchio model (RNEA including the rotor inertia) and parameter vector.

:func:`trajectory_from_time_law` turns a piecewise-polynomial time law sigma(t) into
the common :class:`planners.trajectory.Trajectory`, with torques recomputed by the
robot's full inverse dynamics (smoothed Coulomb friction as in the plant), so what a
planner reports is what the robot model says.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import pinocchio as pin

from planners.paths import JointPath
from planners.trajectory import Trajectory, uniform_times
from robot.dynamics import COULOMB_SLICE, VISCOUS_SLICE, RobotDynamics
from robot.joints import N_JOINTS

FrictionModel = Literal["full", "coulomb", "none"]
DERIVATIVE_STEP = 1e-5
"""Sigma step of the central differences giving m', c', g', v'."""


@dataclass(frozen=True)
class PathDynamics:
    """Coefficients of tau = m a + c b + g + v s + f_c at ``sigma`` (all (n, 6), N m per unit).

    ``dm, dc, dg, dv`` are their sigma-derivatives. ``q, dq, ddq, dddq`` the joint path
    and its sigma-derivatives at the same points.
    """

    sigma: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    dddq: np.ndarray
    m: np.ndarray
    c: np.ndarray
    g: np.ndarray
    v: np.ndarray
    fc: np.ndarray
    dm: np.ndarray
    dc: np.ndarray
    dg: np.ndarray
    dv: np.ndarray


def friction_coefficients(dynamics: RobotDynamics, friction: FrictionModel) -> tuple[np.ndarray, np.ndarray]:
    """(viscous [N m s/rad], Coulomb [N m]) of the chosen friction model, shape (6,) each."""
    p = dynamics.parameter_vector()
    viscous = p[VISCOUS_SLICE] if friction == "full" else np.zeros(N_JOINTS)
    coulomb = p[COULOMB_SLICE] if friction in ("full", "coulomb") else np.zeros(N_JOINTS)
    return viscous, coulomb


def _rigid_coefficients(model: pin.Model, data: pin.Data, q: np.ndarray, dq: np.ndarray,
                        ddq: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = q.shape[0]
    m = np.empty((n, N_JOINTS))
    c = np.empty((n, N_JOINTS))
    g = np.empty((n, N_JOINTS))
    zero = np.zeros(N_JOINTS)
    for k in range(n):
        g[k] = pin.rnea(model, data, q[k], zero, zero)
        m[k] = pin.rnea(model, data, q[k], zero, dq[k]) - g[k]
        c[k] = pin.rnea(model, data, q[k], dq[k], ddq[k]) - g[k]
    return m, c, g


def path_dynamics(path: JointPath, sigma: np.ndarray, dynamics: RobotDynamics | None = None,
                  friction: FrictionModel = "full", derivatives: bool = True) -> PathDynamics:
    """Evaluate the coefficients of tau(sigma, a, b) at ``sigma`` (module docstring)."""
    dyn = dynamics or RobotDynamics()
    sigma = np.asarray(sigma, dtype=float)
    q, dq, ddq, dddq = path.evaluate(sigma)
    m, c, g = _rigid_coefficients(dyn.model, dyn.data, q, dq, ddq)
    viscous, coulomb = friction_coefficients(dyn, friction)
    v = viscous * dq
    fc = coulomb * np.sign(dq)
    if derivatives:
        h = DERIVATIVE_STEP
        lo = np.clip(sigma - h, 0.0, 1.0)
        hi = np.clip(sigma + h, 0.0, 1.0)
        ql, dql, ddql, _ = path.evaluate(lo)
        qh, dqh, ddqh, _ = path.evaluate(hi)
        ml, cl, gl = _rigid_coefficients(dyn.model, dyn.data, ql, dql, ddql)
        mh, ch, gh = _rigid_coefficients(dyn.model, dyn.data, qh, dqh, ddqh)
        width = (hi - lo)[:, None]
        dm, dc, dg = (mh - ml) / width, (ch - cl) / width, (gh - gl) / width
        dv = viscous * ddq
    else:
        dm = dc = dg = dv = np.zeros_like(m)
    return PathDynamics(sigma, q, dq, ddq, dddq, m, c, g, v, fc, dm, dc, dg, dv)


@dataclass(frozen=True)
class TimeLaw:
    """Piecewise-cubic sigma(t): on interval i (t in [t[i], t[i+1]]), with tau = t - t[i],

        sigma = sigma[i] + s[i] tau + a[i] tau^2 / 2 + j[i] tau^3 / 6

    ``t``, ``sigma``, ``s`` have n+1 entries (node times [s], sigma, sigma_dot [1/s]);
    ``a`` (sigma_ddot at the start of each interval [1/s^2]) and ``j`` (sigma jerk
    [1/s^3]) have n. j = 0 is the constant-acceleration law of TOPP-RA.
    """

    t: np.ndarray
    sigma: np.ndarray
    s: np.ndarray
    a: np.ndarray
    j: np.ndarray

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    @classmethod
    def constant_acceleration(cls, sigma: np.ndarray, b: np.ndarray) -> "TimeLaw":
        """The exact law of b = sigma_dot^2 linear in sigma between nodes."""
        sigma = np.asarray(sigma, dtype=float)
        s = np.sqrt(np.maximum(np.asarray(b, dtype=float), 0.0))
        ds = np.diff(sigma)
        h = 2.0 * ds / (s[:-1] + s[1:])
        a = (s[1:] ** 2 - s[:-1] ** 2) / (2.0 * ds)
        t = np.concatenate([[0.0], np.cumsum(h)])
        return cls(t, sigma, s, a, np.zeros_like(a))

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(sigma, sigma_dot, sigma_ddot, sigma_jerk) at times t (clamped)."""
        tt = np.clip(np.asarray(t, dtype=float), self.t[0], self.t[-1])
        i = np.clip(np.searchsorted(self.t, tt, side="right") - 1, 0, self.t.size - 2)
        tau = tt - self.t[i]
        a0, j = self.a[i], self.j[i]
        sig = self.sigma[i] + self.s[i] * tau + 0.5 * a0 * tau**2 + j * tau**3 / 6.0
        sig = np.clip(sig, self.sigma[i], self.sigma[i + 1])
        sd = np.maximum(self.s[i] + a0 * tau + 0.5 * j * tau**2, 0.0)
        sdd = a0 + j * tau
        return sig, sd, sdd, j


def trajectory_from_time_law(path: JointPath, law: TimeLaw, dynamics: RobotDynamics | None = None,
                             dt: float = 1e-3, metadata: dict[str, Any] | None = None) -> Trajectory:
    """Sample q(sigma(t)) every ``dt`` s (plus every node time) into a Trajectory.

    qd = q' sigma_dot, qdd = q' sigma_ddot + q'' sigma_dot^2; tau by
    ``dynamics.inverse_dynamics`` (full model, smoothed Coulomb friction).
    """
    dyn = dynamics or RobotDynamics()
    times = np.union1d(uniform_times(law.t[0], law.t[-1], dt), law.t)
    times = times[np.concatenate([[True], np.diff(times) > 1e-9])]
    sig, sd, sdd, _ = law.evaluate(times)
    q, dq, ddq, _ = path.evaluate(sig)
    qd = dq * sd[:, None]
    qdd = dq * sdd[:, None] + ddq * (sd**2)[:, None]
    tau = np.array([dyn.inverse_dynamics(q[k], qd[k], qdd[k]) for k in range(times.size)])
    meta = dict(metadata or {})
    return Trajectory(times - times[0], q, qd, qdd, tau, {"sigma": sig, "sigma_dot": sd}, meta)
