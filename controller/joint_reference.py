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
(``h`` = time since it), which usually leaves one Newton step.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin
from scipy.linalg import lapack

from robot.inverse_kinematics import NumericIK

N_JOINTS = 6
DEFAULT_IK_TOLERANCE = 1e-10
"""Newton convergence bound on |log6| (m and rad): 0.1 nm / 0.1 nrad, far below the
0.1 um resolution that matters for TCP errors; keeps the derivatives consistent."""


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
        self.last_iterations = 0
        """Newton steps of the last IK (-1: the IK fell back to the analytic branches)."""

    def reset(self, q: np.ndarray) -> None:
        """Seed the next IK with ``q`` (6,) rad at rest."""
        self.q[:] = q
        self.qd[:] = 0.0
        self.qdd[:] = 0.0
        self._have_seed = True

    def solve(self, target: pin.SE3, twist: np.ndarray, acceleration: np.ndarray,
              h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q_d, qd_d, qdd_d (reused arrays) for the flange ``target`` placement (m),
        ``twist`` (6,) (m/s, rad/s) and ``acceleration`` (6,) (m/s^2, rad/s^2)."""
        if not self._have_seed:
            raise RuntimeError("CartesianToJoint.solve: call reset(q_start) first")
        seed = self._seed
        np.multiply(self.qdd, 0.5 * h * h, out=seed)
        seed += self.q
        seed += self.qd * h
        q = self.ik.solve(target, seed)
        self.last_iterations = self.ik.last_iterations
        model, data = self.model, self.data
        jac = pin.computeFrameJacobian(model, data, q, self.frame_id, pin.LOCAL_WORLD_ALIGNED)
        lu, piv, info = lapack.dgetrf(jac)
        if info != 0:
            raise SingularConfigurationError(
                f"the flange Jacobian is singular at q = {np.round(q, 6).tolist()} rad: no joint velocity")
        qd, info = lapack.dgetrs(lu, piv, twist)
        pin.forwardKinematics(model, data, q, qd, self._zeros)
        drift = pin.getFrameClassicalAcceleration(model, data, self.frame_id, pin.LOCAL_WORLD_ALIGNED).vector
        np.subtract(acceleration, drift, out=self._rhs)
        qdd, info = lapack.dgetrs(lu, piv, self._rhs)
        self.q[:] = q
        self.qd[:] = qd
        self.qdd[:] = qdd
        return self.q, self.qd, self.qdd
