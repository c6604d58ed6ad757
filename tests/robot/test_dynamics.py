"""Numeric dynamics against pinocchio used directly (rigid body + rotor + friction terms)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from robot.description import URDF_PATH, load_model
from robot.dynamics import (
    N_PARAMETERS, PARAMETER_NAMES, DynamicParameterError, RobotDynamics, fold_payload, is_physically_consistent,
    link_parameters, nominal_parameter_vector, payload_link_parameters, pseudo_inertia,
)
from robot.parameters import load_parameters

TOL = 1e-10
PAYLOAD = np.array([8.0, 0.04, -0.03, 0.15])


def _states(seed: int, n: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(-2.0, 2.0, size=(n, 3, 6))


def _reference_torque(model: pin.Model, p: np.ndarray, q, qd, qdd) -> np.ndarray:
    """pinocchio RNEA without armature, plus Ia*qdd and smoothed friction written out here."""
    reference = pin.Model(model)
    reference.armature[:] = 0.0
    v_s = load_parameters().coulomb_smoothing_velocity
    rigid = pin.rnea(reference, reference.createData(), q, qd, qdd)
    return rigid + p[60:66] * qdd + p[66:72] * qd + p[72:78] * np.tanh(qd / v_s)


def _model_with_parameters(p: np.ndarray) -> pin.Model:
    model = load_model()
    for j in range(1, 7):
        model.inertias[j] = pin.Inertia.FromDynamicParameters(p[10 * (j - 1): 10 * j])
    return model


def _urdf_with_payload(tmp_path: Path, mass: float, com: np.ndarray, inertia: np.ndarray) -> Path:
    text = URDF_PATH.read_text(encoding="utf-8")
    com = [repr(float(x)) for x in com]
    mass = repr(float(mass))
    inertia = np.vectorize(lambda x: repr(float(x)), otypes=[object])(inertia)
    extra = f"""
  <link name="payload">
    <inertial>
      <origin xyz="{com[0]} {com[1]} {com[2]}" rpy="0 0 0"/>
      <mass value="{mass}"/>
      <inertia ixx="{inertia[0, 0]}" ixy="{inertia[0, 1]}" ixz="{inertia[0, 2]}"
               iyy="{inertia[1, 1]}" iyz="{inertia[1, 2]}" izz="{inertia[2, 2]}"/>
    </inertial>
  </link>
  <joint name="tool0-payload" type="fixed">
    <parent link="tool0"/>
    <child link="payload"/>
    <origin xyz="0 0 0" rpy="0 0 0"/>
  </joint>
</robot>"""
    path = tmp_path / "with_payload.urdf"
    path.write_text(text.replace("</robot>", extra), encoding="utf-8")
    return path


def test_parameter_layout_contract() -> None:
    assert len(PARAMETER_NAMES) == N_PARAMETERS == 78 == len(set(PARAMETER_NAMES))
    assert PARAMETER_NAMES[:10] == ("m1", "mx1", "my1", "mz1", "Ixx1", "Ixy1", "Iyy1", "Ixz1", "Iyz1", "Izz1")
    assert PARAMETER_NAMES[60] == "Ia1" and PARAMETER_NAMES[66] == "fv1" and PARAMETER_NAMES[77] == "fc6"
    p = nominal_parameter_vector()
    model = load_model()
    params = load_parameters()
    for j in range(1, 7):
        np.testing.assert_array_equal(link_parameters(p, j), model.inertias[j].toDynamicParameters())
    np.testing.assert_array_equal(p[60:66], params.rotor_inertia)
    np.testing.assert_array_equal(p[66:72], params.viscous)
    np.testing.assert_array_equal(p[72:78], params.coulomb)
    np.testing.assert_array_equal(RobotDynamics().parameter_vector(), p)


def test_inverse_dynamics_matches_pinocchio_with_rotor_and_friction() -> None:
    dynamics = RobotDynamics(payload=PAYLOAD)
    p_folded = dynamics.parameter_vector(include_payload=True)
    model = _model_with_parameters(p_folded)
    worst = 0.0
    for q, qd, qdd in _states(1, 30):
        reference = _reference_torque(model, p_folded, q, qd, qdd)
        worst = max(worst, np.abs(dynamics.inverse_dynamics(q, qd, qdd) - reference).max())
    assert worst < TOL


def test_regressor_times_parameters_equals_inverse_dynamics() -> None:
    rng = np.random.default_rng(2)
    p = nominal_parameter_vector() * (1.0 + 0.05 * rng.uniform(-1, 1, N_PARAMETERS))
    dynamics = RobotDynamics(p, PAYLOAD)
    states = _states(3, 40)
    batch = dynamics.regressor_batch(states[:, 0], states[:, 1], states[:, 2])
    assert batch.shape == (40, 6, 78)
    p_folded = dynamics.parameter_vector(include_payload=True)
    for k, (q, qd, qdd) in enumerate(states):
        single = dynamics.regressor(q, qd, qdd)
        np.testing.assert_array_equal(single, batch[k])
        np.testing.assert_allclose(single @ p_folded, dynamics.inverse_dynamics(q, qd, qdd), rtol=0, atol=TOL)


def test_forward_dynamics_inverts_inverse_dynamics() -> None:
    dynamics = RobotDynamics(payload=PAYLOAD)
    for q, qd, qdd in _states(4, 30):
        tau = dynamics.inverse_dynamics(q, qd, qdd)
        np.testing.assert_allclose(dynamics.forward_dynamics(q, qd, tau), qdd, rtol=0, atol=TOL)


def test_mass_matrix_bias_gravity_friction_compose_inverse_dynamics() -> None:
    dynamics = RobotDynamics(payload=PAYLOAD)
    rotor = load_parameters().rotor_inertia
    for q, qd, qdd in _states(5, 20):
        mass = dynamics.mass_matrix(q)
        np.testing.assert_array_equal(mass, mass.T)
        assert np.linalg.eigvalsh(mass).min() > 0.0
        np.testing.assert_allclose(mass @ qdd + dynamics.nonlinear_effects(q, qd),
                                   dynamics.inverse_dynamics(q, qd, qdd), rtol=0, atol=TOL)
        np.testing.assert_allclose(dynamics.gravity(q), dynamics.inverse_dynamics(q, 0 * qd, 0 * qdd)
                                   - dynamics.friction(0 * qd), rtol=0, atol=TOL)
        rigid = pin.crba(_model_with_parameters(dynamics.parameter_vector(True)), pin.Data(dynamics.model), q)
        rigid = np.triu(rigid) + np.triu(rigid, 1).T
        np.testing.assert_allclose(mass - rigid, np.diag(rotor), rtol=0, atol=TOL)


def test_friction_is_smoothed_coulomb_plus_viscous() -> None:
    dynamics = RobotDynamics()
    params = load_parameters()
    fast = np.array([1.0, -1.0, 0.5, -0.5, 2.0, -2.0])
    np.testing.assert_allclose(dynamics.friction(fast), params.viscous * fast + params.coulomb * np.sign(fast),
                               rtol=1e-12)
    np.testing.assert_array_equal(dynamics.friction(np.zeros(6)), np.zeros(6))
    half = dynamics.friction(np.full(6, params.coulomb_smoothing_velocity))
    np.testing.assert_allclose(half, params.viscous * 0.01 + params.coulomb * np.tanh(1.0), rtol=1e-12)


@pytest.mark.parametrize("with_inertia", [False, True])
def test_payload_folding_equals_urdf_with_payload_link(tmp_path: Path, with_inertia: bool) -> None:
    mass, com = PAYLOAD[0], PAYLOAD[1:]
    inertia = np.array([[0.05, 0.004, -0.002], [0.004, 0.06, 0.003], [-0.002, 0.003, 0.03]]) if with_inertia \
        else np.zeros((3, 3))
    urdf_model = pin.buildModelFromUrdf(str(_urdf_with_payload(tmp_path, mass, com, inertia)))
    assert urdf_model.nq == 6
    folded = fold_payload(nominal_parameter_vector(), PAYLOAD, inertia_about_com=inertia)
    np.testing.assert_allclose(folded[50:60], urdf_model.inertias[6].toDynamicParameters(), rtol=0, atol=1e-12)
    if with_inertia:
        return
    # the dynamics object (point-mass payload) against the URDF model plus rotor and friction terms
    dynamics = RobotDynamics(payload=PAYLOAD)
    p = dynamics.parameter_vector()
    for q, qd, qdd in _states(6, 10):
        np.testing.assert_allclose(dynamics.inverse_dynamics(q, qd, qdd),
                                   _reference_torque(urdf_model, p, q, qd, qdd), rtol=0, atol=TOL)


def test_payload_parameters_of_a_point_mass() -> None:
    link = payload_link_parameters([2.0, 0.0, 0.0, 0.1])
    # tool0 is 0.03 m above the joint-6 frame: com at z = 0.13 m
    np.testing.assert_allclose(link, [2.0, 0, 0, 0.26, 2 * 0.13**2, 0, 2 * 0.13**2, 0, 0, 0], atol=1e-15)


def test_physical_consistency_check() -> None:
    p = nominal_parameter_vector()
    assert all(is_physically_consistent(link_parameters(p, j)) for j in range(1, 7))
    # Izz > Ixx + Iyy about the centre of mass breaks the triangle inequality
    bad = np.array([1.0, 0, 0, 0, 0.1, 0, 0.1, 0, 0, 0.3])
    assert not is_physically_consistent(bad)
    assert pseudo_inertia(bad).shape == (4, 4)


def test_identified_parameters_with_payload_zero_give_the_same_torque() -> None:
    # an identified vector has the payload inside link 6: RobotDynamics(p_folded, no payload) must agree
    with_payload = RobotDynamics(payload=PAYLOAD)
    identified = RobotDynamics(with_payload.parameter_vector(include_payload=True), np.zeros(4))
    q, qd, qdd = _states(7, 1)[0]
    np.testing.assert_allclose(identified.inverse_dynamics(q, qd, qdd), with_payload.inverse_dynamics(q, qd, qdd),
                               rtol=0, atol=TOL)


def test_bad_arguments_raise_clear_errors() -> None:
    with pytest.raises(DynamicParameterError, match=r"shape \(77,\).*78 finite numbers"):
        RobotDynamics(np.ones(77))
    with pytest.raises(DynamicParameterError, match="payload"):
        RobotDynamics(payload=[-1.0, 0, 0, 0])
    bad = nominal_parameter_vector()
    bad[20] = 0.0
    with pytest.raises(DynamicParameterError, match=r"mass of link 3 \(m3\) = 0.0"):
        RobotDynamics(bad)
    dynamics = RobotDynamics()
    with pytest.raises(DynamicParameterError, match=r"qd has shape \(5,\), expected \(6,\)"):
        dynamics.inverse_dynamics(np.zeros(6), np.zeros(5), np.zeros(6))
    with pytest.raises(DynamicParameterError, match=r"expected \(N, 6\)"):
        dynamics.regressor_batch(np.zeros(6), np.zeros(6), np.zeros(6))
    with pytest.raises(DynamicParameterError, match="link = 7"):
        link_parameters(nominal_parameter_vector(), 7)
    assert issubclass(DynamicParameterError, ValueError)
