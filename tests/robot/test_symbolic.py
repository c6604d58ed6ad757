"""CasADi SX dynamics (own RNEA / ABA / CRBA) against pinocchio plus rotor and friction terms."""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest

from robot.description import load_model
from robot.dynamics import fold_payload, nominal_parameter_vector
from robot.parameters import load_parameters
from robot.symbolic import (
    bias_function, forward_dynamics_function, gravity_function, inverse_dynamics_function,
    inverse_dynamics_symbolic, mass_matrix_function, numeric_inverse_dynamics_function,
)

TOL = 1e-10
V_S = load_parameters().coulomb_smoothing_velocity


def _random_case(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A perturbed parameter vector and a random payload (point mass on tool0)."""
    p = nominal_parameter_vector() * (1.0 + 0.1 * rng.uniform(-1, 1, 78))
    payload = np.array([rng.uniform(0, 10), *rng.uniform(-0.1, 0.2, 3)])
    return p, payload


def _pinocchio_model(p: np.ndarray, payload: np.ndarray, model: pin.Model | None = None) -> pin.Model:
    """pinocchio model with the link inertias of p (payload folded), no armature."""
    folded = fold_payload(p, payload, model)
    out = pin.Model(model if model is not None else load_model())
    for j in range(1, 7):
        out.inertias[j] = pin.Inertia.FromDynamicParameters(folded[10 * (j - 1): 10 * j])
    out.armature[:] = 0.0
    return out


def _friction(p: np.ndarray, qd: np.ndarray) -> np.ndarray:
    return p[66:72] * qd + p[72:78] * np.tanh(qd / V_S)


def _states(rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    return tuple(rng.uniform(-2.5, 2.5, 6) for _ in range(3))


def test_function_names_and_signatures_are_the_contract() -> None:
    fd, inv = forward_dynamics_function(), inverse_dynamics_function()
    assert fd.name() == "rx130l_fd" and inv.name() == "rx130l_id"
    assert fd.name_in() == ["q", "qd", "tau", "p", "payload"] and fd.name_out() == ["qdd"]
    assert inv.name_in() == ["q", "qd", "qdd", "p", "payload"] and inv.name_out() == ["tau"]
    assert [fd.size1_in(k) for k in range(5)] == [6, 6, 6, 78, 4] and fd.size_out(0) == (6, 1)
    assert [inv.size1_in(k) for k in range(5)] == [6, 6, 6, 78, 4]
    for function in (fd, inv, mass_matrix_function(), bias_function(), gravity_function()):
        assert function.is_a("SXFunction")
        assert not function.has_free()
    assert mass_matrix_function().name() == "rx130l_mass_matrix"
    assert bias_function().name() == "rx130l_bias" and gravity_function().name() == "rx130l_gravity"


def test_inverse_and_forward_dynamics_match_pinocchio() -> None:
    rng = np.random.default_rng(11)
    fd, inv = forward_dynamics_function(), inverse_dynamics_function()
    worst_id = worst_fd = 0.0
    for _ in range(25):
        p, payload = _random_case(rng)
        model = _pinocchio_model(p, payload)
        data = model.createData()
        q, qd, qdd = _states(rng)
        tau_ref = pin.rnea(model, data, q, qd, qdd) + p[60:66] * qdd + _friction(p, qd)
        worst_id = max(worst_id, np.abs(np.asarray(inv(q, qd, qdd, p, payload)).ravel() - tau_ref).max())
        tau = rng.uniform(-300, 300, 6)
        model.armature[:] = p[60:66]
        qdd_ref = pin.aba(model, model.createData(), q, qd, tau - _friction(p, qd))
        worst_fd = max(worst_fd, np.abs(np.asarray(fd(q, qd, tau, p, payload)).ravel() - qdd_ref).max())
    assert worst_id < TOL, worst_id
    assert worst_fd < TOL, worst_fd


def test_forward_dynamics_inverts_inverse_dynamics() -> None:
    rng = np.random.default_rng(12)
    fd, inv = forward_dynamics_function(), inverse_dynamics_function()
    for _ in range(20):
        p, payload = _random_case(rng)
        q, qd, qdd = _states(rng)
        tau = inv(q, qd, qdd, p, payload)
        np.testing.assert_allclose(np.asarray(fd(q, qd, tau, p, payload)).ravel(), qdd, rtol=0, atol=TOL)


def test_mass_matrix_bias_and_gravity_match_pinocchio() -> None:
    rng = np.random.default_rng(13)
    mass_f, bias_f, gravity_f = mass_matrix_function(), bias_function(), gravity_function()
    for _ in range(15):
        p, payload = _random_case(rng)
        model = _pinocchio_model(p, payload)
        data = model.createData()
        q, qd, _ = _states(rng)
        mass_ref = pin.crba(model, data, q)
        mass_ref = np.triu(mass_ref) + np.triu(mass_ref, 1).T + np.diag(p[60:66])
        np.testing.assert_allclose(np.asarray(mass_f(q, p, payload)), mass_ref, rtol=0, atol=TOL)
        np.testing.assert_allclose(np.asarray(bias_f(q, qd, p, payload)).ravel(),
                                   pin.nonLinearEffects(model, data, q, qd) + _friction(p, qd), rtol=0, atol=TOL)
        np.testing.assert_allclose(np.asarray(gravity_f(q, p, payload)).ravel(),
                                   pin.computeGeneralizedGravity(model, data, q), rtol=0, atol=TOL)


def test_structure_of_a_model_with_tilted_joints_is_followed() -> None:
    # geometric errors put small rotations into the joint placements: the SX code must follow them
    from robot.geometric_errors import error_model, random_geometric_errors

    errors = random_geometric_errors(5) * 20.0  # exaggerated so rotations are clearly non-trivial
    structure_model = error_model(errors)
    fd = forward_dynamics_function(model=structure_model)
    inv = inverse_dynamics_function(model=structure_model)
    rng = np.random.default_rng(14)
    p, payload = _random_case(rng)
    model = _pinocchio_model(p, payload, structure_model)
    q, qd, qdd = _states(rng)
    tau_ref = pin.rnea(model, model.createData(), q, qd, qdd) + p[60:66] * qdd + _friction(p, qd)
    np.testing.assert_allclose(np.asarray(inv(q, qd, qdd, p, payload)).ravel(), tau_ref, rtol=0, atol=TOL)
    model.armature[:] = p[60:66]
    qdd_ref = pin.aba(model, model.createData(), q, qd, tau_ref - _friction(p, qd))
    np.testing.assert_allclose(np.asarray(fd(q, qd, tau_ref, p, payload)).ravel(), qdd_ref, rtol=0, atol=TOL)
    np.testing.assert_allclose(qdd_ref, qdd, rtol=0, atol=TOL)


def test_negative_and_oblique_joint_axes_are_followed() -> None:
    from robot.description import URDF_PATH

    text = URDF_PATH.read_text(encoding="utf-8")
    text = text.replace('<origin xyz="0 0 0.50" rpy="0 0 0"/>\n    <axis xyz="0 0 1"/>',
                        '<origin xyz="0 0 0.50" rpy="0 0 0"/>\n    <axis xyz="0 0 -1"/>')
    text = text.replace('<axis xyz="0 1 0"/>\n    <limit lower="-1.832595715"',
                        '<axis xyz="0.6 0 0.8"/>\n    <limit lower="-1.832595715"')
    structure_model = pin.buildModelFromXML(text)
    kinds = [structure_model.joints[j].shortname() for j in (4, 5)]
    assert kinds == ["JointModelRevoluteUnaligned"] * 2
    rng = np.random.default_rng(17)
    p, payload = _random_case(rng)
    model = _pinocchio_model(p, payload, structure_model)
    q, qd, qdd = _states(rng)
    tau_ref = pin.rnea(model, model.createData(), q, qd, qdd) + p[60:66] * qdd + _friction(p, qd)
    inv = inverse_dynamics_function(model=structure_model)
    np.testing.assert_allclose(np.asarray(inv(q, qd, qdd, p, payload)).ravel(), tau_ref, rtol=0, atol=TOL)
    fd = forward_dynamics_function(model=structure_model)
    np.testing.assert_allclose(np.asarray(fd(q, qd, tau_ref, p, payload)).ravel(), qdd, rtol=0, atol=TOL)


def test_numeric_parameter_inverse_dynamics_for_planners() -> None:
    rng = np.random.default_rng(15)
    p, payload = _random_case(rng)
    function = numeric_inverse_dynamics_function(p, payload)
    assert function.name_in() == ["q", "qd", "qdd"] and function.n_in() == 3
    q, qd, qdd = _states(rng)
    reference = np.asarray(inverse_dynamics_function()(q, qd, qdd, p, payload)).ravel()
    np.testing.assert_allclose(np.asarray(function(q, qd, qdd)).ravel(), reference, rtol=0, atol=TOL)
    # works on MX and SX symbols (e.g. inside an Opti problem)
    for kind in (ca.MX, ca.SX):
        x = kind.sym("x", 18)
        tau = inverse_dynamics_symbolic(x[:6], x[6:12], x[12:], p, payload)
        assert isinstance(tau, kind) and tau.shape == (6, 1)
        value = ca.Function("check", [x], [tau])(np.concatenate((q, qd, qdd)))
        np.testing.assert_allclose(np.asarray(value).ravel(), reference, rtol=0, atol=TOL)
    # nominal defaults: the URDF inertias and the parameter file payload (none)
    nominal = numeric_inverse_dynamics_function()
    expected = inverse_dynamics_function()(q, qd, qdd, nominal_parameter_vector(), np.zeros(4))
    np.testing.assert_allclose(np.asarray(nominal(q, qd, qdd)), np.asarray(expected), rtol=0, atol=TOL)


@pytest.mark.skipif(shutil.which("gcc") is None, reason="no C compiler")
def test_generated_c_of_forward_dynamics_compiles_and_agrees(tmp_path: Path) -> None:
    fd = forward_dynamics_function()
    generator = ca.CodeGenerator("rx130l_fd.c", {"with_header": True})
    generator.add(fd)
    source = Path(generator.generate(str(tmp_path) + "/"))
    library = tmp_path / "rx130l_fd.so"
    subprocess.run(["gcc", "-O1", "-shared", "-fPIC", str(source), "-o", str(library), "-lm"], check=True)
    compiled = ca.external("rx130l_fd", str(library))
    rng = np.random.default_rng(16)
    for _ in range(5):
        p, payload = _random_case(rng)
        q, qd, tau = _states(rng)
        np.testing.assert_allclose(np.asarray(compiled(q, qd, tau, p, payload)),
                                   np.asarray(fd(q, qd, tau, p, payload)), rtol=1e-13, atol=1e-12)
    text = source.read_text()
    assert "casadi_f0" in text and "callback" not in text.lower()
