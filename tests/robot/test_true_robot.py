"""The seeded true robot: reproducible, bounded deviations, physically consistent."""
from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
import pytest

from robot.dynamics import (
    DynamicParameterError, RobotDynamics, is_physically_consistent, link_parameters, nominal_parameter_vector,
)
from robot.geometric_errors import ERROR_PARAMETER_NAMES, random_geometric_errors
from robot.true_robot import DEFAULT_DEVIATION_MAGNITUDES, DeviationMagnitudes, TrueRobot, make_true_robot

NOMINAL = nominal_parameter_vector()


def test_same_seed_same_robot_other_seed_other_robot() -> None:
    first, again, other = make_true_robot(7), make_true_robot(7), make_true_robot(8)
    assert isinstance(first, TrueRobot) and first.seed == 7
    np.testing.assert_array_equal(first.dynamic_parameters, again.dynamic_parameters)
    np.testing.assert_array_equal(first.geometric_errors, again.geometric_errors)
    assert not np.allclose(first.dynamic_parameters, other.dynamic_parameters)
    assert not np.allclose(first.geometric_errors, other.geometric_errors)
    np.testing.assert_array_equal(first.geometric_errors, random_geometric_errors(7))
    assert first.dynamic_parameters.shape == (78,) and first.geometric_errors.shape == (39,)
    with pytest.raises(ValueError):
        first.dynamic_parameters[0] = 1.0  # read-only


def test_deviations_stay_within_the_documented_bounds_and_are_consistent() -> None:
    bounds = DEFAULT_DEVIATION_MAGNITUDES
    mass_changes, com_shifts = [], []
    for seed in range(30):
        robot = make_true_robot(seed)
        p = robot.dynamic_parameters
        for j in range(1, 7):
            link = link_parameters(p, j)
            assert is_physically_consistent(link), (seed, j)
            nominal = pin.Inertia.FromDynamicParameters(link_parameters(NOMINAL, j))
            true = pin.Inertia.FromDynamicParameters(link)
            inertia_c = np.array(true.inertia)
            moments = np.linalg.eigvalsh(inertia_c)
            assert moments.min() > 0.0
            assert moments.sum() - 2 * moments.max() >= -1e-12  # triangle inequality
            mass_changes.append(true.mass / nominal.mass - 1.0)
            com_shifts.append(np.abs(np.array(true.lever) - np.array(nominal.lever)).max())
        ratios = p[60:] / NOMINAL[60:]
        assert np.all(np.abs(ratios[:6] - 1.0) <= bounds.rotor_inertia_relative + 1e-12)
        assert np.all(np.abs(ratios[6:12] - 1.0) <= bounds.viscous_relative + 1e-12)
        assert np.all(np.abs(ratios[12:] - 1.0) <= bounds.coulomb_relative + 1e-12)
    mass_changes = np.array(mass_changes)
    assert np.abs(mass_changes).max() <= bounds.mass_relative + 1e-12
    assert np.abs(mass_changes).max() > 0.5 * bounds.mass_relative  # the deviations are really there
    assert max(com_shifts) <= bounds.com_shift_m + 1e-12
    assert max(com_shifts) > 0.5 * bounds.com_shift_m


def test_zero_magnitudes_reproduce_the_nominal_dynamics() -> None:
    zero = DeviationMagnitudes(0, 0, 0, 0, 0, 0, 0)
    robot = make_true_robot(3, magnitudes=zero)
    np.testing.assert_allclose(robot.dynamic_parameters, NOMINAL, rtol=1e-12, atol=1e-14)


def test_true_dynamics_with_payload_and_geometry_is_usable() -> None:
    robot = make_true_robot(4, payload=[6.0, 0.0, 0.02, 0.12])
    dynamics = robot.dynamics()
    assert isinstance(dynamics, RobotDynamics)
    np.testing.assert_array_equal(dynamics.payload, [6.0, 0.0, 0.02, 0.12])
    nominal = RobotDynamics()
    rng = np.random.default_rng(0)
    q, qd, qdd = rng.uniform(-1.5, 1.5, (3, 6))
    tau = dynamics.inverse_dynamics(q, qd, qdd)
    np.testing.assert_allclose(dynamics.forward_dynamics(q, qd, tau), qdd, rtol=0, atol=1e-10)
    difference = np.abs(tau - nominal.inverse_dynamics(q, qd, qdd))
    assert difference.max() > 1.0  # N m: the true arm is measurably different
    # the geometric errors really are in the structure model
    model = robot.kinematic_model()
    nominal_model = nominal.model
    assert not np.allclose(model.jointPlacements[2].translation, nominal_model.jointPlacements[2].translation)


def test_summary_is_json_ready_and_complete() -> None:
    summary = make_true_robot(5, payload=[2.0, 0.0, 0.0, 0.1]).to_dict()
    text = json.dumps(summary)
    assert json.loads(text)["seed"] == 5
    assert len(summary["dynamic_parameters"]) == 78 and "fc6" in summary["dynamic_parameters"]
    assert list(summary["geometric_errors"]) == list(ERROR_PARAMETER_NAMES)
    assert summary["payload"] == {"mass_kg": 2.0, "com_in_tool0_m": [0.0, 0.0, 0.1]}
    assert summary["magnitudes"]["mass_relative"] == DEFAULT_DEVIATION_MAGNITUDES.mass_relative


def test_bad_input_is_rejected_clearly() -> None:
    with pytest.raises(DynamicParameterError, match="seed = -1"):
        make_true_robot(-1)
    with pytest.raises(DynamicParameterError, match="payload"):
        make_true_robot(1, payload=[1.0, 0.0])
    with pytest.raises(DynamicParameterError, match=r"mass_relative = 1.5, expected a finite number in \[0, 1\)"):
        DeviationMagnitudes(mass_relative=1.5)
    with pytest.raises(DynamicParameterError, match="com_shift_m"):
        DeviationMagnitudes(com_shift_m=-0.01)
