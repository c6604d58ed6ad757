"""The 39-parameter geometric error model (robot.geometric_errors)."""
from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from robot.description import load_model
from robot.geometric_errors import (
    DEFAULT_ERROR_MAGNITUDES,
    ERROR_PARAMETER_NAMES,
    N_ERROR_PARAMETERS,
    ErrorMagnitudes,
    GeometricErrorInputError,
    GeometricErrorModel,
    default_error_model,
    error_model,
    errors_as_dict,
    export_error_urdf,
    identification_jacobian,
    is_angle_parameter,
    random_geometric_errors,
)
from robot.kinematics import FlangeKinematics, pose_error, pose_from_transform

NOMINAL = FlangeKinematics()


def configurations(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(NOMINAL.lower, NOMINAL.upper, (n, 6))


def single(name: str, value: float) -> np.ndarray:
    p = np.zeros(N_ERROR_PARAMETERS)
    p[ERROR_PARAMETER_NAMES.index(name)] = value
    return p


def test_there_are_39_named_parameters_in_the_paper_groups() -> None:
    names = ERROR_PARAMETER_NAMES
    assert len(names) == 39 == len(set(names))
    # paper: 6x3 lengths, 6 encoder offsets, 12 misalignment angles, 3 base tolerances
    assert names[:18] == tuple(f"len{i}_{c}" for i in range(2, 7) for c in "xyz") + ("flange_x", "flange_y", "flange_z")
    assert names[18:24] == tuple(f"offset{i}" for i in range(1, 7))
    assert names[36:] == ("base_x", "base_y", "base_z")
    # tilts about the link axes perpendicular to each joint axis (z, y, y, z, y, z), without
    # the rotations about z at joints 2 and 5 (on axes 1 and 4: they would be offset1/offset4),
    # plus the flange's own x/y tilt
    assert names[24:36] == (
        "tilt1_x", "tilt1_y", "tilt2_x", "tilt3_x", "tilt3_z", "tilt4_x",
        "tilt4_y", "tilt5_x", "tilt6_x", "tilt6_y", "flange_rx", "flange_ry",
    )
    assert [i for i, n in enumerate(names) if is_angle_parameter(n)] == list(range(18, 36))


def test_no_rotation_parameter_duplicates_another() -> None:
    """The reason for the layout: an earlier split had tilt2_z (= offset1: joint 2 sits on
    axis 1) and tilt5_z (= offset4). Collinear translations (len2_y, len3_y, len4_y ...)
    are identical columns by nature and are merged by the QR reduction."""
    theta = identification_jacobian(configurations(50, 9)).reshape(-1, 39)
    unit = theta / np.linalg.norm(theta, axis=0)
    cosine = np.abs(unit.T @ unit) - np.eye(39)
    identical = [(ERROR_PARAMETER_NAMES[i], ERROR_PARAMETER_NAMES[j])
                 for i, j in np.argwhere(cosine > 1.0 - 1e-9) if i < j]
    assert identical  # the translations along common axes
    assert not [pair for pair in identical if is_angle_parameter(pair[0]) or is_angle_parameter(pair[1])], identical


def test_zero_errors_give_the_nominal_arm() -> None:
    kin = FlangeKinematics(error_model(np.zeros(39)))
    qs = configurations(100, 0)
    np.testing.assert_array_equal(kin.transforms(qs), NOMINAL.transforms(qs))


def test_each_parameter_group_acts_as_documented() -> None:
    zero = np.zeros(6)
    top = NOMINAL.transform(zero)
    # encoder offset: the true joint angle is q + offset
    q = np.array([0.3, -0.5, 0.8, 1.0, 0.6, -0.4])
    for i in range(6):
        dq = np.zeros(6)
        dq[i] = 0.01
        kin = FlangeKinematics(error_model(single(f"offset{i + 1}", 0.01)))
        np.testing.assert_allclose(kin.transform(q), NOMINAL.transform(q + dq), atol=1e-15)
    # length: the joint_3 origin vector (upper arm) grows by 1 mm
    t = FlangeKinematics(error_model(single("len3_z", 1e-3))).transform(zero)
    np.testing.assert_allclose(t[:3, 3], top[:3, 3] + [0, 0, 1e-3], atol=1e-15)
    # base tolerance: the whole arm moves
    t = FlangeKinematics(error_model(single("base_y", 2e-3))).transform(q)
    np.testing.assert_allclose(t[:3, 3], NOMINAL.transform(q)[:3, 3] + [0, 2e-3, 0], atol=1e-15)
    # flange vector error in the link_6 frame
    t = FlangeKinematics(error_model(single("flange_x", 1e-3))).transform(q)
    r6 = NOMINAL.transform(q)[:3, :3]
    np.testing.assert_allclose(t[:3, 3], NOMINAL.transform(q)[:3, 3] + r6[:, 0] * 1e-3, atol=1e-15)
    # tilt of axis 1 about x at its origin (z = 0.30 m): arm leans about the base x axis
    t = FlangeKinematics(error_model(single("tilt1_x", 0.01))).transform(zero)
    rx = Rotation.from_euler("x", 0.01).as_matrix()
    np.testing.assert_allclose(t[:3, 3], [0, 0, 0.30] + rx @ (top[:3, 3] - [0, 0, 0.30]), atol=1e-15)
    np.testing.assert_allclose(t[:3, :3], rx, atol=1e-15)
    # flange tilt: the flange frame turns about its own x (then y) axis, its origin stays
    nominal_t = NOMINAL.transform(q)
    for name, axis in (("flange_rx", "x"), ("flange_ry", "y")):
        t = FlangeKinematics(error_model(single(name, 0.01))).transform(q)
        np.testing.assert_allclose(t[:3, 3], nominal_t[:3, 3], atol=1e-15)
        np.testing.assert_allclose(t[:3, :3], nominal_t[:3, :3] @ Rotation.from_euler(axis, 0.01).as_matrix(), atol=1e-15)
    # the wrist tilt tilt6_x acts before joint 6 turns, the flange tilt after it
    q6 = q.copy()
    q6[5] += 0.7
    t_wrist = FlangeKinematics(error_model(single("tilt6_x", 0.01))).transform(q6)
    t_flange = FlangeKinematics(error_model(single("flange_rx", 0.01))).transform(q6)
    assert np.abs(t_wrist[:3, :3] - t_flange[:3, :3]).max() > 1e-3


def test_layout_follows_the_urdf_structure(tmp_path: Path) -> None:
    # a calibrated description (errors folded into the origins) keeps the same layout
    path = export_error_urdf(tmp_path / "calibrated.urdf", random_geometric_errors(4))
    assert GeometricErrorModel(path).parameter_names == ERROR_PARAMETER_NAMES
    # a shoulder offset (joint 2 off axis 1) leaves 11 joint tilts: not this 39-split
    text = (default_error_model().urdf_path).read_text()
    shifted = text.replace('<origin xyz="0 0 0.25" rpy="0 0 0"/>', '<origin xyz="0.15 0 0.25" rpy="0 0 0"/>')
    assert shifted != text
    (tmp_path / "offset.urdf").write_text(shifted)
    with pytest.raises(GeometricErrorInputError, match=r"offset\.urdf.*10 joint tilts.*got 11"):
        GeometricErrorModel(tmp_path / "offset.urdf")



def test_batched_numpy_fk_equals_pinocchio_on_the_error_model() -> None:
    p = random_geometric_errors(2)
    model = error_model(p)
    data = model.createData()
    fid = model.getFrameId("tool0")
    qs = configurations(200, 1)
    batch = default_error_model().flange_transforms(qs, p)
    for q, t in zip(qs, batch):
        pin.framesForwardKinematics(model, data, q)
        np.testing.assert_allclose(t, data.oMf[fid].homogeneous, atol=1e-13)


@pytest.mark.parametrize("seed", [0, 7])
def test_exported_urdf_reproduces_the_error_model_to_1e12(tmp_path: Path, seed: int) -> None:
    p = random_geometric_errors(seed)
    path = export_error_urdf(tmp_path / "arm_with_errors.urdf", p)
    exported = FlangeKinematics(pin.buildModelFromUrdf(str(path)))
    reference = FlangeKinematics(error_model(p))
    qs = configurations(300, seed)
    worst = max(np.abs(exported.transform(q) - reference.transform(q)).max() for q in qs)
    assert worst < 1e-12
    # also through the project's loader, with the same joint limits and inertias
    loaded = load_model(path)
    np.testing.assert_array_equal(loaded.upperPositionLimit, NOMINAL.upper)
    for i in range(1, 7):
        assert loaded.inertias[i].isApprox(load_model().inertias[i], 1e-15)
    # the XML comment lists every parameter with its value
    text = path.read_text()
    values = errors_as_dict(p)
    for name in ERROR_PARAMETER_NAMES:
        assert f"{name} = {values[name]!r}" in text
    root = ET.fromstring(text.split("?>", 1)[1])
    assert root.tag == "robot"


def test_identification_jacobian_matches_central_finite_differences() -> None:
    model = default_error_model()
    p = random_geometric_errors(3)  # away from p_e = 0: the Jacobian is exact there too
    qs = configurations(40, 2)
    jac = identification_jacobian(qs, p)
    assert jac.shape == (40, 6, 39)
    h = 1e-6
    fd = np.empty_like(jac)
    for k in range(39):
        plus, minus = p.copy(), p.copy()
        plus[k] += h
        minus[k] -= h
        fd[:, :, k] = pose_error(model.flange_transforms(qs, plus), model.flange_transforms(qs, minus)) / (2 * h)
    np.testing.assert_allclose(jac, fd, atol=2e-8)
    # single configuration: shape (1, 6, 39)
    np.testing.assert_allclose(identification_jacobian(qs[0], p)[0], jac[0], atol=1e-15)


def test_offset_columns_are_the_geometric_jacobian() -> None:
    p = random_geometric_errors(4)
    qs = configurations(20, 3)
    jac = identification_jacobian(qs, p)
    geometric = FlangeKinematics(error_model(p)).jacobians(qs)
    offsets = [ERROR_PARAMETER_NAMES.index(f"offset{i}") for i in range(1, 7)]
    np.testing.assert_allclose(jac[:, :, offsets], geometric, atol=1e-14)


def test_30_of_the_39_parameters_are_identifiable_from_full_poses() -> None:
    """The paper's count (30, section 3.2); 25 from positions only."""
    jac = identification_jacobian(configurations(300, 4))
    theta = jac.reshape(-1, 39)
    theta = theta / np.linalg.norm(theta, axis=0)
    singular_values = np.linalg.svd(theta, compute_uv=False)
    assert singular_values[29] > 1e-3 * singular_values[0]
    assert singular_values[30] < 1e-12 * singular_values[0]
    position = jac[:, :3].reshape(-1, 39)
    norms = np.linalg.norm(position, axis=0)
    zero = norms < 1e-12 * norms.max()
    assert [ERROR_PARAMETER_NAMES[i] for i in np.flatnonzero(zero)] == ["offset6", "flange_rx", "flange_ry"]
    s_pos = np.linalg.svd(position[:, ~zero] / norms[~zero], compute_uv=False)
    assert s_pos[24] > 1e-4 * s_pos[0] and s_pos[25] < 1e-12 * s_pos[0]
    # two examples of the dependencies: parallel axes 2 and 3 share their y axis
    names = ERROR_PARAMETER_NAMES
    np.testing.assert_allclose(theta[:, names.index("len2_y")], theta[:, names.index("len3_y")], atol=1e-12)


def test_random_errors_are_seeded_and_scaled_by_the_magnitudes() -> None:
    a = random_geometric_errors(11)
    np.testing.assert_array_equal(a, random_geometric_errors(11))
    assert not np.array_equal(a, random_geometric_errors(12))
    rng = np.random.default_rng(11)
    np.testing.assert_array_equal(random_geometric_errors(rng), a)
    big = np.array([random_geometric_errors(s) for s in range(400)])
    std = big.std(axis=0)
    m = DEFAULT_ERROR_MAGNITUDES
    np.testing.assert_allclose(std[:18], m.length_mm * 1e-3, rtol=0.15)
    np.testing.assert_allclose(std[18:24], np.radians(m.encoder_offset_deg), rtol=0.15)
    np.testing.assert_allclose(std[24:36], np.radians(m.tilt_deg), rtol=0.15)
    np.testing.assert_allclose(std[36:], m.base_mm * 1e-3, rtol=0.15)
    assert not np.any(random_geometric_errors(3, ErrorMagnitudes(0.0, 0.0, 0.0, 0.0)))


def test_uncalibrated_flange_errors_are_like_table_2_of_the_paper() -> None:
    """Paper Table 2 (uncalibrated): max e_x 7.8, e_y 19.0, e_z 12.6 mm; 1.1 - 1.8 deg."""
    qs = configurations(2000, 5)
    nominal = NOMINAL.transforms(qs)
    cardan_nominal = pose_from_transform(nominal)
    upright = np.abs(cardan_nominal[:, 4]) < np.radians(45)  # away from Cardan gimbal lock
    position_max, angle_max = [], []
    for seed in range(10):
        actual = default_error_model().flange_transforms(qs, random_geometric_errors(seed))
        position_max.append(np.abs(actual[:, :3, 3] - nominal[:, :3, 3]).max(axis=0) * 1e3)
        d_angle = pose_from_transform(actual)[upright, 3:] - cardan_nominal[upright, 3:]
        angle_max.append(np.degrees(np.abs(np.angle(np.exp(1j * d_angle))).max(axis=0)))
    position_median = np.median(position_max, axis=0)
    angle_median = np.median(angle_max, axis=0)
    assert np.all((position_median > 5.0) & (position_median < 30.0)), position_median
    assert np.all((angle_median > 0.5) & (angle_median < 2.5)), angle_median


def test_malformed_error_input_raises_clear_errors() -> None:
    with pytest.raises(GeometricErrorInputError, match=r"'errors'.*39.*shape \(38,\)"):
        error_model(np.zeros(38))
    bad = np.zeros(39)
    bad[ERROR_PARAMETER_NAMES.index("tilt3_z")] = np.nan
    with pytest.raises(GeometricErrorInputError, match="tilt3_z"):
        identification_jacobian(np.zeros(6), bad)
    with pytest.raises(GeometricErrorInputError, match="seed"):
        random_geometric_errors(-1)
    with pytest.raises(GeometricErrorInputError, match="tilt_deg"):
        random_geometric_errors(0, ErrorMagnitudes(tilt_deg=-1.0))
    with pytest.raises(ValueError, match=r"\(n, 6\)"):
        identification_jacobian(np.zeros((3, 5)))
