"""Independent monolithic solve of the elastic-joint arm (the plant FMU's equations,
written again in numpy): pinocchio ABA for the links (robot.dynamics.RobotDynamics with
rotor inertia and friction zeroed), the gear spring/damper/dead zone and the motor
inertia with friction per axis, integrated by scipy solve_ivp (DOP853) with the inputs
held over each communication step."""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from robot.dynamics import COULOMB_SLICE, ROTOR_INERTIA_SLICE, VISCOUS_SLICE, RobotDynamics
from robot.parameters import load_parameters


class ElasticArm:
    """Right-hand side and static start state of the two-mass-per-axis arm (SI, joint side)."""

    def __init__(self, p: np.ndarray, payload, gear: dict[str, np.ndarray] | None = None, model=None):
        """``model``: the links' pinocchio model (default nominal; a true robot's
        ``kinematic_model()`` for its geometric errors)."""
        robot = load_parameters()
        self.p = np.asarray(p, dtype=float)
        link_p = self.p.copy()
        link_p[ROTOR_INERTIA_SLICE] = link_p[VISCOUS_SLICE] = link_p[COULOMB_SLICE] = 0.0
        self.links = RobotDynamics(link_p, payload, model=model)
        gear = gear or {}
        self.k = np.asarray(gear.get("stiffness", robot.stiffness), dtype=float)
        self.k3 = np.asarray(gear.get("stiffness_cubic", robot.stiffness_cubic), dtype=float)
        self.c = np.asarray(gear.get("damping", robot.gear_damping), dtype=float)
        self.b = np.asarray(gear.get("backlash", robot.backlash), dtype=float)
        self.share = np.asarray(gear.get("motor_friction_share", robot.motor_friction_share), dtype=float)
        self.fs = np.asarray(gear.get("stribeck_torque", robot.stribeck_torque), dtype=float)
        self.vst = np.asarray(gear.get("stribeck_velocity", robot.stribeck_velocity), dtype=float)
        self.vs = robot.coulomb_smoothing_velocity
        self.ia = self.p[ROTOR_INERTIA_SLICE]
        self.fv = self.p[VISCOUS_SLICE]
        self.fc = self.p[COULOMB_SLICE]

    def _cv(self, v):
        return self.fv * v + self.fc * np.tanh(v / self.vs)

    def spring(self, delta):
        half = 0.5 * self.b
        d = np.where(half > 0, delta - half * np.tanh(delta / np.where(half > 0, half, 1.0)), delta)
        return self.k * d + self.k3 * d ** 3

    def gear_torque(self, x):
        return self.spring(x[12:18] - x[:6]) + self.c * (x[18:] - x[6:12])

    def rhs(self, x, tau, tau_ext):
        q, qd, thd = x[:6], x[6:12], x[18:]
        tau_g = self.gear_torque(x)
        f_link = (1 - self.share) * self._cv(qd)
        f_motor = self.share * self._cv(thd) + self.fs * np.exp(-(thd / self.vst) ** 2) * np.tanh(thd / self.vs)
        qdd = self.links.forward_dynamics(q, qd, tau_g + tau_ext - f_link)
        return np.concatenate((qd, qdd, thd, (tau - tau_g - f_motor) / self.ia))

    def start_state(self, q0, qd0=None, tau_ext=None):
        """Motor where the gear holds the links at rest (linear spring, no backlash: k3 = b = 0)."""
        qd0 = np.zeros(6) if qd0 is None else np.asarray(qd0, dtype=float)
        tau_ext = np.zeros(6) if tau_ext is None else np.asarray(tau_ext, dtype=float)
        hold = self.links.inverse_dynamics(q0, qd0, np.zeros(6)) + (1 - self.share) * self._cv(qd0) - tau_ext
        if np.any(self.k3) or np.any(self.b):
            raise ValueError("start_state solves the linear spring only")
        return np.concatenate((q0, qd0, q0 + hold / self.k, qd0))


def solve(arm: ElasticArm, x0, tau_of_t, h: float, duration: float, tau_ext_of_t=None, tol: float = 1e-12):
    """States at the end of every communication step h (rows), inputs held over each step."""
    x = np.asarray(x0, dtype=float)
    rows = []
    for k in range(int(round(duration / h))):
        tau = np.asarray(tau_of_t(k * h), dtype=float)
        ext = np.zeros(6) if tau_ext_of_t is None else np.asarray(tau_ext_of_t(k * h), dtype=float)
        sol = solve_ivp(lambda t, s: arm.rhs(s, tau, ext), (k * h, (k + 1) * h), x, method="DOP853",
                        rtol=tol, atol=tol)
        x = sol.y[:, -1]
        rows.append(x.copy())
    return np.array(rows)
