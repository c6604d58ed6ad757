"""The feed-forward torque of the paper's eq. 7 from the model the controller is given.

    Q_M,ff = M(q_d) qdd_d + g(q_d, qd_d)

``M`` includes the reflected rotor inertia (pinocchio armature), ``g`` the Coriolis,
centrifugal and gravity torques and the friction ``fv qd + fc tanh(qd / v_s)`` (joint
side, N m) - exactly :meth:`robot.dynamics.RobotDynamics.inverse_dynamics`. The model
is whatever :class:`~robot.dynamics.RobotDynamics` the caller passes: the nominal arm,
an identified parameter vector, or (to bound what feed-forward can do) the true
robot's. This class only prepares the evaluation for the 400 µs cycle: its own
pinocchio Data, friction coefficients as plain floats, a reused output array.
"""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from robot.dynamics import COULOMB_SLICE, VISCOUS_SLICE, RobotDynamics

N_JOINTS = 6


class FeedForward:
    """Evaluates eq. 7's feed-forward torque of one :class:`RobotDynamics` model."""

    def __init__(self, dynamics: RobotDynamics) -> None:
        self.dynamics = dynamics
        self.model: pin.Model = dynamics.model
        self.data: pin.Data = self.model.createData()
        p = dynamics.parameter_vector()
        self._viscous = p[VISCOUS_SLICE].tolist()
        self._coulomb = p[COULOMB_SLICE].tolist()
        self._inv_vs = 1.0 / float(dynamics.coulomb_smoothing_velocity)
        self.tau = np.zeros(N_JOINTS)
        self._friction = [0.0] * N_JOINTS

    def torque(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Feed-forward joint torque (6,) in N m (a reused array) for q, qd, qdd (6,)."""
        rigid = pin.rnea(self.model, self.data, q, qd, qdd)  # includes armature * qdd
        friction = self._friction
        fv, fc, inv_vs = self._viscous, self._coulomb, self._inv_vs
        for i, v in enumerate(qd.tolist()):
            friction[i] = fv[i] * v + fc[i] * math.tanh(v * inv_vs)
        np.add(rigid, friction, out=self.tau)
        return self.tau
