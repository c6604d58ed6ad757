"""Units of the selection problem (calibration.scaling)."""
import math

import numpy as np
import pytest

from calibration.identifiability import identifiable_parameters
from calibration.scaling import (
    COLUMN_SCALINGS,
    ScalingError,
    base_parameter_prior_sigmas,
    selection_jacobians,
)
from calibration.optical_tracker import TrackerNoise
from robot.geometric_errors import ERROR_PARAMETER_NAMES, default_error_model, error_standard_deviations
from robot.kinematics import FlangeKinematics


@pytest.fixture(scope="module")
def problem():
    kin = FlangeKinematics()
    q = np.random.default_rng(5).uniform(kin.lower, kin.upper, size=(120, 6))
    jac = default_error_model().identification_jacobian(q)
    rows = TrackerNoise().row_sigmas(True)
    report = identifiable_parameters(jac / rows[None, :, None], list(ERROR_PARAMETER_NAMES))
    return jac, rows, report


def test_prior_sigmas_are_the_error_magnitudes():
    prior = error_standard_deviations()
    names = ERROR_PARAMETER_NAMES
    assert prior[names.index("len3_z")] == pytest.approx(1e-3)  # 1 mm
    assert prior[names.index("base_x")] == pytest.approx(2e-3)  # 2 mm
    assert prior[names.index("offset2")] == pytest.approx(math.radians(0.2))
    assert prior[names.index("flange_rx")] == pytest.approx(math.radians(0.1))


def test_base_parameter_prior_adds_the_merged_parameters(problem):
    _, _, report = problem
    prior = error_standard_deviations()
    sigmas = base_parameter_prior_sigmas(report, prior)
    names = list(report.names)
    ident = list(report.identifiable_names)
    assert sigmas.shape == (30,)
    # len2_y/len3_y/len4_y are one base parameter: three 1 mm priors -> sqrt(3) mm
    kept = ({"len2_y", "len3_y", "len4_y"} & set(ident)).pop()
    assert sigmas[ident.index(kept)] == pytest.approx(math.sqrt(3) * 1e-3, rel=1e-9)
    # a parameter nothing merges into keeps its own prior
    untouched = set(ident) - {c for d in report.dependencies for c in d.coefficients}
    for name in untouched:
        assert sigmas[ident.index(name)] == pytest.approx(prior[names.index(name)])
    with pytest.raises(ScalingError, match="prior_sigmas"):
        base_parameter_prior_sigmas(report, prior[:30])


def test_whitened_information_is_prior_normalised_fisher_information(problem):
    jac, rows, report = problem
    prior = error_standard_deviations()
    theta = selection_jacobians(jac, report, rows, prior, "whitened")
    raw = jac[:, :, report.identifiable].reshape(-1, 30)
    weight = np.tile(1.0 / rows**2, jac.shape[0])
    s = np.diag(base_parameter_prior_sigmas(report, prior))
    expected = s @ raw.T @ (raw * weight[:, None]) @ s
    flat = theta.reshape(-1, 30)
    np.testing.assert_allclose(flat.T @ flat, expected, rtol=1e-10, atol=1e-12 * np.abs(expected).max())
    # unit_rms: every column has unit RMS norm over the candidates; natural: untouched
    rms = selection_jacobians(jac, report, rows, prior, "unit_rms")
    np.testing.assert_allclose(np.sum(rms**2, axis=(0, 1)) / rms.shape[0], 1.0)
    np.testing.assert_array_equal(selection_jacobians(jac, report, rows, prior, "natural"),
                                  jac[:, :, report.identifiable])
    assert COLUMN_SCALINGS == ("whitened", "unit_rms", "natural")


def test_scaling_input_errors(problem):
    jac, rows, report = problem
    prior = error_standard_deviations()
    with pytest.raises(ScalingError, match="'metric'.*whitened"):
        selection_jacobians(jac, report, rows, prior, "metric")
    with pytest.raises(ScalingError, match="row_sigmas"):
        selection_jacobians(jac, report, rows[:3], prior)
    with pytest.raises(ScalingError, match="row_sigmas"):
        selection_jacobians(jac, report, np.zeros(6), prior)
