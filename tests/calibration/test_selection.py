"""Optimal configuration selection: indices, bounds, exact searches, the exchange algorithm."""
import numpy as np
import pytest

from calibration.config_selection import (
    ConfigurationSelectionError,
    _Search,
    linear_scan_indices,
    random_selection_values,
    select_configurations,
)
from calibration.observability import (
    OBSERVATION_INDICES,
    ObservationIndexError,
    get_index,
    information_matrix,
    observation_index,
)

from calibration_jacobians import correlated_jacobians


def _jacobians(n=150, k=6, p=12, seed=0):
    return correlated_jacobians(n, k, p, seed)


def test_index_values_match_singular_values():
    theta = _jacobians(20)
    s = np.linalg.svd(theta.reshape(-1, theta.shape[2]), compute_uv=False)
    expected = {
        "min_eigenvalue": s[-1] ** 2,
        "d_optimality": np.exp(np.mean(np.log(s))),
        "inverse_condition": s[-1] / s[0],
        "noise_amplification": s[-1] ** 2 / s[0],
    }
    for name, value in expected.items():
        assert observation_index(theta, name) == pytest.approx(value, rel=1e-9)
    assert np.allclose(information_matrix(theta), theta.reshape(-1, 12).T @ theta.reshape(-1, 12))
    with pytest.raises(ObservationIndexError, match="min_eigenvalue"):
        get_index("smallest")


@pytest.mark.parametrize("name", sorted(OBSERVATION_INDICES))
def test_upper_bounds_hold_and_lemma_is_exact(name):
    theta = _jacobians(120)
    index = get_index(name)
    lam = information_matrix(theta[:10])
    d, v = np.linalg.eigh(lam)
    w = (theta.reshape(-1, 12) @ v).reshape(theta.shape)
    exact = index.value(np.linalg.eigvalsh(lam[None] + np.einsum("nkp,nkq->npq", theta, theta)))
    bound = index.upper_bound(d, w)
    if index.bound_is_exact:
        assert np.allclose(bound, exact, rtol=1e-9)
    else:
        assert np.all(bound >= exact * (1 - 1e-12))


@pytest.mark.parametrize("name", sorted(OBSERVATION_INDICES))
def test_bounded_search_finds_the_exhaustive_argmax(name):
    theta = _jacobians(200)
    search = _Search(theta, get_index(name))
    rng = np.random.default_rng(3)
    for trial in range(4):
        subset = rng.choice(200, 8 + trial, replace=False)
        lam = search.information(subset)
        excluded = np.zeros(200, dtype=bool)
        excluded[subset] = True
        j, value = search.best_addition(lam, excluded)
        brute = search.index.value(np.linalg.eigvalsh(lam[None] + search.gram))
        brute[excluded] = -np.inf
        assert value == pytest.approx(brute.max(), rel=1e-10)
        assert brute[j] == pytest.approx(brute.max(), rel=1e-10)
        # exchange search (all removals at once) = brute force over all pairs
        bases = lam[None] - search.gram[subset]
        b, j2, v2 = search.best_pair(bases, excluded)
        pairs = search.index.value(np.linalg.eigvalsh(bases[:, None] + search.gram[None]))
        pairs[:, excluded] = -np.inf
        assert v2 == pytest.approx(pairs.max(), rel=1e-10)
        assert pairs[b, j2] == pytest.approx(pairs.max(), rel=1e-10)


def test_selection_is_a_local_optimum_and_beats_baselines():
    theta = _jacobians(150)
    result = select_configurations(theta, 12, restarts=3, seed=1)
    assert len(result.indices) == 12 and len(set(result.indices.tolist())) == 12
    assert result.index_value == pytest.approx(observation_index(theta[result.indices]), rel=1e-12)
    assert result.index_value == max(result.restart_values)
    # no single exchange improves the index (step 4's stopping rule), checked by brute force
    lam = information_matrix(theta[result.indices])
    gram = np.einsum("nkp,nkq->npq", theta, theta)
    others = np.setdiff1d(np.arange(150), result.indices)
    for j in result.indices:
        values = np.linalg.eigvalsh(lam[None] - gram[j] + gram[others])[:, 0]
        assert values.max() <= result.index_value * (1 + 1e-9)
    linear = observation_index(theta[linear_scan_indices(150, 12)])
    randoms = random_selection_values(theta, 12, draws=100, seed=2)
    assert result.index_value > 2.0 * linear
    assert result.index_value > randoms.max()
    # seeded: the same seed gives the same subset
    again = select_configurations(theta, 12, restarts=3, seed=1)
    assert np.array_equal(again.indices, result.indices)


def test_selection_input_errors():
    theta = _jacobians(30)
    with pytest.raises(ConfigurationSelectionError, match="n_select"):
        select_configurations(theta, 1)  # 6 rows cannot determine 12 parameters
    with pytest.raises(ConfigurationSelectionError, match="n_select"):
        select_configurations(theta, 31)
    with pytest.raises(ConfigurationSelectionError, match="shape"):
        select_configurations(theta[0], 3)
    bad = theta.copy()
    bad[:, :, 5] = bad[:, :, 4]  # two identical columns: rank-deficient candidate set
    with pytest.raises(ConfigurationSelectionError, match="rank-deficient"):
        select_configurations(bad, 8)
    assert linear_scan_indices(10, 4).tolist() == [0, 3, 6, 9]
