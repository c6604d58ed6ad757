"""Own CP planner against TOPP-RA on the paper line, jerk/torque-rate limits, energy
weighting, honest statuses, summaries and figures."""
import math

import numpy as np
import pytest

from planners.base import CPProblem, Planner, PlanResult, PlanStatus
from planners.cp_optimal import OwnCPPlanner
from planners.paper_line import paper_cp_problem, paper_line_path
from planners.report import planner_summary, plot_active_constraints, plot_velocity_profile
from planners.toppra_baseline import ToppraPlanner
from planners.trajectory import constraint_ratios, energy, max_constraint_ratio
from robot.dynamics import RobotDynamics
from robot.kinematics import FlangeKinematics


@pytest.fixture(scope="module")
def dyn():
    return RobotDynamics()


@pytest.fixture(scope="module")
def kinematic_problem(dyn):
    return paper_cp_problem(dynamics=dyn, friction="coulomb", kinematic_only_limits=True)


@pytest.fixture(scope="module")
def own_and_toppra(kinematic_problem):
    return OwnCPPlanner().plan(kinematic_problem), ToppraPlanner().plan(kinematic_problem)


def test_own_cp_is_as_fast_as_toppra_and_respects_limits_between_grid_points(own_and_toppra, kinematic_problem, dyn):
    own, top = own_and_toppra
    assert own.status is PlanStatus.OPTIMAL and own.message == "Solve_Succeeded"
    assert top.status is PlanStatus.FEASIBLE
    assert own.trajectory.duration <= 1.001 * top.trajectory.duration
    assert max_constraint_ratio(own.trajectory, kinematic_problem.limits, dynamics=dyn) <= 1.001
    # the time-optimal solution rides on its limits (paper Figure 8)
    assert max_constraint_ratio(own.trajectory, kinematic_problem.limits, dynamics=dyn) > 0.999
    # TOPP-RA imposes its limits at the grid points only and overshoots in between
    assert max_constraint_ratio(top.trajectory, kinematic_problem.limits, dynamics=dyn) > 1.001


def test_own_cp_with_viscous_friction_matches_toppra_duration(dyn):
    problem = paper_cp_problem(dynamics=dyn, friction="full", kinematic_only_limits=True)
    own = OwnCPPlanner().plan(problem)
    top = ToppraPlanner(viscous_iterations=1).plan(problem)
    assert own.status is PlanStatus.OPTIMAL
    assert own.trajectory.duration <= 1.001 * top.trajectory.duration
    assert max_constraint_ratio(own.trajectory, problem.limits, dynamics=dyn) <= 1.001


def test_trajectory_stays_on_the_line_and_torque_is_the_robots_inverse_dynamics(own_and_toppra, dyn):
    traj = own_and_toppra[0].trajectory
    line = paper_line_path()
    kin = FlangeKinematics()
    pos = kin.transforms(traj.q[::10])[:, :3, 3]
    direction = (line.end - line.start) / np.linalg.norm(line.end - line.start)
    offset = pos - line.start
    off_line = offset - np.outer(offset @ direction, direction)
    assert np.max(np.linalg.norm(off_line, axis=1)) < 1e-6
    k = traj.n_samples // 2
    assert np.allclose(traj.tau[k], dyn.inverse_dynamics(traj.q[k], traj.qd[k], traj.qdd[k]))
    assert traj.qd[0] == pytest.approx(np.zeros(6)) and np.allclose(traj.qd[-1], 0.0)


def test_jerk_and_torque_rate_limits_are_respected_where_toppra_cannot(dyn):
    problem = paper_cp_problem(dynamics=dyn, friction="full")
    own = OwnCPPlanner().plan(problem)
    assert own.status is PlanStatus.OPTIMAL and own.info["transcription"] == "smooth"
    ratios = constraint_ratios(own.trajectory, problem.limits, dynamics=dyn)
    assert max(np.max(ratios[k]) for k in ("velocity", "acceleration", "torque", "jerk", "torque_rate")) <= 1.001
    assert np.max(ratios["jerk"]) > 0.99  # jerk limits bind
    fast = ToppraPlanner(viscous_iterations=1).plan(problem)
    assert np.max(constraint_ratios(fast.trajectory, problem.limits, dynamics=dyn)["jerk"]) > 10.0
    assert own.trajectory.duration > fast.trajectory.duration


def test_energy_weight_lowers_energy_and_lengthens_the_motion(dyn, own_and_toppra):
    base = paper_cp_problem(dynamics=dyn, friction="coulomb", kinematic_only_limits=True)
    weighted = CPProblem(base.path, base.limits, dyn, k1=1.0, k2=1e-5, friction="coulomb")
    res = OwnCPPlanner().plan(weighted)
    assert res.status is PlanStatus.OPTIMAL
    time_optimal = own_and_toppra[0].trajectory
    assert energy(res.trajectory) < 0.95 * energy(time_optimal)
    assert res.trajectory.duration > 1.03 * time_optimal.duration
    assert max_constraint_ratio(res.trajectory, base.limits, dynamics=dyn) <= 1.001


def test_impossible_requests_are_reported_not_optimal(dyn, kinematic_problem):
    # a torque limit below the gravity load of axis 2: no motion can respect it
    weak = kinematic_problem.limits.replace(torque=np.array([700.0, 5.0, 450.0, 70.0, 60.0, 35.0]))
    problem = CPProblem(kinematic_problem.path, weak, dyn, friction="coulomb", n_intervals=50)
    own = OwnCPPlanner().plan(problem)
    assert own.status is PlanStatus.INFEASIBLE and own.trajectory is None
    assert "joint 2" in own.message
    # a limit that can hold the arm at rest but not move it at all: IPOPT itself must say so
    tight = kinematic_problem.limits.replace(torque=np.abs(dyn.gravity(problem.path.q[0])) * 1.0005 + 1e-3)
    stuck = OwnCPPlanner(ipopt_options={"ipopt.max_iter": 200}).plan(
        CPProblem(kinematic_problem.path, tight, dyn, friction="coulomb", n_intervals=50))
    assert stuck.status is not PlanStatus.OPTIMAL and stuck.trajectory is None
    top = ToppraPlanner().plan(problem)
    assert top.status is PlanStatus.INFEASIBLE and top.trajectory is None
    with pytest.raises(ValueError, match="k2"):
        ToppraPlanner().plan(CPProblem(kinematic_problem.path, kinematic_problem.limits, dyn, k2=1.0))


def test_a_user_planner_plugs_into_the_same_interface_and_summary(kinematic_problem, own_and_toppra, dyn, tmp_path):
    class SlowedDown(Planner):
        """Replays the own planner's trajectory twice as slowly (a user-written planner)."""

        name = "slowed"

        def plan(self, problem):
            src = own_and_toppra[0].trajectory
            from planners.trajectory import Trajectory

            traj = Trajectory(2 * src.t, src.q, src.qd / 2, src.qdd / 4, src.tau, metadata={"planner": self.name})
            return PlanResult(self.name, PlanStatus.FEASIBLE, traj, 0.0)

    res = SlowedDown().plan(kinematic_problem)
    summary = planner_summary(res, kinematic_problem.limits, dyn)
    assert summary["duration_s"] == pytest.approx(2 * own_and_toppra[0].trajectory.duration)
    assert set(summary) >= {"duration_s", "solve_time_s", "max_constraint_ratio", "energy", "status"}
    own, top = own_and_toppra
    fig7 = plot_velocity_profile({"own_cp": own.trajectory, "toppra": top.trajectory}, tmp_path / "fig7.png")
    fig8 = plot_active_constraints(own.trajectory, kinematic_problem.limits, tmp_path / "fig8.png", dyn)
    assert fig7.stat().st_size > 10_000 and fig8.stat().st_size > 10_000
    csv = own.trajectory.write_csv(tmp_path / "own_cp.csv")
    assert csv.stat().st_size > 0
    assert math.isfinite(planner_summary(own, kinematic_problem.limits, dyn)["energy"])
