"""The servo drives' object dictionaries with their defaults from the drive's parameter files.

``fieldbus.object_dictionary`` holds the dictionary (one data file) but imports nothing above
the ground floor; this module hands it the values of ``fmus/servo_drive/drive_params.toml`` and
``robot/rx130l_params.toml`` (with the URDF's limits) that its ``param`` keys name: the
servo-drive FMU's start values of the axis (:func:`fmus.servo_drive.params.drive_start_values`,
the values the FMU runs with), the joint's rated torque and position limits.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from fieldbus.config import FieldbusConfig
from fieldbus.object_dictionary import ObjectDictionary, build
from fmus.servo_drive.params import N_AXES, DriveParameters, drive_start_values, load_drive_parameters
from robot.parameters import RobotParameters, load_parameters


def drive_values(axis: int, robot: RobotParameters | None = None, drive: DriveParameters | None = None,
                 overrides: Mapping[str, float] | None = None) -> dict[str, Any]:
    """The SI values the object dictionary of ``axis`` (1..6) takes its defaults from: the FMU's
    start values (``overrides``: a scenario's parameters of that drive on top), ``rated_torque``
    (N·m, joint side)."""
    robot = robot or load_parameters()
    values: dict[str, Any] = drive_start_values(axis, robot, drive or load_drive_parameters())
    values.update(overrides or {})
    j = axis - 1
    values["rated_torque"] = float(robot.rated_torque[j])
    return values


def drive_object_dictionary(axis: int, config: Any = None, robot: RobotParameters | None = None,
                            drive: DriveParameters | None = None,
                            overrides: Mapping[str, float] | None = None) -> ObjectDictionary:
    """The object dictionary of the drive of ``axis`` (1..6), node id = axis; ``config``: the bus's
    ``FieldbusConfig`` (default: ``powerlink_defaults.toml``)."""
    if config is None:
        config = FieldbusConfig.from_dict({})
    robot = robot or load_parameters()
    values = drive_values(axis, robot, drive, overrides)
    j = axis - 1
    counts_per_rad = float(robot.encoder_counts_per_motor_rev) * float(robot.gear_ratio[j]) / (2.0 * math.pi)
    return build(axis, values, counts_per_rad=counts_per_rad, rated_torque=float(robot.rated_torque[j]),
                 config=config)


def drive_object_dictionaries(config: Any = None, robot: RobotParameters | None = None,
                              drive: DriveParameters | None = None) -> list[ObjectDictionary]:
    """The six drives' object dictionaries (nodes 1..6)."""
    return [drive_object_dictionary(axis, config, robot, drive) for axis in range(1, N_AXES + 1)]


__all__ = ["drive_object_dictionaries", "drive_object_dictionary", "drive_values"]
