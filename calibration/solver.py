"""Geometric calibration by iterated least squares (paper eq. 10-14).

Unknowns: the identifiable subset of the 39 error parameters of
:mod:`robot.geometric_errors` (the others stay 0; see
:mod:`calibration.identifiability`). Residual of pose j (eq. 10):
``e_j = z_Mj - f_DK(q_j, p_e)`` with the position difference (m) and, when
orientations are measured, the rotation vector of ``R_Mj R(q_j, p_e)^T`` (rad,
base-frame axes; :func:`robot.kinematics.pose_error`), whose derivative is the
identification Jacobian ``Theta`` of :meth:`GeometricErrorModel.identification_jacobian`.
Rows are weighted by the tracker noise (divided by sigma), so the weighted problem has
unit noise and mixed units do not matter.

Gauss-Newton step (eq. 14) ``dp = (Theta^T Theta)^-1 Theta^T e``, computed by a QR
least-squares solve of the stacked system rather than the normal equations. When a
step does not reduce the cost ``|e|^2 / 2`` the Levenberg-Marquardt damping
``(Theta^T Theta + mu diag(Theta^T Theta)) dp = Theta^T e`` is raised (mu x 10,
starting at 1e-3) until it does; after an accepted damped step mu shrinks by 10 and
below 1e-9 the iteration is pure Gauss-Newton again.

Statistics: ``sigma_hat^2 = |e_w|^2 / (m - p)`` (weighted residuals: about 1 when
the assumed noise is right) and the parameter covariance
``sigma_hat^2 (Theta_w^T Theta_w)^-1`` at the solution.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from calibration.identifiability import IdentifiabilityReport, identifiable_parameters
from calibration.measurements import Measurements
from calibration.optical_tracker import TrackerNoise
from robot.geometric_errors import GeometricErrorModel, default_error_model
from robot.kinematics import FlangeKinematics, pose_error

MAX_ITERATIONS = 50
STEP_TOLERANCE = 1e-12
"""Stop when the weighted step norm is below this fraction of the parameter scale
(1e-12 m / rad absolute floor) or the relative cost decrease below COST_TOLERANCE."""
COST_TOLERANCE = 1e-14
MIN_POSES_FACTOR = 1.0
"""At least ceil(p / k) poses are required (square system); the campaign uses 32."""
GENERIC_CONFIGURATIONS = 300
"""Random configurations used to find the model's generic identifiable set."""


class CalibrationError(ValueError):
    """The calibration problem cannot be solved as posed."""


class TooFewPosesError(CalibrationError):
    """Fewer measured pose components than identifiable parameters."""


class RankDeficientDataError(CalibrationError):
    """The measured poses do not excite every identifiable parameter."""


@dataclass(frozen=True)
class CalibrationResult:
    """Outcome of :func:`calibrate`.

    ``errors`` (39,) identified error vector (m, rad; unidentifiable parameters 0);
    ``std`` (39,) standard deviations (NaN for parameters not identified);
    ``identified`` indices of the identified parameters; ``identifiability`` the QR
    report of the generic model; ``residuals`` (n, k) final unweighted residuals (m,
    rad); ``initial_residuals`` the same at p_e = 0 (uncalibrated); ``sigma_hat``
    weighted residual standard deviation; ``iterations``; ``cost_history``;
    ``damping_history`` (mu per accepted step); ``converged``.
    """

    parameter_names: tuple[str, ...]
    errors: np.ndarray
    std: np.ndarray
    identified: np.ndarray
    identifiability: IdentifiabilityReport
    residuals: np.ndarray
    initial_residuals: np.ndarray
    sigma_hat: float
    iterations: int
    cost_history: tuple[float, ...]
    damping_history: tuple[float, ...]
    converged: bool
    has_orientation: bool
    covariance: np.ndarray

    def residual_statistics(self, which: str = "calibrated") -> dict:
        """Residual statistics in mm and deg (``which``: 'calibrated' or 'uncalibrated')."""
        return residual_statistics(self.residuals if which == "calibrated" else self.initial_residuals)


def residual_statistics(residuals: np.ndarray) -> dict:
    """max |e|, RMS, mean and peak-to-peak per component of residuals (n, 3 or 6) in
    m / rad, reported in mm (e_x, e_y, e_z) and deg (e_alpha... as rotation vector)."""
    r = np.asarray(residuals, dtype=float)
    names = ["e_x", "e_y", "e_z", "e_rx", "e_ry", "e_rz"][: r.shape[1]]
    scale = [1e3] * 3 + [180.0 / math.pi] * 3
    out = {}
    for c, name in enumerate(names):
        v = r[:, c] * scale[c]
        out[name] = {
            "unit": "mm" if c < 3 else "deg",
            "max_abs": float(np.max(np.abs(v))),
            "rms": float(np.sqrt(np.mean(v**2))),
            "mean": float(np.mean(v)),
            "peak_to_peak": float(np.ptp(v)),
        }
    dist = np.linalg.norm(r[:, :3], axis=1) * 1e3
    out["position_norm"] = {"unit": "mm", "max": float(dist.max()), "rms": float(np.sqrt(np.mean(dist**2)))}
    return out


@lru_cache(maxsize=8)
def _generic_report(urdf: str, orientation: bool, n: int, seed: int) -> IdentifiabilityReport:
    model = GeometricErrorModel(urdf) if urdf else default_error_model()
    kin = FlangeKinematics(model.nominal_model)
    q = np.random.default_rng(seed).uniform(kin.lower, kin.upper, size=(n, 6))
    jac = model.identification_jacobian(q)[:, : 6 if orientation else 3]
    return identifiable_parameters(jac, list(model.parameter_names))


def generic_identifiability(
    model: GeometricErrorModel | None = None, *, orientation: bool = True,
    configurations: int = GENERIC_CONFIGURATIONS, seed: int = 0,
) -> IdentifiabilityReport:
    """QR identifiability of the error model from ``configurations`` uniformly random
    joint configurations (position+orientation or position-only measurements)."""
    urdf = "" if model is None or model is default_error_model() else str(model.urdf_path)
    return _generic_report(urdf, bool(orientation), int(configurations), int(seed))


def _rows(has_orientation: bool) -> slice:
    return slice(0, 6 if has_orientation else 3)


def pose_residuals(model: GeometricErrorModel, meas: Measurements, errors: np.ndarray) -> np.ndarray:
    """Residuals ``z_M - f_DK(q, p_e)`` (n, 3 or 6): m, then rad (rotation vector)."""
    predicted = model.flange_transforms(meas.q, errors)
    full = pose_error(meas.transforms(), predicted)
    return full[:, _rows(meas.has_orientation)]


def calibrate(
    measurements: Measurements,
    *,
    model: GeometricErrorModel | None = None,
    noise: TrackerNoise | None = None,
    identifiable: list[str] | tuple[str, ...] | None = None,
    max_iterations: int = MAX_ITERATIONS,
) -> CalibrationResult:
    """Identify the error parameters from tracker ``measurements``.

    ``model``: the error model (default: nominal URDF); ``noise``: tracker noise used
    to weight rows (default :class:`TrackerNoise`); ``identifiable``: names of the
    parameters to identify (default: the generic identifiable set of the model for
    this kind of measurement). Raises :class:`TooFewPosesError` or
    :class:`RankDeficientDataError` when the poses cannot determine them.
    """
    model = model or default_error_model()
    noise = noise or TrackerNoise()
    k = 6 if measurements.has_orientation else 3
    report = generic_identifiability(model, orientation=measurements.has_orientation)
    names = list(model.parameter_names)
    if identifiable is None:
        ident = report.identifiable
    else:
        unknown = [n for n in identifiable if n not in names]
        if unknown:
            raise CalibrationError(f"argument 'identifiable': unknown parameter names {unknown}")
        ident = np.array(sorted(names.index(n) for n in identifiable))
    p = len(ident)
    needed = math.ceil(MIN_POSES_FACTOR * p / k)
    if measurements.count < needed:
        raise TooFewPosesError(
            f"{measurements.source}: {measurements.count} poses give {measurements.count * k} "
            f"equations for {p} identifiable parameters; at least {needed} poses are needed "
            f"({'position and orientation' if k == 6 else 'position only'}), 32 are recommended"
        )
    sig = noise.row_sigmas(measurements.has_orientation)
    if np.any(sig <= 0.0):
        sig = np.where(sig > 0.0, sig, 1.0)
    errors = np.zeros(len(names))
    jac0 = model.identification_jacobian(measurements.q, errors)[:, :k][:, :, ident] / sig[None, :, None]
    data_report = identifiable_parameters(jac0, [names[i] for i in ident])
    if data_report.rank < p:
        raise RankDeficientDataError(
            f"{measurements.source}: the {measurements.count} poses determine only {data_report.rank} "
            f"of the {p} identifiable parameters; not excited: {list(data_report.dropped_names)} "
            f"({'; '.join(d.describe() for d in data_report.dependencies)}). Measure more "
            "varied poses (all six joints moving between poses), e.g. the optimal configurations "
            "of `calibration.config_selection`"
        )

    def evaluate(x: np.ndarray) -> tuple[np.ndarray, float]:
        full = errors.copy()
        full[ident] = x
        r = pose_residuals(model, measurements, full) / sig
        return r, 0.5 * float(np.sum(r**2))

    x = np.zeros(p)
    res, cost = evaluate(x)
    initial = res * sig
    costs, damps = [cost], []
    mu = 0.0
    converged = False
    it = 0
    for it in range(1, max_iterations + 1):
        full = errors.copy()
        full[ident] = x
        jac = (model.identification_jacobian(measurements.q, full)[:, :k][:, :, ident] / sig[None, :, None]).reshape(-1, p)
        rhs = res.reshape(-1)
        scale = np.sqrt(np.sum(jac**2, axis=0))
        accepted = False
        while True:
            if mu > 0.0:
                a = np.vstack([jac, np.diag(np.sqrt(mu) * scale)])
                b = np.concatenate([rhs, np.zeros(p)])
            else:
                a, b = jac, rhs
            step = np.linalg.lstsq(a, b, rcond=None)[0]
            new_res, new_cost = evaluate(x + step)
            if new_cost <= cost:
                accepted = True
                break
            mu = 1e-3 if mu == 0.0 else mu * 10.0
            if mu > 1e12:
                break
        if not accepted:
            converged = True  # no descent direction left: at a minimum within round-off
            break
        decrease = cost - new_cost
        x, res, cost = x + step, new_res, new_cost
        costs.append(cost)
        damps.append(mu)
        mu = mu / 10.0 if mu > 1e-9 else 0.0
        if np.all(np.abs(step) <= STEP_TOLERANCE + 1e-10 * np.abs(x)) or decrease <= COST_TOLERANCE * max(cost, 1e-300):
            converged = True
            break
    full = errors.copy()
    full[ident] = x
    jac = (model.identification_jacobian(measurements.q, full)[:, :k][:, :, ident] / sig[None, :, None]).reshape(-1, p)
    m = jac.shape[0]
    dof = max(m - p, 1)
    sigma_hat = math.sqrt(2.0 * cost / dof)
    cov = sigma_hat**2 * np.linalg.inv(jac.T @ jac)
    std = np.full(len(names), np.nan)
    std[ident] = np.sqrt(np.diag(cov))
    return CalibrationResult(
        parameter_names=tuple(names),
        errors=full,
        std=std,
        identified=ident,
        identifiability=report,
        residuals=res * sig,
        initial_residuals=initial,
        sigma_hat=sigma_hat,
        iterations=it,
        cost_history=tuple(costs),
        damping_history=tuple(damps),
        converged=converged,
        has_orientation=measurements.has_orientation,
        covariance=cov,
    )
