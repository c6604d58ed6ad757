"""Gear stiffness identified from a closed-loop run of the elastic cell (motor encoders +
laser tracker, nominal link model) against the plant's true stiffness."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from cosim.results import read_csv
from identification.gear_stiffness import gear_torques, identify_gear_stiffness
from robot.dynamics import COULOMB_SLICE, ROTOR_INERTIA_SLICE, VISCOUS_SLICE, RobotDynamics
from robot.parameters import load_parameters
from robot.true_robot import make_true_robot
from scenario_files import run_scenario, write_variant

ROOT = Path(__file__).resolve().parents[2]


def test_stiffness_of_the_excited_axes_within_ten_percent(tmp_path):
    text = (ROOT / "scenarios" / "iso9283_elastic.toml").read_text(encoding="utf-8")
    path = write_variant(text, tmp_path / "iso.toml", [
        ('stop_time = "12.6 s"', 'stop_time = "6.0 s"'),
        ('signals = ["drive*.current_demand"]', 'signals = ["plant.q_motor*"]'),
        ('modes = ["standard", "model_based", "model_based_elastic"]', 'modes = ["model_based"]'),
        ("can_log = true", "can_log = false"), ("figures = true", "figures = false")])
    code, summary = run_scenario(path, tmp_path / "out")
    assert code == 0
    names, data = read_csv(tmp_path / "out" / "timeseries_model_based.csv")
    columns = {name: data[:, k] for k, name in enumerate(names)}
    t = columns["time"]
    keep = t >= 0.3  # after enabling and settling
    motor = np.column_stack([columns[f"plant.q_motor[{j}]"] for j in range(1, 7)])[keep]
    tracker = np.column_stack([columns[f"tracker.{a}"] for a in "xyz"])[keep]
    robot = load_parameters()
    payload = [8.0, 0.0, 0.0, 0.08]
    p = RobotDynamics(payload=payload).parameter_vector().copy()  # the NOMINAL links (not the truth)
    p[ROTOR_INERTIA_SLICE] = 0.0
    p[VISCOUS_SLICE] *= 1 - robot.motor_friction_share
    p[COULOMB_SLICE] *= 1 - robot.motor_friction_share
    tau = gear_torques(RobotDynamics(p, payload), motor, 1e-3)
    true = make_true_robot(1, payload=payload)  # calibrated kinematics assumed
    est = identify_gear_stiffness(motor, tracker, tau, true.kinematic_model())
    error = est.stiffness / true.gear_stiffness - 1.0  # the true gears deviate +-10 % from the nominal
    print("identified / true - 1:", np.round(error, 4), "std / k:", np.round(est.stiffness_std / true.gear_stiffness, 4),
          "nominal / true - 1:", np.round(robot.stiffness / true.gear_stiffness - 1, 4),
          "identifiable:", est.identifiable, "cond", round(est.condition_number, 1))
    assert est.identifiable[:5].all() and not est.identifiable[5]  # axis 6 carries ~no gear torque here
    assert np.all(np.abs(error[:5]) < 0.10)
    assert np.abs(error[:3]).max() < np.abs(robot.stiffness / true.gear_stiffness - 1)[:3].max()  # beats the prior
