"""Job ``identification``: the paper's section 4 campaign, closed through the co-simulation.

The workflow (design the excitation -> run the experiment -> estimate -> report) lives in
:mod:`identification.campaign` as pure steps; this job passes it the cell-specific part,
the **experiment** (:func:`_cell_experiment`), and adds what only a simulated cell can do:

* **Excite on the cell**: the trajectory, repeated ``[excitation] periods`` times, runs closed
  loop on the robot cell (:mod:`cosim.cell`: controller -> POWERLINK-timed CiA 402 fieldbus ->
  servo-drive FMUs <-> plant FMU set to the seeded TRUE robot, whose inertias, friction, rotor
  inertias, payload and - on the elastic plant - gear stiffness the controller does not know).
  The data are what a user gets: the drives' ``position_actual`` (0x6064, encoder counts) and
  ``torque_actual`` (0x6077, 0.1 % of rated torque) as the fieldbus delivers them to the
  controller every 400 us (:class:`FieldbusRecorder`), plus an optional Gaussian
  current-measurement noise; the drives' torque-sampling term measured on the drive FMU
  (:mod:`cosim.jobs.identification_torque_sampling`); on the elastic plant
  (``elastic_joints = 1``) the laser tracker's readings of a reflector on the tool
  (``[stiffness] reflector``), from which the campaign identifies the gear stiffness and damping.
* **Judge against the truth**: every identified parameter against the true robot (the report).
* **Validate** on the EN ISO 9283 path (the main job's path, run with the nominal model's
  feed-forward): measured versus predicted torque per joint (Figure 5(b)), relative RMS error
  per joint for the identified, nominal and true models.
* **Use**: the ISO 9283 path runs in model-based mode with the identified model, and with the
  true parameters; the TCP errors of the three models are compared.

Results: ``summary.json``; ``excitation.json`` (trajectory, condition numbers, solve
time, feasibility); ``parameters.json`` (identified base parameters, definitions, std,
true values; gear stiffness on the elastic plant); ``identification_record.csv`` and
``validation_record.csv`` (what was measured, in the ``python -m cosim identify`` format);
``validation_torques.csv``; per ISO run ``timeseries_<model>``, ``controller_<model>``,
``tcp_<model>``; figures ``figure5a_excitation_path.png``, ``figure5b_torques.png``,
``figure_parameter_errors.png``.
"""
from __future__ import annotations

import dataclasses
import json
import math
from typing import Any

import numpy as np

from controller import Controller, ControllerConfig, JointTrajectory, TcpTrajectory
from cosim.cell import wiring
from cosim.cell.checks import check_cell, fill_defaults
from cosim.cell.description import describe_cell
from cosim.cell.evaluation import evaluate_run
from cosim.cell.parts import (CAN_LOG_FORMAT_FIELD, CONTROLLER_CONFIG_FIELDS, TRACKER_TABLE, TRUE_ROBOT_TABLE,
                              can_log_path, make_true_robot, tracker_config)
from cosim.cell.info import controller_info
from cosim.execution import run_cell
from cosim.scenario.context import RunContext
from cosim.scenario.cosim_tables import COSIM_FIELDS
from cosim.scenario.loader import SCENARIO_FIELD, Scenario
from cosim.scenario.job_type import JobType
from cosim.scenario.schema import AnyValue, Boolean, Field, Integer, List, Number, String, Table, Where

JOB_NAME = "identification"
MODEL_LABELS = ("nominal", "identified", "true")

EXCITATION_TABLE = Table({
    "order": Field(Integer(min=1, max=20), default=5, doc="the Fourier order N of eq. 29 (paper: 5)"),
    "omega_f": Field(Number(unit="rad/s", gt=0), default=0.8, doc="the base frequency in rad/s (paper: 0.8)"),
    "samples": Field(Integer(min=10), default=80, doc="samples per period k of the objective (paper: 80)"),
    "constraint_samples": Field(Integer(min=10), default=160, doc="samples per period of the constraints"),
    "max_iterations": Field(Integer(min=1), default=300, doc="SLSQP iterations at most"),
    "random_baselines": Field(Integer(min=1), default=10, doc="random feasible series to compare with"),
    "seed": Field(Integer(min=0), default=0, doc="seed of the random series (the best one starts SLSQP)"),
    "periods": Field(Integer(min=2), default=5, doc="periods run on the cell (the first is skipped)"),
    "skip_periods": Field(Integer(min=0), default=1, doc="periods dropped before averaging"),
    "torque_fraction": Field(Number(gt=0, max=1), default=0.8,
                             doc="fraction of the URDF effort the model torque may use"),
    "position_margin": Field(Number(unit="rad", min=0), default=math.radians(5.0),
                             doc="margin inside the joint position limits"),
    "tcp_box_min": Field(List(Number(unit="m"), length=3), default=[0.3, -1.2, 0.3],
                         doc="lower corner of the allowed flange box in base_link"),
    "tcp_box_max": Field(List(Number(unit="m"), length=3), default=[1.8, 1.2, 2.0],
                         doc="upper corner of the allowed flange box in base_link"),
    "centre": Field(List(Number(unit="rad"), length=6), default=[0.0, 0.4, 1.2, 0.0, 0.6, 0.0],
                    doc="centre pose of the random series (offsets q_i0), rad"),
}, doc="the [excitation] table")

MEASUREMENT_TABLE = Table({
    "cutoff": Field(Number(unit="Hz", gt=0), default=20.0, doc="low-pass cut-off for differentiating q"),
    "torque_noise_percent_rated": Field(Number(min=0, max=10), default=0.1,
                                        doc="added Gaussian current-measurement noise, sigma in % of rated torque"),
    "noise_seed": Field(Integer(min=0), default=0, doc="seed of the added torque measurement noise"),
    "method": Field(String(choices=("wls", "ols")), default="wls",
                     doc="least squares of the base parameters: 'wls' (weighted by each axis' noise) or 'ols'"),
    "position_lag_cycles": Field(Integer(min=0, max=10), default=0,
                                 doc="cycles by which position actual lags torque actual (0: the drives latch "
                                     "both at the SoC, as the servo_drive FMU does; 1: a drive that reports "
                                     "the previous cycle's position)"),
    "consistent": Field(Boolean(), default=True,
                        doc="also fit a physically consistent parameter vector and validate it"),
    "kinematics": Field(String(choices=("calibrated", "nominal")), default="calibrated",
                        doc="the arm's geometry in the regressor (and the stiffness fit): 'calibrated' = the true "
                            "robot's (a perfectly calibrated arm, as after the calibration campaign), 'nominal' = "
                            "the URDF's (the plant's true geometry then biases the base parameters)"),
    "torque_sampling_correction": Field(Boolean(), default=True,
                                        doc="remove the drives' torque-actual sampling term b_i qdd_i (measured on "
                                            "the drive FMU, cosim/jobs/identification_torque_sampling.py) before "
                                            "identifying; false: the rotor inertias come out as Ia_i + b_i"),
}, doc="the [measurement] table")

CONTROLLER_TABLE = Table({
    "period": CONTROLLER_CONFIG_FIELDS["period"],
    "excitation_mode": Field(String(choices=("standard", "model_based")), default="model_based",
                             doc="controller mode while the exciting trajectory runs (nominal model)"),
    "payload_known": Field(Boolean(), default=False,
                           doc="true: the nominal model includes the [true_robot] payload"),
    "drive_compensation": CONTROLLER_CONFIG_FIELDS["drive_compensation"],
    "compute_budget": CONTROLLER_CONFIG_FIELDS["compute_budget"],
    "settle_time": CONTROLLER_CONFIG_FIELDS["settle_time"],
    "compare_models": Field(List(String(choices=MODEL_LABELS), min_len=1, unique=True), default=list(MODEL_LABELS),
                            doc="feed-forward models run on the ISO 9283 path"),
    "iso_mode": Field(String(choices=("model_based", "model_based_elastic")), default="model_based",
                      doc="controller mode of the ISO 9283 runs: the rigid eq. 7 feed-forward, or (elastic plant) "
                          "the flatness-based feed-forward for elastic gears with each model's gear stiffness "
                          "(nominal: the catalogue's, identified: the campaign's, true: the plant's)"),
}, doc="the [controller] table")

STIFFNESS_TABLE = Table({
    "reflector": Field(List(Number(unit="m"), length=3), default=[0.10, 0.05, 0.08],
                       doc="where the laser tracker's reflector sits on the tool during the excitation run, m in "
                           "tool0 (off the axis of joint 6, so that its gear's twist is seen); elastic plant only"),
    "decimate": Field(Integer(min=1), default=2, doc="every n-th tracker sample enters the stiffness fit"),
    "max_relative_std": Field(Number(gt=0), default=0.15,
                              doc="an axis whose compliance has a larger relative standard error is reported "
                                  "as not identifiable"),
}, doc="the [stiffness] table (gear stiffness and damping; used when the plant has elastic_joints = 1)")

PATH_TABLE = Table({
    "speed": Field(Number(unit="m/s", gt=0, max=2.0), default=1.0, doc="TCP speed along the ISO 9283 path"),
    "acceleration": Field(Number(unit="m/s^2", gt=0, max=20.0), default=5.0,
                          doc="TCP acceleration along the ISO 9283 path"),
}, doc="the [path] table")

RESULTS_TABLE = Table({
    "can_log": Field(Boolean(), default=False, doc="write can_<run>.parquet (or .blf) for every run"),
    "can_log_format": CAN_LOG_FORMAT_FIELD,
    "figures": Field(Boolean(), default=True, doc="draw the figures (PNG) of the campaign"),
    "records": Field(Boolean(), default=True, doc="write the measured records as CSV"),
    "report": Field(Boolean(), default=True, doc="write report.html, the interactive view of the run (docs/how-to/view_results.md)"),
}, doc="the [results] table")

SCHEMA = Table({
    "scenario": SCENARIO_FIELD,
    **COSIM_FIELDS,
    "true_robot": Field(TRUE_ROBOT_TABLE, default={},
                        doc="the simulated robot whose parameters are identified"),
    "controller": Field(CONTROLLER_TABLE, default={},
                        doc="the controller during the excitation run and the ISO 9283 validation runs"),
    "excitation": Field(EXCITATION_TABLE, default={}, doc="the optimal exciting trajectory"),
    "measurement": Field(MEASUREMENT_TABLE, default={},
                         doc="how the drives' records are measured, filtered and fitted"),
    "stiffness": Field(STIFFNESS_TABLE, default={}),
    "path": Field(PATH_TABLE, default={}, doc="the ISO 9283 validation path's speed and acceleration"),
    "tracker": Field(TRACKER_TABLE, default={}, doc="the laser tracker measuring the TCP: sample period, noise"),
    "fieldbus": Field(Table({}, extra=AnyValue(), doc="a [fieldbus] table (fieldbus/powerlink_defaults.toml keys)"),
                      default={}),
    "results": Field(RESULTS_TABLE, default={}, doc="which result files the campaign writes"),
}, doc="an identification scenario document")

_TABLES = ("true_robot", "controller", "excitation", "measurement", "stiffness", "path", "tracker", "results")


def _fill_table_defaults(doc: dict[str, Any]) -> None:
    fill_defaults(doc, SCHEMA, _TABLES)


def check(doc: dict[str, Any], where: Where) -> None:
    """The cell (:func:`cosim.cell.checks.check_cell`), the excitation and measurement settings."""
    _fill_table_defaults(doc)
    check_cell(doc, where)
    ctrl = doc["controller"]
    exc_t = doc["excitation"]
    if exc_t["skip_periods"] >= exc_t["periods"]:
        raise (where / "excitation" / "skip_periods").error(
            f"fewer than [excitation] periods = {exc_t['periods']} (at least one period must be averaged)",
            exc_t["skip_periods"])
    if exc_t["constraint_samples"] < exc_t["samples"]:
        raise (where / "excitation" / "constraint_samples").error(
            f"at least [excitation] samples = {exc_t['samples']}", exc_t["constraint_samples"])
    if any(lo >= hi for lo, hi in zip(exc_t["tcp_box_min"], exc_t["tcp_box_max"])):
        raise (where / "excitation" / "tcp_box_max").error(f"above tcp_box_min = {exc_t['tcp_box_min']}",
                                                           exc_t["tcp_box_max"])
    if ctrl["iso_mode"] == "model_based_elastic" and not elastic_plant(doc):
        raise (where / "controller" / "iso_mode").error("'model_based' on a rigid plant (elastic_joints = 0)",
                                                        ctrl["iso_mode"])
    record = doc.get("record") or {}
    if elastic_plant(doc) and abs(record.get("period", -1.0) - doc["tracker"]["period"]) > 1e-12:
        raise (where / "record" / "period").error(
            f"[tracker] period = {doc['tracker']['period']:g} s on the elastic plant (the gear-stiffness fit needs "
            "every tracker reading)", record.get("period"))
    if elastic_plant(doc) and doc["measurement"]["kinematics"] != "calibrated":
        raise (where / "measurement" / "kinematics").error(
            "'calibrated' on the elastic plant (the gear-stiffness fit needs the arm's true geometry)",
            doc["measurement"]["kinematics"])
    nyquist = 0.5 / ctrl["period"]
    if doc["measurement"]["cutoff"] >= nyquist:
        raise (where / "measurement" / "cutoff").error(f"below the Nyquist frequency {nyquist:g} Hz of the "
                                                       "controller cycle", doc["measurement"]["cutoff"])


# ---------------------------------------------------------------------------------------- measurement
class FieldbusRecorder:
    """The controller PC's data logger: wraps a :class:`controller.Controller` and keeps, every
    cycle, what the fieldbus delivered (``ObservedActuals``: position actual in rad, torque
    actual in N m joint side, both quantised by the drive and the CiA 402 scaling), plus
    optional Gaussian current-measurement noise on the torque (sigma in N m per joint).

    ``keep_after_start_s``: keep only the rows from the wrapped controller's ``motion_start_s``
    (when the drives apply trajectory time 0) to that many seconds after it - what
    :meth:`window` reads for a motion of that duration - so memory is bounded by the motion,
    not by the run's stop time (a 600 s validation run holds the 12.2 s ISO path's rows). None
    keeps every row. Rows are held in arrays that grow as needed (nothing is preallocated
    for the run); the noise is drawn every cycle either way, so the kept rows are the same.

    Everything else is delegated to the wrapped controller, so the robot cell's
    :class:`~cosim.cell.link.FieldbusLink` drives it like the controller itself.
    """

    #: Rows of the first allocation; the arrays double when full.
    FIRST_ROWS = 4096

    def __init__(self, controller: Controller, torque_noise_sigma: np.ndarray, seed: int,
                 keep_after_start_s: float | None = None) -> None:
        self._controller = controller
        self._keep_s = keep_after_start_s
        self.t = np.empty(0)
        self.position = np.empty((0, 6))
        self.torque = np.empty((0, 6))
        self.fresh = np.empty((0, 6), dtype=bool)
        self.rows = 0
        self._sigma = np.asarray(torque_noise_sigma, dtype=float)
        self._rng = np.random.default_rng(seed)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._controller, name)

    def _keeps(self, t: float) -> bool:
        if self._keep_s is None:
            return True
        start = getattr(self._controller, "motion_start_s", None)
        return start is not None and start - 1e-9 <= t < start + self._keep_s - 1e-9

    def _grow(self) -> None:
        n = max(self.FIRST_ROWS, 2 * self.t.size)
        for name in ("t", "position", "torque", "fresh"):
            old = getattr(self, name)
            new = np.empty((n, *old.shape[1:]), dtype=old.dtype)
            new[:self.rows] = old[:self.rows]
            setattr(self, name, new)

    def step(self, inputs: Any) -> Any:
        """Keep this cycle's :class:`controller.ControllerInput` values, then the controller's step."""
        noise = self._sigma * self._rng.standard_normal(6)
        if self._keeps(inputs.time_s):
            k = self.rows
            if k == self.t.size:
                self._grow()
            self.t[k] = inputs.time_s
            self.position[k] = inputs.position
            self.torque[k] = inputs.torque + noise
            self.fresh[k] = inputs.fresh
            self.rows = k + 1
        return self._controller.step(inputs)

    @staticmethod
    def keep_for(duration_s: float, period_s: float, position_lag_cycles: int = 0) -> float:
        """``keep_after_start_s`` that holds every row :meth:`window` reads for a motion of
        ``duration_s`` from its start with ``position_lag_cycles`` (and one cycle to spare)."""
        return duration_s + (position_lag_cycles + 2) * period_s

    def window(self, start_s: float, duration_s: float, period_s: float,
               position_lag_cycles: int = 0) -> tuple[np.ndarray, ...]:
        """Rows with start_s - 1e-9 <= t < start_s + duration_s - 1e-9: (t, position, torque).

        ``position_lag_cycles``: the positions are taken that many rows later (a drive that
        latches position actual one cycle before torque actual reports at t_k + T the
        position of t_k), so that position and torque of a row belong to the same instant.
        """
        n = self.rows
        first = int(np.searchsorted(self.t[:n], start_s - 1e-9))
        count = int(round(duration_s / period_s))
        last = min(first + count, n - position_lag_cycles)
        lag = position_lag_cycles
        return self.t[first:last], self.position[first + lag:last + lag], self.torque[first:last]


# ---------------------------------------------------------------------------------------- set-up
def elastic_plant(doc: dict[str, Any]) -> bool:
    """Whether the scenario's plant FMU runs the flexible-joint model (``elastic_joints = 1``)."""
    return any(f["name"] == wiring.PLANT and int(f.get("parameters", {}).get("elastic_joints", 0))
               for f in doc["fmus"])


def _config(doc: dict[str, Any], mode: str, lead_cycles: int) -> ControllerConfig:
    c = doc["controller"]
    return ControllerConfig(mode=mode, period_s=c["period"], lead_cycles=lead_cycles,
                            compute_budget_s=c["compute_budget"], settle_time_s=c["settle_time"])


def _noise_sigma(doc: dict[str, Any]) -> np.ndarray:
    from robot.parameters import load_parameters

    return doc["measurement"]["torque_noise_percent_rated"] / 100.0 * load_parameters().rated_torque


# ---------------------------------------------------------------------------------------- running
@dataclasses.dataclass
class _Cell:
    """What every run of the campaign on the robot cell shares (built once from the scenario)."""

    scenario: Scenario
    fieldbus: Any
    true_robot: Any
    kinematics: Any
    nominal: Any  # the controller's nominal RobotDynamics (payload only if [controller] payload_known)
    drive_model: Any
    tracker: Any
    sigma: np.ndarray  # N m, the added current-measurement noise per joint

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> "_Cell":
        from fieldbus import FieldbusConfig
        from robot.description import load_model
        from robot.dynamics import RobotDynamics

        doc = scenario.data
        _fill_table_defaults(doc)
        ctrl = doc["controller"]
        true_robot = make_true_robot(doc["true_robot"])
        known_payload = true_robot.payload.copy() if ctrl["payload_known"] else np.zeros(4)
        kin = load_model()
        return cls(scenario, FieldbusConfig.from_dict(doc["fieldbus"], source=str(scenario.path)), true_robot, kin,
                   RobotDynamics(payload=known_payload, model=kin),
                   wiring.drive_loop_model(doc["fmus"], ctrl["period"]) if ctrl["drive_compensation"] else None,
                   tracker_config(doc["tracker"]), _noise_sigma(doc))

    @property
    def lead(self) -> int:
        return self.fieldbus.lead_cycles

    def run(self, ctx: RunContext, ctl: Any, label: str, stop: float, name: str, tracker: Any = None):
        """Run the cell with ``ctl`` (a controller or its FieldbusRecorder) for ``stop`` s."""
        doc = self.scenario.data
        cell = describe_cell(doc, self.true_robot,
                             controller_info(ctl, self.fieldbus, label=label, source=str(self.scenario.path)),
                             label=label, stop_time=stop, fieldbus=self.fieldbus,
                             tracker=self.tracker if tracker is None else tracker,
                             record_file=f"timeseries_{name}.csv",
                             can_log=can_log_path(ctx, doc["results"], name))
        return run_cell(cell, ctl, ctx)

    def iso_run(self, ctx: RunContext, label: str, dynamics: Any, path: Any, tcp_ref: Any, gear: Any = None):
        """The ISO 9283 path in ``[controller] iso_mode`` with ``dynamics`` (and ``gear``), recorded at
        the fieldbus for the validation over the path's duration only, evaluated:
        (summary entry, recorder, controller, cell run)."""
        from controller.elastic import make_controller
        from planners.iso9283 import ISO_Q_HINT

        doc = self.scenario.data
        ctrl, meas = doc["controller"], doc["measurement"]
        period, stop = ctrl["period"], doc["simulation"]["stop_time"]
        ctl = make_controller(tcp_ref, _config(doc, ctrl["iso_mode"], self.lead), kinematic_model=self.kinematics,
                              dynamics=dynamics, q_hint=np.array(ISO_Q_HINT), drive_model=self.drive_model,
                              capacity=int(stop / period) + 16, **({"gear": gear} if gear is not None else {}))
        rec = FieldbusRecorder(ctl, self.sigma, meas["noise_seed"] + 1,
                               keep_after_start_s=FieldbusRecorder.keep_for(path.duration, period,
                                                                            meas["position_lag_cycles"]))
        cell = self.run(ctx, rec, f"iso9283_{label}", stop, label)
        entry, _ = evaluate_run(ctx, label, cell, ctl, tcp_ref, path, self.true_robot)
        return entry, rec, ctl, cell


def iso_path(doc: dict[str, Any]) -> tuple[Any, Any]:
    """The validation's EN ISO 9283 test path (``[path]``) and the controller's TCP trajectory of it."""
    from planners.iso9283 import iso9283_test_path

    path = iso9283_test_path(speed=doc["path"]["speed"], acceleration=doc["path"]["acceleration"])
    return path, TcpTrajectory.from_reference(path.reference, path.duration, doc["controller"]["period"])


def run_validation_path(scenario: Scenario, ctx: RunContext, label: str = "nominal") -> dict[str, Any]:
    """Only the ISO 9283 validation run with the nominal model, recorded at the fieldbus as the job
    does (no campaign): what ``benchmarks/bench_memory.py --job identification`` measures."""
    cell = _Cell.from_scenario(scenario)
    path, tcp_ref = iso_path(scenario.data)
    entry, rec, ctl, run = cell.iso_run(ctx, label, cell.nominal, path, tcp_ref)
    if run.failure is not None:
        raise run.failure
    meas = scenario.data["measurement"]
    t, _, _ = rec.window(ctl.motion_start_s, path.duration, scenario.data["controller"]["period"],
                         meas["position_lag_cycles"])
    return {"tcp_error_max_mm": entry["tcp_error_max_mm"], "validation_samples": int(t.size),
            "recorder_rows": rec.rows, "sim_time_s": run.reached_s}


def run(scenario: Scenario, ctx: RunContext) -> dict[str, Any]:
    """Design, excite on the cell, identify (identification.campaign), validate, compare."""
    from identification.campaign import CampaignSettings, Truth, run_campaign
    from identification.data import motion_record, write_motion_csv
    from identification.identify import validate
    from robot.dynamics import RobotDynamics
    from robot.parameters import load_parameters

    cell = _Cell.from_scenario(scenario)
    doc = scenario.data
    ctrl, exc_t, meas = doc["controller"], doc["excitation"], doc["measurement"]
    period = ctrl["period"]
    true_robot, kin, nominal, sigma = cell.true_robot, cell.kinematics, cell.nominal, cell.sigma
    params = load_parameters()
    known_payload = true_robot.payload.copy() if ctrl["payload_known"] else np.zeros(4)
    elastic = elastic_plant(doc)
    ctx.summary.update(
        phase="designing the exciting trajectory",
        true_robot={"seed": true_robot.seed, "payload_mass_kg": float(true_robot.payload[0]),
                    "payload_com_m": true_robot.payload[1:].tolist(),
                    "dynamic_deviations": doc["true_robot"]["dynamic_deviations"],
                    "geometric_errors": doc["true_robot"]["geometric_errors"]},
        plant="elastic" if elastic else "rigid",
        noise_assumptions=_noise_assumptions(params, cell.fieldbus, sigma, meas))
    settings = CampaignSettings.from_tables(period, exc_t, meas, doc["stiffness"] if elastic else None)
    state: dict[str, Any] = {}

    def experiment(trajectory, duration: float):
        """The cell-specific step: the trajectory closed loop on the robot cell, measured as a user
        would (fieldbus actual values, the tracker on the reflector, the drives' sampling term)."""
        return _cell_experiment(doc, ctx, trajectory, duration, cell, params, elastic, state)

    def on_step(name: str, fields: dict[str, Any]) -> None:
        if name == "designed":
            excitation = fields["excitation"]
            ctx.path("excitation.json").write_text(json.dumps(excitation.to_dict(), indent=2) + "\n")
            state["excitation_fields"] = {k: v for k, v in excitation.to_dict().items()
                                          if k not in ("trajectory", "limits")}
            state["excitation_fields"].update(omega_f_requested_rad_s=exc_t["omega_f"],
                                              samples_per_period_400us=fields["samples_per_period"])
            ctx.summary.update(phase="exciting", excitation=state["excitation_fields"])
        elif name == "measured":
            ctx.summary.update(phase="identifying", excitation_run=fields["data"].info)

    # the plant's own model: the true parameters on the true geometry, the payload folded into link 6
    # through the true flange (docs/explanation/fmus.md); compared in the regressor's base parameters
    truth_p = RobotDynamics(true_robot.dynamic_parameters, true_robot.payload,
                            model=true_robot.kinematic_model()).parameter_vector(include_payload=True)
    truth_k, truth_b = _true_gears(doc, true_robot, params) if elastic else (None, None)
    stiffness_model = {"rotor_inertia": params.rotor_inertia,
                       "motor_friction_share": params.motor_friction_share,
                       "nominal_stiffness": params.stiffness} if elastic else None
    calibrated = true_robot.kinematic_model() if meas["kinematics"] == "calibrated" else None
    campaign = run_campaign(settings, experiment, payload=known_payload, truth=Truth(truth_p, truth_k, truth_b),
                            kinematic_model=calibrated, stiffness_model=stiffness_model, on_step=on_step)
    ident = campaign.identification
    excitation_fields, excite_summary = state["excitation_fields"], campaign.data.info
    true_base = ident.base.base_values(truth_p)
    parameters = ident.to_dict()
    for entry, value in zip(parameters["base_parameters"], true_base):
        entry["true_value"] = float(value)
        entry["error_in_std"] = (entry["value"] - float(value)) / entry["std"] if entry["std"] > 0 else None
    if campaign.stiffness is not None:
        parameters["gear_stiffness"] = campaign.report["gear_stiffness"]
    ctx.path("parameters.json").write_text(json.dumps(parameters, indent=2) + "\n")
    ident_summary = dict(campaign.report)
    ident_summary["standard_vector_links_physically_consistent"] = (
        parameters["standard_parameters_matching_base_values"]["links_physically_consistent"])
    if campaign.stiffness is not None:
        ident_summary["gear_stiffness"].update(
            reflector_m_in_tool0=list(settings.reflector), periods_averaged=settings.periods - settings.skip_periods,
            assumptions=STIFFNESS_ASSUMPTIONS.format(cutoff=settings.cutoff_hz))
    ctx.summary.update(phase="validating", excitation_run=excite_summary, identification=ident_summary)
    excitation = campaign.excitation


    # 4-5. ISO 9283 with the three models ----------------------------------------------------
    path, tcp_ref = iso_path(doc)
    # the controller's models all live on its own (nominal) geometry, which it also uses for the IK;
    # "true": the true robot's dynamic parameters and payload (the plant adds the true geometry)
    models = {"nominal": nominal, "identified": RobotDynamics(ident.full_parameters, np.zeros(4), model=kin),
              "true": RobotDynamics(true_robot.dynamic_parameters, true_robot.payload, model=kin)}
    # the torque predictions of the validation on the regressor's geometry (calibrated or nominal)
    predictors = dict(models, true=RobotDynamics(true_robot.dynamic_parameters, true_robot.payload,
                                                 model=calibrated if calibrated is not None else kin))
    gears = _gear_models(campaign, truth_k, truth_b) if ctrl["iso_mode"] == "model_based_elastic" else {}
    runs: dict[str, Any] = {}
    validation_fields: dict[str, Any] = {}
    for label in ctrl["compare_models"]:
        entry, rec, ctl, iso_cell = cell.iso_run(ctx, label, models[label], path, tcp_ref, gears.get(label))
        runs[label] = {k: entry[k] for k in ("status", "tcp_error_max_mm", "tcp_error_rms_mm",
                                             "tcp_error_max_noise_free_mm", "tcp_error_rms_noise_free_mm",
                                             "path_accuracy_AT_mm", "joint_lag_max_rad", "path_completed",
                                             "loop_wall_time_s") if k in entry}
        ctx.summary.update(iso9283_runs=runs)
        if iso_cell.failure is not None:
            raise iso_cell.failure
        if label == "nominal" or "nominal" not in ctrl["compare_models"] and not validation_fields:
            validation_fields = _validate(ctx, doc, rec, ctl, path, ident, predictors, true_robot, validate,
                                          motion_record, write_motion_csv, label)
            ctx.summary.update(validation=validation_fields)

    fields: dict[str, Any] = {"phase": "done", "excitation": excitation_fields, "excitation_run": excite_summary,
                              "identification": ident_summary, "validation": validation_fields,
                              "iso9283_runs": runs}
    if {"nominal", "identified"} <= set(runs):
        fields["tcp_error_max_ratio_nominal_over_identified"] = _ratio(runs["nominal"]["tcp_error_max_mm"],
                                                                       runs["identified"]["tcp_error_max_mm"])
    if {"true", "identified"} <= set(runs):
        fields["tcp_error_max_ratio_identified_over_true"] = _ratio(runs["identified"]["tcp_error_max_mm"],
                                                                    runs["true"]["tcp_error_max_mm"])
    if doc["results"]["figures"]:
        from cosim.jobs.identification_figures import (figure_excitation_path, figure_parameter_errors,
                                                       figure_torques)

        figures = [figure_excitation_path(ctx.path("figure5a_excitation_path.png"), excitation),
                   figure_torques(ctx.path("figure5b_torques.png"), ctx.path("validation_torques.csv")),
                   figure_parameter_errors(ctx.path("figure_parameter_errors.png"), ident_summary)]
        fields["figures"] = [p.name for p in figures]
    return fields


STIFFNESS_ASSUMPTIONS = (
    "calibrated kinematics (the true robot's geometry for f_DK and J); gear torques from the identified base "
    "parameters minus the rotor inertias (Ia1, Ia2 regrouped with link inertias: their catalogue values, "
    "robot/rx130l_params.toml) and the motor share of the friction ([elastic] motor_friction_share); "
    "quasi-static deflection below the cut-off {cutoff:g} Hz; linear gears")


def _gear_models(campaign, true_k, true_b) -> dict[str, Any]:
    """The elastic feed-forward's gear model per compared model: the catalogue's (nominal), the
    campaign's identified stiffness (catalogue value where an axis was not identifiable; catalogue
    damping: the identified damping is not reliable, docs/explanation/identification.md) and the plant's (true)."""
    from controller.feedforward import GearModel

    nominal = GearModel.from_parameters()
    est = campaign.stiffness
    identified = nominal
    if est is not None:
        k = np.where(est.identifiable, est.stiffness, nominal.stiffness)
        identified = dataclasses.replace(nominal, stiffness=k)
    true = dataclasses.replace(nominal, stiffness=np.asarray(true_k, dtype=float),
                               damping=np.asarray(true_b, dtype=float))
    return {"nominal": nominal, "identified": identified, "true": true}


def _true_gears(doc: dict[str, Any], true_robot, params) -> tuple[np.ndarray, np.ndarray]:
    """The plant's gear stiffness and damping per axis (the scenario's plant parameters, else
    the true robot's stiffness and the parameter file's damping, as cosim.cell.wiring sets them)."""
    plant = next(f for f in doc["fmus"] if f["name"] == wiring.PLANT).get("parameters", {})
    nominal_k = true_robot.gear_stiffness if true_robot.gear_stiffness is not None else params.stiffness
    k = np.array([plant.get(f"stiffness[{i}]", nominal_k[i - 1]) for i in range(1, 7)], dtype=float)
    b = np.array([plant.get(f"damping[{i}]", params.gear_damping[i - 1]) for i in range(1, 7)], dtype=float)
    return k, b


def _cell_experiment(doc, ctx, trajectory, duration, cell: _Cell, params, elastic, state):
    """Run ``trajectory`` for ``duration`` s closed loop on the cell (controller in the scenario's
    excitation mode with the nominal model) and return the :class:`identification.campaign.ExperimentData`
    a user gets: the fieldbus actual values every cycle (positions aligned with the torques), the
    drives' torque-sampling term measured on the drive FMU, and on the elastic plant the tracker's
    readings of the reflector on the tool."""
    from identification.campaign import ExperimentData, TrackerRecord
    from identification.data import motion_record, write_motion_csv

    ctrl, meas = doc["controller"], doc["measurement"]
    period, tracker = ctrl["period"], cell.tracker
    reference = JointTrajectory.from_sampler(trajectory.sample, duration, period)
    stop_time = 0.02 + ctrl["settle_time"] + duration + 0.3
    capacity = int(stop_time / period) + 16
    controller = Controller(reference, _config(doc, ctrl["excitation_mode"], cell.lead),
                            kinematic_model=cell.kinematics, dynamics=cell.nominal, drive_model=cell.drive_model,
                            capacity=capacity)
    recorder = FieldbusRecorder(controller, cell.sigma, meas["noise_seed"],
                                keep_after_start_s=FieldbusRecorder.keep_for(duration, period,
                                                                             meas["position_lag_cycles"]))
    reflector = tuple(doc["stiffness"]["reflector"]) if elastic else (0.0, 0.0, 0.0)
    run = cell.run(ctx, recorder, "excitation", stop_time, "excitation",
                   tracker=dataclasses.replace(tracker, reflector=reflector))
    from cosim.cell.verdict import judge

    verdict = judge(run).fields()  # the excitation run's verdict (cosim/cell/verdict.py)
    ctx.note_verdict("excitation", verdict)
    ctx.summary.update(excitation_verdict=verdict)
    if run.failure is not None:  # stopped early: no complete excitation data to identify from
        raise run.failure
    start = controller.motion_start_s
    if start is None:
        raise RuntimeError("the controller never started the exciting trajectory")
    t_x, q_x, tau_x = recorder.window(start, duration, period, meas["position_lag_cycles"])
    info = {"motion_start_s": start, "duration_s": duration, "samples": int(t_x.size), "sim_time_s": run.reached_s,
            "loop_wall_time_s": run.loop_wall_time_s, "controller_mode": ctrl["excitation_mode"],
            "max_abs_torque_Nm": np.abs(tau_x).max(axis=0).tolist(),
            "max_torque_ratio_of_effort": float(np.max(np.abs(tau_x) / params.effort_limit))}
    if doc["results"]["records"]:
        write_motion_csv(ctx.path("identification_record.csv"),
                         motion_record(t_x - t_x[0], q_x, tau_x, source="identification_record"))
    sampling = None
    if meas["torque_sampling_correction"]:
        from cosim.jobs.identification_torque_sampling import sampled_torque_bias

        sampling = sampled_torque_bias(doc["fmus"], period)
    readings = None
    if elastic:
        rec = run.recording
        cols = list(rec.columns)
        t = rec.data[:, 0]
        step = float(np.median(np.diff(t[:100]))) if t.size > 1 else float("nan")
        if not abs(step - tracker.period_s) < 1e-9:
            raise ValueError(f"the excitation run was recorded every {step} s; the stiffness fit needs every tracker "
                             f"reading: set [record] period = [tracker] period = {tracker.period_s} s")
        keep = t >= start - 1e-9
        positions = rec.data[keep][:, [cols.index(c) for c in ("tracker.x", "tracker.y", "tracker.z")]]
        readings = TrackerRecord(t[keep] - start, positions, reflector)
    bias = np.asarray(sampling["bias_Nm_per_rad_s2"]) if sampling is not None else None
    return ExperimentData(q_x, tau_x, period, readings, bias, sampling, info)


def _ratio(a: float, b: float) -> float:
    return a / b if (b and math.isfinite(a) and math.isfinite(b)) else float("nan")


def _validate(ctx: RunContext, doc: dict[str, Any], rec: FieldbusRecorder, ctl: Controller, path, ident, models,
              true_robot, validate, motion_record, write_motion_csv, label: str) -> dict[str, Any]:
    """Measured (fieldbus) vs predicted torques along the ISO 9283 path run with model ``label``."""
    from identification.estimation import relative_rms_error
    from identification.identify import prepare_motion
    from identification.signals import zero_phase_lowpass

    period = doc["controller"]["period"]
    t, q, tau = rec.window(ctl.motion_start_s, path.duration, period, doc["measurement"]["position_lag_cycles"])
    if doc["results"]["records"]:
        write_motion_csv(ctx.path("validation_record.csv"),
                         motion_record(t - t[0], q, tau, source="validation_record"))
    cutoff = doc["measurement"]["cutoff"]
    bias = ident.data.get("torque_acceleration_bias_Nm_per_rad_s2")
    if bias is not None:
        # the same known sampling term as in the identification, removed from the measured torque
        tau = tau - np.asarray(bias) * prepare_motion(motion_record(t, q, tau, source="validation"), cutoff).qdd
    record = motion_record(t, q, tau, source=f"ISO 9283 run with the {label} model (fieldbus actual values)")
    result = validate(ident, record, cutoff)
    prepared = prepare_motion(record, cutoff)
    predictions = {"identified": result.tau_predicted}
    for name in ("nominal", "true"):
        dyn = models[name]
        predictions[name] = np.array([dyn.inverse_dynamics(a, b, c)
                                      for a, b, c in zip(prepared.q, prepared.qd, prepared.qdd)])
    measured_f = zero_phase_lowpass(tau, period, cutoff)
    filtered = {name: zero_phase_lowpass(pred, period, cutoff) for name, pred in predictions.items()}
    errors = {name: relative_rms_error(measured_f, pred).tolist() for name, pred in filtered.items()}
    if ident.consistent is not None:
        errors["identified_consistent"] = validate(ident.consistent_model(), record, cutoff).relative_rms_error.tolist()
    errors_raw = {name: relative_rms_error(tau, pred).tolist() for name, pred in predictions.items()}
    columns = {"t": t - t[0]}
    for j in range(6):
        columns[f"tau_measured{j + 1}"] = tau[:, j]
    for j in range(6):
        columns[f"tau_measured_filtered{j + 1}"] = measured_f[:, j]
    for name, pred in predictions.items():
        for j in range(6):
            columns[f"tau_{name}{j + 1}"] = pred[:, j]
    from cosim.results import write_columns

    write_columns(ctx.path("validation_torques.csv"), columns)  # CSV by its suffix
    return {"trajectory": "EN ISO 9283 test path", "run_with_model": label, "samples": int(t.size),
            "relative_rms_error": errors["identified"],
            "max_relative_rms_error": float(max(errors["identified"])),
            "relative_rms_error_by_model": errors,
            "relative_rms_error_unfiltered_by_model": errors_raw,
            "rms_measured_Nm": np.sqrt(np.mean(tau**2, axis=0)).tolist(),
            "definition": "per joint RMS(predicted - measured) / RMS(measured) after the same zero-phase "
                          f"low-pass at {cutoff:g} Hz on both (parallel filtering; '_unfiltered': without it); "
                          "measured = torque_actual over the fieldbus (with the added current noise"
                          + ("; minus the drives' sampling term b_i qdd_i" if bias is not None else "") + "); predicted "
                          f"from the fieldbus positions, zero-phase differentiated at {cutoff:g} Hz"}


def _noise_assumptions(params, fb, sigma: np.ndarray, meas: dict[str, Any]) -> dict[str, Any]:
    lsb_q = 2 * math.pi / (params.encoder_counts_per_motor_rev * params.gear_ratio)
    return {
        "encoder": f"{params.encoder_counts_per_motor_rev} counts per motor revolution (drive floor-quantises "
                   "position_actual), joint-side LSB per joint in rad",
        "encoder_lsb_rad": lsb_q.tolist(),
        "torque_actual_lsb_Nm": (1e-3 * params.rated_torque).tolist(),
        "torque_actual": "0x6077 INT16 in 0.1 % of rated torque (fieldbus scaling), the drive's N k_t i: includes "
                         "reflected rotor inertia and friction torque (both are regressor columns)",
        "added_current_noise_sigma_Nm": np.asarray(sigma).tolist(),
        "added_current_noise": f"Gaussian, sigma {meas['torque_noise_percent_rated']:g} % of rated torque, white "
                               f"per 400 us sample, seed {meas['noise_seed']}",
        "sampling": f"{fb.cycle_time_s * 1e6:g} us (every controller cycle, values latched at the SoC, "
                    f"{fb.dead_time_cycles} cycle(s) dead time for set-points)",
    }


JOB = JobType(JOB_NAME, run, SCHEMA, check,
              "Dynamic identification campaign: optimal excitation, closed-loop data over the fieldbus, "
              "identification, ISO 9283 validation and model comparison")
