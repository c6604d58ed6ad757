"""TOPP-RA baseline for continuous paths (the ``toppra`` package, Pham & Pham 2018).

Same joint path, same limits, same dynamics as our own CP planner:

* joint velocity limits: ``toppra.constraint.JointVelocityConstraint``;
* joint acceleration limits: ``JointAccelerationConstraint``;
* joint torque limits: ``SecondOrderConstraint.joint_torque_constraint`` with the
  rigid-body inverse dynamics of ``robot.dynamics.RobotDynamics`` (rotor inertia
  included) and the Coulomb friction F_c sign(q') as toppra's dry-friction term.

Fairness: both constraint kinds use the Interpolation discretisation (constraints at
both ends of every interval with the interval's constant sigma_ddot) and the output
is ``ParametrizeConstAccel`` (the exact time law of that discretisation), because
toppra's default spline output overshoots the limits between grid points.

What toppra cannot express: viscous friction (a torque F_v q' sigma_dot, linear in
sigma_dot, whereas toppra's constraints are linear in sigma_ddot and sigma_dot^2), jerk
and torque-rate limits. With ``friction="full"`` the viscous torque is added as a
known path term F_v q'(sigma) sigma_dot_prev(sigma) taken from the previous
solution (fixed-point iteration, ``viscous_iterations`` passes, first pass at zero
speed); the result is checked, not assumed, by max_constraint_ratio. Jerk and
torque-rate limits are ignored (and show up in its constraint ratios).

``compute_trajectory`` returns None on failure: the status is then INFEASIBLE.
"""
from __future__ import annotations

import logging
import os
import time
from typing import Any

os.environ.setdefault("MPLBACKEND", "Agg")  # toppra imports matplotlib

import numpy as np
import toppra
import toppra.algorithm
import toppra.constraint

from planners.base import CPProblem, Planner, PlannerInputError, PlanResult, PlanStatus
from planners.path_dynamics import TimeLaw, friction_coefficients, trajectory_from_time_law
from planners.paths import JointPath
from robot.dynamics import RobotDynamics
from robot.joints import N_JOINTS

logging.getLogger("toppra").setLevel(logging.ERROR)


class JointPathForToppra(toppra.interpolator.AbstractGeometricPath):
    """Our JointPath behind toppra's geometric-path interface (sigma in [0, 1])."""

    def __init__(self, path: JointPath) -> None:
        self._path = path

    def __call__(self, path_positions, order: int = 0):
        scalar = np.ndim(path_positions) == 0
        s = np.atleast_1d(np.asarray(path_positions, dtype=float))
        values = self._path.evaluate(s)
        if order not in (0, 1, 2, 3):
            raise ValueError(f"order: expected 0..3, got {order!r}")
        out = values[order]
        return out[0] if scalar else out

    @property
    def dof(self) -> int:
        return N_JOINTS

    @property
    def path_interval(self) -> np.ndarray:
        return np.array([0.0, 1.0])

    @property
    def waypoints(self):
        return self._path.sigma, self._path.q


class ToppraPlanner(Planner):
    """Time-optimal CP baseline by TOPP-RA (module docstring). k2 must be 0."""

    name = "toppra"
    kind = "cp"

    def __init__(self, viscous_iterations: int = 4) -> None:
        self.viscous_iterations = int(viscous_iterations)

    def plan(self, problem: CPProblem) -> PlanResult:
        if not isinstance(problem, CPProblem):
            raise PlannerInputError(f"ToppraPlanner.plan: expected a CPProblem, got {type(problem).__name__}")
        if problem.k2 != 0.0:
            raise PlannerInputError(f"ToppraPlanner: TOPP-RA is time-optimal only; k2 must be 0, got {problem.k2}")
        dyn = problem.dynamics or RobotDynamics()
        limits = problem.limits
        viscous, coulomb = friction_coefficients(dyn, problem.friction)
        path = JointPathForToppra(problem.path)
        grid = np.linspace(0.0, 1.0, int(problem.n_intervals) + 1)
        model, data = dyn.model, dyn.data

        def rigid_inverse_dynamics(q, qd, qdd):
            import pinocchio as pin

            return pin.rnea(model, data, np.asarray(q, float), np.asarray(qd, float), np.asarray(qdd, float))

        interp = toppra.constraint.DiscretizationType.Interpolation
        sd_prev = np.zeros_like(grid)

        def build(sd_profile: np.ndarray) -> list:
            cons = []
            if np.all(np.isfinite(limits.velocity)):
                cons.append(toppra.constraint.JointVelocityConstraint(np.column_stack([-limits.velocity, limits.velocity])))
            if np.all(np.isfinite(limits.acceleration)):
                cons.append(toppra.constraint.JointAccelerationConstraint(
                    np.column_stack([-limits.acceleration, limits.acceleration]), discretization_scheme=interp))
            if np.all(np.isfinite(limits.torque)):
                tau_lim = np.column_stack([-limits.torque, limits.torque])
                torque = toppra.constraint.SecondOrderConstraint.joint_torque_constraint(
                    rigid_inverse_dynamics, tau_lim, coulomb, discretization_scheme=interp)
                if np.any(viscous > 0.0):
                    def custom_term(p, s, _sd=sd_profile):
                        sd_here = np.interp(s, grid, _sd)
                        return np.sign(p(s, 1)) * coulomb + viscous * p(s, 1) * sd_here
                    torque.custom_term = custom_term
                cons.append(torque)
            return cons

        passes = 1 + (self.viscous_iterations if np.any(viscous > 0.0) and np.all(np.isfinite(limits.torque)) else 0)
        solve_time = 0.0
        build_time = 0.0
        sd_vec = None
        for _ in range(passes):
            t0 = time.perf_counter()
            instance = toppra.algorithm.TOPPRA(build(sd_prev), path, gridpoints=grid,
                                               parametrizer="ParametrizeConstAccel")
            t1 = time.perf_counter()
            output = instance.compute_trajectory(0.0, 0.0)
            t2 = time.perf_counter()
            build_time += t1 - t0
            solve_time += t2 - t1
            if output is None:
                return PlanResult(self.name, PlanStatus.INFEASIBLE, None, solve_time, build_time,
                                  message=f"toppra: {instance.problem_data.return_code}")
            sd_vec = np.asarray(instance.problem_data.sd_vec, dtype=float)
            sd_prev = sd_vec
        law = TimeLaw.constant_acceleration(grid, sd_vec**2)
        traj = trajectory_from_time_law(problem.path, law, dyn, metadata={
            "planner": self.name, "status": PlanStatus.FEASIBLE.value, "solve_time_s": solve_time})
        info: dict[str, Any] = {"sigma": grid, "sigma_dot": sd_vec, "duration_grid_s": law.duration,
                                "passes": passes}
        return PlanResult(self.name, PlanStatus.FEASIBLE, traj, solve_time, build_time,
                          message="toppra: Ok", info=info)
