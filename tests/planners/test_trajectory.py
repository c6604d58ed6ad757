"""The common trajectory type: interpolation, CSV round trip, metrics; limits and interface types."""
import math

import numpy as np
import pytest

from planners.base import CPProblem, JointLimits, PlannerInputError, PlanResult, PlanStatus
from planners.trajectory import (
    Trajectory,
    TrajectoryError,
    constraint_ratios,
    energy,
    max_constraint_ratio,
    uniform_times,
)


def _sine_trajectory(dt=0.01, t_end=2.0, amplitude=0.5, omega=3.0):
    t = np.linspace(0.0, t_end, int(round(t_end / dt)) + 1)
    phase = omega * t[:, None] + np.arange(6)[None, :]
    q = amplitude * np.sin(phase)
    qd = amplitude * omega * np.cos(phase)
    qdd = -amplitude * omega**2 * np.sin(phase)
    tau = 10.0 * q
    return Trajectory(t, q, qd, qdd, tau, {"x": t.copy()}, {"planner": "sine", "status": PlanStatus.OPTIMAL})


def test_quintic_sampling_matches_analytic_signal_and_is_self_consistent():
    traj = _sine_trajectory()
    times = np.linspace(0.0, 2.0, 3001)
    s = traj.sample(times)
    phase = 3.0 * times[:, None] + np.arange(6)[None, :]
    assert np.max(np.abs(s.q - 0.5 * np.sin(phase))) < 1e-9
    assert np.max(np.abs(s.qd - 1.5 * np.cos(phase))) < 1e-6
    assert np.max(np.abs(s.qdd + 4.5 * np.sin(phase))) < 1e-3
    # qd is the derivative of q: central differences agree
    fd = (s.q[2:] - s.q[:-2]) / (times[2:] - times[:-2])[:, None]
    assert np.max(np.abs(fd - s.qd[1:-1])) < 1e-4
    scalar = traj.sample(0.123)
    assert scalar.q.shape == (6,)


def test_resample_keeps_end_points_and_csv_round_trip(tmp_path):
    traj = _sine_trajectory()
    fine = traj.resample(4e-4)
    assert fine.t[0] == traj.t[0] and fine.t[-1] == traj.t[-1]
    assert np.allclose(np.diff(fine.t)[:-1], 4e-4)
    path = traj.write_csv(tmp_path / "traj.csv")
    back = Trajectory.read_csv(path)
    assert np.array_equal(back.q, traj.q) and np.array_equal(back.tau, traj.tau)
    assert np.array_equal(back.cartesian["x"], traj.cartesian["x"])
    assert back.metadata == {"planner": "sine", "status": "optimal"}


def test_uniform_times_end_exactly():
    times = uniform_times(0.0, 1.0005, 1e-3)
    assert times[-1] == 1.0005 and np.all(np.diff(times) > 0)


def test_energy_and_ratios_of_a_known_signal():
    traj = _sine_trajectory(dt=1e-3, t_end=2 * math.pi / 3.0)  # one full period
    # tau = 5 sin(.): integral of 25 sin^2 over one period = 25 * T / 2, six joints
    expected = 6 * 25.0 * (2 * math.pi / 3.0) / 2
    assert energy(traj) == pytest.approx(expected, rel=1e-5)
    limits = JointLimits(velocity=3.0, acceleration=9.0, jerk=27.0, torque=10.0, torque_rate=30.0)
    ratios = constraint_ratios(traj, limits)
    assert np.allclose(ratios["velocity"], 0.5, rtol=1e-5)
    assert np.allclose(ratios["acceleration"], 0.5, rtol=1e-5)
    assert np.allclose(ratios["jerk"], 0.5, rtol=1e-3)
    assert np.allclose(ratios["torque"], 0.5, rtol=1e-5)
    assert np.allclose(ratios["torque_rate"], 0.5, rtol=1e-3)
    assert max_constraint_ratio(traj, limits) == pytest.approx(0.5, rel=1e-3)
    assert max_constraint_ratio(traj, limits.replace(torque=1.0)) == pytest.approx(5.0, rel=1e-4)
    assert max_constraint_ratio(traj, limits.replace(velocity=math.inf, acceleration=math.inf,
                                                     torque=math.inf, torque_rate=math.inf)) == 0.0


def test_bad_inputs_raise_value_errors_naming_the_field():
    traj = _sine_trajectory()
    with pytest.raises(TrajectoryError, match="Trajectory.q"):
        Trajectory(traj.t, traj.q[:, :5], traj.qd, traj.qdd, traj.tau)
    with pytest.raises(TrajectoryError, match="strictly increasing"):
        Trajectory(traj.t[::-1], traj.q, traj.qd, traj.qdd, traj.tau)
    with pytest.raises(TrajectoryError, match="dt"):
        traj.resample(0.0)
    with pytest.raises(PlannerInputError, match="JointLimits.torque"):
        JointLimits(velocity=1.0, acceleration=1.0, jerk=1.0, torque=[1.0] * 5, torque_rate=1.0)
    with pytest.raises(PlannerInputError, match="positive"):
        JointLimits(velocity=1.0, acceleration=-1.0, jerk=1.0, torque=1.0, torque_rate=1.0)
    with pytest.raises(PlannerInputError, match="friction"):
        CPProblem(path=None, limits=JointLimits.from_robot(), friction="dry")
    with pytest.raises(TrajectoryError, match="does not exist"):
        Trajectory.read_csv("/nonexistent/traj.csv")


def test_robot_limits_come_from_the_robot_description():
    from robot.parameters import load_parameters

    params = load_parameters()
    limits = JointLimits.from_robot()
    assert np.array_equal(limits.torque, params.effort_limit)
    assert np.array_equal(limits.torque_rate, params.torque_rate_limit)
    assert np.array_equal(limits.jerk, params.jerk_limit)
    assert limits.active("jerk") and not limits.replace(jerk=math.inf).active("jerk")


def test_plan_result_ok_only_with_a_trajectory():
    traj = _sine_trajectory()
    assert PlanResult("x", PlanStatus.FEASIBLE, traj, 0.1).ok
    assert not PlanResult("x", PlanStatus.FAILED, None, 0.1).ok
