"""Base dynamic parameters (QR, kappa), least-squares estimators and signal processing."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from identification.base_parameters import (BaseParameterError, base_parameters_of, compute_base_parameters,
                                                    format_coefficient, nominal_base_parameters)
from identification.errors import IdentificationDataError, InsufficientExcitationError
from identification.estimation import (check_excitation, ordinary_least_squares, relative_rms_error,
                                               weighted_least_squares)
from identification.signals import (average_periods, periodic_derivatives, sample_time_of,
                                            zero_phase_derivatives)
from robot.dynamics import PARAMETER_NAMES, RobotDynamics, nominal_parameter_vector
from robot.parameters import load_parameters
from robot.symbolic import chain_structure, inverse_dynamics_expression
from robot.true_robot import make_true_robot


@pytest.fixture(scope="module")
def base():
    return nominal_base_parameters()


@pytest.fixture(scope="module")
def states():
    rng = np.random.default_rng(99)
    p = load_parameters()
    n = 150
    return (rng.uniform(p.position_lower, p.position_upper, (n, 6)), rng.uniform(-3, 3, (n, 6)),
            rng.uniform(-10, 10, (n, 6)))


def test_base_parameter_count_and_structure(base):
    # 6 links x 10 + 6 rotor + 12 friction; 36 inertial base parameters, Ia1 and Ia2 merged
    assert base.count == 52
    assert base.count == base.independent.size == 78 - base.dependent.size
    assert {PARAMETER_NAMES[j] for j in base.zero_columns} == {
        "m1", "mx1", "my1", "mz1", "Ixx1", "Ixy1", "Iyy1", "Ixz1", "Iyz1", "m2", "my2"}
    assert base.gap > 1e10  # exact dependencies leave round-off only
    definitions = dict(zip(base.base_names, base.definitions()))
    assert definitions["Izz1R"] == "Izz1 + Izz2 + Izz3 + Ia1"
    assert definitions["mz2R"] == "mz2 + 0.625*m3 + 0.625*m4 + 0.625*m5 + 0.625*m6"  # upper arm 0.625 m
    assert definitions["Ixx2R"].startswith("Ixx2 - Izz2 + 0.390625*m3")  # 0.625^2
    assert "0.855625*m5" in definitions["Iyy3R"]  # forearm 0.925^2
    assert definitions["fc6"] == "fc6" and definitions["Ia3"] == "Ia3"
    report = base.report()
    assert "52 base parameters of 78" in report and "Izz1R" in report and "no effect on the torques (11)" in report


def test_kappa_reproduces_the_full_regressor_on_new_states_and_parameters(base, states):
    """Theta p = Theta_1 (p_1 + kappa p_2) to 1e-9 for random (non-physical) p and unseen states."""
    theta = RobotDynamics().regressor_batch(*states).reshape(-1, 78)
    rng = np.random.default_rng(5)
    for p in (nominal_parameter_vector(), rng.normal(size=78), make_true_robot(31337).dynamic_parameters):
        full = theta @ p
        reduced = base.base_regressor(theta) @ base.base_values(p)
        assert np.max(np.abs(full - reduced)) <= 1e-9 * max(1.0, np.max(np.abs(full)))
    assert base.kappa_residual < 1e-12


def test_rank_agrees_with_the_symbolic_regressor(base, states):
    """An independent regressor (CasADi Jacobian of the own symbolic RNEA) has the same rank."""
    q, qd, qdd = (ca.SX.sym(n, 6) for n in ("q", "qd", "qdd"))
    p = ca.SX.sym("p", 78)
    tau = ca.vertcat(*inverse_dynamics_expression(chain_structure(), q, qd, qdd, p, [0.0] * 4))
    f = ca.Function("y", [q, qd, qdd], [ca.jacobian(tau, p)]).map(states[0].shape[0])
    y = np.asarray(f(states[0].T, states[1].T, states[2].T)).reshape(6, -1, 78).transpose(1, 0, 2).reshape(-1, 78)
    norms = np.linalg.norm(y, axis=0)
    keep = norms > 1e-10 * norms.max()
    s = np.linalg.svd(y[:, keep] / norms[keep], compute_uv=False)
    assert int(np.sum(s > 1e-8 * s[0])) == base.count
    pin_y = RobotDynamics().regressor_batch(*states).reshape(-1, 78)
    assert np.max(np.abs(y - pin_y)) < 1e-9 * np.abs(pin_y).max()


def test_independent_of_the_random_states():
    other = compute_base_parameters(n_states=40, seed=3)
    ref = nominal_base_parameters()
    assert np.array_equal(other.independent, ref.independent)
    assert np.allclose(other.kappa, ref.kappa, atol=1e-9)


def test_full_parameters_hit_the_base_values(base):
    nominal = nominal_parameter_vector()
    target = base.base_values(make_true_robot(2024, payload=[3.0, 0.0, 0.0, 0.05]).dynamics().parameter_vector(True))
    full = base.full_parameters(target, nominal)
    assert np.allclose(base.base_values(full), target, rtol=0, atol=1e-10)
    assert np.all(full[[10 * k for k in range(6)]] > 0.0)  # masses stay positive
    RobotDynamics(full, np.zeros(4))  # usable as a model


def test_format_coefficient():
    assert format_coefficient(0.390625) == "0.390625"
    assert format_coefficient(-1.0) == "-1"
    assert format_coefficient(1.0 / 3.0) == "1/3"
    assert format_coefficient(0.123456789123) == "0.123457"


def test_base_parameters_of_rejects_bad_input():
    with pytest.raises(BaseParameterError, match="expected"):
        base_parameters_of(np.zeros((10, 78)))
    with pytest.raises(BaseParameterError, match="n_states"):
        compute_base_parameters(n_states=5)


def test_least_squares_recover_exact_and_weighted_noise(base, states):
    theta = RobotDynamics().regressor_batch(*states)
    w = base.base_regressor(theta)
    truth = base.base_values(make_true_robot(4711).dynamics().parameter_vector(True))
    tau = np.einsum("kjn,n->kj", w, truth)
    exact = ordinary_least_squares(w, tau, base.base_names)
    assert np.allclose(exact.values, truth, rtol=1e-9, atol=1e-9)
    sigma = np.array([2.0, 2.0, 1.0, 0.1, 0.1, 0.05])
    noisy = tau + np.random.default_rng(0).normal(size=tau.shape) * sigma
    ols = ordinary_least_squares(w, noisy, base.base_names)
    wls = weighted_least_squares(w, noisy, base.base_names)
    assert np.allclose(wls.joint_sigma, sigma, rtol=0.25)  # per-joint noise estimated from the OLS residual
    # WLS is the better estimator with unequal noise: smaller error in the weighted metric
    assert np.linalg.norm((wls.values - truth) / wls.std) < np.linalg.norm((ols.values - truth) / wls.std)
    assert np.all(np.abs(wls.values - truth) < 5 * wls.std + 1e-12)


def test_excitation_check_names_poorly_excited_parameters(base, states):
    q, qd, qdd = (x.copy() for x in states)
    q[:, 5], qd[:, 5], qdd[:, 5] = 0.3, 0.0, 0.0  # joint 6 never moves
    w = base.base_regressor(RobotDynamics().regressor_batch(q, qd, qdd))
    with pytest.raises(InsufficientExcitationError) as info:
        check_excitation(w, base.base_names)
    # the joint-6 rotor and friction columns vanish; Izz6 is still excited through the other joints
    assert set(info.value.poorly_excited) == {"Ia6", "fv6", "fc6"}
    assert "fv6" in str(info.value) and "rank deficient" in str(info.value)
    with pytest.raises(IdentificationDataError, match="too few samples"):
        check_excitation(w[:50], base.base_names)


def test_relative_rms_error():
    m = np.array([[1.0] * 6, [-1.0] * 6])
    assert np.allclose(relative_rms_error(m, 1.1 * m), 0.1)


def test_periodic_derivatives_are_exact_for_band_limited_signals():
    n, dt = 400, 0.01
    t = np.arange(n) * dt
    w = 2 * np.pi / (n * dt)
    q = np.sin(3 * w * t)[:, None] + 0.2 * np.cos(7 * w * t)[:, None]
    qf, qd, qdd = periodic_derivatives(q, dt, cutoff_hz=10.0)
    assert np.allclose(qd[:, 0], 3 * w * np.cos(3 * w * t) - 1.4 * w * np.sin(7 * w * t), atol=1e-10)
    assert np.allclose(qdd[:, 0], -9 * w * w * np.sin(3 * w * t) - 9.8 * w * w * np.cos(7 * w * t), atol=1e-9)


def test_zero_phase_derivatives_have_no_lag_and_clean_edges():
    dt = 1e-3
    t = np.arange(0.0, 4.0, dt)
    q = np.sin(2.0 * t + 0.3) + 0.1 * t**2
    noisy = q + np.random.default_rng(1).uniform(-5e-7, 5e-7, t.size)  # encoder-like quantisation
    qf, qd, qdd = zero_phase_derivatives(noisy[:, None], dt, cutoff_hz=20.0)
    assert np.max(np.abs(qd[:, 0] - (2 * np.cos(2 * t + 0.3) + 0.2 * t))) < 2e-3
    assert np.max(np.abs(qdd[:, 0] - (-4 * np.sin(2 * t + 0.3) + 0.2))) < 0.1  # edges included


def test_average_periods_and_sampling_checks():
    x = np.tile(np.arange(5.0), 4)[:, None] + np.repeat([0.0, 0.1, -0.1, 0.0], 5)[:, None]
    mean, std = average_periods(x, 5, skip_periods=0)
    assert np.allclose(mean[:, 0], np.arange(5.0)) and std.shape == (5, 1)
    with pytest.raises(IdentificationDataError, match="complete period"):
        average_periods(x, 5, periods=5)
    assert sample_time_of([0.0, 0.1, 0.2]) == pytest.approx(0.1)
    with pytest.raises(IdentificationDataError, match="non-monotonic"):
        sample_time_of([0.0, 0.1, 0.1, 0.2])
    with pytest.raises(IdentificationDataError, match="uniform sampling"):
        sample_time_of([0.0, 0.1, 0.2, 0.35, 0.45])


def test_long_records_are_pre_decimated_without_edge_damage():
    """Records above MAX_PROCESSED_SAMPLES are low-passed and decimated; angles far from zero
    must survive at the ends (zero-padding decimation would pull them towards 0)."""
    from identification.data import motion_record
    from identification.identify import MAX_PROCESSED_SAMPLES, prepare_motion

    dt = 4e-4
    t = np.arange(MAX_PROCESSED_SAMPLES + 5000) * dt
    q = 1.2 + 0.3 * np.sin(np.outer(t, [0.5, 0.7, 0.9, 1.1, 1.3, 1.5]))
    prepared = prepare_motion(motion_record(t, q, np.zeros_like(q)), cutoff_hz=20.0)
    assert prepared.how["pre_decimation"] == 2
    factor = prepared.how["pre_decimation"]
    assert np.max(np.abs(prepared.q - q[::factor])) < 1e-5  # scipy.signal.decimate: 0.16 rad at the ends
    w = np.array([0.5, 0.7, 0.9, 1.1, 1.3, 1.5])
    qdd = -0.3 * w**2 * np.sin(np.outer(t[::factor], w))
    error = np.abs(prepared.qdd - qdd)
    assert np.max(error[100:-100]) < 1e-3  # interior
    assert np.max(error) < 0.05 * 0.3 * 1.5**2  # ends: within 5 % of the largest amplitude


def test_regrouped_on_a_calibrated_geometry():
    """The nominal grouping carried over to a true robot's geometry (mm-level errors): same names,
    friction and rotor parameters still alone, and the true torques reproduced far better by the
    regrouped coefficients than by the nominal ones."""
    from identification.base_parameters import regrouped_on
    from robot.true_robot import make_true_robot

    arm = make_true_robot(7, payload=[8.0, 0.02, -0.01, 0.08])
    structure = RobotDynamics(model=arm.kinematic_model())
    nominal = nominal_base_parameters()
    base = regrouped_on(nominal, structure)
    assert base.base_names == nominal.base_names and base.structure is structure
    for name, terms in zip(base.base_names, base.terms()):
        if name.startswith(("fv", "fc", "Ia3", "Ia4", "Ia5", "Ia6")):
            assert [t.name for t in terms] == [name]
    p = RobotDynamics(arm.dynamic_parameters, arm.payload, model=arm.kinematic_model()).parameter_vector(
        include_payload=True)
    rng = np.random.default_rng(3)
    q, qd, qdd = rng.uniform(-1, 1, (50, 6)), rng.uniform(-1, 1, (50, 6)), rng.uniform(-3, 3, (50, 6))
    theta = structure.regressor_batch(q, qd, qdd)
    tau = theta @ p
    errors = {}
    for label, b in (("regrouped", base), ("nominal", nominal)):
        errors[label] = np.abs(b.base_regressor(theta) @ b.base_values(p) - tau).max() / np.abs(tau).max()
    print(errors)
    assert errors["regrouped"] < 1e-4 and errors["nominal"] > 10 * errors["regrouped"]
    # a 78-vector with these base values stays physical (masses positive) and reproduces them
    shifted = base.base_values(p) * (1 + 0.05 * rng.standard_normal(base.count))
    full = base.full_parameters(shifted, nominal_parameter_vector())
    assert np.allclose(base.base_values(full), shifted, rtol=1e-9, atol=1e-12)
    assert np.all(full[0:60:10][1:] > 0)
