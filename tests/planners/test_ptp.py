"""Own time/energy-optimal PtP planner (paper eq. 40): its targets on the paper line,
dense-output consistency with pinocchio's inverse dynamics, exact derivatives, energy
weighting, and honest statuses for requests that cannot be met."""
from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from planners.base import JointLimits, PlannerInputError, PlanStatus, PtPProblem, CPProblem
from planners.cp_optimal import OwnCPPlanner
from planners.paper_line import paper_cp_problem, paper_line_configurations
from planners.ptp_dynamics import ptp_dynamics
from planners.ptp_figures import normalised_torques_velocities, plot_ptp_torques_velocities
from planners.ptp_nodes import node_functions
from planners.ptp_optimal import (
    OptimalPtPPlanner, PtPUnreachableError, _P_INDEX, _P_SIZE, _transcription, paper_ptp_problem,
    ptp_problem_from_poses,
)
from planners.ruckig_baseline import FeasibleRuckigPlanner
from planners.trajectory import Trajectory, energy, max_constraint_ratio
from robot.dynamics import RobotDynamics
from robot.symbolic import chain_structure

EQ40 = JointLimits.from_robot().replace(acceleration=math.inf, jerk=math.inf)


@pytest.fixture(scope="module")
def dynamics() -> RobotDynamics:
    return RobotDynamics()


@pytest.fixture(scope="module")
def paper_ptp():
    """Own PtP on the paper line, eq. 40 limits, the default 100 intervals."""
    return OptimalPtPPlanner().plan(paper_ptp_problem())


def test_paper_line_targets(paper_ptp, dynamics):
    """Certified optimal, max_constraint_ratio <= 1.001 at 1 ms (torques by
    pinocchio's inverse dynamics), <= 0.7 x own CP duration, shorter than ruckig_feasible."""
    res = paper_ptp
    assert res.status is PlanStatus.OPTIMAL and res.message == "Solve_Succeeded"
    traj = res.trajectory
    ratio = max_constraint_ratio(traj, EQ40, dynamics=dynamics)
    assert ratio <= 1.001
    assert ratio >= 0.99  # time-optimal: some limit is active
    cp = OwnCPPlanner().plan(paper_cp_problem())
    assert cp.status is PlanStatus.OPTIMAL
    assert traj.duration <= 0.7 * cp.trajectory.duration
    ruckig = FeasibleRuckigPlanner().plan(paper_ptp_problem())
    assert ruckig.ok
    assert traj.duration < ruckig.trajectory.duration
    # the same end points as the CP line, at rest
    q0, qe = paper_line_configurations()
    np.testing.assert_allclose(traj.q[0], q0, atol=1e-9)
    np.testing.assert_allclose(traj.q[-1], qe, atol=1e-9)
    np.testing.assert_allclose(traj.qd[[0, -1]], 0.0, atol=1e-9)
    np.testing.assert_allclose(traj.qdd[[0, -1]], 0.0, atol=1e-9)


def test_dense_output_is_consistent(paper_ptp, dynamics):
    """Dense samples every 1 ms; qd, qdd are the derivatives of q; tau is pinocchio's
    inverse dynamics of (q, qd, qdd); resampling at 1 ms reproduces the samples."""
    traj = paper_ptp.trajectory
    steps = np.diff(traj.t)
    assert np.all(steps <= 1e-3 + 1e-12)
    tau_ref = np.array([dynamics.inverse_dynamics(traj.q[k], traj.qd[k], traj.qdd[k]) for k in range(traj.n_samples)])
    np.testing.assert_allclose(traj.tau, tau_ref, atol=1e-8 * np.max(np.abs(tau_ref)))
    # q is piecewise cubic: central differences over +-1 ms err by h^2/6 * jerk at most
    jerk = np.max(np.abs(paper_ptp.info["motion"].jerk), axis=0)
    mid = slice(1, -2)
    qd_fd = (traj.q[2:-1] - traj.q[:-3]) / (traj.t[2:-1] - traj.t[:-3])[:, None]
    assert np.all(np.max(np.abs(qd_fd - traj.qd[mid]), axis=0) <= 1.01 * 1e-6 / 6 * jerk + 1e-9)
    qdd_fd = (traj.qd[2:-1] - traj.qd[:-3]) / (traj.t[2:-1] - traj.t[:-3])[:, None]
    assert np.all(np.max(np.abs(qdd_fd - traj.qdd[mid]), axis=0) <= 1e-3 * jerk + 1e-9)
    again = traj.resample(1e-3)
    np.testing.assert_allclose(again.q, traj.q, atol=1e-12)
    # the optimiser's node motion is the dense motion
    motion = paper_ptp.info["motion"]
    q, qd, qdd, _ = motion.sample(motion.t)
    np.testing.assert_allclose(q, motion.q, atol=1e-12)
    np.testing.assert_allclose(qd, motion.qd, atol=1e-12)


def test_node_torque_rates_are_exact_derivatives(paper_ptp):
    """The compiled node function's torque rates (the constraint) equal the time
    derivative of the Coulomb-free torque along the piecewise-cubic motion (differences)."""
    motion = paper_ptp.info["motion"]
    dyn = ptp_dynamics()
    nodes = node_functions(chain_structure())
    scales = np.ones(36)
    dp = np.concatenate([dyn.parameter_vector, dyn.dynamics.payload, [dyn.smoothing_velocity]])
    eps = 1e-6
    for k in (10, 37, 71):
        v = np.concatenate([motion.q[k], motion.qd[k], motion.qdd[k], motion.jerk[k - 1], motion.jerk[k]])
        out = np.asarray(nodes.f(v, scales, dp)).reshape(-1)
        tk = motion.t[k]
        before = (dyn.smooth_torques(*motion.sample(np.array([tk]))[:3])
                  - dyn.smooth_torques(*motion.sample(np.array([tk - eps]))[:3])) / eps
        after = (dyn.smooth_torques(*motion.sample(np.array([tk + eps]))[:3])
                 - dyn.smooth_torques(*motion.sample(np.array([tk]))[:3])) / eps
        scale = np.max(np.abs(out[6:18]))
        np.testing.assert_allclose(out[6:12], before[0], atol=2e-4 * scale)
        np.testing.assert_allclose(out[12:18], after[0], atol=2e-4 * scale)
        np.testing.assert_allclose(out[:6], dyn.torques(motion.q[k:k + 1], motion.qd[k:k + 1],
                                                        motion.qdd[k:k + 1])[0], rtol=1e-12, atol=1e-9)


def test_assembled_derivatives_match_automatic_differentiation():
    """grad_f, jac_g and the triu Hessian of the Lagrangian that IPOPT gets, assembled from
    per-node functions, equal CasADi's AD of the NLP (virtual-machine node functions)."""
    dyn = ptp_dynamics()
    tr, _ = _transcription(dyn, 4, compile_code=False)
    z, p = tr.nlp["x"], tr.nlp["p"]
    lam_f, lam_g = ca.MX.sym("lf"), ca.MX.sym("lg", tr.nlp["g"].numel())
    lag = lam_f * tr.nlp["f"] + ca.dot(lam_g, tr.nlp["g"])
    reference = ca.Function("ref", [z, p, lam_f, lam_g],
                            [ca.gradient(tr.nlp["f"], z), ca.jacobian(tr.nlp["g"], z), ca.triu(ca.hessian(lag, z)[0])])
    rng = np.random.default_rng(3)
    par = np.zeros(_P_SIZE)
    par[:36] = rng.uniform(0.5, 2.0, 36) * np.repeat([1.5, 3.0, 20.0, 300.0, 300.0, 5000.0], 6)
    par[_P_INDEX["s_time"]] = 0.8
    par[_P_INDEX["s_cost"]] = 1.3
    par[_P_INDEX["k1"]], par[_P_INDEX["k2"]], par[_P_INDEX["reg"]] = 1.0, 2e-6, 1e-3
    par[_P_INDEX["dp"]] = np.concatenate([dyn.parameter_vector, [2.0, 0.01, 0.0, 0.05], [0.03]])
    zv = rng.uniform(-0.6, 0.6, tr.layout.size)
    zv[tr.layout.t_index] = 1.1
    lf, lg = 0.7, rng.normal(size=tr.nlp["g"].numel())
    grad_ref, jac_ref, hess_ref = (np.asarray(ca.densify(x)) for x in reference(zv, par, lf, lg))
    _, grad = tr.functions["grad_f"](zv, par)
    _, jac = tr.functions["jac_g"](zv, par)
    hess = tr.functions["hess_lag"](zv, par, lf, lg)
    np.testing.assert_allclose(np.asarray(grad).reshape(-1), grad_ref.reshape(-1), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(np.asarray(ca.densify(jac)), jac_ref, rtol=1e-9, atol=1e-8)
    np.testing.assert_allclose(np.asarray(ca.densify(hess)), hess_ref, rtol=1e-8,
                               atol=1e-9 * np.max(np.abs(hess_ref)))


def test_energy_weighting_trades_time_for_energy():
    """Increasing k2 lowers integral tau^T tau dt and lengthens the motion (coarse grid)."""
    planner = OptimalPtPPlanner()
    rows = []
    for k2 in (0.0, 1e-6, 1e-5):
        res = planner.plan(paper_ptp_problem(k2=k2, n_intervals=40))
        assert res.status is PlanStatus.OPTIMAL, res.message
        assert res.info["max_constraint_ratio"] <= 1.001
        rows.append((res.trajectory.duration, energy(res.trajectory)))
    durations, energies = zip(*rows)
    assert durations[0] < durations[1] < durations[2]
    assert energies[0] > energies[1] > energies[2]
    assert energies[2] < 0.5 * energies[0]


def test_boundary_velocities_are_met():
    """Non-zero start and end velocities: the trajectory starts and ends in those states."""
    q0, qe = paper_line_configurations()
    qd0 = np.array([0.5, 0.0, 0.0, -0.8, 0.0, 0.3])
    qde = np.array([0.0, 0.2, 0.0, 0.5, 0.0, 0.0])
    res = OptimalPtPPlanner().plan(PtPProblem(q0, qe, EQ40, qd0=qd0, qde=qde, n_intervals=40))
    assert res.status is PlanStatus.OPTIMAL, res.message
    traj = res.trajectory
    np.testing.assert_allclose(traj.qd[0], qd0, atol=1e-8)
    np.testing.assert_allclose(traj.qd[-1], qde, atol=1e-8)
    np.testing.assert_allclose(traj.q[-1], qe, atol=1e-8)
    assert res.info["max_constraint_ratio"] <= 1.001


def test_boundary_states_outside_the_limits_are_refused():
    q0, qe = paper_line_configurations()
    planner = OptimalPtPPlanner()
    outside = qe.copy()
    outside[2] = 2.7  # joint 3 range is +-2.618 rad
    res = planner.plan(PtPProblem(q0, outside, EQ40))
    assert res.status is PlanStatus.INFEASIBLE and res.trajectory is None
    assert "qe[joint 3] = 2.7" in res.message and "position range" in res.message
    res = planner.plan(PtPProblem(q0, qe, EQ40, qd0=np.array([4.0, 0, 0, 0, 0, 0])))
    assert res.status is PlanStatus.INFEASIBLE
    assert "qd0[joint 1] = 4" in res.message and "velocity limit" in res.message
    weak = EQ40.replace(torque=np.array([700.0, 50.0, 450.0, 70.0, 60.0, 35.0]))
    res = planner.plan(PtPProblem(q0, qe, weak))
    assert res.status is PlanStatus.INFEASIBLE
    assert "holding torque at the start state, joint 2" in res.message


def test_unmet_requests_are_never_reported_optimal():
    """Joint 1 runs at 3.4 rad/s towards its limit 0.09 rad away: no torque can stop it in
    time. Within a small iteration budget IPOPT certifies nothing and the status says so."""
    q0 = np.array([2.70, 0.5, 1.0, 0.0, 0.5, 0.0])
    qe = np.array([1.5, 0.5, 1.0, 0.0, 0.5, 0.0])
    problem = PtPProblem(q0, qe, EQ40, qd0=np.array([3.4, 0, 0, 0, 0, 0]), n_intervals=20)
    res = OptimalPtPPlanner(ipopt_options={"max_iter": 40}, coulomb_continuation=()).plan(problem)
    assert res.status in (PlanStatus.INFEASIBLE, PlanStatus.FAILED)
    assert res.trajectory is None and not res.ok
    assert "IPOPT" in res.message or "certified" in res.message


def test_solver_failure_gives_failed_status():
    res = OptimalPtPPlanner(ipopt_options={"max_iter": 3}, coulomb_continuation=()).plan(
        paper_ptp_problem(n_intervals=20))
    assert res.status is PlanStatus.FAILED and res.trajectory is None
    assert "Maximum_Iterations_Exceeded" in res.message


def test_malformed_requests_raise():
    q0, qe = paper_line_configurations()
    planner = OptimalPtPPlanner()
    with pytest.raises(PlannerInputError, match="n_intervals"):
        planner.plan(PtPProblem(q0, qe, EQ40, n_intervals=2))
    with pytest.raises(PlannerInputError, match="nothing to plan"):
        planner.plan(PtPProblem(q0, q0, EQ40))
    with pytest.raises(PlannerInputError, match="expected a PtPProblem"):
        planner.plan(CPProblem(None, EQ40))
    with pytest.raises(PlannerInputError, match="jerk_regularisation"):
        OptimalPtPPlanner(jerk_regularisation=-1.0)


def test_unreachable_end_pose_is_a_clear_error():
    start = (1.2, -0.6, 1.1, 0.0, math.pi / 2, 0.0)
    problem = ptp_problem_from_poses(start, (1.2, 0.6, 1.1, 0.0, math.pi / 2, 0.0), EQ40,
                                     (-0.4, 0.5, 1.3, 0.0, -0.3, 0.0))
    np.testing.assert_allclose(problem.q0, paper_line_configurations()[0], atol=1e-8)
    with pytest.raises(PtPUnreachableError, match=r"end_pose \[3.2.*out of reach"):
        ptp_problem_from_poses(start, (3.2, 0.6, 1.1, 0.0, math.pi / 2, 0.0), EQ40, (-0.4, 0.5, 1.3, 0.0, -0.3, 0.0))
    assert issubclass(PtPUnreachableError, ValueError)


def test_figure9_normalised_torques_and_velocities(paper_ptp, tmp_path):
    traj: Trajectory = paper_ptp.trajectory
    t, tau_n, qd_n = normalised_torques_velocities(traj, EQ40)
    assert t.size == traj.n_samples
    assert 0.99 <= np.max(np.abs(tau_n)) <= 1.001
    assert 0.99 <= np.max(np.abs(qd_n)) <= 1.001
    path = plot_ptp_torques_velocities(traj, EQ40, tmp_path / "figure9.png")
    assert path.is_file() and path.stat().st_size > 10_000
    with pytest.raises(PlannerInputError, match="joint numbers"):
        plot_ptp_torques_velocities(traj, EQ40, tmp_path / "bad.png", joints=[0, 7])
