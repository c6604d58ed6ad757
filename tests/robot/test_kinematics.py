"""Forward kinematics, Cardan angles and the geometric Jacobian (robot.kinematics)."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from robot.description import load_model
from robot.kinematics import (
    FlangeKinematics,
    KinematicsInputError,
    as_rotation_matrix,
    as_transform,
    cardan_from_rotation,
    pose_error,
    pose_from_transform,
    rotation_from_cardan,
    transform_from_pose,
)


@pytest.fixture(scope="module")
def kin() -> FlangeKinematics:
    return FlangeKinematics()


def random_configurations(kin: FlangeKinematics, n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(kin.lower, kin.upper, (n, 6))


def test_zero_configuration_is_the_arm_straight_up(kin: FlangeKinematics) -> None:
    t = kin.transform(np.zeros(6))
    np.testing.assert_allclose(t[:3, 3], [0.0, 0.0, 0.30 + 0.25 + 0.625 + 0.50 + 0.425 + 0.080 + 0.030], atol=1e-15)
    np.testing.assert_allclose(t[:3, :3], np.eye(3), atol=1e-15)


def test_horizontal_reach_matches_the_datasheet(kin: FlangeKinematics) -> None:
    # axis 2 at 90 deg: arm stretched horizontally, flange 1.660 m from axis 1 at shoulder height
    p = kin.position([0.0, np.pi / 2, 0.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(p, [1.660, 0.0, 0.550], atol=1e-12)
    # axis 1 at 90 deg turns it onto the y axis
    p = kin.position([np.pi / 2, np.pi / 2, 0.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(p, [0.0, 1.660, 0.550], atol=1e-12)


def test_fk_agrees_with_a_plain_pinocchio_evaluation(kin: FlangeKinematics) -> None:
    model = load_model()
    data = model.createData()
    fid = model.getFrameId("tool0")
    for q in random_configurations(kin, 50):
        pin.framesForwardKinematics(model, data, q)
        np.testing.assert_allclose(kin.transform(q), data.oMf[fid].homogeneous, atol=1e-15)


def test_batched_fk_and_jacobian_equal_the_single_pinocchio_calls(kin: FlangeKinematics) -> None:
    qs = random_configurations(kin, 300, seed=1)
    transforms = kin.transforms(qs)
    jacobians = kin.jacobians(qs)
    for q, t, j in zip(qs, transforms, jacobians):
        np.testing.assert_allclose(t, kin.transform(q), atol=1e-13)
        np.testing.assert_allclose(j, kin.jacobian(q), atol=1e-13)


def test_batched_positions_are_the_transforms_translations_bit_for_bit() -> None:
    """positions() (the evaluation's flange points) is the translation of transforms(), the same
    numbers, on the nominal and on a true robot's model (geometric errors: rotated placements)."""
    from robot.true_robot import make_true_robot

    for model in (None, make_true_robot(3).kinematic_model()):
        kin = FlangeKinematics(model)
        qs = random_configurations(kin, 500, seed=2)
        assert np.array_equal(kin.positions(qs), kin.transforms(qs)[:, :3, 3])
        assert np.array_equal(kin.positions(qs[7]), kin.transforms(qs[7])[:, :3, 3])


def test_pose_is_position_and_cardan_angles(kin: FlangeKinematics) -> None:
    q = np.array([0.3, -0.4, 0.9, 1.2, -0.7, 2.0])
    pose = kin.pose(q)
    np.testing.assert_allclose(pose[:3], kin.position(q), atol=1e-15)
    np.testing.assert_allclose(rotation_from_cardan(pose[3:]), kin.rotation(q), atol=1e-14)


def test_jacobian_matches_central_finite_differences(kin: FlangeKinematics) -> None:
    h = 1e-6
    for q in random_configurations(kin, 30, seed=2):
        jac = kin.jacobian(q)
        fd = np.empty((6, 6))
        for i in range(6):
            dq = np.zeros(6)
            dq[i] = h
            fd[:, i] = pose_error(kin.transform(q + dq), kin.transform(q - dq)) / (2 * h)
        np.testing.assert_allclose(jac, fd, atol=1e-8)


def test_cardan_angles_are_intrinsic_xyz_like_scipy() -> None:
    rng = np.random.default_rng(3)
    angles = np.column_stack(
        [rng.uniform(-np.pi, np.pi, 1000), rng.uniform(-np.pi / 2, np.pi / 2, 1000), rng.uniform(-np.pi, np.pi, 1000)]
    )
    reference = Rotation.from_euler("XYZ", angles).as_matrix()  # capitals: intrinsic
    np.testing.assert_allclose(rotation_from_cardan(angles), reference, atol=1e-15)
    single = rotation_from_cardan([0.1, 0.2, 0.3])
    rx = Rotation.from_euler("x", 0.1).as_matrix()
    ry = Rotation.from_euler("y", 0.2).as_matrix()
    rz = Rotation.from_euler("z", 0.3).as_matrix()
    np.testing.assert_allclose(single, rx @ ry @ rz, atol=1e-15)


def test_cardan_round_trip_both_ways() -> None:
    rng = np.random.default_rng(4)
    angles = np.column_stack(
        [rng.uniform(-np.pi, np.pi, 10000), rng.uniform(-np.pi / 2, np.pi / 2, 10000), rng.uniform(-np.pi, np.pi, 10000)]
    )
    np.testing.assert_allclose(cardan_from_rotation(rotation_from_cardan(angles)), angles, atol=1e-9)
    rotations = Rotation.random(10000, random_state=5).as_matrix()
    np.testing.assert_allclose(rotation_from_cardan(cardan_from_rotation(rotations)), rotations, atol=1e-14)


def test_cardan_gimbal_lock_is_deterministic() -> None:
    for beta in (np.pi / 2, -np.pi / 2):
        r = rotation_from_cardan([0.4, beta, -0.3])
        angles = cardan_from_rotation(r)
        assert angles[2] == 0.0
        assert angles[1] == pytest.approx(beta, abs=1e-12)
        np.testing.assert_allclose(rotation_from_cardan(angles), r, atol=1e-14)


def test_pose_transform_round_trip() -> None:
    pose = np.array([0.8, -0.2, 1.1, 0.5, -0.3, 2.5])
    np.testing.assert_allclose(pose_from_transform(transform_from_pose(pose)), pose, atol=1e-14)
    poses = np.tile(pose, (5, 1))
    assert transform_from_pose(poses).shape == (5, 4, 4)


def test_pose_error_is_position_difference_and_rotation_vector() -> None:
    target = transform_from_pose([1.0, 2.0, 3.0, 0.0, 0.0, 0.0])
    actual = transform_from_pose([0.5, 2.0, 3.0, 0.0, 0.0, 0.0])
    rotated = target.copy()
    rotated[:3, :3] = Rotation.from_rotvec([0.0, 0.0, 0.2]).as_matrix()
    np.testing.assert_allclose(pose_error(target, actual), [0.5, 0, 0, 0, 0, 0], atol=1e-15)
    np.testing.assert_allclose(pose_error(rotated, target), [0, 0, 0, 0, 0, 0.2], atol=1e-15)


def test_wrong_length_joint_vectors_raise_clear_errors(kin: FlangeKinematics) -> None:
    with pytest.raises(KinematicsInputError, match=r"'q'.*shape \(6,\).*shape \(5,\)"):
        kin.transform(np.zeros(5))
    with pytest.raises(ValueError, match="finite"):
        kin.jacobian([0, 0, np.nan, 0, 0, 0])
    with pytest.raises(KinematicsInputError, match=r"\(n, 6\)"):
        kin.transforms(np.zeros((4, 7)))


def test_bad_rotation_matrices_raise_clear_errors() -> None:
    good = rotation_from_cardan([0.1, 0.2, 0.3])
    np.testing.assert_array_equal(as_rotation_matrix(good), good)
    with pytest.raises(KinematicsInputError, match="not a rotation matrix"):
        as_rotation_matrix(1.01 * good)
    with pytest.raises(KinematicsInputError, match=r"det R = -1"):
        as_rotation_matrix(-good)  # a reflection
    with pytest.raises(KinematicsInputError, match="3x3"):
        as_rotation_matrix(np.eye(4))
    with pytest.raises(KinematicsInputError, match="finite"):
        as_rotation_matrix(np.full((3, 3), np.nan))
    bad_transform = np.eye(4)
    bad_transform[3, 0] = 1.0
    with pytest.raises(KinematicsInputError, match="last row"):
        as_transform(bad_transform)
    with pytest.raises(KinematicsInputError, match="4x4"):
        as_transform(np.eye(3))


def test_models_other_than_this_arm_are_rejected() -> None:
    model = pin.buildSampleModelManipulator()
    with pytest.raises(KinematicsInputError, match="model"):
        FlangeKinematics(model)


def test_within_limits(kin: FlangeKinematics) -> None:
    assert kin.within_limits(np.zeros(6))
    assert not kin.within_limits([0.0, 0.0, 0.0, 0.0, 2.5, 0.0])  # axis 5 upper limit 120 deg
