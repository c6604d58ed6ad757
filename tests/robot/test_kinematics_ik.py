"""Inverse kinematics: analytic (nominal arm) and numeric (any model), robot.inverse_kinematics."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from robot.geometric_errors import error_model, random_geometric_errors
from robot.inverse_kinematics import (
    AnalyticIK,
    NumericIK,
    UnreachablePoseError,
    closest_equivalent,
    wrap_angle,
)
from robot.kinematics import FlangeKinematics, KinematicsInputError, pose_error, rotation_from_cardan

N_POSES = 10_000
TOL = 1e-9  # m and rad: the required FK(IK(x)) = x bound


@pytest.fixture(scope="module")
def analytic() -> AnalyticIK:
    return AnalyticIK()


@pytest.fixture(scope="module")
def kin() -> FlangeKinematics:
    return FlangeKinematics()


@pytest.fixture(scope="module")
def poses(kin: FlangeKinematics) -> tuple[np.ndarray, np.ndarray]:
    """10,000 reachable poses: FK of joint angles drawn uniformly inside the limits."""
    qs = np.random.default_rng(10).uniform(kin.lower, kin.upper, (N_POSES, 6))
    return qs, kin.transforms(qs)


def max_pose_error(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    e = pose_error(a, b)
    return float(np.abs(e[..., :3]).max()), float(np.abs(e[..., 3:]).max())


def test_analytic_ik_reproduces_10000_poses_on_every_branch(
    analytic: AnalyticIK, kin: FlangeKinematics, poses: tuple[np.ndarray, np.ndarray]
) -> None:
    qs, targets = poses
    q, valid = analytic.solve_batch(targets[:, :3, 3], targets[:, :3, :3])
    counts = valid.sum(axis=1)
    assert counts.min() >= 1 and counts.max() <= 8
    assert np.mean(counts == 8) > 0.3  # most of the workspace has all 8 branches
    back = kin.transforms(q[valid])
    owner = np.repeat(np.arange(N_POSES), counts)
    pos_err, rot_err = max_pose_error(back, targets[owner])
    assert pos_err < TOL and rot_err < TOL
    # every solution respects the joint limits, and the generating angles are among them
    assert np.all(q[valid] >= kin.lower - 1e-12) and np.all(q[valid] <= kin.upper + 1e-12)
    distance = np.abs(wrap_angle(q - qs[:, None, :])).max(axis=2)
    assert np.all(np.any((distance < 1e-7) & valid, axis=1))


def test_analytic_nearest_picks_the_seed_branch_and_2pi_equivalents(analytic: AnalyticIK, kin: FlangeKinematics) -> None:
    q = np.array([0.4, 0.3, 0.8, 4.0, 0.9, -4.2])  # q4, q6 beyond +-pi, inside +-270 deg
    target = kin.transform(q)
    np.testing.assert_allclose(analytic.nearest(target, q + 0.05), q, atol=1e-9)
    plain = analytic.solutions(target)
    assert np.all(np.abs(plain[:, [3, 5]]) <= np.pi)  # without seed: angles in (-pi, pi]
    flipped = analytic.solutions(target, seed=q)  # sorted by distance to the seed
    np.testing.assert_allclose(flipped[0], q, atol=1e-9)


def test_wrist_singularity_is_deterministic(analytic: AnalyticIK, kin: FlangeKinematics) -> None:
    q = np.array([0.3, 0.4, -0.6, 0.7, 0.0, -0.2])  # q5 = 0: only q4 + q6 is defined
    target = kin.transform(q)
    without_seed = analytic.solutions(target)
    singular = without_seed[np.abs(without_seed[:, 4]) < 1e-12]
    assert len(singular) == 1  # the wrist flip is the same configuration
    assert singular[0, 3] == 0.0  # no seed: q4 = 0, q6 takes q4 + q6
    assert singular[0, 5] == pytest.approx(wrap_angle(0.7 - 0.2), abs=1e-12)
    with_seed = analytic.nearest(target, q)
    np.testing.assert_allclose(with_seed, q, atol=1e-12)  # seed's q4 kept
    np.testing.assert_array_equal(analytic.nearest(target, q), with_seed)  # repeatable
    for sol in without_seed:
        assert max_pose_error(kin.transform(sol), target) < (TOL, TOL)


def test_shoulder_singularity_takes_q1_from_the_seed(analytic: AnalyticIK, kin: FlangeKinematics) -> None:
    # wrist centre on axis 1: q2 + q3 bend the forearm back over axis 1
    a2, a3 = analytic.upper_arm, analytic.forearm
    q2 = 0.5
    q3 = -q2 - np.arcsin(a2 * np.sin(q2) / a3)  # a2 sin q2 + a3 sin(q2 + q3) = 0
    q = np.array([1.1, q2, q3, 0.2, 0.6, -0.3])
    target = kin.transform(q)
    np.testing.assert_allclose(
        (target[:3, 3] - analytic.wrist_to_flange * target[:3, 2])[:2], 0.0, atol=1e-12
    )
    sols = analytic.solutions(target, seed=q)
    np.testing.assert_allclose(sols[0], q, atol=1e-9)
    assert set(np.round(np.abs(sols[:, 0]), 9)) <= {1.1, round(np.pi - 1.1, 9)}


def test_numeric_ik_agrees_with_analytic_ik_on_10000_poses(
    kin: FlangeKinematics, poses: tuple[np.ndarray, np.ndarray]
) -> None:
    qs, targets = poses
    numeric = NumericIK()
    rng = np.random.default_rng(11)
    seeds = qs + rng.uniform(-0.02, 0.02, qs.shape)  # warm start: about one controller cycle
    seeds = np.clip(seeds, kin.lower, kin.upper)
    solved = np.array([numeric.solve(t, s) for t, s in zip(targets, seeds)])
    # away from the elbow (q3 = 0) and wrist (q5 = 0) singularities, where two branches
    # come within the seed's distance of each other, Newton must land on the branch
    # the pose was made from
    regular = (np.abs(np.sin(qs[:, 4])) > 0.05) & (np.abs(qs[:, 2]) > 0.05)
    assert regular.sum() > 0.9 * N_POSES
    np.testing.assert_allclose(solved[regular], qs[regular], atol=1e-7)
    pos_err, rot_err = max_pose_error(kin.transforms(solved), targets)
    assert pos_err < TOL and rot_err < TOL


def test_numeric_ik_on_an_error_model(kin: FlangeKinematics) -> None:
    model = error_model(random_geometric_errors(5))
    numeric = NumericIK(model)
    err_kin = FlangeKinematics(model)
    qs = np.random.default_rng(12).uniform(kin.lower * 0.9, kin.upper * 0.9, (500, 6))
    targets = err_kin.transforms(qs)
    solved = np.array([numeric.solve(t, q + 0.01) for t, q in zip(targets, qs)])
    pos_err, rot_err = max_pose_error(err_kin.transforms(solved), targets)
    assert pos_err < TOL and rot_err < TOL
    # all solutions of the error model lie near the nominal analytic ones
    all_solutions = numeric.solve_all(targets[0])
    nominal = AnalyticIK().solutions(targets[0])
    for sol in all_solutions:
        assert max_pose_error(err_kin.transform(sol), targets[0]) < (TOL, TOL)
        assert np.min(np.abs(wrap_angle(nominal - sol)).max(axis=1)) < 0.05


def test_numeric_ik_from_a_cold_seed_falls_back_to_the_nearest_branch(kin: FlangeKinematics) -> None:
    numeric = NumericIK()
    q = np.array([1.05, -0.53, -1.91, 2.08, 0.23, -1.79])
    target = kin.transform(q)
    far_seed = np.array([-2.0, 1.5, 2.0, -3.0, -1.5, 3.0])
    sol = numeric.solve(target, far_seed)
    assert max_pose_error(kin.transform(sol), target) < (TOL, TOL)
    assert kin.within_limits(sol)
    nearest = numeric.solve_nearest(target, far_seed)
    assert max_pose_error(kin.transform(nearest), target) < (TOL, TOL)
    # warm start needs only a few Newton steps
    numeric.solve(pin.SE3(target), q + 1e-3)
    assert 1 <= numeric.last_iterations <= 3


def test_unreachable_poses_raise_unreachable_pose_error(analytic: AnalyticIK) -> None:
    far = np.eye(4)
    far[:3, 3] = [3.0, 0.0, 1.0]
    with pytest.raises(UnreachablePoseError, match=r"out of reach.*expected 0\.300 \.\.\. 1\.550 m"):
        analytic.solutions(far)
    with pytest.raises(UnreachablePoseError, match="out of reach"):
        NumericIK().solve(far, np.zeros(6))
    # flange pointing down just above the base: every branch needs |q5| of about 163 deg
    down = np.eye(4)
    down[:3, :3] = rotation_from_cardan([np.pi, 0.0, 0.0])
    down[:3, 3] = [0.0, 0.0, 1.89]
    with pytest.raises(UnreachablePoseError, match="joint limits"):
        analytic.solutions(down)
    with pytest.raises(UnreachablePoseError, match="joint limits"):
        NumericIK().solve(down, np.zeros(6))
    assert issubclass(UnreachablePoseError, ValueError)


def test_malformed_ik_input_raises_clear_errors(analytic: AnalyticIK, kin: FlangeKinematics) -> None:
    numeric = NumericIK()
    target = kin.transform(np.full(6, 0.3))
    with pytest.raises(KinematicsInputError, match=r"'seed'.*shape \(6,\).*shape \(5,\)"):
        numeric.solve(target, np.zeros(5))
    with pytest.raises(KinematicsInputError, match=r"'seed'.*finite"):
        numeric.solve(target, [0, 0, np.nan, 0, 0, 0])
    with pytest.raises(KinematicsInputError, match=r"'seed'"):
        analytic.nearest(target, np.zeros(7))
    skewed = target.copy()
    skewed[:3, :3] *= 1.001
    for solve in (lambda t: numeric.solve(t, np.zeros(6)), analytic.solutions):
        with pytest.raises(KinematicsInputError, match="not a rotation matrix"):
            solve(skewed)
        with pytest.raises(KinematicsInputError, match="4x4"):
            solve(np.eye(3))
    reflected = target.copy()
    reflected[:3, 0] *= -1.0
    with pytest.raises(KinematicsInputError, match="det"):
        numeric.solve(pin.SE3(reflected[:3, :3], reflected[:3, 3]), np.zeros(6))
    with pytest.raises(KinematicsInputError, match="tolerance"):
        NumericIK(tolerance=0.0)


def test_analytic_ik_refuses_a_model_with_errors() -> None:
    with pytest.raises(KinematicsInputError, match="NumericIK"):
        AnalyticIK(error_model(random_geometric_errors(1)))


def test_closest_equivalent_stays_inside_limits() -> None:
    lower = np.full(6, -1.5 * np.pi)
    upper = np.full(6, 1.5 * np.pi)
    q = np.array([3.0, -3.0, 0.1, 3.0, 3.0, 0.0])
    seed = np.array([-3.2, 3.2, 0.1, 7.0, -7.0, 6.0])
    out = closest_equivalent(q, seed, lower, upper)
    np.testing.assert_allclose(out, [3.0 - 2 * np.pi, -3.0 + 2 * np.pi, 0.1, 3.0, 3.0 - 2 * np.pi, 0.0])
    assert np.all(out >= lower) and np.all(out <= upper)
