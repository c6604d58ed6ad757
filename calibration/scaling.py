"""Units of the selection problem: how rows and columns of Theta are scaled.

The identification Jacobian mixes units in its rows (flange position in m,
orientation in rad) and its columns (length errors: m per m, angle errors: m or rad
per rad), so every observation index of ``Lambda = Theta^T Theta`` depends on a choice
of units. Three choices (``scaling`` names):

``whitened`` (default)
    rows divided by the tracker noise of each measured component (m, rad) and each
    column multiplied by the prior standard deviation of its parameter (from
    :class:`robot.geometric_errors.ErrorMagnitudes`: a 1 mm length error and a 0.1 deg
    tilt are typical sizes). ``Lambda = S Theta^T Sigma_e^-1 Theta S`` is then the
    Fisher information of the prior-normalised parameters: ``1 / lambda`` of an
    eigenvector is the posterior variance of that parameter combination in units of
    its prior variance (ignoring the prior's own contribution). Every index compares
    "how much better than the prior" in a unit-free way. Identifiable parameters are
    base parameters ``p_b = p_1 + kappa p_2`` (QR reduction), so their prior sigma is
    ``sqrt(sigma_1^2 + sum kappa^2 sigma_2^2)``.
``unit_rms``
    rows divided by the tracker noise, each column scaled to unit RMS norm over the
    candidate set (a data-dependent normalisation; the campaign's choice before
    ``whitened`` existed).
``natural``
    no scaling: m and rad as they come (what a paper that does not state its units
    most likely used).
"""
from __future__ import annotations

import numpy as np

from calibration.identifiability import IdentifiabilityReport

COLUMN_SCALINGS = ("whitened", "unit_rms", "natural")
"""Names of the supported scalings (see the module docstring)."""


class ScalingError(ValueError):
    """An unknown scaling name or inconsistent shapes were given."""


def base_parameter_prior_sigmas(report: IdentifiabilityReport, prior_sigmas: np.ndarray) -> np.ndarray:
    """Prior standard deviation (p,) of each identifiable base parameter (m or rad).

    ``prior_sigmas`` (P,): standard deviation of every error parameter (m, rad); a
    dropped parameter ``j`` that merges into identifiable ``i`` with coefficient
    ``kappa_ij`` adds ``kappa_ij^2 sigma_j^2`` to ``i``'s variance (independent priors).
    """
    prior = np.asarray(prior_sigmas, dtype=float)
    names = list(report.names)
    if prior.shape != (len(names),):
        raise ScalingError(
            f"argument 'prior_sigmas': expected shape ({len(names)},) (one per parameter), got {prior.shape}"
        )
    variance = prior**2
    for dep in report.dependencies:
        j = names.index(dep.parameter)
        for name, coefficient in dep.coefficients.items():
            variance[names.index(name)] += coefficient**2 * prior[j] ** 2
    return np.sqrt(variance[report.identifiable])


def selection_jacobians(
    jacobians: np.ndarray,
    report: IdentifiabilityReport,
    row_sigmas: np.ndarray,
    prior_sigmas: np.ndarray,
    scaling: str = "whitened",
) -> np.ndarray:
    """Identifiable columns of the candidates' Jacobians (N, k, P) in the units of
    ``scaling``; shape (N, k, p).

    ``row_sigmas`` (k,): tracker noise of each measured component (m, rad);
    ``prior_sigmas`` (P,): prior standard deviation of each error parameter (m, rad).
    """
    theta = np.asarray(jacobians, dtype=float)
    rows = np.asarray(row_sigmas, dtype=float)
    if theta.ndim != 3 or rows.shape != (theta.shape[1],) or np.any(rows <= 0.0):
        raise ScalingError(
            f"argument 'row_sigmas': expected {theta.shape[1:2]} positive noise sigmas for Jacobians of "
            f"shape (N, k, P), got {rows.shape} for {theta.shape}"
        )
    reduced = theta[:, :, report.identifiable]
    if scaling == "natural":
        return reduced
    weighted = reduced / rows[None, :, None]
    if scaling == "whitened":
        return weighted * base_parameter_prior_sigmas(report, prior_sigmas)
    if scaling == "unit_rms":
        return weighted / np.sqrt(np.sum(weighted**2, axis=(0, 1)) / weighted.shape[0])
    raise ScalingError(f"scaling {scaling!r} is unknown; expected one of {list(COLUMN_SCALINGS)}")
