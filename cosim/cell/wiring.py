"""The robot cell's wiring: its FMU instances, master variables, generated connections and start values.

A cell is the plant FMU ``plant`` (``rx130l_plant``), six drive FMUs ``drive1`` ...
``drive6`` (``servo_drive``), the master variables of the fieldbus task (``bus.*``:
what each drive applies from the SoC, written every bus cycle by
:class:`cosim.cell.link.FieldbusLink`) and of the laser tracker (``tracker.x/y/z``).

The connections are GENERATED (:func:`cell_connections`): per axis i, drive torque ->
plant, plant joint state -> drive measurement, ``bus.*[i]`` -> drive inputs. A scenario
lists only what differs (:func:`merged_connections`): a connection into an input the cell
drives replaces the generated one; any other connection (a plugged-in FMU, e.g. a
payload acting through ``plant.tau_ext[i]``) is added.

The plant is set to the TRUE robot (``robot.true_robot.make_true_robot``): its 78
dynamic parameters, payload and 39 geometric errors as FMU start values, its start configuration ``q0`` =
the controller's start pose (the arm starts at rest there). Drive parameters are
:func:`fmus.servo_drive.params.drive_start_values` of each axis, overridden by the
scenario's ``[fmus.parameters]``.
"""
from __future__ import annotations

import copy
from collections.abc import Collection, Mapping, Sequence
from typing import Any

import numpy as np

from controller import DriveLoopModel, speed_comparison_lead
from cosim.tracking.laser_tracker import TRACKER_VARIABLES
from cosim.master.variables import parse_connection
from fieldbus import JointScaling
from fmus.servo_drive.interface import REQUIRED as DRIVE_REQUIRED
from fmus.servo_drive.params import drive_start_values
from robot.parameters import RobotParameters, load_parameters
from robot.true_robot import TrueRobot
from robot.joints import N_JOINTS

PLANT = "plant"
DRIVES: tuple[str, ...] = tuple(f"drive{i}" for i in range(1, N_JOINTS + 1))
PLANT_FMU = "rx130l_plant"
DRIVE_FMU = "servo_drive"

BUS_REAL = ("target_position", "torque_offset", "target_velocity", "velocity_offset", "target_torque")
"""Real master variables ``bus.<name>[i]`` of the fieldbus task (rad, N·m, rad/s, rad/s, N·m)."""
BUS_INTEGER = ("controlword", "fault_code", "modes_of_operation")
"""Integer master variables ``bus.<name>[i]`` of the fieldbus task."""
BUS_START = {"modes_of_operation": 8}
"""Start values of bus variables that are not 0 (cyclic synchronous position, CiA 402 0x6060 = 8)."""
APPLIED_FIELD = {"target_position": "position"}
"""The ``fieldbus.AppliedSetpoints`` field of a bus variable where the names differ."""

REQUIRED_DRIVE_VARIABLES: frozenset[str] = DRIVE_REQUIRED
"""Variables every drive FMU of the cell has (the minimal drive interface,
``fmus.servo_drive.interface``, docs/explanation/fmus.md); the cell connects, reads and records every
optional one a drive FMU has and leaves out the others."""


def bus_variables() -> dict[str, tuple[str, object]]:
    """Master variables of the fieldbus task: name -> (type, start), declared in this order
    (so each group of six is one contiguous writable view)."""
    out: dict[str, tuple[str, object]] = {}
    for name in BUS_REAL:
        for i in range(1, N_JOINTS + 1):
            out[f"bus.{name}[{i}]"] = ("Real", 0.0)
    for name in BUS_INTEGER:
        for i in range(1, N_JOINTS + 1):
            out[f"bus.{name}[{i}]"] = ("Integer", BUS_START.get(name, 0))
    return out


def tracker_variables() -> dict[str, tuple[str, object]]:
    """Master variables of the laser tracker (m, base_link)."""
    return {name: ("Real", 0.0) for name in TRACKER_VARIABLES}


def cell_variables() -> dict[str, tuple[str, object]]:
    """All master variables of a cell (fieldbus + tracker)."""
    return {**bus_variables(), **tracker_variables()}


def cell_connections(drive_variables: Mapping[str, Collection[str]] | None = None) -> list[str]:
    """The connections the cell generates, in the order the master makes them: per axis, drive
    torque -> plant, plant motor angle and speed -> drive encoder, ``bus.*[i]`` -> the drive's
    set-point inputs: the required ones (``target_position``, ``controlword``) and, where
    ``drive_variables`` (drive instance -> its variable names) says the drive FMU has them, the
    optional ones (torque offset, fault code, the CiA 402 modes of operation: 66 connections in
    all with the servo_drive FMU, 30 with a drive of the minimal interface)."""
    out = []
    for i, drive in enumerate(DRIVES, start=1):
        out += [f"{drive}.tau_out -> {PLANT}.tau[{i}]", f"{PLANT}.q_motor[{i}] -> {drive}.q_meas",
                f"{PLANT}.qd_motor[{i}] -> {drive}.qd_meas"]
        have = set(drive_variables.get(drive, ())) if drive_variables is not None else set()
        out += [f"bus.{name}[{i}] -> {drive}.{name}" for name in BUS_REAL + BUS_INTEGER
                if name in REQUIRED_DRIVE_VARIABLES or name in have]
    return out


def drive_variables_of(fmus: Sequence[Mapping[str, Any]]) -> dict[str, set[str]]:
    """Drive instance -> the variable names of its FMU (from the ``[[fmus]]`` tables' paths)."""
    from cosim.master import load_model_description
    from fmus.fmu import variables_of

    return {f["name"]: set(variables_of(load_model_description(f["path"]))) for f in fmus if f["name"] in DRIVES}


def _destination(text: str) -> str | None:
    try:
        return parse_connection(text).destination
    except ValueError:
        return None  # reported by the scenario checks at its index


def merged_connections(scenario_connections: Sequence[str],
                       drive_variables: Mapping[str, Collection[str]] | None = None) -> list[str]:
    """The connections of a cell: the scenario's own (in its order; a connection into an input the
    cell drives replaces the generated one; one identical to a generated one is kept once),
    then the generated ones not replaced (:func:`cell_connections` with ``drive_variables``)."""
    own = list(dict.fromkeys(scenario_connections))
    taken = {_destination(text) for text in own}
    return own + [text for text in cell_connections(drive_variables) if _destination(text) not in taken]


RECORDED_SIGNALS: tuple[str, ...] = (
    tuple(f"{PLANT}.q[{i}]" for i in range(1, 7)) + tuple(f"{PLANT}.qd[{i}]" for i in range(1, 7))
    + tuple(f"{d}.tau_out" for d in DRIVES) + tuple(f"{d}.current_actual" for d in DRIVES)
    + tuple(f"{d}.following_error" for d in DRIVES) + TRACKER_VARIABLES
)
"""What every cell records (besides the scenario's [record] signals): joint angles and
speeds of the plant, joint torques and motor currents of the drives, the drives' own
following errors, the tracker's measurement."""

JOB_SET_PLANT_PARAMETERS = ("q0[", "qd0[", "p[", "payload_mass", "payload_com[", "geometric_errors[")
"""Plant parameters the cell sets itself (from the true robot and the start pose)."""


def plant_start_values(true_robot: TrueRobot, q0: Sequence[float]) -> dict[str, float]:
    """Start values of the plant FMU: the true robot's 78 parameters, payload and 39 geometric errors
    (the plant's dynamics run on the true geometry, as the tracker's kinematics do), at rest at ``q0`` (rad)."""
    values: dict[str, float] = {}
    for i, q in enumerate(q0, start=1):
        values[f"q0[{i}]"] = float(q)
        values[f"qd0[{i}]"] = 0.0
    for k, p in enumerate(true_robot.dynamic_parameters, start=1):
        values[f"p[{k}]"] = float(p)
    values["payload_mass"] = float(true_robot.payload[0])
    for i, c in enumerate(true_robot.payload[1:], start=1):
        values[f"payload_com[{i}]"] = float(c)
    for k, e in enumerate(true_robot.geometric_errors, start=1):
        values[f"geometric_errors[{k}]"] = float(e)
    return values


def joint_scaling(parameters: RobotParameters | None = None) -> JointScaling:
    """CiA 402 scaling of the arm's joints (gear ratios, encoder counts, rated torques)."""
    p = parameters or load_parameters()
    return JointScaling(p.gear_ratio, p.encoder_counts_per_motor_rev, p.rated_torque)


def gear_start_values(true_robot: TrueRobot) -> dict[str, float]:
    """The true robot's gear stiffness as plant start values (``stiffness[1..6]``, N m/rad)."""
    if true_robot.gear_stiffness is None:
        return {}
    return {f"stiffness[{i}]": float(k) for i, k in enumerate(true_robot.gear_stiffness, start=1)}


def cell_fmus(doc_fmus: list[dict[str, Any]], true_robot: TrueRobot, q0: Sequence[float]) -> list[dict[str, Any]]:
    """A copy of the scenario's ``[[fmus]]`` with the plant's and drives' start values filled in
    (drive defaults first, then the scenario's own parameters on top). An elastic plant
    (``elastic_joints = 1``) gets the true robot's gear stiffness unless the scenario sets it."""
    fmus = copy.deepcopy(doc_fmus)
    for fmu in fmus:
        if fmu["name"] == PLANT:
            gears = gear_start_values(true_robot) if fmu["parameters"].get("elastic_joints") else {}
            fmu["parameters"] = {**gears, **fmu["parameters"], **plant_start_values(true_robot, q0)}
        elif fmu["name"] in DRIVES:
            axis = DRIVES.index(fmu["name"]) + 1
            fmu["parameters"] = {**drive_start_values(axis), **fmu["parameters"]}
    return fmus


def drive_parameters(doc_fmus: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each drive's effective parameters (defaults of its axis + the scenario's), axis 1..6."""
    by_name = {fmu["name"]: fmu for fmu in doc_fmus}
    return [{**drive_start_values(axis), **by_name[d]["parameters"]} for axis, d in enumerate(DRIVES, start=1)]


def drive_loop_model(doc_fmus: list[dict[str, Any]], period_s: float) -> DriveLoopModel:
    """What the model-based controller knows of the drives' position loops (their Kv,
    speed feed-forward gain and speed-comparison lead), from the effective parameters."""
    params = drive_parameters(doc_fmus)
    for axis, p in enumerate(params, start=1):
        if abs(p["position_sample_time"] - period_s) > 1e-12:
            raise ValueError(f"drive{axis}: position_sample_time = {p['position_sample_time']!r} s, expected the "
                             f"controller period {period_s!r} s for set-point shaping")
    return DriveLoopModel(
        position_kv=np.array([p["position_kv"] for p in params]),
        speed_feedforward_gain=np.array([p["speed_feedforward_gain"] for p in params]),
        lead_s=np.array([speed_comparison_lead(p["position_sample_time"], p["speed_sample_time"],
                                               p["speed_filter_time"]) for p in params]),
        period_s=period_s)
