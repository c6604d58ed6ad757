"""The campaign's workflow (identification.campaign) with an experiment that is not the cell:
a synthetic elastic arm written here (true robot seed 424242, 8 kg offset payload; gear
deflection tau_g / k; a reflector on the tool read with 2 um noise; torque with 0.1 % noise
and a known drive sampling term). It shows the contract a user's own experiment fulfils and
that one campaign returns every parameter's error against the truth."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from identification.campaign import (CampaignSettings, ExperimentData, TrackerRecord, Truth, run_campaign,
                                     snapped_omega)
from robot.dynamics import COULOMB_SLICE, ROTOR_INERTIA_SLICE, VISCOUS_SLICE, RobotDynamics
from robot.parameters import load_parameters
from robot.true_robot import make_true_robot

REFLECTOR = (0.10, 0.05, 0.08)  # m in tool0
BIAS = np.array([-0.2, -0.4, -0.15, -0.01, -0.01, -0.003])  # N m per rad/s^2


class SyntheticElasticArm:
    """An experiment: runs the trajectory on a flexible-joint arm made of the true robot's
    rigid-body model and its gears (quasi-static deflection), measures like a cell."""

    def __init__(self, arm, sample_time: float):
        self.arm, self.dt = arm, sample_time
        self.robot = load_parameters()
        self.rng = np.random.default_rng(5)

    def __call__(self, trajectory, duration_s: float) -> ExperimentData:
        t = np.arange(int(round(duration_s / self.dt))) * self.dt
        s = trajectory.sample(t)
        truth = RobotDynamics(self.arm.dynamic_parameters, self.arm.payload, model=self.arm.kinematic_model())
        tau = np.array([truth.inverse_dynamics(a, b, c) for a, b, c in zip(s.q, s.qd, s.qdd)])
        p = truth.parameter_vector(include_payload=True).copy()  # the links alone: what the gears carry
        p[ROTOR_INERTIA_SLICE] = 0.0
        p[VISCOUS_SLICE] *= 1 - self.robot.motor_friction_share
        p[COULOMB_SLICE] *= 1 - self.robot.motor_friction_share
        links = RobotDynamics(p, np.zeros(4), model=self.arm.kinematic_model())
        tau_gear = np.array([links.inverse_dynamics(a, b, c) for a, b, c in zip(s.q, s.qd, s.qdd)])
        q_link = s.q - tau_gear / self.arm.gear_stiffness
        model = self.arm.kinematic_model()
        data = model.createData()
        frame = model.getFrameId("tool0")
        readings = []
        for q in q_link:
            pin.forwardKinematics(model, data, q)
            readings.append(pin.updateFramePlacement(model, data, frame).act(np.array(REFLECTOR)))
        readings = np.array(readings) + self.rng.normal(0.0, 2e-6, (t.size, 3))
        noise = 1e-3 * self.robot.rated_torque * self.rng.standard_normal(tau.shape)
        measured = tau + BIAS * s.qdd + noise
        return ExperimentData(s.q, measured, self.dt, TrackerRecord(t, readings, REFLECTOR), BIAS,
                              {"bias_Nm_per_rad_s2": BIAS.tolist(), "source": "given"}, {"samples": int(t.size)})


def test_one_campaign_identifies_base_parameters_rotors_and_gears():
    dt = 4e-3
    settings = CampaignSettings(sample_time=dt, max_iterations=5, random_baselines=1, samples=40,
                                constraint_samples=60, periods=3, skip_periods=1, cutoff_hz=5.0, consistent=False,
                                reflector=REFLECTOR, stiffness_decimate=1)
    arm = make_true_robot(424242, payload=[8.0, 0.02, -0.01, 0.08])
    robot = load_parameters()
    steps = []
    result = run_campaign(
        settings, SyntheticElasticArm(arm, dt),
        truth=Truth(RobotDynamics(arm.dynamic_parameters, arm.payload, model=arm.kinematic_model())
                    .parameter_vector(include_payload=True),
                    arm.gear_stiffness, robot.gear_damping),
        kinematic_model=arm.kinematic_model(),
        stiffness_model={"rotor_inertia": np.asarray(arm.dynamic_parameters)[ROTOR_INERTIA_SLICE],
                         "motor_friction_share": robot.motor_friction_share, "nominal_stiffness": robot.stiffness},
        on_step=lambda name, fields: steps.append(name))
    assert steps == ["designed", "measured", "estimated"]
    assert result.samples_per_period == snapped_omega(0.8, dt)[1]
    report = result.report
    print({k: round(v["error_percent"], 2) for k, v in report["rotor_inertias"].items()},
          np.round(report["gear_stiffness"]["stiffness_error_percent"], 2))
    assert len(report["parameter_errors"]) == 52
    assert report["rotor_inertias_within_10_percent"]
    assert report["within_3_std_of_true"] >= 45  # the calibrated grouping: no geometric bias left
    assert report["stiffness_within_10_percent"] and all(report["gear_stiffness"]["stiffness_identifiable"])
    assert max(abs(e) for e in report["gear_stiffness"]["stiffness_error_percent"]) < 3.0
    assert report["torque_sampling_correction"]["source"] == "given"
    assert report["gear_stiffness"]["nominal_stiffness_error_percent"][0] == pytest.approx(
        100 * (robot.stiffness[0] / arm.gear_stiffness[0] - 1))


def test_stiffness_needs_tracker_readings_at_a_rate_that_divides_the_period():
    from identification.campaign import estimate_stiffness

    settings = CampaignSettings(sample_time=4e-3)
    data = ExperimentData(np.zeros((10, 6)), np.zeros((10, 6)), 4e-3)
    with pytest.raises(ValueError, match="no tracker readings"):
        estimate_stiffness(None, data, settings, 1963, None, np.zeros(6), np.zeros(6))
    data.tracker = TrackerRecord(np.arange(100) * 3e-3, np.zeros((100, 3)))
    with pytest.raises(ValueError, match="whole number of tracker samples"):
        estimate_stiffness(None, data, settings, 1963, None, np.zeros(6), np.zeros(6))
