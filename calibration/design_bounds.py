"""How close to optimal is a selection? Upper bounds from the continuous relaxation.

Choosing n of N candidate configurations is a combinatorial problem; the exchange
algorithm (:mod:`calibration.config_selection`) finds a local optimum.
Relaxing the choice to weights ``0 <= w_j <= 1`` with ``sum w_j = n`` (each candidate
measured at most once) gives a concave maximisation whose optimum bounds every subset
of n candidates from above. Two indices have cheap certified bounds:

``min_eigenvalue`` (E-optimality, the paper's B)
    for every density matrix ``Z`` (``Z >= 0``, ``tr Z = 1``) and every subset S of n
    candidates, ``lambda_min(sum_S G_j) <= tr(Z sum_S G_j) <= top_n_j tr(Z G_j)`` with
    ``G_j = Theta_j^T Theta_j``. Minimising the right-hand side over Z (the dual of the
    relaxation, whose minimum equals the relaxation's optimum) by mirror descent on
    density matrices (matrix multiplicative weights: ``Z ~ exp(-S)``, S accumulating the
    subgradients ``sum_top G_j``), every iterate's value is a valid upper bound; the
    smallest is reported. The average of the iterates' top-n indicator vectors is a
    feasible relaxed design, whose ``lambda_min`` brackets the relaxation optimum from
    below.
``d_optimality`` (``det(Lambda)^(1/2p)``)
    ``f(w) = log det(sum w_j G_j)`` is concave with gradient ``g_j = tr(Lambda^-1 G_j)``,
    so ``f* <= f(w) + max_v g.(v - w) = f(w) + top_n(g) - p`` for any feasible w (the
    Frank-Wolfe gap). Frank-Wolfe steps with exact line search (one generalised
    eigenproblem per step) improve w; the smallest bound is reported.

The condition-number indices (``inverse_condition``, ``noise_amplification``) are
ratios of eigenvalues and have no such cheap bound; they are not covered.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from threadpoolctl import threadpool_limits

from calibration.config_selection import BLAS_THREADS

MMW_ITERATIONS = 400
"""Mirror-descent iterations of the E-optimal bound. On the campaign set (3,680
candidates, 30 parameters, n = 32) the bound settles within 0.5 % after ~200."""
MMW_STEP = 0.5
"""Step ``eta_t = MMW_STEP / (lambda_ref sqrt(t))`` with ``lambda_ref`` the smallest
eigenvalue of the start design (or the average eigenvalue of an n-design)."""
MMW_START_SHARPNESS = 3.0
"""Start ``S_0 = MMW_START_SHARPNESS (Lambda_start - lambda_min I) / lambda_ref``: Z_0
concentrated on the start design's weakest directions."""
FW_ITERATIONS = 150
"""Frank-Wolfe iterations of the D-optimal bound."""


class DesignBoundError(ValueError):
    """Malformed candidate Jacobians, subset size or start design."""


@dataclass(frozen=True)
class DesignBound:
    """Upper bound of an observation index over all subsets of ``n_select`` candidates.

    ``upper_bound``: no subset reaches a larger index value; ``relaxed_value``: the
    index of a continuous design found on the way (the relaxation's optimum lies
    between the two); ``iterations``; ``cpu_s`` CPU time of the computation (s).
    """

    index_name: str
    n_select: int
    upper_bound: float
    relaxed_value: float
    iterations: int
    cpu_s: float


def _check(jacobians: np.ndarray, n_select: int, start: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    theta = np.ascontiguousarray(jacobians, dtype=float)
    if theta.ndim != 3 or not np.all(np.isfinite(theta)):
        raise DesignBoundError(
            f"argument 'jacobians': expected a finite array of shape (N, k, p), got shape {np.shape(jacobians)}"
        )
    n = theta.shape[0]
    if not 1 <= n_select < n:
        raise DesignBoundError(f"argument 'n_select' = {n_select}: expected between 1 and {n - 1} (N = {n})")
    if start is None:
        return theta, None
    idx = np.asarray(start, dtype=int)
    if idx.ndim != 1 or len(np.unique(idx)) != n_select or idx.min() < 0 or idx.max() >= n:
        raise DesignBoundError(
            f"argument 'start': expected {n_select} distinct candidate indices in [0, {n}), got {start!r}"
        )
    return theta, idx


def _weighted_information(theta: np.ndarray, weights: np.ndarray) -> np.ndarray:
    flat = theta.reshape(-1, theta.shape[2])
    rows = np.repeat(weights, theta.shape[1])
    return flat.T @ (flat * rows[:, None])


def _quadratic_forms(flat: np.ndarray, half: np.ndarray, n: int, k: int) -> np.ndarray:
    """``tr(H H^T Theta_j^T Theta_j)`` for every candidate j, shape (n,)."""
    w = (flat @ half).reshape(n, k * half.shape[1])
    return np.einsum("nr,nr->n", w, w)


def _top(values: np.ndarray, n_select: int) -> np.ndarray:
    return np.argpartition(-values, n_select - 1)[:n_select]


def min_eigenvalue_upper_bound(
    jacobians: np.ndarray, n_select: int, *, start: np.ndarray | None = None,
    iterations: int = MMW_ITERATIONS,
) -> DesignBound:
    """Upper bound of ``lambda_min(Lambda)`` over all subsets of ``n_select`` candidates
    (see the module docstring). ``start``: indices of a good design (e.g. the selection)
    to warm-start the dual from its weakest directions."""
    theta, start_idx = _check(jacobians, n_select, start)
    n, k, p = theta.shape
    flat = theta.reshape(n * k, p)
    c0 = time.process_time()
    with threadpool_limits(limits=BLAS_THREADS, user_api="blas"):
        if start_idx is not None:
            lam = _weighted_information(theta[start_idx], np.ones(n_select))
            d = np.linalg.eigvalsh(lam)
            ref = max(d[0], 1e-12 * d[-1])
            s_acc = MMW_START_SHARPNESS * (lam - d[0] * np.eye(p)) / ref
        else:
            ref = n_select * float(np.sum(flat * flat)) / (n * p)
            s_acc = np.zeros((p, p))
        best = np.inf
        counts = np.zeros(n)
        for t in range(1, iterations + 1):
            ds, vs = np.linalg.eigh(s_acc)
            z = np.exp(-(ds - ds[0]))
            z /= z.sum()
            values = _quadratic_forms(flat, vs * np.sqrt(z), n, k)
            top = _top(values, n_select)
            best = min(best, float(values[top].sum()))
            counts[top] += 1.0
            block = theta[top].reshape(-1, p)
            s_acc = s_acc + (MMW_STEP / (ref * np.sqrt(t))) * (block.T @ block)
        relaxed = float(np.linalg.eigvalsh(_weighted_information(theta, counts / iterations))[0])
    return DesignBound("min_eigenvalue", n_select, best, relaxed, iterations, time.process_time() - c0)


def d_optimality_upper_bound(
    jacobians: np.ndarray, n_select: int, *, start: np.ndarray | None = None,
    iterations: int = FW_ITERATIONS,
) -> DesignBound:
    """Upper bound of ``det(Lambda)^(1/2p)`` over all subsets of ``n_select`` candidates
    (Frank-Wolfe gap of the relaxation, see the module docstring). ``start``: indices of
    a non-singular design to begin from (default: the n_select/N uniform design)."""
    theta, start_idx = _check(jacobians, n_select, start)
    n, k, p = theta.shape
    flat = theta.reshape(n * k, p)
    c0 = time.process_time()
    with threadpool_limits(limits=BLAS_THREADS, user_api="blas"):
        w = np.full(n, n_select / n)
        if start_idx is not None:
            w = np.zeros(n)
            w[start_idx] = 1.0
        lam = _weighted_information(theta, w)
        sign, logdet = np.linalg.slogdet(lam)
        if sign <= 0:
            raise DesignBoundError("argument 'start': the start design is singular")
        best = np.inf
        for _ in range(iterations):
            chol = np.linalg.cholesky(lam)
            half = scipy.linalg.solve_triangular(chol, np.eye(p), lower=True).T  # half half^T = lam^-1
            grad = _quadratic_forms(flat, half, n, k)
            top = _top(grad, n_select)
            best = min(best, logdet + float(grad[top].sum()) - p)
            vertex = np.zeros(n)
            vertex[top] = 1.0
            lam_v = _weighted_information(theta, vertex)
            # exact line search: logdet((1-g) lam + g lam_v) = logdet(lam) + sum log(1 - g + g mu)
            mu = np.maximum(scipy.linalg.eigvalsh(lam_v, lam), 0.0)
            gammas = np.linspace(0.0, 1.0, 201)[1:]
            gains = np.sum(np.log(np.maximum(1.0 - gammas[:, None] + gammas[:, None] * mu[None, :], 1e-300)), axis=1)
            i = int(np.argmax(gains))
            if gains[i] <= 0.0:
                break
            g = gammas[i]
            w = (1.0 - g) * w + g * vertex
            lam = (1.0 - g) * lam + g * lam_v
            logdet += float(gains[i])
    return DesignBound("d_optimality", n_select, float(np.exp(best / (2 * p))), float(np.exp(logdet / (2 * p))),
                       iterations, time.process_time() - c0)


BOUNDED_INDICES = {"min_eigenvalue": min_eigenvalue_upper_bound, "d_optimality": d_optimality_upper_bound}
"""Observation indices with a certified upper bound."""


def observation_index_upper_bound(jacobians: np.ndarray, n_select: int, index: str, *,
                                  start: np.ndarray | None = None) -> DesignBound | None:
    """The upper bound of ``index`` (None when the index has no cheap bound)."""
    bound = BOUNDED_INDICES.get(index)
    return None if bound is None else bound(jacobians, n_select, start=start)
