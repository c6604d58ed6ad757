"""Certified upper bounds of the observation index and the per-index comparison."""
from itertools import combinations

import numpy as np
import pytest

from calibration.config_selection import select_configurations
from calibration.design_bounds import (
    DesignBoundError,
    d_optimality_upper_bound,
    min_eigenvalue_upper_bound,
)
from calibration.index_comparison import compare_observation_indices
from calibration.observability import OBSERVATION_INDICES, get_index

from calibration_jacobians import correlated_jacobians


def _jacobians(n=16, k=3, p=5, seed=0):
    return correlated_jacobians(n, k, p, seed)


def _brute_force_best(theta, n_select, index):
    idx = get_index(index)
    subsets = np.array(list(combinations(range(theta.shape[0]), n_select)))
    blocks = theta[subsets].reshape(len(subsets), -1, theta.shape[2])
    lams = np.einsum("smp,smq->spq", blocks, blocks)
    return float(np.max(idx.value(np.linalg.eigvalsh(lams))))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_bounds_hold_against_brute_force(seed):
    """On small problems (every 4-of-16 subset enumerated): selection <= best subset <=
    upper bound, and the bound is not vacuous."""
    theta = _jacobians(seed=seed)
    for index, bound_fn, slack in (("min_eigenvalue", min_eigenvalue_upper_bound, 1.3),
                                   ("d_optimality", d_optimality_upper_bound, 1.1)):
        best = _brute_force_best(theta, 4, index)
        sel = select_configurations(theta, 4, index=index, restarts=3, seed=seed)
        bound = bound_fn(theta, 4, start=sel.indices)
        assert sel.index_value <= best * (1 + 1e-12)
        assert bound.upper_bound >= best * (1 - 1e-9)
        assert bound.upper_bound <= slack * best  # measured: 1.004-1.12 (E), 1.003-1.02 (D)
        assert bound.relaxed_value <= bound.upper_bound * (1 + 1e-9)
        # without a warm start the bound stays valid
        assert bound_fn(theta, 4).upper_bound >= best * (1 - 1e-9)


def test_bound_input_errors():
    theta = _jacobians()
    with pytest.raises(DesignBoundError, match="n_select"):
        min_eigenvalue_upper_bound(theta, 16)
    with pytest.raises(DesignBoundError, match="start"):
        min_eigenvalue_upper_bound(theta, 4, start=[0, 0, 1, 2])
    with pytest.raises(DesignBoundError, match="shape"):
        d_optimality_upper_bound(theta[0], 2)


def test_comparison_table_reports_every_index_and_its_equivalent_forms():
    theta = _jacobians(n=60, k=6, p=8, seed=4)
    table = compare_observation_indices(theta, 6, restarts=2, random_draws=30)
    assert set(table) == set(OBSERVATION_INDICES)
    for name, entry in table.items():
        assert entry["ratio_vs_linear_scan"] == pytest.approx(entry["selected"] / entry["linear_scan"])
        assert entry["ratio_vs_random"] > 1.0
        assert entry["meets_paper_factor_vs_linear_scan"] == (entry["ratio_vs_linear_scan"] >= 18.5)
    ic = table["inverse_condition"]
    forms = ic["equivalent_forms_vs_linear_scan"]
    assert forms["condition_number_of_lambda_reduced_by"] == pytest.approx(ic["ratio_vs_linear_scan"] ** 2)
    d = table["d_optimality"]
    assert d["equivalent_forms_vs_linear_scan"]["product_of_singular_values_of_theta_ratio"] == pytest.approx(
        d["ratio_vs_linear_scan"] ** 8)
    for name in ("min_eigenvalue", "d_optimality"):
        assert table[name]["selected"] <= table[name]["upper_bound"] * (1 + 1e-9)
        assert table[name]["largest_possible_ratio_vs_linear_scan"] >= table[name]["ratio_vs_linear_scan"]
    assert "upper_bound" not in table["inverse_condition"]
