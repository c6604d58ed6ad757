"""Exciting trajectories: Fourier series (eq. 29), the optimisation of eq. 30 on a reduced problem.

The full problem (order 5, 80 samples) takes about a minute; here order 2 with 30
samples and 25 SLSQP iterations shows the same effect (about 10x) in a few seconds. The full figures are in
``benchmarks/bench_identification.py`` and the identification campaign.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from identification.errors import ExcitationDesignError
from identification.excitation import (ExcitationLimits, ExcitationProblem, ExcitationSettings,
                                               design_excitation, random_feasible_trajectory)
from identification.fourier import FourierTrajectory
from robot.dynamics import RobotDynamics
from robot.kinematics import FlangeKinematics


@pytest.fixture(scope="module")
def small_problem():
    return ExcitationProblem(settings=ExcitationSettings(order=2, samples=30, constraint_samples=40,
                                                         max_iterations=25))


def test_fourier_series_derivatives_period_and_rest():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(6, 5)), rng.normal(size=(6, 5))
    a[:, -1] = -a[:, :-1].sum(axis=1)  # qd(0) = 0
    b[:, -1] = -(b[:, :-1] * np.arange(1, 5)).sum(axis=1) / 5  # qdd(0) = 0
    traj = FourierTrajectory(a, b, rng.normal(size=6), 0.8)
    assert traj.period == pytest.approx(2 * math.pi / 0.8)
    t = np.linspace(0.0, 3.0, 3001)
    s = traj.sample(t)
    assert np.allclose(np.gradient(s.q, t, axis=0)[1:-1], s.qd[1:-1], atol=2e-5)
    assert np.allclose(np.gradient(s.qd, t, axis=0)[1:-1], s.qdd[1:-1], atol=2e-5)
    end = traj.sample([0.0, traj.period])
    assert np.allclose(end.q[0], end.q[1]) and np.allclose(end.qd[0], end.qd[1])
    assert traj.starts_at_rest()
    assert np.allclose(FourierTrajectory.from_dict(traj.to_dict()).vector(), traj.vector())
    with pytest.raises(ExcitationDesignError, match="q0"):
        FourierTrajectory(a, b, np.zeros(5))


def test_objective_gradient_matches_finite_differences(small_problem):
    x = random_feasible_trajectory(small_problem, np.random.default_rng(3))
    f, g = small_problem.objective(x)
    assert math.exp(f) == pytest.approx(small_problem.condition_number(x), rel=1e-12)
    d = np.random.default_rng(4).normal(size=x.size)
    h = 1e-6
    fd = (small_problem.objective(x + h * d)[0] - small_problem.objective(x - h * d)[0]) / (2 * h)
    assert fd == pytest.approx(g @ d, rel=1e-5)
    c, jac = small_problem.nonlinear_constraints(x)
    fd_c = (small_problem.nonlinear_constraints(x + h * d)[0] - small_problem.nonlinear_constraints(x - h * d)[0]) / (2 * h)
    assert np.max(np.abs(fd_c - jac @ d)) < 1e-5 * max(1.0, np.max(np.abs(jac @ d)))


def test_constraints_agree_with_pinocchio(small_problem):
    """Torque and flange-position constraints use CasADi; check them against pinocchio."""
    x = random_feasible_trajectory(small_problem, np.random.default_rng(5))
    traj = small_problem.trajectory(x)
    s = traj.sample(np.arange(40) * traj.period / 40)
    nominal, flange = RobotDynamics(), FlangeKinematics()
    tau = np.array([nominal.inverse_dynamics(*z) for z in zip(s.q, s.qd, s.qdd)])
    lim = small_problem.limits
    margin = small_problem.settings.margin
    c = small_problem.nonlinear_constraints(x)[0]
    assert np.allclose(1.0 - margin - c[:240], (tau / lim.tau_max).reshape(-1), atol=1e-9)  # 40 samples x 6
    r = np.array([flange.position(q) for q in s.q])
    span = lim.tcp_upper - lim.tcp_lower
    assert np.allclose(c[480:600] + margin, ((r - lim.tcp_lower) / span).reshape(-1), atol=1e-9)


def test_optimised_excitation_beats_random_by_five(small_problem):
    result = design_excitation(small_problem, seed=1, random_baselines=6)
    assert result.feasibility.feasible, result.feasibility
    assert result.trajectory.starts_at_rest(1e-7)
    assert result.condition_number < result.initial_condition_number
    assert result.improvement_over_random >= 5.0, (result.condition_number, result.random_condition_numbers)
    summary = result.to_dict()
    assert summary["condition_number_of_information_matrix"] == pytest.approx(result.condition_number**2)
    assert len(result.history) >= 2 and result.history[-1] <= result.history[0]


def test_bad_limits_and_settings_are_refused():
    with pytest.raises(ExcitationDesignError, match="torque_fraction"):
        ExcitationLimits.from_parameters(torque_fraction=1.5)
    with pytest.raises(ExcitationDesignError, match="tcp box"):
        ExcitationLimits.from_parameters(tcp_box=((1.0, 0.0, 0.0), (0.5, 1.0, 1.0)))
    with pytest.raises(ExcitationDesignError, match="order"):
        ExcitationSettings(order=0)


def test_infeasible_centre_is_reported(small_problem):
    with pytest.raises(ExcitationDesignError, match="centre pose"):
        random_feasible_trajectory(small_problem, np.random.default_rng(0), centre=np.zeros(6))  # flange at z 2.21
