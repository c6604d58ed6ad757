"""Least-squares estimates of the base parameters (paper eq. 26-28) and their quality.

Stacking ``k`` samples of ``Theta_1(q, qd, qdd) p_b = Q_M`` gives the over-determined
system ``Theta_f p_b = Q_f`` (eq. 26). Two estimators:

* **ordinary least squares** (eq. 28, ``p_b = (Theta_f^T Theta_f)^-1 Theta_f^T Q_f``),
  solved by an SVD of the column-normalised ``Theta_f`` (never the normal equations);
  covariance ``sigma^2 (Theta_f^T Theta_f)^-1`` with one noise variance
  ``sigma^2 = |e|^2 / (rows - n_base)``;
* **weighted least squares** (Gautier & Poignet): the joints' torques have different
  noise levels (a 700 N m axis versus a 35 N m wrist axis), so each joint's rows are
  divided by the standard deviation of that joint's residual in a first OLS pass,
  ``sigma_j^2 = |e_j|^2 / (k - n_j)`` (``n_j``: base parameters acting on joint j),
  re-estimated from the weighted fit's residuals (:data:`WLS_PASSES` passes);
  covariance ``(Theta_f^T Sigma^-1 Theta_f)^-1``.

Before solving, :func:`check_excitation` refuses data that cannot determine every
base parameter: a regressor whose column-normalised condition number exceeds
:data:`MAX_CONDITION_NUMBER` (or is rank deficient) raises
:class:`~identification.errors.InsufficientExcitationError` naming the base
parameters in the badly determined directions. A fit is never returned silently
poor.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from threadpoolctl import threadpool_limits

from identification.defaults import MAX_CONDITION_NUMBER
from identification.errors import IdentificationDataError, InsufficientExcitationError
from robot.joints import N_JOINTS

MIN_ROWS_PER_PARAMETER = 10
"""At least this many torque rows (samples x 6) per base parameter."""
WLS_PASSES = 3
"""Weighted passes: the per-joint noise is estimated from the OLS residuals, then again from
each weighted fit's residuals (iteratively reweighted; converged after about 3 passes)."""
POORLY_EXCITED_COMPONENT = 0.2
"""A base parameter is named as poorly excited when its weight in a badly determined
right singular vector (unit norm) is at least this."""


@dataclass(frozen=True)
class BaseEstimate:
    """Estimated base parameters.

    ``values``/``std``: (n_base,) in the units of each base parameter; ``method``:
    ``"ols"`` or ``"wls"``; ``joint_sigma``: (6,) N m, standard deviation of each
    joint's torque residual (first OLS pass); ``residual_rms``: (6,) N m of this fit;
    ``condition_number``: of the column-normalised regressor; ``samples``: time
    samples used (rows / 6).
    """

    names: tuple[str, ...]
    values: np.ndarray
    std: np.ndarray
    method: str
    joint_sigma: np.ndarray
    residual_rms: np.ndarray
    condition_number: float
    samples: int

    @property
    def relative_std_percent(self) -> np.ndarray:
        """100 * std / |value| per base parameter (inf for a zero estimate)."""
        with np.errstate(divide="ignore"):
            return np.where(self.values != 0.0, 100.0 * self.std / np.abs(self.values), math.inf)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: method, condition number, samples, per-joint noise, per-parameter value/std."""
        return {
            "method": self.method,
            "condition_number": self.condition_number,
            "samples": self.samples,
            "joint_noise_sigma_Nm": self.joint_sigma.tolist(),
            "residual_rms_Nm": self.residual_rms.tolist(),
            "values": dict(zip(self.names, self.values.tolist())),
            "std": dict(zip(self.names, self.std.tolist())),
        }


@dataclass(frozen=True)
class ExcitationDiagnosis:
    """Condition of a stacked base regressor (column-normalised).

    ``singular_values`` descending, ``condition_number`` (inf when rank deficient),
    ``poorly_excited`` base-parameter names in the weakest directions (empty if fine),
    ``column_norms`` of the unnormalised columns.
    """

    condition_number: float
    singular_values: np.ndarray
    poorly_excited: tuple[str, ...]
    column_norms: np.ndarray


def _stack(regressor: ArrayLike, torques: ArrayLike | None, n_names: int) -> tuple[np.ndarray, np.ndarray | None]:
    w = np.asarray(regressor, dtype=float)
    if w.ndim != 3 or w.shape[1] != N_JOINTS or w.shape[2] != n_names:
        raise IdentificationDataError(
            f"regressor has shape {w.shape}, expected (samples, {N_JOINTS}, {n_names}) base-regressor rows")
    if not np.all(np.isfinite(w)):
        raise IdentificationDataError("regressor: contains NaN or infinite values (check q, qd, qdd)")
    if torques is None:
        return w, None
    tau = np.asarray(torques, dtype=float)
    if tau.shape != w.shape[:2]:
        raise IdentificationDataError(f"torques have shape {tau.shape}, expected {w.shape[:2]} (samples, 6) in N m")
    if not np.all(np.isfinite(tau)):
        raise IdentificationDataError("torques: contain NaN or infinite values")
    return w, tau


@threadpool_limits.wrap(limits=1, user_api="blas")
def diagnose_excitation(regressor: ArrayLike, names: tuple[str, ...]) -> ExcitationDiagnosis:
    """Singular values and condition number of the column-normalised (samples, 6, n) regressor."""
    w, _ = _stack(regressor, None, len(names))
    a = w.reshape(-1, len(names))
    norms = np.linalg.norm(a, axis=0)
    scale = np.where(norms > 0.0, norms, 1.0)
    r = np.linalg.qr(a / scale, mode="r")  # tall-skinny: same singular values as the 6k x n matrix
    s, vt = np.linalg.svd(r)[1:]
    tiny = s <= s[0] * 1e-13
    cond = math.inf if np.any(tiny) or np.any(norms == 0.0) else float(s[0] / s[-1])
    return ExcitationDiagnosis(cond, s, _weak_parameters(s, vt, norms, names, MAX_CONDITION_NUMBER), norms)


def _weak_parameters(s: np.ndarray, vt: np.ndarray, norms: np.ndarray, names: tuple[str, ...],
                     max_condition: float) -> tuple[str, ...]:
    weak: list[str] = [names[j] for j in np.flatnonzero(norms == 0.0)]
    for k in np.flatnonzero(s < s[0] / max_condition):
        for j in np.argsort(-np.abs(vt[k])):
            if abs(vt[k, j]) < POORLY_EXCITED_COMPONENT:
                break
            if names[j] not in weak:
                weak.append(names[j])
    return tuple(weak)


def check_excitation(regressor: ArrayLike, names: tuple[str, ...],
                     max_condition: float = MAX_CONDITION_NUMBER) -> ExcitationDiagnosis:
    """Raise :class:`InsufficientExcitationError` unless the data determine every base parameter.

    Checks: enough rows (:data:`MIN_ROWS_PER_PARAMETER` per parameter), no column that
    is identically zero, and a column-normalised condition number <= ``max_condition``.
    """
    w, _ = _stack(regressor, None, len(names))
    rows_needed = MIN_ROWS_PER_PARAMETER * len(names)
    if w.shape[0] * N_JOINTS < rows_needed:
        raise IdentificationDataError(
            f"too few samples: {w.shape[0]} time samples give {w.shape[0] * N_JOINTS} torque rows, expected at "
            f"least {rows_needed} ({MIN_ROWS_PER_PARAMETER} per base parameter, {len(names)} base parameters), "
            f"i.e. >= {math.ceil(rows_needed / N_JOINTS)} samples")
    diagnosis = diagnose_excitation(w, names)
    if diagnosis.condition_number > max_condition:
        weak = diagnosis.poorly_excited or tuple(names)
        what = ("rank deficient" if math.isinf(diagnosis.condition_number)
                else f"condition number {diagnosis.condition_number:.3g}")
        raise InsufficientExcitationError(
            f"the data do not excite the dynamics enough to identify the base parameters: column-normalised "
            f"regressor {what}, expected <= {max_condition:g}; poorly excited base parameters: "
            f"{', '.join(weak)} (move every joint over a wide range with varying speed and acceleration, "
            f"e.g. an optimised exciting trajectory)", weak, diagnosis.condition_number)
    return diagnosis


@threadpool_limits.wrap(limits=1, user_api="blas")
def _solve(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least squares of column-normalised ``a``: (solution, inverse of a^T a) in natural units.

    QR of the tall matrix, then the SVD of the small triangular factor (never the normal
    equations): ``a_n = Q R``, ``R = U s V^T``, ``x = V s^-1 U^T Q^T b``.
    """
    norms = np.linalg.norm(a, axis=0)
    scale = np.where(norms > 0.0, norms, 1.0)
    q, r = np.linalg.qr(a / scale, mode="reduced")
    u, s, vt = np.linalg.svd(r)
    x = vt.T @ ((u.T @ (q.T @ b)) / s) / scale
    inv = (vt.T / s**2) @ vt / np.outer(scale, scale)
    return x, inv


def ordinary_least_squares(regressor: ArrayLike, torques: ArrayLike, names: tuple[str, ...],
                           max_condition: float = MAX_CONDITION_NUMBER) -> BaseEstimate:
    """OLS estimate (eq. 28) from a (samples, 6, n_base) regressor and (samples, 6) torques in N m."""
    w, tau = _stack(regressor, torques, len(names))
    diagnosis = check_excitation(w, names, max_condition)
    a, b = w.reshape(-1, len(names)), tau.reshape(-1)
    x, inv = _solve(a, b)
    residual = (a @ x - b).reshape(-1, N_JOINTS)
    dof = a.shape[0] - len(names)
    sigma2 = float(residual.ravel() @ residual.ravel()) / dof
    std = np.sqrt(np.clip(np.diag(inv), 0.0, None) * sigma2)
    return BaseEstimate(tuple(names), x, std, "ols", _joint_sigma(w, residual),
                        np.sqrt(np.mean(residual**2, axis=0)), diagnosis.condition_number, w.shape[0])


def weighted_least_squares(regressor: ArrayLike, torques: ArrayLike, names: tuple[str, ...],
                           max_condition: float = MAX_CONDITION_NUMBER, first: BaseEstimate | None = None,
                           passes: int = WLS_PASSES) -> BaseEstimate:
    """WLS estimate: rows of joint j divided by its residual std, first from an OLS pass
    (``first``, computed here when not given), then re-estimated from the WLS residuals
    ``passes - 1`` more times (the OLS residual of a quiet wrist joint also holds the
    leakage of the noisy base joints' errors, which a weighted fit removes)."""
    w, tau = _stack(regressor, torques, len(names))
    first = first or ordinary_least_squares(w, tau, names, max_condition)
    sigma = first.joint_sigma
    for _ in range(max(1, passes)):
        floor = 1e-9 * max(float(sigma.max()), 1e-300)
        weights = 1.0 / np.maximum(sigma, floor)
        a = (w * weights[None, :, None]).reshape(-1, len(names))
        b = (tau * weights[None, :]).reshape(-1)
        x, inv = _solve(a, b)
        residual = np.einsum("kjn,n->kj", w, x) - tau
        used_sigma, sigma = sigma, _joint_sigma(w, residual)
    std = np.sqrt(np.clip(np.diag(inv), 0.0, None))
    return BaseEstimate(tuple(names), x, std, "wls", used_sigma, np.sqrt(np.mean(residual**2, axis=0)),
                        first.condition_number, w.shape[0])


def _joint_sigma(w: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """Per-joint residual std with the degrees of freedom of the parameters acting on that joint."""
    acting = np.sum(np.any(w != 0.0, axis=0), axis=1)  # (6,) base parameters with a nonzero entry per joint
    dof = np.maximum(w.shape[0] - acting, 1)
    return np.sqrt(np.sum(residual**2, axis=0) / dof)


def predict_torques(regressor: ArrayLike, values: ArrayLike) -> np.ndarray:
    """``Theta_1 p_b`` of a (samples, 6, n) regressor: torques (samples, 6) in N m."""
    w = np.asarray(regressor, dtype=float)
    return np.einsum("kjn,n->kj", w, np.asarray(values, dtype=float))


def relative_rms_error(measured: ArrayLike, predicted: ArrayLike) -> np.ndarray:
    """Per joint: RMS(predicted - measured) / RMS(measured), (6,) dimensionless."""
    m, p = np.asarray(measured, dtype=float), np.asarray(predicted, dtype=float)
    if m.shape != p.shape or m.ndim != 2:
        raise IdentificationDataError(f"measured {m.shape} and predicted {p.shape} torques: expected equal (n, 6)")
    rms = np.sqrt(np.mean(m**2, axis=0))
    err = np.sqrt(np.mean((p - m) ** 2, axis=0))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(rms > 0.0, err / rms, math.inf)
