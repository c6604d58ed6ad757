"""Dynamic identification of a measured record: prepare, estimate, validate, write.

Pipeline (paper section 4.1):

1. :func:`prepare_motion`: joint speeds and accelerations by zero-phase filtering and
   central differences (:mod:`identification.signals`) unless the record
   carries them. Records longer than :data:`MAX_PROCESSED_SAMPLES` are first
   decimated by an integer factor after a zero-phase anti-aliasing low-pass (the same
   Butterworth with cubic end padding, at 0.8 x the new Nyquist frequency) on q and
   tau (``scipy.signal.decimate`` pads with zeros and ruins the ends of a record with
   non-zero angles).
2. **Parallel filtering** (Gautier 1997): the base regressor ``Theta_1`` is evaluated
   on the states at the full rate, then the SAME zero-phase low-pass is applied to the
   measured torque and to every column of ``Theta_1`` (the model is linear in the
   parameters, so ``lowpass(tau) = lowpass(Theta_1) p_b`` holds exactly). This removes
   what the states cannot explain - on the co-simulated cell the drives' speed loops
   add a torque ripple of about 5 % of the RMS torque at 100-1250 Hz (quantised speed
   feedback) - without the bias a low-pass on tau alone would cause: the Coulomb term
   ``fc tanh(qd / v_s)`` is a near-step at each velocity reversal and is smeared
   identically on both sides. The filtered rows are decimated (at most ``max_samples``,
   >= 4 samples per cut-off period) and go to :func:`identify_regressor`: excitation
   check, weighted (default) or ordinary least squares
   (:mod:`identification.estimation`).
   For a record that repeats a periodic (exciting) trajectory,
   :func:`identify_periodic` averages whole periods first, differentiates in the
   Fourier domain and parallel-filters by dropping the same harmonics from tau and
   ``Theta_1`` (:func:`prepare_periodic`).
3. :func:`validate`: the torques the identified model predicts along another record
   versus the measured ones; relative RMS error per joint = RMS(error) / RMS(measured),
   both after the same zero-phase low-pass (``relative_rms_error``) and unfiltered
   (``relative_rms_error_unfiltered``, which includes the unexplainable ripple).

The identified base parameters include everything rigidly attached to the flange (a
payload is part of link 6's inertia) and the drive-side effects the torques contain
(reflected rotor inertia, viscous and Coulomb friction): ``tau`` must be the joint-side
torque the motor produces, ``N k_t i``, not the torque behind the gear.
"""
from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from identification.base_parameters import BaseParameters, nominal_base_parameters
from identification.consistent import ConsistentEstimate, consistent_estimate
from identification.data import MotionRecord, write_prediction_csv
from identification.errors import IdentificationDataError, IdentificationError
from identification.estimation import (MAX_CONDITION_NUMBER, BaseEstimate, ordinary_least_squares,
                                               predict_torques, relative_rms_error, weighted_least_squares)
from identification.signals import (DEFAULT_CUTOFF_HZ, FILTER_ORDER, average_periods, minimum_samples,
                                            periodic_derivatives, periodic_lowpass, zero_phase_derivatives,
                                            zero_phase_lowpass)
from robot.dynamics import PARAMETER_NAMES, RobotDynamics, is_physically_consistent, nominal_parameter_vector

DEFAULT_MAX_SAMPLES = 5000
"""Time samples of the least-squares problem at most (after parallel filtering, by decimation;
never below 4 samples per period of the cut-off, where nothing is lost)."""
ANTI_ALIAS_FRACTION = 0.8
"""Anti-aliasing cut-off before pre-decimation, as a fraction of the new Nyquist frequency."""
MAX_PROCESSED_SAMPLES = 50000
"""Longer records are decimated before the regressor is built (memory: 50000 x 6 x 52 doubles
= 125 MB for the parallel-filtered regressor)."""
DECIMATION_CUTOFF_MARGIN = 10.0
"""Pre-decimation keeps at least this many samples per period of the cut-off frequency."""
METHODS = ("wls", "ols")
_CHUNK = 4096


@dataclass(frozen=True)
class PreparedMotion:
    """States and torques ready for the regressor: ``t`` (n,) s, ``q``/``qd``/``qdd`` (n, 6)
    rad, rad/s, rad/s^2, ``tau`` (n, 6) N m (filtered like q), ``how`` describes the processing."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    how: dict[str, Any] = field(default_factory=dict)


def prepare_motion(record: MotionRecord, cutoff_hz: float = DEFAULT_CUTOFF_HZ) -> PreparedMotion:
    """States (q, qd, qdd) and torques of a record at the processing rate (see module docstring)."""
    dt = record.sample_time
    t, q_raw, tau, qd_raw, qdd_raw = record.t, record.q, record.tau, record.qd, record.qdd
    factor = 1
    if record.samples > MAX_PROCESSED_SAMPLES:
        factor = max(1, min(int(math.ceil(record.samples / MAX_PROCESSED_SAMPLES)),
                            int(1.0 / (DECIMATION_CUTOFF_MARGIN * cutoff_hz * dt))))
    if factor > 1:
        anti_alias_hz = ANTI_ALIAS_FRACTION * 0.5 / (dt * factor)

        def down(x):
            return None if x is None else zero_phase_lowpass(x, dt, anti_alias_hz)[::factor]
        t, q_raw, tau, qd_raw, qdd_raw = t[::factor], down(q_raw), down(tau), down(qd_raw), down(qdd_raw)
        dt *= factor
    if qd_raw is not None and qdd_raw is not None:
        q, qd, qdd = q_raw, qd_raw, qdd_raw
        how = {"derivatives": "given in the record"}
    else:
        need = minimum_samples(dt, cutoff_hz)
        if t.size < need:
            raise IdentificationDataError(
                f"{record.source}: record too short: {record.samples} samples ({record.duration:.4g} s), expected at "
                f"least {need} samples to filter and differentiate at {cutoff_hz:g} Hz")
        q, qd, qdd = zero_phase_derivatives(q_raw, dt, cutoff_hz)
        if qd_raw is not None:
            qd = zero_phase_lowpass(qd_raw, dt, cutoff_hz)
            qdd = np.gradient(qd, dt, axis=0, edge_order=2)
        how = {"derivatives": ("qd given, qdd by central differences of it" if qd_raw is not None else
                               "central differences of the zero-phase filtered q")}
    how.update({"filter": f"Butterworth order {FILTER_ORDER} forwards and backwards (sosfiltfilt, cubic end "
                          f"padding), cut-off {cutoff_hz:g} Hz, on q; the same filter on tau and on every "
                          "regressor column (parallel filtering)",
                "sample_time_s": dt, "cutoff_hz": cutoff_hz, "pre_decimation": factor})
    return PreparedMotion(t, q, qd, qdd, tau, how)


def base_regressor(base: BaseParameters, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike,
                   dynamics: RobotDynamics | None = None) -> np.ndarray:
    """``Theta_1`` (n, 6, n_base) of joint states (n, 6) on the kinematic structure of ``dynamics``,
    else the one ``base`` was computed on (``base.structure``), else the nominal arm."""
    dynamics = dynamics or getattr(base, "structure", None) or _structure_dynamics()
    q, qd, qdd = (np.asarray(x, dtype=float) for x in (q, qd, qdd))
    return base.base_regressor(dynamics.regressor_batch(q, qd, qdd))


def _structure_dynamics() -> RobotDynamics:
    return RobotDynamics()


@dataclass(frozen=True)
class DynamicIdentification:
    """Identified base parameters and how they were obtained.

    ``estimate``: the chosen estimate (``wls`` default), ``ordinary``: the OLS estimate;
    ``full_parameters``: a 78-vector with exactly these base values, closest to the
    nominal parameters (:meth:`BaseParameters.full_parameters`), payload included in
    link 6; ``data``: samples, duration and processing of the identification record;
    ``consistent``: the physically consistent fit (:mod:`identification.consistent`)
    when requested.
    """

    base: BaseParameters
    estimate: BaseEstimate
    ordinary: BaseEstimate
    full_parameters: np.ndarray
    data: dict[str, Any]
    consistent: ConsistentEstimate | None = None

    @property
    def values(self) -> np.ndarray:
        return self.estimate.values

    def dynamics(self, consistent: bool = False) -> RobotDynamics:
        """A RobotDynamics of the identified model (payload zero: it is in the parameters);
        ``consistent=True``: the physically consistent fit's parameters."""
        if consistent:
            if self.consistent is None:
                raise IdentificationError("no physically consistent estimate was computed (consistent=True)")
            return RobotDynamics(self.consistent.parameters, np.zeros(4), model=self._model())
        return RobotDynamics(self.full_parameters, np.zeros(4), model=self._model())

    def _model(self):
        """The kinematic structure the base parameters belong to (None: the nominal arm)."""
        return None if self.base.structure is None else self.base.structure.model

    def consistent_model(self) -> "DynamicIdentification":
        """This identification with the physically consistent fit's base values and parameters."""
        if self.consistent is None:
            raise IdentificationError("no physically consistent estimate was computed (consistent=True)")
        estimate = dataclasses.replace(self.estimate, values=self.consistent.base_values)
        return dataclasses.replace(self, estimate=estimate, full_parameters=self.consistent.parameters)

    def predict(self, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike) -> np.ndarray:
        """Model torques (n, 6) in N m along joint states (n, 6) (evaluated in chunks)."""
        q, qd, qdd = (np.atleast_2d(np.asarray(x, dtype=float)) for x in (q, qd, qdd))
        out = np.empty_like(q)
        dynamics = self.base.structure or _structure_dynamics()
        for k in range(0, q.shape[0], _CHUNK):
            sl = slice(k, k + _CHUNK)
            out[sl] = predict_torques(base_regressor(self.base, q[sl], qd[sl], qdd[sl], dynamics), self.values)
        return out

    def to_dict(self) -> dict[str, Any]:
        """parameters.json content: base parameters (value, std, definition), estimates, data."""
        rel = self.estimate.relative_std_percent
        entries = []
        for k, (name, unit, text, terms) in enumerate(zip(self.base.base_names, self.base.base_units,
                                                          self.base.definitions(), self.base.terms())):
            entries.append({"name": name, "unit": unit, "definition": text,
                            "terms": {t.name: t.coefficient for t in terms},
                            "value": float(self.estimate.values[k]), "std": float(self.estimate.std[k]),
                            "relative_std_percent": float(rel[k]) if math.isfinite(rel[k]) else None,
                            "ols_value": float(self.ordinary.values[k])})
        structure = self.base.to_dict()
        consistent = None
        if self.consistent is not None:
            c = self.consistent
            consistent = {
                "method": "nonlinear least squares on log-Cholesky pseudo-inertias (identification.consistent)",
                "misfit_in_noise_units": c.misfit, "physically_consistent": c.consistent, "evaluations": c.nfev,
                "base_values": dict(zip(self.base.base_names, c.base_values.tolist())),
                "standard_parameters": dict(zip(PARAMETER_NAMES, c.parameters.tolist())),
            }
        links_ok = [bool(is_physically_consistent(self.full_parameters[10 * i:10 * i + 10])) for i in range(6)]
        return {
            "method": self.estimate.method,
            "count": self.base.count,
            "base_parameters": entries,
            "condition_number": self.estimate.condition_number,
            "joint_noise_sigma_Nm": self.estimate.joint_sigma.tolist(),
            "residual_rms_Nm": self.estimate.residual_rms.tolist(),
            "samples": self.estimate.samples,
            "data": self.data,
            "structure": {k: structure[k] for k in ("rank_tolerance", "pivot_gap", "kappa_residual", "states",
                                                    "no_effect", "merged")},
            "standard_parameters_matching_base_values": {
                "note": "one 78-vector with exactly these base values (closest to the nominal parameters; payload "
                        "folded into link 6); only the base values are determined by the data",
                "links_physically_consistent": links_ok,
                "values": dict(zip(PARAMETER_NAMES, self.full_parameters.tolist())),
            },
            "physically_consistent_estimate": consistent,
        }


def identify_regressor(w: ArrayLike, tau: ArrayLike, *, base: BaseParameters | None = None, method: str = "wls",
                       max_condition: float = MAX_CONDITION_NUMBER, reference: ArrayLike | None = None,
                       data: dict[str, Any] | None = None, independent_samples: float | None = None,
                       consistent: bool = False) -> DynamicIdentification:
    """Estimate the base parameters from a (filtered) base regressor (n, 6, n_base) and torques (n, 6).

    ``reference`` (78,) is the vector the consistent full parameters stay closest to
    (default: nominal). ``independent_samples``: how many of the n samples carry
    independent noise (low-pass filtered data: about 2 x cut-off x duration); the
    standard deviations are scaled by sqrt(n / independent_samples) (least squares
    assumes independent rows). ``consistent``: also fit a physically consistent 78-vector
    (:func:`identification.consistent.consistent_estimate`, started from the
    least-squares solution, weighted like the WLS). Raises InsufficientExcitationError /
    IdentificationDataError.
    """
    if method not in METHODS:
        raise IdentificationError(f"method = {method!r}, expected one of {METHODS}")
    base = base or nominal_base_parameters()
    names = base.base_names
    ordinary = ordinary_least_squares(w, tau, names, max_condition)
    estimate = weighted_least_squares(w, tau, names, max_condition, ordinary) if method == "wls" else ordinary
    n = int(np.shape(w)[0])
    info = dict(data or {}, samples=n)
    if independent_samples is not None and 0 < independent_samples < n:
        factor = math.sqrt(n / independent_samples)
        estimate = dataclasses.replace(estimate, std=estimate.std * factor)
        ordinary = dataclasses.replace(ordinary, std=ordinary.std * factor)
        info.update(independent_samples=float(independent_samples), std_correlation_factor=factor)
    ref = nominal_parameter_vector() if reference is None else np.asarray(reference, dtype=float)
    full = base.full_parameters(estimate.values, ref)
    full.setflags(write=False)
    fit = None
    if consistent:
        fit = consistent_estimate(base, w, tau, ref, weights=1.0 / np.maximum(estimate.joint_sigma, 1e-300))
    return DynamicIdentification(base, estimate, ordinary, full, info, fit)


def identify_states(q: ArrayLike, qd: ArrayLike, qdd: ArrayLike, tau: ArrayLike, *,
                    base: BaseParameters | None = None, method: str = "wls",
                    max_condition: float = MAX_CONDITION_NUMBER, reference: ArrayLike | None = None,
                    data: dict[str, Any] | None = None) -> DynamicIdentification:
    """Estimate the base parameters from clean joint states and torques (n, 6) each (no filtering)."""
    base = base or nominal_base_parameters()
    return identify_regressor(base_regressor(base, q, qd, qdd), tau, base=base, method=method,
                              max_condition=max_condition, reference=reference, data=data)


def identify(record: MotionRecord, *, base: BaseParameters | None = None, method: str = "wls",
             cutoff_hz: float = DEFAULT_CUTOFF_HZ, max_condition: float = MAX_CONDITION_NUMBER,
             max_samples: int | None = DEFAULT_MAX_SAMPLES, consistent: bool = False,
             torque_acceleration_bias: ArrayLike | None = None) -> DynamicIdentification:
    """Identify the base parameters from a record (prepare, parallel filtering, least squares).

    ``torque_acceleration_bias``: (6,) N m per rad/s^2, the drives' torque-sampling term
    ``b_i qdd_i`` removed from the measured torque first (see :func:`identify_periodic`)."""
    base = base or nominal_base_parameters()
    prepared = prepare_motion(record, cutoff_hz)
    w = base_regressor(base, prepared.q, prepared.qd, prepared.qdd)
    tau = _remove_sampling_term(prepared.tau, prepared.qdd, torque_acceleration_bias)
    dt = prepared.how["sample_time_s"]
    if prepared.how["derivatives"] != "given in the record":
        n = w.shape[0]
        w = zero_phase_lowpass(w.reshape(n, -1), dt, cutoff_hz).reshape(w.shape)
        tau = zero_phase_lowpass(tau, dt, cutoff_hz)
    stride = 1
    if max_samples is not None and w.shape[0] > max_samples:
        stride = max(1, min(int(math.ceil(w.shape[0] / max_samples)), int(1.0 / (4.0 * cutoff_hz * dt))))
    data = {"source": record.source, "record_samples": record.samples, "duration_s": record.duration,
            **prepared.how, "decimation": stride}
    if torque_acceleration_bias is not None:
        data["torque_acceleration_bias_Nm_per_rad_s2"] = np.asarray(torque_acceleration_bias, dtype=float).tolist()
    filtered = prepared.how["derivatives"] != "given in the record"
    return identify_regressor(w[::stride], tau[::stride], base=base, method=method, max_condition=max_condition,
                              data=data, independent_samples=2.0 * cutoff_hz * record.duration if filtered else None,
                              consistent=consistent)


def prepare_periodic(q: ArrayLike, tau: ArrayLike, sample_time: float, samples_per_period: int, *,
                     skip_periods: int = 1, periods: int | None = None,
                     cutoff_hz: float = DEFAULT_CUTOFF_HZ) -> PreparedMotion:
    """One averaged period of a record that repeats a periodic trajectory.

    ``q``, ``tau`` (n, 6) sampled every ``sample_time`` s from the start of a period;
    ``skip_periods`` whole periods are dropped (start-up transients), the next
    ``periods`` (default: all complete ones) are averaged; ``qd``, ``qdd`` are the exact
    derivatives of the averaged ``q``'s Fourier series up to ``cutoff_hz``; ``tau`` is the
    plain average (parallel filtering follows in :func:`identify_periodic`). ``how``
    holds the per-joint RMS standard deviation of q and tau across periods (measurement
    noise plus any non-repeatability).
    """
    q_mean, q_std = average_periods(q, samples_per_period, periods, skip_periods)
    tau_mean, tau_std = average_periods(tau, samples_per_period, periods, skip_periods)
    used = periods if periods is not None else np.shape(q)[0] // samples_per_period - skip_periods
    qf, qd, qdd = periodic_derivatives(q_mean, sample_time, cutoff_hz)
    t = np.arange(samples_per_period) * sample_time
    how = {"derivatives": f"Fourier series of the averaged period up to {cutoff_hz:g} Hz (exact derivatives of "
                          "the band-limited periodic signal)",
           "filter": f"periodic average; harmonics above {cutoff_hz:g} Hz dropped from q, and from tau and every "
                     "regressor column alike (parallel filtering)",
           "sample_time_s": sample_time, "cutoff_hz": cutoff_hz, "samples_per_period": samples_per_period,
           "periods_averaged": int(used), "periods_skipped": int(skip_periods),
           "q_std_across_periods_rad": np.sqrt(np.mean(q_std**2, axis=0)).tolist(),
           "tau_std_across_periods_Nm": np.sqrt(np.mean(tau_std**2, axis=0)).tolist()}
    return PreparedMotion(t, qf, qd, qdd, tau_mean, how)


def identify_periodic(q: ArrayLike, tau: ArrayLike, sample_time: float, samples_per_period: int, *,
                      skip_periods: int = 1, periods: int | None = None, cutoff_hz: float = DEFAULT_CUTOFF_HZ,
                      base: BaseParameters | None = None, method: str = "wls",
                      max_condition: float = MAX_CONDITION_NUMBER, max_samples: int | None = DEFAULT_MAX_SAMPLES,
                      consistent: bool = False,
                      torque_acceleration_bias: ArrayLike | None = None) -> DynamicIdentification:
    """Identify from a record of a repeated periodic trajectory (:func:`prepare_periodic`,
    then the same harmonics dropped from tau and the regressor, then least squares).

    ``torque_acceleration_bias``: (6,) N m per rad/s^2, a known measurement term ``b_i qdd_i``
    in joint i's torque besides the rigid-body torque (a drive that samples its torque in step
    with its speed loop reports ``b_i qdd_i`` too, ``b_i < 0``; see docs/explanation/identification.md). It
    is subtracted from the averaged torque, with qdd the Fourier derivative: the term is exactly
    collinear with the rotor-inertia column of joint i, so no excitation can separate it and,
    uncorrected, it is identified as rotor inertia ``Ia_i + b_i``.
    """
    base = base or nominal_base_parameters()
    prepared = prepare_periodic(q, tau, sample_time, samples_per_period, skip_periods=skip_periods,
                                periods=periods, cutoff_hz=cutoff_hz)
    w = base_regressor(base, prepared.q, prepared.qd, prepared.qdd)
    n = w.shape[0]
    w = periodic_lowpass(w.reshape(n, -1), sample_time, cutoff_hz).reshape(w.shape)
    tau_avg = prepared.tau
    how = dict(prepared.how)
    if torque_acceleration_bias is not None:
        tau_avg = _remove_sampling_term(tau_avg, prepared.qdd, torque_acceleration_bias)
        how["torque_acceleration_bias_Nm_per_rad_s2"] = np.asarray(torque_acceleration_bias, dtype=float).tolist()
    tau_f = periodic_lowpass(tau_avg, sample_time, cutoff_hz)
    stride = 1
    if max_samples is not None and n > max_samples:
        stride = max(1, min(int(math.ceil(n / max_samples)), int(1.0 / (4.0 * cutoff_hz * sample_time))))
    # band-limited to cutoff_hz over one period T: about 2 cutoff T independent values per joint
    return identify_regressor(w[::stride], tau_f[::stride], base=base, method=method, max_condition=max_condition,
                              data=dict(how, decimation=stride),
                              independent_samples=2.0 * cutoff_hz * n * sample_time, consistent=consistent)


@dataclass(frozen=True)
class Validation:
    """Predicted versus measured torques along a record.

    ``tau_measured`` as recorded and ``tau_predicted`` by the identified model from the
    prepared states, both (n, 6) N m at the record's samples; ``relative_rms_error``
    (6,) = RMS(pred - meas) / RMS(meas) per joint after the same zero-phase low-pass on
    both (parallel filtering, what a model of the rigid body can explain);
    ``relative_rms_error_unfiltered`` without it.
    """

    t: np.ndarray
    tau_measured: np.ndarray
    tau_predicted: np.ndarray
    relative_rms_error: np.ndarray
    relative_rms_error_unfiltered: np.ndarray
    rms_error_filtered: np.ndarray
    how: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        return {"relative_rms_error": self.relative_rms_error.tolist(),
                "relative_rms_error_unfiltered": self.relative_rms_error_unfiltered.tolist(),
                "rms_error_Nm": self.rms_error_filtered.tolist(),
                "rms_measured_Nm": np.sqrt(np.mean(self.tau_measured**2, axis=0)).tolist(),
                "max_relative_rms_error": float(np.max(self.relative_rms_error)),
                "definition": "per joint RMS(predicted - measured) / RMS(measured), both through the same "
                              f"zero-phase low-pass at {self.how['cutoff_hz']:g} Hz (the _unfiltered values "
                              "without it)",
                "samples": int(self.t.size), "processing": self.how}


def _remove_sampling_term(tau: np.ndarray, qdd: np.ndarray, bias: ArrayLike | None) -> np.ndarray:
    """``tau - b qdd`` (the drives' torque-sampling term), or ``tau`` without a bias."""
    if bias is None:
        return tau
    b = np.asarray(bias, dtype=float)
    if b.shape != (tau.shape[1],) or not np.all(np.isfinite(b)):
        raise IdentificationDataError(f"torque_acceleration_bias: expected {tau.shape[1]} finite values "
                                      f"in N m per rad/s^2, got {np.ravel(b).tolist()!r}")
    return tau - b * qdd


def validate(identification: DynamicIdentification, record: MotionRecord,
             cutoff_hz: float = DEFAULT_CUTOFF_HZ, torque_acceleration_bias: ArrayLike | None = None) -> Validation:
    """Predict the torques of ``record`` with the identified model and compare (all samples).

    ``torque_acceleration_bias``: the drives' torque-sampling term is removed from the measured
    torque first (as in the identification); the validation's ``tau`` is then that corrected torque."""
    if record.samples > MAX_PROCESSED_SAMPLES:
        raise IdentificationDataError(f"{record.source}: {record.samples} samples, expected at most "
                                      f"{MAX_PROCESSED_SAMPLES} for a validation record (predictions are written "
                                      "for every sample; split or decimate it)")
    prepared = prepare_motion(record, cutoff_hz)
    predicted = identification.predict(prepared.q, prepared.qd, prepared.qdd)
    dt = prepared.how["sample_time_s"]
    tau = _remove_sampling_term(np.asarray(record.tau, dtype=float), prepared.qdd, torque_acceleration_bias)
    measured_f = zero_phase_lowpass(tau, dt, cutoff_hz)
    predicted_f = zero_phase_lowpass(predicted, dt, cutoff_hz)
    return Validation(record.t, tau, predicted, relative_rms_error(measured_f, predicted_f),
                      relative_rms_error(tau, predicted),
                      np.sqrt(np.mean((predicted_f - measured_f) ** 2, axis=0)),
                      {"source": record.source, **prepared.how})


def write_identification_outputs(out_dir: str | Path, identification: DynamicIdentification,
                                 validation: Validation | None = None,
                                 extra_summary: dict[str, Any] | None = None) -> dict[str, Path]:
    """Write ``parameters.json`` and, with a validation, ``prediction.csv`` and ``summary.json``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"parameters": out / "parameters.json"}
    _write_json(paths["parameters"], identification.to_dict())
    if validation is not None:
        paths["prediction"] = write_prediction_csv(out / "prediction.csv", validation.t, validation.tau_predicted)
        paths["summary"] = out / "summary.json"
        summary = {"status": "ok", "method": identification.estimate.method,
                   "base_parameters": identification.base.count,
                   "condition_number": identification.estimate.condition_number,
                   "identification_samples": identification.estimate.samples,
                   **validation.to_dict(), **(extra_summary or {})}
        _write_json(paths["summary"], summary)
    return paths


def _write_json(path: Path, content: dict[str, Any]) -> None:
    path.write_text(json.dumps(content, indent=2, allow_nan=False, default=_json_default) + "\n")


def _json_default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
