"""Ruckig baselines: Ruckig with the kinematic limits as given, and Ruckig tuned to the
torque limits; both behind the Planner interface with torques from inverse dynamics."""
from __future__ import annotations

import math

import numpy as np
import pytest
from ruckig import InputParameter, Result, Ruckig
from ruckig import Trajectory as RuckigTrajectory

from planners.base import CPProblem, JointLimits, Planner, PlannerInputError, PlanStatus, PtPProblem
from planners.paper_line import paper_line_configurations
from planners.ptp_optimal import eq40_limits, paper_ptp_problem
from planners.ruckig_baseline import FeasibleRuckigPlanner, RuckigPlanner, kinematic_limits, torque_tuned_motion
from planners.ptp_dynamics import ptp_dynamics
from planners.trajectory import constraint_ratios, max_constraint_ratio
from robot.dynamics import RobotDynamics

ROBOT = JointLimits.from_robot()


@pytest.fixture(scope="module")
def dynamics() -> RobotDynamics:
    return RobotDynamics()


def _reference_duration(problem: PtPProblem, velocity, acceleration, jerk) -> float:
    inp = InputParameter(6)
    inp.current_position, inp.target_position = problem.q0.tolist(), problem.qe.tolist()
    inp.current_velocity, inp.target_velocity = problem.qd0.tolist(), problem.qde.tolist()
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = list(velocity), list(acceleration), list(jerk)
    out = RuckigTrajectory(6)
    assert Ruckig(6).calculate(inp, out) == Result.Working
    return out.duration


def test_ruckig_as_given(dynamics):
    """Kinematic limits as given: Ruckig's own duration, limits kept, boundary states met,
    torque = pinocchio inverse dynamics of the samples."""
    q0, qe = paper_line_configurations()
    problem = PtPProblem(q0, qe, ROBOT)
    res = RuckigPlanner().plan(problem)
    assert isinstance(RuckigPlanner(), Planner) and RuckigPlanner.kind == "ptp"
    assert res.status is PlanStatus.FEASIBLE and res.message == "Result.Working"
    traj = res.trajectory
    assert traj.duration == pytest.approx(_reference_duration(problem, ROBOT.velocity, ROBOT.acceleration, ROBOT.jerk),
                                          abs=1e-12)
    np.testing.assert_allclose(traj.q[[0, -1]], [q0, qe], atol=1e-9)
    ratios = constraint_ratios(traj, ROBOT, dynamics=dynamics)
    for kind in ("velocity", "acceleration", "jerk"):
        assert np.max(ratios[kind]) <= 1.0 + 1e-6
    tau_ref = np.array([dynamics.inverse_dynamics(traj.q[k], traj.qd[k], traj.qdd[k]) for k in range(0, traj.n_samples, 7)])
    np.testing.assert_allclose(traj.tau[::7], tau_ref, atol=1e-8 * np.max(np.abs(tau_ref)))
    assert res.info["torque_checked"] is False


def test_feasible_ruckig_scales_down_until_torques_hold(dynamics):
    """Halved torque limits: Ruckig as given exceeds them; the tuned one keeps them, with
    the largest scale (within the resolution) and a longer duration."""
    weak = ROBOT.replace(torque=ROBOT.torque * 0.45)
    q0, qe = paper_line_configurations()
    problem = PtPProblem(q0, qe, weak)
    plain = RuckigPlanner().plan(problem)
    assert plain.info["max_constraint_ratio"] > 1.0
    tuned = FeasibleRuckigPlanner().plan(problem)
    assert tuned.status is PlanStatus.FEASIBLE
    scale = tuned.info["scale"]
    assert 0.0 < scale < 1.0 and tuned.info["velocity_scaled"] is False
    assert max_constraint_ratio(tuned.trajectory, weak, dynamics=dynamics) <= 1.0 + 1e-9
    assert tuned.trajectory.duration > plain.trajectory.duration
    # a slightly larger scale breaks a torque limit: the scale is the largest one
    dyn = ptp_dynamics()
    velocity, acceleration, jerk, _ = kinematic_limits(problem)
    from planners.ruckig_baseline import ruckig_motion

    bigger = ruckig_motion(problem, velocity, acceleration * scale * 1.004, jerk * scale * 1.004)
    ratios = dyn.ratios(bigger.t, bigger.q, bigger.qd, bigger.qdd, weak)
    assert max(np.max(ratios["torque"]), np.max(ratios["torque_rate"])) > 1.0


def test_feasible_ruckig_without_kinematic_limits_uses_rated_stand_ins(dynamics):
    """Eq. 40 limits (no acceleration/jerk): the robot's rated values stand in and may be
    scaled up; torque and torque-rate limits are then the binding ones."""
    problem = paper_ptp_problem()
    plain = RuckigPlanner().plan(problem)
    tuned = FeasibleRuckigPlanner().plan(problem)
    assert plain.ok and tuned.ok
    assert tuned.info["scale"] > 1.0
    assert tuned.trajectory.duration < plain.trajectory.duration
    ratios = constraint_ratios(tuned.trajectory, problem.limits, dynamics=dynamics)
    binding = max(np.max(ratios["torque"]), np.max(ratios["torque_rate"]))
    assert 0.99 <= binding <= 1.0 + 1e-9
    assert kinematic_limits(problem)[3] > 1.0
    assert kinematic_limits(PtPProblem(problem.q0, problem.qe, ROBOT))[3] == 1.0


def test_requests_that_cannot_be_met():
    q0, qe = paper_line_configurations()
    for planner in (RuckigPlanner(), FeasibleRuckigPlanner()):
        res = planner.plan(PtPProblem(q0, qe, ROBOT, qde=np.array([0, 0, 0, 6.0, 0, 0])))
        assert res.status is PlanStatus.INFEASIBLE and "qde[joint 4] = 6" in res.message
        # joint 1 at 3.4 rad/s, 0.09 rad from its limit: Ruckig overshoots the range
        res = planner.plan(PtPProblem(np.array([2.7, 0.5, 1.0, 0, 0.5, 0]), np.array([1.5, 0.5, 1.0, 0, 0.5, 0]),
                                      ROBOT, qd0=np.array([3.4, 0, 0, 0, 0, 0])))
        assert res.status is PlanStatus.INFEASIBLE and "position range" in res.message
    # a torque limit below what holding the arm needs on the way: no scale helps
    slow = eq40_limits().replace(torque=np.array([700.0, 1000.0, 100.0, 70.0, 60.0, 35.0]), velocity=1.0)
    res = FeasibleRuckigPlanner().plan(PtPProblem(np.zeros(6), np.array([0, 0, 2.6, 0, 0, 0]), slow))
    assert res.status is PlanStatus.INFEASIBLE and res.trajectory is None
    assert "no common limit scale" in res.message
    assert torque_tuned_motion(PtPProblem(np.zeros(6), np.array([0, 0, 2.6, 0, 0, 0]), slow), ptp_dynamics()) is None


def test_malformed_input():
    q0, qe = paper_line_configurations()
    with pytest.raises(PlannerInputError, match="expected a PtPProblem"):
        RuckigPlanner().plan(CPProblem(None, ROBOT))
    with pytest.raises(PlannerInputError, match="sample_dt"):
        RuckigPlanner(sample_dt=0.0)
    with pytest.raises(PlannerInputError, match="scale_resolution"):
        FeasibleRuckigPlanner(scale_resolution=-1.0)
    no_stand_in = ROBOT.replace(acceleration=math.inf)
    with pytest.raises(PlannerInputError, match="finite acceleration"):
        RuckigPlanner(fallback_limits=no_stand_in).plan(PtPProblem(q0, qe, no_stand_in))
