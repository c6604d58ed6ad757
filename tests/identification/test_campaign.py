"""Campaign pieces: periodic identification with parallel filtering, the physically consistent fit,
the 'identification' scenario's validation and the fieldbus recorder.

The full campaign (about 10 min) is run by ``python -m cosim run scenarios/identification.toml``;
its figures are in docs/explanation/identification.md.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from cosim.jobs.identification import FieldbusRecorder
from identification.campaign import snapped_omega
from cosim.scenario import ScenarioError, load_scenario
from identification.base_parameters import nominal_base_parameters
from identification.consistent import (parameters_from_theta, parameters_jacobian,
                                               theta_from_parameters)
from identification.identify import base_regressor, identify_periodic, identify_regressor
from robot.dynamics import RobotDynamics, is_physically_consistent, nominal_parameter_vector
from robot.true_robot import make_true_robot

SCENARIO = "scenarios/identification.toml"


@pytest.fixture(scope="module")
def periodic_record():
    """Three periods of a Fourier trajectory on an unseen arm with an 8 kg payload; the torque
    carries a 100 Hz ripple (like the drives' speed loops) and white noise."""
    arm = make_true_robot(90210, payload=[8.0, 0.02, -0.01, 0.08])
    truth = RobotDynamics(arm.dynamic_parameters, arm.payload)
    dt, n = 4e-3, 1000  # one period 4 s
    t = np.arange(3 * n) * dt
    rng = np.random.default_rng(7)
    centre = np.array([0.0, 0.4, 1.2, 0.0, 0.6, 0.0])
    q, qd, qdd = np.tile(centre, (t.size, 1)), np.zeros((t.size, 6)), np.zeros((t.size, 6))
    w0 = 2 * math.pi / (n * dt)
    for j in range(6):
        for harmonic in range(1, 6):
            a = rng.uniform(-0.25, 0.25) / harmonic
            phase = rng.uniform(0, 2 * math.pi)
            w = harmonic * w0
            q[:, j] += a * np.sin(w * t + phase)
            qd[:, j] += a * w * np.cos(w * t + phase)
            qdd[:, j] -= a * w * w * np.sin(w * t + phase)
    tau = np.array([truth.inverse_dynamics(a, b, c) for a, b, c in zip(q, qd, qdd)])
    ripple = 0.03 * np.abs(tau).max(axis=0) * np.sin(2 * math.pi * 100.0 * t)[:, None]
    tau_meas = tau + ripple + rng.normal(size=tau.shape) * 0.002 * np.abs(tau).max(axis=0)
    return dt, n, q, tau_meas, truth


def test_periodic_identification_with_parallel_filtering(periodic_record):
    dt, n, q, tau, truth = periodic_record
    result = identify_periodic(q, tau, dt, n, skip_periods=1, cutoff_hz=20.0, consistent=True)
    assert result.data["periods_averaged"] == 2
    base = result.base
    true_base = base.base_values(truth.parameter_vector(include_payload=True))
    # predicted torques of the identified model along the (noise-free) period match the truth
    s = slice(0, n)
    qs = q[s]
    qd = np.gradient(qs, dt, axis=0)
    qdd = np.gradient(qd, dt, axis=0)
    w = base_regressor(base, qs[5:-5], qd[5:-5], qdd[5:-5])
    exact = np.einsum("kjn,n->kj", w, true_base)
    predicted = np.einsum("kjn,n->kj", w, result.values)
    rel = np.sqrt(np.mean((predicted - exact) ** 2, axis=0) / np.mean(exact**2, axis=0))
    assert np.all(rel < 0.02), rel
    # the consistent fit: real rigid bodies, same torques
    fit = result.consistent
    assert fit is not None and fit.consistent
    assert all(is_physically_consistent(fit.parameters[10 * i:10 * i + 10]) for i in range(6))
    predicted_c = np.einsum("kjn,n->kj", w, fit.base_values)
    rel_c = np.sqrt(np.mean((predicted_c - exact) ** 2, axis=0) / np.mean(exact**2, axis=0))
    assert np.all(rel_c < 0.02), rel_c
    assert result.dynamics(consistent=True).parameter_vector().shape == (78,)


def test_log_cholesky_round_trip_and_jacobian():
    p = make_true_robot(5).dynamic_parameters
    theta = theta_from_parameters(np.asarray(p))
    assert np.allclose(parameters_from_theta(theta), p, rtol=1e-10, atol=1e-12)
    theta = theta + np.random.default_rng(0).normal(size=78) * 0.2
    d = np.random.default_rng(1).normal(size=78)
    h = 1e-6
    fd = (parameters_from_theta(theta + h * d) - parameters_from_theta(theta - h * d)) / (2 * h)
    assert np.allclose(fd, parameters_jacobian(theta) @ d, atol=1e-6 * np.abs(fd).max())
    assert all(is_physically_consistent(parameters_from_theta(theta)[10 * i:10 * i + 10]) for i in range(6))


def test_identify_regressor_std_correction():
    base = nominal_base_parameters()
    rng = np.random.default_rng(3)
    n = 400
    w = base_regressor(base, rng.uniform(-1, 1, (n, 6)), rng.uniform(-2, 2, (n, 6)), rng.uniform(-5, 5, (n, 6)))
    tau = np.einsum("kjn,n->kj", w, base.base_values(nominal_parameter_vector())) + rng.normal(size=(n, 6))
    plain = identify_regressor(w, tau)
    corrected = identify_regressor(w, tau, independent_samples=100.0)
    assert np.allclose(corrected.estimate.std, plain.estimate.std * 2.0)
    assert corrected.data["std_correlation_factor"] == pytest.approx(2.0)


def assert_refused(path, text, old, new, key):
    """The scenario ``text`` with ``old`` replaced by ``new``, written to ``path``, is refused with a
    ScenarioError naming ``key`` (and ``old`` really is in the text, so the edit happened)."""
    assert old in text, old
    path.write_text(text.replace(old, new))
    with pytest.raises(ScenarioError, match=key.replace(".", r"\.")):
        load_scenario(path)


def test_scenario_loads_and_bad_values_are_named(tmp_path):
    scenario = load_scenario(SCENARIO)
    assert scenario.job.name == "identification"
    assert scenario.data["excitation"]["order"] == 5 and scenario.data["measurement"]["cutoff"] == 20.0
    text = open(SCENARIO).read()
    bad = tmp_path / "bad.toml"
    assert_refused(bad, text, "skip_periods = 1", "skip_periods = 5", "excitation.skip_periods")
    assert_refused(bad, text, 'cutoff = "20 Hz"', 'cutoff = "2 kHz"', "measurement.cutoff")
    assert_refused(bad, text, "order = 5 ", "order = 0 ", "excitation.order")


def test_snapped_omega_and_recorder():
    omega, n = snapped_omega(0.8, 400e-6)
    assert n == 19635 and abs(omega - 0.8) < 1e-5
    assert 2 * math.pi / omega == pytest.approx(n * 400e-6, rel=1e-12)

    from controller import ControllerInput

    class Inner:
        stopped = False

        def step(self, inputs):
            return ("setpoints", inputs.cycle)

    rec = FieldbusRecorder(Inner(), torque_noise_sigma=np.zeros(6), seed=0)
    for k in range(4):
        inputs = ControllerInput.zeros(6)
        inputs.cycle, inputs.time_s = k, k * 4e-4
        inputs.position = np.full(6, float(k))
        inputs.torque = np.ones(6)
        assert rec.step(inputs) == ("setpoints", k)
    assert rec.stopped is False  # delegated
    t, q, tau = rec.window(4e-4, 2 * 4e-4, 4e-4)
    assert np.allclose(t, [4e-4, 8e-4]) and np.allclose(q[:, 0], [1.0, 2.0]) and np.allclose(tau, 1.0)
    t, q, tau = rec.window(4e-4, 2 * 4e-4, 4e-4, position_lag_cycles=1)  # position of t_k arrives at t_k+1
    assert np.allclose(t, [4e-4, 8e-4]) and np.allclose(q[:, 0], [2.0, 3.0])


def test_recorder_keeps_only_the_motion_window_and_the_same_rows():
    """keep_after_start_s: only the rows window() reads (from the controller's motion start for the
    motion's duration plus the position lag) are held, however long the run; they equal a
    recorder keeping every row, noise included; the arrays grow, nothing sized by the run."""
    from controller import ControllerInput

    period, start_cycle, duration, lag = 4e-4, 300, 1000 * 4e-4, 1

    class Inner:
        motion_start_s = None

        def step(self, inputs):
            if inputs.cycle == start_cycle - 2:  # the clock sets the start ahead of time (lead cycles)
                self.motion_start_s = start_cycle * period
            return None

    inner = Inner()
    sigma = np.full(6, 0.5)
    every = FieldbusRecorder(inner, sigma, seed=3)
    kept = FieldbusRecorder(inner, sigma, seed=3, keep_after_start_s=FieldbusRecorder.keep_for(duration, period, lag))
    cycles = 20_000  # 8 s of a run whose motion lasts 0.4 s
    inputs = ControllerInput.zeros(6)
    for k in range(cycles):
        inputs.cycle, inputs.time_s = k, k * period
        inputs.position = np.full(6, 1e-3 * k)
        inputs.torque = np.full(6, -2e-3 * k)
        every.step(inputs)
        kept.step(inputs)
    assert every.rows == cycles and kept.rows == 1000 + lag + 2
    assert kept.t.size == FieldbusRecorder.FIRST_ROWS and every.t.size < 2 * cycles
    assert kept.t[0] == pytest.approx(start_cycle * period)
    for a, b in zip(every.window(inner.motion_start_s, duration, period, lag),
                    kept.window(inner.motion_start_s, duration, period, lag)):
        assert a.shape[0] == 1000 and np.array_equal(a, b)


def test_elastic_campaign_scenario_loads(tmp_path):
    from cosim.jobs.identification import elastic_plant

    scenario = load_scenario("scenarios/identification_elastic.toml")
    assert scenario.job.name == "identification" and elastic_plant(scenario.data)
    assert not elastic_plant(load_scenario(SCENARIO).data)
    assert len(scenario.data["stiffness"]["reflector"]) == 3
    assert scenario.data["measurement"]["cutoff"] < 14.0  # below the first gear resonance
    text = open("scenarios/identification_elastic.toml").read()
    bad = tmp_path / "bad.toml"
    assert_refused(bad, text, 'period = "1 ms"              # besides', 'period = "2 ms"              # besides',
                   "record.period")
    assert_refused(bad, text, 'method = "wls"', 'kinematics = "nominal"\nmethod = "wls"', "measurement.kinematics")
    assert_refused(bad, text, 'iso_mode = "model_based_elastic"', 'iso_mode = "bogus"', "controller.iso_mode")
    rigid = open(SCENARIO).read()  # the elastic feed-forward on a rigid plant is refused
    assert_refused(bad, rigid, 'compare_models = [', 'iso_mode = "model_based_elastic"\ncompare_models = [',
                   "controller.iso_mode")
