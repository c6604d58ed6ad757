"""The dynamic identification campaign (paper section 4) as pure steps, the experiment passed in.

    design  ->  run the experiment  ->  estimate  ->  report

* :func:`design`: the optimal exciting Fourier trajectory (eq. 29-30) for the controller's model,
  ``omega_f`` snapped so that one period is a whole number of samples (periodic averaging needs it);
* the **experiment** is whatever runs the trajectory and measures: a callable ``experiment(trajectory,
  duration_s) -> ExperimentData`` (:class:`Experiment`). The co-simulation job passes one that runs the
  robot cell (``cosim/jobs/identification.py``); a user passes one that drives a real cell or replays
  a log. Nothing here knows a cell, a fieldbus or an FMU;
* :func:`estimate`: periodic averaging, Fourier derivatives, parallel filtering, (weighted) least
  squares on the base parameters, optionally the physically consistent fit
  (:func:`identification.identify.identify_periodic`), the drives' torque-sampling term
  removed when the experiment reports it;
* :func:`estimate_stiffness`: with tracker readings in the data (an elastic arm), the gear stiffness
  and damping of every axis (:func:`identification.gear_stiffness.identify_gear_stiffness_periodic`);
* :func:`report`: every identified parameter against a known truth (simulation studies): base
  parameters, rotor inertias, gear stiffness and damping.

:func:`run_campaign` chains them.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol

import numpy as np
from numpy.typing import ArrayLike

ROTOR_TERMS = {"Izz1R": "Ia1", "Iyy2R": "Ia2", "Ia3": "Ia3", "Ia4": "Ia4", "Ia5": "Ia5", "Ia6": "Ia6"}
"""The base parameters that hold the rotor inertias (Ia1 and Ia2 are regrouped with link inertias
about the same axis: only the sums are identifiable; Ia3-Ia6 are base parameters alone)."""

WITHIN_PERCENT = 10.0
"""The acceptance band for the identified gear stiffness and rotor inertias, % of the true value
(docs/explanation/identification.md)."""


# ------------------------------------------------------------------------------------------ settings
@dataclass(frozen=True)
class CampaignSettings:
    """Everything the steps need besides the experiment (units: s, rad, rad/s, Hz, m)."""

    sample_time: float = 400e-6
    order: int = 5
    omega_f: float = 0.8
    samples: int = 80
    constraint_samples: int = 160
    max_iterations: int = 300
    random_baselines: int = 10
    seed: int = 0
    periods: int = 5
    skip_periods: int = 1
    torque_fraction: float = 0.8
    position_margin: float = math.radians(5.0)
    tcp_box_min: tuple[float, float, float] = (0.3, -1.2, 0.3)
    tcp_box_max: tuple[float, float, float] = (1.8, 1.2, 2.0)
    centre: tuple[float, ...] = (0.0, 0.4, 1.2, 0.0, 0.6, 0.0)
    cutoff_hz: float = 20.0
    method: str = "wls"
    consistent: bool = True
    reflector: tuple[float, float, float] = (0.0, 0.0, 0.0)
    stiffness_decimate: int = 2
    stiffness_max_relative_std: float = 0.15

    @classmethod
    def from_tables(cls, sample_time: float, excitation: dict[str, Any], measurement: dict[str, Any],
                    stiffness: dict[str, Any] | None = None) -> "CampaignSettings":
        """From the scenario's ``[excitation]``, ``[measurement]`` and ``[stiffness]`` tables."""
        e, m, s = excitation, measurement, stiffness or {}
        return cls(sample_time=sample_time, order=e["order"], omega_f=e["omega_f"], samples=e["samples"],
                   constraint_samples=e["constraint_samples"], max_iterations=e["max_iterations"],
                   random_baselines=e["random_baselines"], seed=e["seed"], periods=e["periods"],
                   skip_periods=e["skip_periods"], torque_fraction=e["torque_fraction"],
                   position_margin=e["position_margin"], tcp_box_min=tuple(e["tcp_box_min"]),
                   tcp_box_max=tuple(e["tcp_box_max"]), centre=tuple(e["centre"]), cutoff_hz=m["cutoff"],
                   method=m["method"], consistent=m["consistent"],
                   reflector=tuple(s.get("reflector", (0.0, 0.0, 0.0))),
                   stiffness_decimate=s.get("decimate", 2),
                   stiffness_max_relative_std=s.get("max_relative_std", 0.15))


@dataclass(frozen=True)
class TrackerRecord:
    """Laser-tracker readings of a reflector on the tool: times (m,) s from the motion start,
    positions (m, 3) m in the robot base frame, the reflector's place (m in the flange frame)."""

    t: np.ndarray
    positions: np.ndarray
    reflector: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass
class ExperimentData:
    """What an experiment measured while the trajectory ran, from its start:
    ``q`` (n, 6) rad motor-side joint positions (encoder / gear ratio) and ``tau`` (n, 6) N m
    joint-side drive torques, both every ``sample_time`` s and belonging to the same instants;
    optionally the tracker's readings (needed for the gear stiffness), the drives' torque-sampling
    term b (N m per rad/s^2, removed before estimating; ``sampling`` says where it comes from), and
    anything the experiment wants in the summary (``info``)."""

    q: np.ndarray
    tau: np.ndarray
    sample_time: float
    tracker: TrackerRecord | None = None
    torque_acceleration_bias: np.ndarray | None = None
    sampling: dict[str, Any] | None = None
    info: dict[str, Any] = field(default_factory=dict)


class Experiment(Protocol):
    """Runs ``trajectory`` (a :class:`identification.fourier.FourierTrajectory`, repeated
    for ``duration_s``) on a robot and returns what was measured."""

    def __call__(self, trajectory: Any, duration_s: float) -> ExperimentData: ...


@dataclass(frozen=True)
class Truth:
    """The true robot of a simulation study: the 78 standard parameters with the payload folded
    into link 6 (``robot.dynamics.RobotDynamics.parameter_vector(include_payload=True)``), the
    gear stiffness (N m/rad) and damping (N m s/rad) per axis (None: rigid)."""

    parameters: np.ndarray
    gear_stiffness: np.ndarray | None = None
    gear_damping: np.ndarray | None = None


@dataclass
class CampaignResult:
    """The steps' outputs: the excitation design, the measured data, the identification, the
    stiffness estimate (None without tracker data) and the report (dict, JSON-ready)."""

    excitation: Any
    samples_per_period: int
    data: ExperimentData
    identification: Any
    stiffness: Any
    report: dict[str, Any]


# ------------------------------------------------------------------------------------------ steps
def snapped_omega(omega_f: float, period_s: float) -> tuple[float, int]:
    """(omega_f, samples per period) with the period a whole number of ``period_s`` samples."""
    n = int(round(2.0 * math.pi / omega_f / period_s))
    return 2.0 * math.pi / (n * period_s), n


def design(settings: CampaignSettings, payload: ArrayLike = (0.0, 0.0, 0.0, 0.0)):
    """The optimal exciting trajectory for the controller's model (``payload``: what it knows of
    the load), with ``omega_f`` snapped to the sample time; returns (ExcitationResult, samples per
    period)."""
    from identification.excitation import (ExcitationLimits, ExcitationProblem, ExcitationSettings,
                                                   design_excitation)

    s = settings
    omega_f, per_period = snapped_omega(s.omega_f, s.sample_time)
    limits = ExcitationLimits.from_parameters(position_margin=s.position_margin, torque_fraction=s.torque_fraction,
                                              tcp_box=(list(s.tcp_box_min), list(s.tcp_box_max)))
    excitation = ExcitationSettings(order=s.order, omega_f=omega_f, samples=s.samples,
                                    constraint_samples=s.constraint_samples, max_iterations=s.max_iterations)
    problem = ExcitationProblem(limits=limits, settings=excitation, payload=np.asarray(payload, dtype=float))
    result = design_excitation(problem, seed=s.seed, random_baselines=s.random_baselines, centre=list(s.centre))
    return result, per_period


def estimate(data: ExperimentData, settings: CampaignSettings, samples_per_period: int, kinematic_model=None):
    """The base parameters from the averaged periods (see module docstring); ``kinematic_model``:
    the arm's calibrated kinematics (a pinocchio model) for the regressor, None: the nominal arm."""
    from identification.base_parameters import nominal_base_parameters, regrouped_on
    from identification.identify import identify_periodic
    from robot.dynamics import RobotDynamics

    if abs(data.sample_time - settings.sample_time) > 1e-12:
        raise ValueError(f"the experiment sampled every {data.sample_time} s, the design every "
                         f"{settings.sample_time} s")
    # the nominal arm's grouping (names, which columns) with the calibrated geometry's regressor and
    # regrouping coefficients: a base set computed afresh on the calibrated geometry would split groups
    # whose columns differ only by the mm-level geometric errors (Ia2 from Iyy2R: cond 2e4)
    base = None if kinematic_model is None else regrouped_on(nominal_base_parameters(),
                                                             RobotDynamics(model=kinematic_model))
    return identify_periodic(data.q, data.tau, data.sample_time, samples_per_period, base=base,
                             skip_periods=settings.skip_periods, cutoff_hz=settings.cutoff_hz,
                             method=settings.method, consistent=settings.consistent,
                             torque_acceleration_bias=data.torque_acceleration_bias)


def estimate_stiffness(identification, data: ExperimentData, settings: CampaignSettings, samples_per_period: int,
                       kinematic_model, rotor_inertia: ArrayLike, motor_friction_share: ArrayLike):
    """Gear stiffness and damping per axis from the averaged periods of the motor positions and
    of the tracker's readings (``data.tracker``, sampled at a constant rate that divides the
    period), gear torques from ``identification``'s base parameters. ``kinematic_model``: the
    arm's (calibrated) kinematics; ``rotor_inertia`` (kg m^2, joint side): the catalogue values
    for the rotors regrouped with link inertias; ``motor_friction_share``: the motor side's
    share of the friction (1)."""
    from identification.signals import average_periods
    from identification.gear_stiffness import identify_gear_stiffness_periodic

    tracker = data.tracker
    if tracker is None:
        raise ValueError("the experiment returned no tracker readings: the gear stiffness needs them")
    t = np.asarray(tracker.t, dtype=float)
    if t.size < 3:
        raise ValueError(f"{t.size} tracker readings: too few for the gear stiffness")
    dt = float(np.median(np.diff(t)))
    period = samples_per_period * data.sample_time
    per_period = period / dt
    if abs(per_period - round(per_period)) > 1e-6:
        raise ValueError(f"the excitation period {period} s is not a whole number of tracker samples "
                         f"({dt} s): the tracker's readings cannot be averaged over periods")
    m = int(round(per_period))
    averaged = settings.periods - settings.skip_periods
    start = settings.skip_periods * period
    first = int(np.searchsorted(t, start - 1e-9))
    readings = np.asarray(tracker.positions, dtype=float)[first:first + averaged * m]
    if readings.shape[0] < averaged * m:
        raise ValueError(f"{readings.shape[0]} tracker readings after the skipped period(s), "
                         f"expected {averaged * m}")
    tracker_mean, _ = average_periods(readings, m, averaged)
    motor_mean, _ = average_periods(data.q, samples_per_period, averaged, settings.skip_periods)
    return identify_gear_stiffness_periodic(
        identification.base, identification.values, motor_mean, data.sample_time, tracker_mean, dt,
        float(t[first] - start), kinematic_model, rotor_inertia=rotor_inertia,
        motor_friction_share=motor_friction_share, cutoff_hz=settings.cutoff_hz, reflector=tracker.reflector,
        decimate=settings.stiffness_decimate, max_relative_std=settings.stiffness_max_relative_std)


def parameter_error_table(names, definitions, values, std, true_base, bias=None) -> dict[str, Any]:
    """Every identified base parameter against the true robot, and the rotor inertias.

    ``bias``: the torque-sampling term removed before identifying (N m per rad/s^2 per joint)
    or None; each rotor-inertia row also gives the value the identification would report
    without the correction (identified + b_i: the term is collinear with that column alone).
    """
    values, std, true_base = (np.asarray(v, dtype=float) for v in (values, std, true_base))
    error = values - true_base
    rel = 100.0 * error / np.maximum(np.abs(true_base), 1e-12)
    table = [{"name": n, "definition": d, "identified": float(v), "true": float(t), "error_percent": float(r),
              "error_in_std": float(e / s) if s > 0 else None}
             for n, d, v, t, r, e, s in zip(names, definitions, values, true_base, rel, error, std)]
    rotors: dict[str, Any] = {}
    index = {n: i for i, n in enumerate(names)}
    for name, rotor in ROTOR_TERMS.items():
        if name not in index:
            continue
        i = index[name]
        row = {"base_parameter": name, "definition": definitions[i], "identified": float(values[i]),
               "true": float(true_base[i]), "error_percent": float(rel[i])}
        if bias is not None:
            joint = int(rotor[-1]) - 1
            apparent = float(values[i] + bias[joint])
            row.update(uncorrected=apparent, uncorrected_error_percent=float(100.0 * (apparent - true_base[i])
                                                                             / abs(true_base[i])))
        rotors[rotor] = row
    return {"parameter_errors": table,
            "max_abs_relative_error_percent": float(np.max(np.abs(rel))),
            "rotor_inertias": rotors,
            "rotor_inertias_within_10_percent": bool(all(abs(r["error_percent"]) <= WITHIN_PERCENT
                                                         for r in rotors.values()))}


def report(identification, stiffness=None, truth: Truth | None = None, bias: ArrayLike | None = None,
           nominal_stiffness: ArrayLike | None = None) -> dict[str, Any]:
    """The campaign's summary: the identification's figures and, with a ``truth``, the error of
    every identified parameter (base parameters, rotor inertias, gear stiffness and damping)."""
    ident = identification
    est = ident.estimate
    out: dict[str, Any] = {"base_parameters": ident.base.count, "method": est.method,
                           "condition_number_measured": est.condition_number,
                           "joint_noise_sigma_Nm": est.joint_sigma.tolist(), "processing": ident.data}
    true_base = None
    if truth is not None:
        true_base = ident.base.base_values(np.asarray(truth.parameters, dtype=float))
        rel_err = np.abs(ident.values - true_base) / np.maximum(np.abs(true_base), 1e-12)
        out.update(within_3_std_of_true=int(np.sum(np.abs(ident.values - true_base) <= 3 * est.std)),
                   median_relative_error_vs_true=float(np.median(rel_err)))
        out.update(parameter_error_table(ident.base.base_names, ident.base.definitions(), ident.values, est.std,
                                         true_base, None if bias is None else np.asarray(bias, dtype=float)))
    if ident.consistent is not None:
        c = ident.consistent
        out["physically_consistent_fit"] = {"physically_consistent": c.consistent, "misfit_in_noise_units": c.misfit,
                                            "evaluations": c.nfev}
        if true_base is not None:
            out["physically_consistent_fit"]["median_relative_error_vs_true"] = float(np.median(
                np.abs(c.base_values - true_base) / np.maximum(np.abs(true_base), 1e-12)))
    if stiffness is not None:
        gears = stiffness.to_dict(None if truth is None else truth.gear_stiffness,
                                  None if truth is None else truth.gear_damping)
        if truth is not None and truth.gear_stiffness is not None:
            errors = gears["stiffness_error_percent"]
            gears["within_10_percent"] = bool(all(e is not None and abs(e) <= WITHIN_PERCENT for e in errors))
            if nominal_stiffness is not None:
                gears["nominal_stiffness_error_percent"] = (
                    100.0 * (np.asarray(nominal_stiffness) / np.asarray(truth.gear_stiffness) - 1.0)).tolist()
            out["stiffness_within_10_percent"] = gears["within_10_percent"]
        out["gear_stiffness"] = gears
    return out


def run_campaign(settings: CampaignSettings, experiment: Experiment, *, payload: ArrayLike = (0.0, 0.0, 0.0, 0.0),
                 truth: Truth | None = None, kinematic_model=None, stiffness_model: dict[str, Any] | None = None,
                 on_step: Callable[[str, dict[str, Any]], None] | None = None) -> CampaignResult:
    """design -> experiment -> estimate (-> stiffness when the data hold tracker readings and
    ``stiffness_model`` gives ``rotor_inertia``, ``motor_friction_share`` and optionally
    ``nominal_stiffness``) -> report. ``kinematic_model``: the arm's calibrated kinematics for the
    regressor and the tracker model (None: the nominal arm). ``on_step(name, fields)`` is called
    after each step (progress, partial results)."""
    note = on_step or (lambda name, fields: None)
    wall = time.perf_counter()
    excitation, per_period = design(settings, payload)
    note("designed", {"excitation": excitation, "samples_per_period": per_period,
                      "design_wall_time_s": time.perf_counter() - wall})
    data = experiment(excitation.trajectory, settings.periods * excitation.trajectory.period)
    note("measured", {"data": data})
    wall = time.perf_counter()
    ident = estimate(data, settings, per_period, kinematic_model)
    ident_wall = time.perf_counter() - wall
    stiffness = None
    if data.tracker is not None and stiffness_model is not None:
        wall = time.perf_counter()
        if kinematic_model is None:
            from robot.description import load_model

            kinematic_model = load_model()
        model = {k: v for k, v in stiffness_model.items() if k != "nominal_stiffness"}
        stiffness = estimate_stiffness(ident, data, settings, per_period, kinematic_model, **model)
        stiffness_wall = time.perf_counter() - wall
    rep = report(ident, stiffness, truth, data.torque_acceleration_bias,
                 None if stiffness_model is None else stiffness_model.get("nominal_stiffness"))
    rep["wall_time_s"] = ident_wall
    if stiffness is not None:
        rep["gear_stiffness"]["wall_time_s"] = stiffness_wall
    rep["torque_sampling_correction"] = data.sampling if data.sampling is not None else "off"
    note("estimated", {"report": rep})
    return CampaignResult(excitation, per_period, data, ident, stiffness, rep)
