"""QR identifiability of the 39 geometric error parameters (paper eq. 20-25)."""
import numpy as np
import pytest

from calibration.identifiability import IdentifiabilityError, identifiable_parameters
from calibration.solver import generic_identifiability
from robot.geometric_errors import ERROR_PARAMETER_NAMES, default_error_model
from robot.kinematics import FlangeKinematics


@pytest.fixture(scope="module")
def jacobians():
    kin = FlangeKinematics()
    q = np.random.default_rng(11).uniform(kin.lower, kin.upper, size=(200, 6))
    return default_error_model().identification_jacobian(q)


def _svd_rank(block):
    a = block.reshape(-1, block.shape[-1])
    norms = np.linalg.norm(a, axis=0)
    a = a[:, norms > 1e-9 * norms.max()]  # columns without first-order effect are zero
    a = a / np.linalg.norm(a, axis=0)
    s = np.linalg.svd(a, compute_uv=False)
    return int(np.sum(s > 1e-8 * s[0]))


@pytest.mark.parametrize("rows", [6, 3])
def test_rank_matches_svd_and_dependencies_are_exact(jacobians, rows):
    block = jacobians[:, :rows]
    report = identifiable_parameters(block, list(ERROR_PARAMETER_NAMES))
    assert report.rank == _svd_rank(block)
    assert report.gap > 1e8  # a clear numerical rank, independent of the tolerance
    assert len(report.dependencies) == 39 - report.rank
    a = block.reshape(-1, 39)
    names = list(ERROR_PARAMETER_NAMES)
    for dep in report.dependencies:
        # Theta_2 = Theta_1 kappa, in natural units
        rebuilt = sum(c * a[:, names.index(n)] for n, c in dep.coefficients.items())
        col = a[:, names.index(dep.parameter)]
        largest = np.linalg.norm(a, axis=0).max()
        assert np.linalg.norm(rebuilt - col) <= 1e-9 * max(np.linalg.norm(col), largest * 1e-6)


def test_counts_and_reasons(jacobians):
    pose = identifiable_parameters(jacobians, list(ERROR_PARAMETER_NAMES))
    position = identifiable_parameters(jacobians[:, :3], list(ERROR_PARAMETER_NAMES))
    # the paper's 30 with orientation; position only: 25 (offset6 and the flange tilts then
    # have no first-order effect: they turn the flange about its own origin, on axis 6)
    assert (pose.rank, position.rank) == (30, 25)
    assert {"offset6", "flange_rx", "flange_ry"} <= set(position.dropped_names)
    assert {"offset6", "flange_rx", "flange_ry"} <= set(pose.identifiable_names)
    by_name = {d.parameter: d for d in pose.dependencies}
    # joints 2 and 3 are parallel: translations along their common axis are one parameter
    merged_y = {"len2_y", "len3_y", "len4_y"}
    assert len(merged_y & set(pose.identifiable_names)) == 1
    # joint 5 sits on axis 4: translations of joints 4 and 5 along it are one parameter
    pair = {"len4_z", "len5_z"}
    assert len(pair & set(pose.identifiable_names)) == 1
    dropped = (pair - set(pose.identifiable_names)).pop()
    assert abs(list(by_name[dropped].coefficients.values())[0]) == pytest.approx(1.0, abs=1e-9)
    assert "merged" in by_name[dropped].describe()
    # the encoder offsets of the parallel joints 2 and 3 merge into lengths and tilt4_y
    assert set(by_name["offset3"].coefficients) == {"len4_x", "tilt4_y"}
    assert generic_identifiability(orientation=True).rank == 30


def test_zero_column_and_input_errors():
    rng = np.random.default_rng(0)
    a = rng.standard_normal((40, 4))
    a[:, 2] = 0.0
    report = identifiable_parameters(a, ["a", "b", "c", "d"])
    assert report.rank == 3 and report.dropped_names == ("c",)
    assert "no effect" in report.dependencies[0].describe()
    with pytest.raises(IdentifiabilityError, match="names"):
        identifiable_parameters(a, ["a", "b"])
    a[0, 0] = np.nan
    with pytest.raises(IdentifiabilityError, match="NaN"):
        identifiable_parameters(a, ["a", "b", "c", "d"])
    with pytest.raises(IdentifiabilityError, match="rows"):
        identifiable_parameters(a[1:3], ["a", "b", "c", "d"])
