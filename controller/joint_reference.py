"""Desired joint motion from the desired flange motion: IK plus consistent derivatives.

Each cycle (paper section 2.3.2): the numeric inverse kinematics of the controller's
kinematic model (the nominal URDF, or a calibrated one) gives ``q_d``; the joint
velocity and acceleration are the ones of THAT model, so that the three are
consistent with each other and with the feed-forward:

    J(q_d) qd_d = [v; w]                          (geometric Jacobian, base-frame axes)
    J(q_d) qdd_d = [a; dw] - Jdot(q_d, qd_d) qd_d  (Jdot qd: classical flange acceleration at qdd = 0)

``v, a`` are the linear velocity and acceleration of the flange origin (m/s, m/s^2),
``w, dw`` the angular velocity and acceleration (rad/s, rad/s^2), base_link axes; the
Jacobian is pinocchio's ``LOCAL_WORLD_ALIGNED`` frame Jacobian of ``tool0`` and
``Jdot qd`` its ``getFrameClassicalAcceleration`` after a forward pass with
``qdd = 0``. One LU factorisation (LAPACK ``dgetrf``) serves both solves.

The IK is :class:`robot.inverse_kinematics.NumericIK` (Newton on SE(3), LAPACK), warm
started from a second-order prediction ``q + qd h + qdd h^2 / 2`` of the last solution
(``h`` = time since it), which leaves one Newton step; that step is taken here with
NumericIK's own acceptance rule (no call overhead), anything else goes to
``NumericIK.solve``.
"""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
from scipy.linalg import lapack

from robot.inverse_kinematics import LIMIT_TOLERANCE, NumericIK
from robot.joints import N_JOINTS

DEFAULT_IK_TOLERANCE = 1e-10
"""Newton convergence bound on |log6| (m and rad): 0.1 nm / 0.1 nrad, far below the
0.1 um resolution that matters for TCP errors; keeps the derivatives consistent."""


SINGULARITY_TOLERANCE = 1e-9
"""Smallest accepted Hadamard ratio ``|det J| / prod_i |J[:, i]|`` of the flange Jacobian
(1: orthogonal columns, 0: singular); below it the configuration counts as singular.
On the ISO 9283 cube the ratio stays above 1e-2."""


def hadamard_ratio(lu: np.ndarray, jac: np.ndarray) -> float:
    """``|det J| / prod_i |J[:, i]|`` from the LU factors of J (6x6) and J itself."""
    # math.prod over lists: the same left-to-right products as np.prod, without its
    # reduction set-up (this runs once per knot, 30 520 times for an elastic reference)
    det = abs(math.prod(lu.diagonal().tolist()))
    norms = math.prod(np.sqrt(np.einsum("ij,ij->j", jac, jac)).tolist())
    return det / norms if norms > 0.0 else 0.0


class SingularConfigurationError(ArithmeticError):
    """The Jacobian at the desired configuration is singular: the derivatives are undefined."""


class CartesianToJoint:
    """IK and joint derivatives of one kinematic model (pinocchio model of the arm).

    ``solve(target, twist, acceleration, h)`` fills and returns the reused arrays
    ``q``, ``qd``, ``qdd`` (6,) in rad, rad/s, rad/s^2. ``h`` (s) is the time since the
    previous solve (for the warm-start prediction); ``reset(q)`` sets the seed.
    """

    def __init__(self, model: pin.Model, tolerance: float = DEFAULT_IK_TOLERANCE) -> None:
        self.ik = NumericIK(model, tolerance=tolerance)
        self.model = self.ik.model
        self.data: pin.Data = self.model.createData()  # separate from the IK's own Data
        self.frame_id: int = self.ik.frame_id
        self.q = np.zeros(N_JOINTS)
        self.qd = np.zeros(N_JOINTS)
        self.qdd = np.zeros(N_JOINTS)
        self._zeros = np.zeros(N_JOINTS)
        self._seed = np.zeros(N_JOINTS)
        self._rhs = np.zeros(N_JOINTS)
        self._have_seed = False
        self._lower = (self.ik.lower - LIMIT_TOLERANCE).tolist()
        self._upper = (self.ik.upper + LIMIT_TOLERANCE).tolist()
        self.last_iterations = 0
        """Newton steps of the last IK (-1: the IK fell back to the analytic branches)."""

    def reset(self, q: np.ndarray) -> None:
        """Seed the next IK with ``q`` (6,) rad at rest."""
        self.set_state(q, 0.0, 0.0)

    def set_state(self, q: np.ndarray, qd: np.ndarray | float, qdd: np.ndarray | float) -> None:
        """The last solution (q rad, qd rad/s, qdd rad/s^2) from which the next seed is predicted."""
        self.q[:] = q
        self.qd[:] = qd
        self.qdd[:] = qdd
        self._have_seed = True

    def solve(self, target: pin.SE3, twist: np.ndarray, acceleration: np.ndarray,
              h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q_d, qd_d, qdd_d (reused arrays) for the flange ``target`` placement (m),
        ``twist`` (6,) (m/s, rad/s) and ``acceleration`` (6,) (m/s^2, rad/s^2).

        Fast path (the normal case in a cycle): from the predicted seed, the NumericIK
        Newton step - SE(3) error ``log6(M(seed)^-1 M_target)``, local frame Jacobian,
        LAPACK solve - accepted without a further FK when error and step lie below
        NumericIK's acceptance bound (its tolerance is then met, see
        ``NumericIK._acceptance_bound``) and the result is inside the joint limits.
        Otherwise :meth:`NumericIK.solve` from the same seed (more Newton steps, or the
        analytic branches as fallback).
        """
        if not self._have_seed:
            raise RuntimeError("CartesianToJoint.solve: call reset(q_start) first")
        seed = self._seed
        np.multiply(self.qdd, 0.5 * h * h, out=seed)
        seed += self.q
        seed += self.qd * h
        ik = self.ik
        model, data, fid = self.model, self.data, self.frame_id
        q = None
        pin.forwardKinematics(model, data, seed)
        err = pin.log6(pin.updateFramePlacement(model, data, fid).actInv(target)).vector
        err2 = err.dot(err)
        if err2 <= ik._tol2:
            q, iterations = seed.copy(), 0
        elif err2 <= ik._accept2:
            jac = pin.computeFrameJacobian(model, data, seed, fid, pin.LOCAL)
            _, _, dq, info = lapack.dgesv(jac, err)
            if info == 0 and dq.dot(dq) <= ik._accept2:
                q, iterations = seed + dq, 1
        if q is None or not all(lo <= x <= hi for lo, x, hi in zip(self._lower, q.tolist(), self._upper)):
            q = ik.solve(target, seed)
            iterations = ik.last_iterations
        self.last_iterations = iterations
        jac = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL_WORLD_ALIGNED)
        lu, piv, info = lapack.dgetrf(jac)
        if info != 0 or hadamard_ratio(lu, jac) < SINGULARITY_TOLERANCE:
            raise SingularConfigurationError(
                f"the flange Jacobian is singular at q = {np.round(q, 6).tolist()} rad: no joint velocity")
        qd, info = lapack.dgetrs(lu, piv, twist)
        pin.forwardKinematics(model, data, q, qd, self._zeros)
        drift = pin.getFrameClassicalAcceleration(model, data, fid, pin.LOCAL_WORLD_ALIGNED).vector
        np.subtract(acceleration, drift, out=self._rhs)
        qdd, info = lapack.dgetrs(lu, piv, self._rhs)
        self.q[:] = q
        self.qd[:] = qd
        self.qdd[:] = qdd
        return self.q, self.qd, self.qdd
