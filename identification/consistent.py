"""Physically consistent estimates: a full parameter vector of real rigid bodies that fits the data.

The least-squares base parameters (:mod:`identification.estimation`) can
correspond to no physical arm (a negative mass or an inertia breaking the triangle
inequality hidden in a combination). Here the 78 standard parameters are written
through a parameterisation that is consistent by construction (Wensing, Kim & Slotine
2017; the log-Cholesky form of Rucker & Wensing 2022):

* per link, the 4x4 pseudo-inertia ``J = [[Sigma, h], [h^T, m]]`` (positive definite
  iff the body is physically consistent, :func:`robot.dynamics.pseudo_inertia`) as
  ``J = L L^T`` with ``L`` lower triangular and ``L_ii = exp(d_i)`` (10 numbers);
* rotor inertias and friction coefficients as ``exp(.)`` (positive).

The fit, with ``Theta_f = Q R`` from the least-squares problem, is the small nonlinear
least-squares problem (no SDP/LMI solver)::

    minimise  |R (K p(theta) - p_b_ls)|^2 / s^2  +  lambda |(p(theta) - p_ref) / scale|^2

(``K`` maps standard to base parameters, ``s^2`` the residual variance), i.e. the
data misfit of the base parameters in the metric of the information matrix, plus a
small pull ``lambda`` toward the reference (nominal) parameters for the directions
the data cannot see. It starts from the least-squares solution (the 78-vector of
:meth:`BaseParameters.full_parameters` closest to the reference, each link's
pseudo-inertia projected on the consistent set by clipping its eigenvalues; starting
from the nominal arm instead ends on the degenerate boundary when a payload changes
link 6 a lot) and is solved by ``scipy.optimize.least_squares`` (trust region
reflective, analytic Jacobian).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize
from numpy.typing import ArrayLike
from threadpoolctl import threadpool_limits

from identification.base_parameters import BaseParameters, default_scale
from identification.errors import IdentificationError
from robot.dynamics import N_PARAMETERS, is_physically_consistent, pseudo_inertia

N_LINKS = 6
N_LINK_THETA = 10
_TRIL = np.tril_indices(4)
_TRIL_DIAGONAL = np.array([0, 2, 5, 9])
"""Positions of L00, L11, L22, L33 in the row-major lower-triangle order of ``_TRIL``."""
START_EIGENVALUE_FLOOR = 1e-3
"""A start link whose pseudo-inertia has an eigenvalue below this fraction of its largest is
moved to the nearest consistent one (eigenvalues clipped), away from the degenerate boundary."""
DEFAULT_REGULARISATION = 1e-4
"""lambda: weight of the pull toward the reference relative to the data misfit (per parameter,
in units of the noise); small, so the data dominate every identifiable direction."""


def link_parameters_from_pseudo_inertia(j: np.ndarray) -> np.ndarray:
    """10 link parameters [m, hx, hy, hz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz] of a pseudo-inertia."""
    sigma, h, m = j[:3, :3], j[:3, 3], j[3, 3]
    inertia = np.trace(sigma) * np.eye(3) - sigma
    return np.array([m, h[0], h[1], h[2], inertia[0, 0], inertia[0, 1], inertia[1, 1], inertia[0, 2],
                     inertia[1, 2], inertia[2, 2]])


def _theta_of_link(link: np.ndarray, relative_floor: float) -> np.ndarray:
    j = pseudo_inertia(link)
    values, vectors = np.linalg.eigh(j)
    floor = relative_floor * max(values.max(), 1e-12)
    if values.min() < floor:  # the nearest consistent body: eigenvalues clipped to a small floor
        j = (vectors * np.maximum(values, floor)) @ vectors.T
    low = np.linalg.cholesky(j)
    values = low[_TRIL].copy()
    values[_TRIL_DIAGONAL] = np.log(values[_TRIL_DIAGONAL])
    return values


def _cholesky_factor(values: np.ndarray) -> np.ndarray:
    """The lower-triangular 4x4 L of a link's 10 log-Cholesky coordinates (diagonal entries as logs)."""
    low = np.zeros((4, 4))
    entries = values.copy()
    entries[_TRIL_DIAGONAL] = np.exp(entries[_TRIL_DIAGONAL])
    low[_TRIL] = entries
    return low


def _link_of_theta(values: np.ndarray) -> np.ndarray:
    low = _cholesky_factor(values)
    return link_parameters_from_pseudo_inertia(low @ low.T)


def _link_jacobian(values: np.ndarray) -> np.ndarray:
    """d(10 link parameters) / d(10 log-Cholesky coordinates), analytic (J = L L^T is bilinear)."""
    low = _cholesky_factor(values)
    out = np.empty((10, 10))
    for k, (a, b) in enumerate(zip(*_TRIL)):
        d_low = np.zeros((4, 4))
        d_low[a, b] = low[a, b] if a == b else 1.0
        d_j = d_low @ low.T + low @ d_low.T
        out[:, k] = link_parameters_from_pseudo_inertia(d_j)  # linear in J
    return out


def parameters_jacobian(theta: np.ndarray) -> np.ndarray:
    """d p / d theta (78 x 78, block diagonal)."""
    out = np.zeros((N_PARAMETERS, N_PARAMETERS))
    for i in range(N_LINKS):
        sl = slice(10 * i, 10 * i + 10)
        out[sl, sl] = _link_jacobian(theta[sl])
    out[60:, 60:] = np.diag(np.exp(theta[60:]))
    return out


def theta_from_parameters(p: np.ndarray, relative_floor: float = 1e-12) -> np.ndarray:
    """Unconstrained coordinates (78,) of a 78-vector (positive rotor and friction). A link whose
    pseudo-inertia has an eigenvalue below ``relative_floor`` times its largest (not consistent,
    or nearly degenerate) is first moved to the nearest such body by clipping the eigenvalues."""
    theta = np.concatenate([_theta_of_link(p[10 * i:10 * i + 10], relative_floor) for i in range(N_LINKS)])
    rest = np.log(np.maximum(p[60:], 1e-9))
    return np.concatenate((theta, rest))


def parameters_from_theta(theta: np.ndarray) -> np.ndarray:
    """The 78-vector of unconstrained coordinates: always physically consistent."""
    links = [_link_of_theta(theta[10 * i:10 * i + 10]) for i in range(N_LINKS)]
    return np.concatenate(links + [np.exp(theta[60:])])


@dataclass(frozen=True)
class ConsistentEstimate:
    """``parameters`` (78,) consistent by construction; ``base_values`` (n_base,) = K p;
    ``misfit``: data misfit term (in noise units, chi-square like); ``nfev``, ``status``."""

    parameters: np.ndarray
    base_values: np.ndarray
    misfit: float
    least_squares_misfit: float
    nfev: int
    status: str

    @property
    def consistent(self) -> bool:
        return all(is_physically_consistent(self.parameters[10 * i:10 * i + 10]) for i in range(N_LINKS))


def consistent_estimate(base: BaseParameters, regressor: ArrayLike, torques: ArrayLike, reference: ArrayLike, *,
                        regularisation: float = DEFAULT_REGULARISATION, weights: ArrayLike | None = None,
                        max_evaluations: int = 200) -> ConsistentEstimate:
    """Fit a physically consistent 78-vector to (samples, 6, n_base) regressor rows and (samples, 6) torques.

    ``weights`` (6,): per-joint row weights (1 / noise sigma, as in WLS; default ones).
    ``reference`` (78,): start and regularisation target (e.g. the nominal parameters with
    the declared payload folded in).
    """
    w = np.asarray(regressor, dtype=float)
    tau = np.asarray(torques, dtype=float)
    ref = np.asarray(reference, dtype=float)
    if ref.shape != (N_PARAMETERS,):
        raise IdentificationError(f"reference has shape {ref.shape}, expected (78,)")
    weight = np.ones(6) if weights is None else np.asarray(weights, dtype=float)
    a = (w * weight[None, :, None]).reshape(-1, base.count)
    b = (tau * weight[None, :]).reshape(-1)
    q, r = np.linalg.qr(a, mode="reduced")
    qb = q.T @ b
    p_ls = np.linalg.solve(r, qb)
    residual = a @ p_ls - b
    s2 = max(float(residual @ residual) / max(a.shape[0] - base.count, 1), 1e-300)
    scale = default_scale(ref)
    k = base.combination
    sqrt_lambda = np.sqrt(regularisation)

    data_rows = r @ k / np.sqrt(s2)
    prior_rows = sqrt_lambda / scale

    def fun(theta: np.ndarray) -> np.ndarray:
        p = parameters_from_theta(theta)
        return np.concatenate((data_rows @ p - r @ p_ls / np.sqrt(s2), prior_rows * (p - ref)))

    def jac(theta: np.ndarray) -> np.ndarray:
        dp = parameters_jacobian(theta)
        return np.vstack((data_rows @ dp, prior_rows[:, None] * dp))

    # start near the data: the minimum-norm 78-vector of the least-squares base values, made consistent
    theta0 = theta_from_parameters(base.full_parameters(p_ls, ref), START_EIGENVALUE_FLOOR)
    with threadpool_limits(limits=1, user_api="blas"):
        result = scipy.optimize.least_squares(fun, theta0, jac=jac, method="trf", max_nfev=max_evaluations,
                                              x_scale="jac", ftol=1e-5, xtol=1e-10, gtol=1e-8)
    p = parameters_from_theta(result.x)
    misfit = float(np.sum((r @ (k @ p - p_ls)) ** 2) / s2)
    return ConsistentEstimate(p, k @ p, misfit, 0.0, int(result.nfev), str(result.message))
