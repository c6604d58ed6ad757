"""Observation indices of a calibration experiment (paper section 3.3.1).

A set of measured configurations gives the stacked identification Jacobian
``Theta`` (m x p) and the information ("covariance" in the paper) matrix
``Lambda = Theta^T Theta`` (p x p). An observation index is a scalar of the
eigenvalues ``lambda_1 <= ... <= lambda_p`` of ``Lambda`` (``lambda_i = sigma_i(Theta)^2``)
that grows when the experiment identifies the parameters better. Every index here is
*maximised*:

===================== ======================================== =====================
name                  value                                    reference
===================== ======================================== =====================
``min_eigenvalue``    ``lambda_1 = sigma_min(Lambda)``          paper's B (eq. 16)
``d_optimality``      ``(prod sigma_i(Theta))^(1/p)``           Borm & Menq O1
``inverse_condition`` ``sigma_min(Theta) / sigma_max(Theta)``   Driels & Pathre
``noise_amplification`` ``sigma_min(Theta)^2 / sigma_max(Theta)`` Nahvi & Hollerbach O4
===================== ======================================== =====================

Besides the exact value (from eigenvalues), each index gives a cheap *upper bound*
of its value after adding one candidate configuration, computed from the current
eigen-decomposition ``Lambda = V diag(d) V^T`` and the candidate's rotated Jacobian
``W = Theta_j V`` (k x p): with the Rayleigh quotients of the unit vectors,
``lambda_min(Lambda + Theta_j^T Theta_j) <= min_i (d_i + |W_:,i|^2)`` and
``lambda_max(...) >= max_i (d_i + |W_:,i|^2)``; D-optimality is exact through the
matrix determinant lemma ``det(D + W^T W) = det(D) det(I_k + W D^-1 W^T)``. The selection search
(:mod:`calibration.config_selection`) evaluates exact values only
for candidates whose bound can still beat the best one found, so its result is the
exact argmax of an exhaustive search at a fraction of the cost.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


class ObservationIndexError(ValueError):
    """An unknown observation-index name was given."""


def _min_eig(eigs: np.ndarray) -> np.ndarray:
    return eigs[..., 0]


def _d_opt(eigs: np.ndarray) -> np.ndarray:
    clipped = np.maximum(eigs, 1e-300)
    return np.exp(0.5 * np.mean(np.log(clipped), axis=-1)) * (eigs[..., 0] > 0.0)


def _inv_cond(eigs: np.ndarray) -> np.ndarray:
    return np.sqrt(np.maximum(eigs[..., 0], 0.0) / eigs[..., -1])


def _noise_amp(eigs: np.ndarray) -> np.ndarray:
    return np.maximum(eigs[..., 0], 0.0) / np.sqrt(eigs[..., -1])


def rayleigh_bounds(d: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the extreme eigenvalues of ``diag(d) + W W^T`` for N candidates.

    ``d`` (p,) eigenvalues of the current Lambda, ``w`` (N, k, p) rotated candidate
    Jacobians ``Theta_j V``. Returns (upper bound of lambda_min, lower bound of lambda_max), each
    (N,), from the Rayleigh quotients of the p unit vectors (the diagonal).
    """
    diag = d[None, :] + np.einsum("nkp,nkp->np", w, w)
    return diag.min(axis=1), np.maximum(diag.max(axis=1), d[-1])


def _exact_d_opt(d: np.ndarray, w: np.ndarray) -> np.ndarray:
    # matrix determinant lemma: det(D + W^T W) = det(D) det(I_k + W D^-1 W^T)
    k = w.shape[1]
    y = w / np.sqrt(d)
    small = np.matmul(y, np.swapaxes(y, 1, 2))
    small[:, np.arange(k), np.arange(k)] += 1.0
    logdet = np.sum(np.log(d)) + np.linalg.slogdet(small)[1]
    return np.exp(0.5 * logdet / d.shape[0])


@dataclass(frozen=True)
class ObservationIndex:
    """One observation index: exact value from eigenvalues and cheap upper bounds.

    ``value(eigs)``: eigenvalues of Lambda in ascending order, shape (..., p) -> (...).
    ``from_extremes(low, high)``: the index's upper bound from an upper bound ``low``
    of lambda_min and a lower bound ``high`` of lambda_max (arrays (N,)).
    ``lemma(d, w)``: exact value after adding each candidate without an eigenvalue
    problem (D-optimality), or None. ``uses_lambda_max``: the bound needs a lower
    bound of lambda_max.
    """

    name: str
    description: str
    value: Callable[[np.ndarray], np.ndarray]
    from_extremes: Callable[[np.ndarray, np.ndarray], np.ndarray]
    lemma: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    uses_lambda_max: bool = False

    @property
    def bound_is_exact(self) -> bool:
        """True when :meth:`upper_bound` is the exact value."""
        return self.lemma is not None

    def upper_bound(self, d: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Upper bound (N,) of the index after adding each candidate.

        ``d`` (r,) eigenvalues of the current Lambda for r of its eigenvectors ``V_r``
        (the last one the highest eigenvalue), ``w = Theta_j V_r`` (N, k, r). With the
        lemma (``r = p``, all eigenvectors) the value is exact.
        """
        if self.lemma is not None:
            return self.lemma(d, w)
        low, high = rayleigh_bounds(d, w)
        return self.from_extremes(low, high)

    def upper_bound_from_extremes(self, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        """Index bound from eigenvalue bounds (see ``from_extremes``)."""
        return self.from_extremes(low, high)


OBSERVATION_INDICES: dict[str, ObservationIndex] = {
    "min_eigenvalue": ObservationIndex(
        "min_eigenvalue",
        "smallest eigenvalue of Lambda = Theta^T Theta (the paper's B = sigma_m(Lambda))",
        _min_eig,
        lambda low, high: low,
    ),
    "d_optimality": ObservationIndex(
        "d_optimality",
        "geometric mean of the singular values of Theta, det(Lambda)^(1/(2p))",
        _d_opt,
        lambda low, high: np.full(low.shape, np.inf),
        lemma=_exact_d_opt,
    ),
    "inverse_condition": ObservationIndex(
        "inverse_condition",
        "inverse condition number sigma_min(Theta)/sigma_max(Theta)",
        _inv_cond,
        lambda low, high: np.sqrt(np.maximum(low, 0.0) / high),
        uses_lambda_max=True,
    ),
    "noise_amplification": ObservationIndex(
        "noise_amplification",
        "noise amplification index sigma_min(Theta)^2/sigma_max(Theta)",
        _noise_amp,
        lambda low, high: np.maximum(low, 0.0) / np.sqrt(high),
        uses_lambda_max=True,
    ),
}


def get_index(name: str) -> ObservationIndex:
    """Return the observation index called ``name`` (see :data:`OBSERVATION_INDICES`)."""
    try:
        return OBSERVATION_INDICES[name]
    except KeyError:
        raise ObservationIndexError(
            f"observation index {name!r} is unknown; expected one of "
            f"{sorted(OBSERVATION_INDICES)}"
        ) from None


def information_matrix(jacobians: np.ndarray) -> np.ndarray:
    """``Lambda = sum_j Theta_j^T Theta_j`` (p, p) of stacked per-configuration
    Jacobians of shape (n, k, p) (or an already stacked (m, p) matrix)."""
    theta = np.asarray(jacobians, dtype=float)
    theta = theta.reshape(-1, theta.shape[-1])
    return theta.T @ theta


def observation_index(jacobians: np.ndarray, index: str = "min_eigenvalue") -> float:
    """Value of the observation index ``index`` of the configurations whose
    Jacobians are stacked in ``jacobians`` (n, k, p) or (m, p)."""
    eigs = np.linalg.eigvalsh(information_matrix(jacobians))
    return float(get_index(index).value(eigs))
