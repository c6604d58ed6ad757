"""What the robot jobs share about the cell's parts: the scenario tables of a cell, the seeded
true robot, the controller's models and built-in modes, and a user's controller.

The tables (:data:`CELL_FIELDS`: ``[true_robot]``, ``[controller]``, ``[path]``,
``[tracker]``, ``[fieldbus]``, ``[results]``) are those of every job that runs the cell
(``iso9283``, ``fieldbus_fault``, ``planners``; ``identification`` has its own
``[controller]``); :func:`check_cell_scenario` is their common check. The built-in
controller modes (:data:`BUILTIN_MODES`) are ``standard``, ``standard_speed_ff`` and
``model_based`` (paper section 2.3, Figure 1, eq. 7), all run by
:class:`controller.Controller` through the controller contract; a user's controller
(``[controller] class`` or ``fmu``) is loaded by :mod:`cosim.cell.user_controller`.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any

import numpy as np

from controller import ControllerConfig
from cosim.cell import wiring
from cosim.cell.checks import check_cell, fill_defaults
from cosim.tracking.laser_tracker import DEFAULT_POSITION_SIGMA_M
from cosim.scenario.schema import AnyValue, Boolean, Field, FilePath, Integer, List, Number, String, Table, Where

SPEED_FEEDFORWARD_PARAMETER = "speed_feedforward_gain"
"""The servo-drive FMU parameter set per built-in mode."""


@dataclass(frozen=True)
class BuiltinMode:
    """One built-in controller mode of the cell.

    controller_mode: the :class:`controller.ControllerConfig` mode (``"standard"``: zero
        torque offset, target = q_d; ``"model_based"``: eq. 7 torque offset + set-point shaping).
    drive_speed_feedforward: default of ``[controller.<mode>] drive_speed_feedforward``:
        True = the drives' ``speed_feedforward_gain`` of fmus/servo_drive/drive_params.toml
        (1.0), False = 0 (pure P position loop).
    description: one line for summary.json.
    """

    controller_mode: str
    drive_speed_feedforward: bool
    description: str


BUILTIN_MODES: dict[str, BuiltinMode] = {
    "standard": BuiltinMode("standard", False, "position set-points only: the drives' P position / PI speed / PI current "
                                           "cascade, no speed or torque feed-forward (paper section 2.3, Figure 1)"),
    "standard_speed_ff": BuiltinMode("standard", True, "position set-points, the drives' own speed feed-forward from "
                                                   "target differences, no torque feed-forward"),
    "model_based": BuiltinMode("model_based", True, "eq. 7: velocity reference through the drives' speed feed-forward, "
                                                "torque feed-forward M(q_d) qdd_d + g(q_d, qd_d) as torque offset, "
                                                "drive set-point shaping"),
    "model_based_elastic": BuiltinMode("model_based_elastic", True,
                                       "flatness-based feed-forward for elastic gears: motor reference q_d + K^-1 "
                                       "tau_g (from q_d and its derivatives up to the 4th) as target, motor torque "
                                       "as torque offset, drive set-point shaping (controller/elastic.py)"),
}
"""The built-in modes (``[controller] modes``), in the order they are reported."""

TORQUE_FEEDFORWARD_MODES = ("model_based", "model_based_elastic")
"""The controller modes that send a torque feed-forward (and shape the drives' set-points when
``[controller] drive_compensation``)."""

SPEED_FEEDFORWARD_PARAMETER = "speed_feedforward_gain"
"""The servo-drive FMU parameter the job sets per mode."""


def _mode_table(mode: str) -> Table:
    default = BUILTIN_MODES[mode].drive_speed_feedforward
    return Table({
        "drive_speed_feedforward": Field(
            Boolean(), default=default,
            doc=f"true: the drives add their speed feed-forward from target differences (gain of "
                f"fmus/servo_drive/drive_params.toml), false: gain 0; default for {mode!r}: "
                f"{str(default).lower()}"),
    }, doc=f"the [controller.{mode}] table")

#: Largest accepted |x|, |y|, |z| of the payload's centre of mass in tool0, m: load diagrams of 10 kg-class
#: arms end at a few hundred mm of offset; 1 m leaves room for long tools and refuses unit slips (mm for m).
MAX_PAYLOAD_COM_M = 1.0

TRUE_ROBOT_TABLE = Table({
    "seed": Field(Integer(min=0), default=1, doc="the seed of the true robot's deviations: an integer >= 0"),
    "payload_mass": Field(Number(unit="kg", min=0, max=10), default=0.0,
                          doc="the payload on tool0: a number in kg in [0, 10] (rated load 10 kg)"),
    "payload_com": Field(List(Number(unit="m", min=-MAX_PAYLOAD_COM_M, max=MAX_PAYLOAD_COM_M), length=3),
                         default=[0.0, 0.0, 0.0],
                         doc="the payload's centre of mass in tool0: 3 numbers in m"),
    "dynamic_deviations": Field(Boolean(), default=True,
                                doc="the true robot's inertial and friction deviations from the nominal model"),
    "geometric_errors": Field(Boolean(), default=True,
                              doc="the true robot's geometric errors (false: nominal geometry)"),
}, doc="the [true_robot] table")

CONTROLLER_CONFIG_FIELDS: dict[str, Field] = {
    "period": Field(Number(unit="s", gt=0), default=ControllerConfig.period_s,
                    doc="the controller cycle: a number in s > 0"),
    "drive_compensation": Field(Boolean(), default=True,
                                doc="model_based: shape the targets for the drives' speed feed-forward and filter"),
    "compute_budget": Field(Number(unit="s", gt=0), default=ControllerConfig.compute_budget_s,
                            doc="compute time above which a cycle counts as a deadline miss: a number in s > 0"),
    "settle_time": Field(Number(unit="s", min=0), default=ControllerConfig.settle_time_s,
                         doc="hold at the start configuration after all drives are enabled: a number in s >= 0"),
}
"""The ``[controller]`` keys of every job that runs :class:`controller.Controller` (the cell
jobs here, identification with its own modes): their defaults are the controller's own
(:class:`controller.ControllerConfig`), defined there once."""

DEFAULT_MODES = ("standard", "model_based")
"""``[controller] modes`` when the table leaves it out and names no user controller."""


def _default_modes(table: dict[str, Any], where: Where) -> None:
    """``modes`` left out: the built-in :data:`DEFAULT_MODES`, or none when the table names a user
    controller (``class`` or ``fmu``: it runs alone unless modes are listed)."""
    if "modes" not in table:
        table["modes"] = [] if (table.get("class") or table.get("fmu")) else list(DEFAULT_MODES)


CONTROLLER_TABLE = Table({
    "modes": Field(List(String(choices=tuple(BUILTIN_MODES)), min_len=0, unique=True),
                   doc="the built-in modes to run; default ['standard', 'model_based'], or [] when the table "
                       "names a user controller (class or fmu): list modes to run them besides it"),
    "period": CONTROLLER_CONFIG_FIELDS["period"],
    "kinematics": Field(String(choices=("nominal", "true")), default="nominal",
                        doc="the controller's IK model: 'nominal' (URDF) or 'true' (perfectly calibrated)"),
    "calibrated_urdf": Field(FilePath(must_exist=True, suffix=".urdf"),
                             doc="a calibrated URDF for the controller's IK (overrides kinematics)"),
    "dynamics": Field(String(choices=("nominal", "true")), default="nominal",
                      doc="the feed-forward model: 'nominal' (URDF + parameter file) or 'true' (ideal)"),
    "payload_known": Field(Boolean(), default=True,
                           doc="true: the controller's model includes the [true_robot] payload (declared tool load)"),
    "drive_compensation": CONTROLLER_CONFIG_FIELDS["drive_compensation"],
    "compute_budget": CONTROLLER_CONFIG_FIELDS["compute_budget"],
    "settle_time": CONTROLLER_CONFIG_FIELDS["settle_time"],
    **{mode: Field(_mode_table(mode), doc=f"settings of the built-in mode {mode!r}") for mode in BUILTIN_MODES},
    "class": Field(String(pattern=r"^[^:]+:[A-Za-z_][A-Za-z0-9_.]*$",
                          pattern_doc="'path/to/file.py:ClassName' or 'package.module:ClassName'"),
                   doc="a user controller run besides the modes: 'path/to/file.py:Class' or 'package.module:Class' "
                       "(controller.CellController)"),
    "fmu": Field(FilePath(must_exist=True, suffix=".fmu"),
                 doc="an FMI 2.0 co-simulation controller FMU run besides the modes, stepped at the bus cycle"),
    "label": Field(String(pattern=r"^[A-Za-z0-9_.-]+$", pattern_doc="letters, digits, '_', '.', '-'"),
                   doc="the name of the user controller's run (files, summary): default the class or FMU name"),
    "parameters": Field(Table({}, extra=AnyValue(), doc="the [controller.parameters] table"), default={},
                        doc="passed to the user controller class as keyword arguments / set as FMU parameters"),
    "fmu_inputs": Field(Table({}, extra=String(), doc="the [controller.fmu_inputs] table"), default={},
                        doc="FMU input variable = controller input field[joint] (e.g. pos1 = 'position[1]')"),
    "fmu_outputs": Field(Table({}, extra=String(), doc="the [controller.fmu_outputs] table"), default={},
                         doc="FMU output variable = controller output field[joint] (e.g. tau1 = 'target_torque[1]')"),
}, check_fn=_default_modes, doc="the [controller] table")

TRACKER_TABLE = Table({
    "period": Field(Number(unit="s", gt=0), default=1e-3, doc="the laser tracker's sample period"),
    "noise_sigma": Field(Number(unit="m", min=0, max=1e-3), default=DEFAULT_POSITION_SIGMA_M,
                         doc="standard deviation of the tracker's position noise per axis"),
    "seed": Field(Integer(min=0), default=0, doc="seed of the tracker noise"),
}, doc="the [tracker] table")

PATH_TABLE = Table({
    "speed": Field(Number(unit="m/s", gt=0, max=2.0), default=1.0, doc="TCP speed along the ISO 9283 path"),
    "acceleration": Field(Number(unit="m/s^2", gt=0, max=20.0), default=5.0,
                          doc="TCP acceleration along the ISO 9283 path"),
}, doc="the [path] table")

CAN_LOG_FORMATS = {"parquet": ".parquet", "blf": ".blf"}
"""``[results] can_log_format`` -> suffix of ``can_<mode>``: the columnar CAN log (default,
``fieldbus.canlog``; ``cosim export-blf`` turns it into the BLF file byte for byte) or BLF."""
CAN_LOG_FORMAT_FIELD = Field(String(choices=tuple(CAN_LOG_FORMATS)), default="parquet",
                             doc="the CAN log's format: 'parquet' (columnar, every frame, fieldbus.canlog; "
                                 "'cosim export-blf' writes the same frames as BLF) or 'blf' (python-can's BLF)")

RESULTS_TABLE = Table({
    "can_log": Field(Boolean(), default=True, doc="write the CAN log can_<mode>.parquet (or .blf)"),
    "can_log_format": CAN_LOG_FORMAT_FIELD,
    "figures": Field(Boolean(), default=True, doc="write the PNG figures"),
    "report": Field(Boolean(), default=True, doc="write report.html, the interactive view of the run (docs/how-to/view_results.md)"),
}, doc="the [results] table")


def can_log_path(ctx: Any, results: dict[str, Any], name: str) -> Any:
    """The CAN log file ``can_<name>`` in the results folder, in ``[results] can_log_format``
    (None without a context or with ``can_log = false``)."""
    if ctx is None or not results.get("can_log"):
        return None
    return ctx.path(f"can_{name}{CAN_LOG_FORMATS[results.get('can_log_format', 'parquet')]}")

CELL_FIELDS: dict[str, Field] = {
    "true_robot": Field(TRUE_ROBOT_TABLE, default={},
                        doc="the simulated robot: seed of its deviations from the nominal model, payload"),
    "controller": Field(CONTROLLER_TABLE, default={},
                        doc="the controller: built-in modes or a user class/FMU, cycle, compute budget"),
    "path": Field(PATH_TABLE, default={}, doc="the ISO 9283 test path's speed and acceleration"),
    "tracker": Field(TRACKER_TABLE, default={}, doc="the laser tracker measuring the TCP: sample period, noise"),
    "fieldbus": Field(Table({}, extra=AnyValue(), doc="a [fieldbus] table (fieldbus/powerlink_defaults.toml keys; "
                                                      "[[fieldbus.asynchronous]]: SDO/NMT requests sent in the "
                                                      "asynchronous slot, docs/how-to/sdo_nmt.md)"),
                      default={}),
    "results": Field(RESULTS_TABLE, default={}, doc="which result files the run writes"),
}
"""The scenario tables of a job that runs the cell (besides [scenario] and the co-simulation tables)."""
_CELL_TABLES = ("true_robot", "controller", "path", "tracker", "results")


def fill_cell_defaults(doc: dict[str, Any]) -> None:
    """Give the cell's tables their fields' defaults where the document leaves them out."""
    fill_defaults(doc, Table(CELL_FIELDS), _CELL_TABLES)


def check_cell_scenario(doc: dict[str, Any], where: Where) -> None:
    """Everything of a cell scenario that can be checked before running (raises ScenarioError at
    the key): the cell (:func:`cosim.cell.checks.check_cell`; no drive sets the speed feed-forward
    gain, the modes do) and a user controller (:func:`cosim.cell.user_controller.check_user_controller`)."""
    from cosim.cell.user_controller import check_user_controller

    fill_cell_defaults(doc)
    check_cell(doc, where, job_set_drive_parameters={
        SPEED_FEEDFORWARD_PARAMETER: "no speed_feedforward_gain here: the job sets it per mode "
                                     "([controller.<mode>] drive_speed_feedforward = true/false)"},
        run_length_s=doc["simulation"]["stop_time"])
    check_user_controller(doc["controller"], where / "controller")
    ctrl = doc["controller"]
    if not ctrl["modes"] and not (ctrl.get("class") or ctrl.get("fmu")):
        raise (where / "controller" / "modes").error(
            f"at least one of {list(BUILTIN_MODES)}, or a user controller ([controller] class or fmu)", [])


def tracker_config(table: dict[str, Any]):
    """The :class:`cosim.tracking.laser_tracker.TrackerConfig` of a ``[tracker]`` table."""
    from cosim.tracking.laser_tracker import TrackerConfig

    return TrackerConfig(table["period"], table["noise_sigma"], table["seed"])


def make_true_robot(table: dict[str, Any]):
    """The seeded true robot of the [true_robot] table."""
    from robot.geometric_errors import ErrorMagnitudes
    from robot.true_robot import DeviationMagnitudes, make_true_robot as draw

    payload = [table["payload_mass"], *table["payload_com"]]
    dyn = DeviationMagnitudes() if table["dynamic_deviations"] else DeviationMagnitudes(
        **{k: 0.0 for k in DeviationMagnitudes.__dataclass_fields__})
    geo = None if table["geometric_errors"] else _zero_error_magnitudes(ErrorMagnitudes)
    return draw(table["seed"], payload, dyn, geometric_magnitudes=geo)


def _zero_error_magnitudes(cls):
    fields = cls.__dataclass_fields__
    return cls(**{k: 0.0 for k in fields})


def controller_models(ctrl: dict[str, Any], true_robot) -> tuple[Any, Any, str, str]:
    """(kinematic model, dynamics, kinematics label, dynamics label) of the controller."""
    from robot.description import load_model
    from robot.dynamics import RobotDynamics

    if ctrl.get("calibrated_urdf") is not None:
        kin, kin_label = load_model(ctrl["calibrated_urdf"]), f"calibrated URDF {ctrl['calibrated_urdf']}"
    elif ctrl["kinematics"] == "true":
        kin, kin_label = true_robot.kinematic_model(), "true (ideal calibration)"
    else:
        kin, kin_label = load_model(), "nominal URDF"
    payload = true_robot.payload if ctrl["payload_known"] else np.zeros(4)
    if ctrl["dynamics"] == "true":
        dyn, dyn_label = true_robot.dynamics(), "true robot (ideal identification)"
    else:
        dyn, dyn_label = RobotDynamics(payload=payload, model=kin), "nominal (URDF + rx130l_params.toml)"
    return kin, dyn, kin_label, dyn_label


def drive_speed_feedforward(ctrl: dict[str, Any], mode: str) -> bool:
    """Whether the drives' speed feed-forward is on in ``mode`` ([controller.<mode>] or the mode's default)."""
    table = ctrl.get(mode) or {}
    return bool(table.get("drive_speed_feedforward", BUILTIN_MODES[mode].drive_speed_feedforward))


def mode_fmus(doc_fmus: list[dict[str, Any]], speed_feedforward: bool) -> list[dict[str, Any]]:
    """A copy of the scenario's ``[[fmus]]`` with every drive's ``speed_feedforward_gain`` set:
    the drive parameter file's value (1.0) when ``speed_feedforward``, else 0."""
    from fmus.servo_drive.params import drive_start_values

    fmus = copy.deepcopy(doc_fmus)
    for fmu in fmus:
        if fmu["name"] in wiring.DRIVES:
            axis = wiring.DRIVES.index(fmu["name"]) + 1
            gain = drive_start_values(axis)[SPEED_FEEDFORWARD_PARAMETER] if speed_feedforward else 0.0
            fmu["parameters"] = {**fmu["parameters"], SPEED_FEEDFORWARD_PARAMETER: float(gain)}
    return fmus
