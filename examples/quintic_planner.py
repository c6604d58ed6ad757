"""A user planner: synchronised quintic point-to-point motion (an example of the planner contract).

Every joint follows the same rest-to-rest quintic time law s(t) = 10 u^3 - 15 u^4 + 6 u^5,
u = t / T, from the start to the end configuration. The duration T is the smallest one at
which each joint stays within ``speed_factor`` times its velocity limit and
``speed_factor`` times its acceleration limit (peak |s'| = 15 / (8 T), peak |s''| =
10 sqrt(3) / (3 T^2)). Torques come from the problem's dynamics (inverse dynamics).

Used in a scenario as::

    [planners]
    run = ["ruckig", "examples/quintic_planner.py:QuinticPtP"]
    [planners.parameters."examples/quintic_planner.py:QuinticPtP"]
    speed_factor = 0.8

It imports only the public planner types (docs/how-to/own_planner.md).
"""
from __future__ import annotations

import math
import time

import numpy as np

from planners.base import PlannerInputError, PlanResult, PlanStatus, PtPProblem
from planners.trajectory import Trajectory


class QuinticPtP:
    """Synchronised quintic PtP planner (satisfies ``planners.base.Planner``)."""

    name = "quintic_ptp"
    kind = "ptp"

    def __init__(self, speed_factor: float = 1.0, dt: float = 1e-3) -> None:
        if not 0.0 < speed_factor <= 1.0:
            raise ValueError(f"speed_factor = {speed_factor!r}: expected a number in (0, 1]")
        self.speed_factor = float(speed_factor)
        self.dt = float(dt)

    def plan(self, problem: PtPProblem) -> PlanResult:
        if not isinstance(problem, PtPProblem):
            raise PlannerInputError(f"{self.name} plans PtPProblem requests, got {type(problem).__name__}")
        start = time.perf_counter()
        if np.any(problem.qd0 != 0.0) or np.any(problem.qde != 0.0):
            return PlanResult(self.name, PlanStatus.INFEASIBLE, None, 0.0, message="rest-to-rest only")
        dq = np.abs(problem.qe - problem.q0)
        lim = problem.limits
        t_vel = 15.0 / 8.0 * dq / (self.speed_factor * lim.velocity)
        t_acc = np.sqrt(10.0 * math.sqrt(3.0) / 3.0 * dq / (self.speed_factor * lim.acceleration))
        duration = float(max(np.max(t_vel), np.max(t_acc), 10 * self.dt))
        n = int(math.ceil(duration / self.dt))
        t = np.linspace(0.0, duration, n + 1)
        u = t / duration
        s = 10 * u**3 - 15 * u**4 + 6 * u**5
        sd = (30 * u**2 - 60 * u**3 + 30 * u**4) / duration
        sdd = (60 * u - 180 * u**2 + 120 * u**3) / duration**2
        delta = problem.qe - problem.q0
        q = problem.q0 + np.outer(s, delta)
        qd, qdd = np.outer(sd, delta), np.outer(sdd, delta)
        dynamics = problem.dynamics
        if dynamics is None:
            from robot.dynamics import RobotDynamics

            dynamics = RobotDynamics()
        tau = np.array([dynamics.inverse_dynamics(q[k], qd[k], qdd[k]) for k in range(t.size)])
        status = PlanStatus.FEASIBLE
        message = f"T = {duration:.4f} s at {self.speed_factor:g} x the velocity/acceleration limits"
        if np.any(np.abs(tau) > lim.torque):
            status, message = PlanStatus.INFEASIBLE, message + "; a torque limit is exceeded"
        traj = Trajectory(t, q, qd, qdd, tau, metadata={"planner": self.name})
        return PlanResult(self.name, status, traj if status.has_trajectory else None,
                          time.perf_counter() - start, message=message, info={"speed_factor": self.speed_factor})
