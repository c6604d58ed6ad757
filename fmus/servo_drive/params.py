"""Load ``drive_params.toml`` and form the servo-drive FMU start values of one axis.

The drive FMU is one axis; the scenario runner instantiates it six times and sets
``drive_start_values(axis)`` as start values. Those combine this file (sample times,
motor model, gains, limits, stop reactions) with ``robot/rx130l_params.toml`` and the
URDF (gear ratio, torque constant, current limit, encoder counts, velocity and effort
limits). All values SI; joint side unless the name says motor.
"""
from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from robot.parameters import RobotParameters, load_parameters

DRIVE_PARAMS_PATH: Path = Path(__file__).resolve().parent / "drive_params.toml"
N_AXES = 6


class DriveParameterError(ValueError):
    """``drive_params.toml`` is missing, unreadable or holds a malformed value."""


# (section, key, length or None for a scalar, rule)
_ENTRIES: tuple[tuple[str, str, int | None, str], ...] = (
    ("sample_times", "current", None, "positive"),
    ("sample_times", "speed", None, "positive"),
    ("sample_times", "position", None, "positive"),
    ("motor", "resistance", N_AXES, "positive"),
    ("motor", "inductance", N_AXES, "positive"),
    ("motor", "back_emf_ratio", None, "positive"),
    ("motor", "bus_voltage", None, "positive"),
    ("tuning", "current_delay_factor", None, "positive"),
    ("tuning", "speed_filter_time", None, "nonnegative"),
    ("tuning", "phase_margin", None, "positive"),
    ("tuning", "inertia_min", N_AXES, "positive"),
    ("tuning", "inertia_max", N_AXES, "positive"),
    ("current_loop", "kp", N_AXES, "positive"),
    ("current_loop", "tn", N_AXES, "positive"),
    ("speed_loop", "kp", N_AXES, "positive"),
    ("speed_loop", "tn", N_AXES, "positive"),
    ("position_loop", "kv", N_AXES, "nonnegative"),
    ("position_loop", "speed_feedforward_gain", None, "nonnegative"),
    ("limits", "velocity_limit_factor", None, "positive"),
    ("protection", "max_torque_factor", None, "positive"),
    ("protection", "max_current_factor", None, "positive"),
    ("protection", "rated_current_factor", None, "positive"),
    ("protection", "peak_current_time", None, "positive"),
    ("protection", "i2t_release", None, "fraction"),
    ("protection", "max_motor_speed_factor", None, "positive"),
    ("protection", "position_limit_margin", None, "nonnegative"),
    ("protection", "following_error_window", None, "nonnegative"),
    ("protection", "following_error_time", None, "nonnegative"),
    ("stops", "standstill_velocity", None, "nonnegative"),
    ("stops", "standstill_time", None, "nonnegative"),
    ("stops", "quick_stop_deceleration", N_AXES, "positive"),
    ("stops", "fault_reaction_deceleration", N_AXES, "positive"),
    ("stops", "quick_stop_option_code", None, "option_code"),
    ("brake", "holding_torque_factor", None, "nonnegative"),
    ("brake", "natural_frequency", None, "positive"),
    ("brake", "damping_ratio", None, "nonnegative"),
    ("brake", "closing_time", None, "nonnegative"),
)


@dataclass(frozen=True)
class DriveParameters:
    """Validated contents of ``drive_params.toml``.

    ``values[("section", "key")]`` is a float or a read-only array of shape (6,);
    ``units`` and ``sources`` map ``"section.key"`` to the file's texts, ``objects`` to the
    CiA 402 object an entry stands for (``"0x6072"``; entries that have one).
    """

    source_path: Path
    values: Mapping[tuple[str, str], Any]
    units: Mapping[str, str]
    sources: Mapping[str, str]
    objects: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))

    def get(self, section: str, key: str) -> Any:
        """The value of ``[section] key`` (float, int or array (6,))."""
        try:
            return self.values[(section, key)]
        except KeyError:
            raise DriveParameterError(f"{self.source_path}: no entry '[{section}] {key}'") from None

    def axis_value(self, section: str, key: str, axis: int) -> float:
        """The value of ``[section] key`` for ``axis`` (1..6); scalars apply to all axes."""
        value = self.get(section, key)
        return float(value) if np.ndim(value) == 0 else float(value[axis - 1])


def load_drive_parameters(path: str | Path | None = None) -> DriveParameters:
    """Load and validate a drive parameter file (default: the nominal ``drive_params.toml``).

    Raises :class:`DriveParameterError` naming the file, the key, the value given and
    what was expected.
    """
    resolved = Path(path or DRIVE_PARAMS_PATH).resolve()
    if not resolved.is_file():
        raise DriveParameterError(f"drive parameter file {str(resolved)!r} does not exist")
    return _load_cached(str(resolved), resolved.stat().st_mtime_ns)


@lru_cache(maxsize=4)
def _load_cached(path: str, _mtime_ns: int) -> DriveParameters:
    try:
        with open(path, "rb") as handle:
            document = tomllib.load(handle)
    except tomllib.TOMLDecodeError as exc:
        raise DriveParameterError(f"drive parameter file {path!r} is not valid TOML: {exc}") from exc
    values: dict[tuple[str, str], Any] = {}
    units: dict[str, str] = {}
    sources: dict[str, str] = {}
    objects: dict[str, str] = {}
    for section, key, length, rule in _ENTRIES:
        where = f"drive parameter file {path!r}: key '[{section}] {key}'"
        table = document.get(section)
        entry = table.get(key) if isinstance(table, dict) else None
        if not isinstance(entry, dict) or "value" not in entry:
            raise DriveParameterError(
                f"{where} = {entry!r}, expected a table {{ value = ..., unit = \"...\", source = \"...\" }}")
        for text_key in ("unit", "source"):
            if not isinstance(entry.get(text_key), str) or not entry[text_key].strip():
                raise DriveParameterError(f"{where}: {text_key} = {entry.get(text_key)!r}, expected a non-empty string")
        values[(section, key)] = _check(where, entry["value"], length, rule)
        units[f"{section}.{key}"] = entry["unit"]
        sources[f"{section}.{key}"] = entry["source"]
        if "object" in entry:
            if not isinstance(entry["object"], str) or not re.fullmatch(r"0x[0-9A-F]{4}", entry["object"]):
                raise DriveParameterError(f"{where}: object = {entry['object']!r}, expected a CiA 402 object "
                                          "index such as \"0x6072\"")
            objects[f"{section}.{key}"] = entry["object"]
    return DriveParameters(Path(path), MappingProxyType(values), MappingProxyType(units), MappingProxyType(sources),
                           MappingProxyType(objects))


def _check(where: str, raw: Any, length: int | None, rule: str) -> Any:
    if rule == "option_code":
        if isinstance(raw, bool) or raw not in (2, 6):
            raise DriveParameterError(f"{where}: value = {raw!r}, expected 2 or 6")
        return int(raw)
    text = {"positive": "finite numbers > 0", "nonnegative": "finite numbers >= 0",
            "fraction": "numbers in (0, 1)"}[rule]
    expected = f"a list of {length} {text}" if length else f"a single number: {text}"
    items = raw if length else [raw]
    if length and (not isinstance(raw, list) or len(raw) != length):
        raise DriveParameterError(f"{where}: value = {raw!r}, expected {expected}")
    for item in items:
        bad = isinstance(item, bool) or not isinstance(item, (int, float)) or not math.isfinite(item)
        if bad or (rule == "positive" and item <= 0) or (rule == "nonnegative" and item < 0) or (
                rule == "fraction" and not 0 < item < 1):
            raise DriveParameterError(f"{where}: value = {raw!r}, expected {expected}")
    if not length:
        return float(raw)
    array = np.asarray(raw, dtype=float)
    array.setflags(write=False)
    return array


def drive_start_values(axis: int, robot: RobotParameters | None = None,
                       drive: DriveParameters | None = None) -> dict[str, float | int]:
    """Start values of every servo_drive FMU parameter for ``axis`` (1..6).

    Keys are the FMU variable names (see docs/explanation/fmus.md); values SI, joint side unless
    the name says otherwise.
    """
    if isinstance(axis, bool) or axis not in range(1, N_AXES + 1):
        raise DriveParameterError(f"axis = {axis!r}, expected an integer 1..6")
    robot = robot or load_parameters()
    drive = drive or load_drive_parameters()
    j = axis - 1

    def d(section: str, key: str) -> float:
        return drive.axis_value(section, key, axis)

    torque_limit = d("protection", "max_torque_factor") * float(robot.effort_limit[j])
    motor_torque = float(robot.gear_ratio[j]) * float(robot.torque_constant[j])  # N m joint side per A
    margin = d("protection", "position_limit_margin")
    j_max = d("tuning", "inertia_max")
    brake_stiffness = j_max * (2.0 * math.pi * d("brake", "natural_frequency")) ** 2
    return {
        "gear_ratio": float(robot.gear_ratio[j]),
        "torque_constant": float(robot.torque_constant[j]),
        "back_emf_constant": d("motor", "back_emf_ratio") * float(robot.torque_constant[j]),
        "current_limit": d("protection", "max_current_factor") * float(robot.current_limit[j]),
        "torque_limit": torque_limit,
        "velocity_limit": d("limits", "velocity_limit_factor") * float(robot.velocity_limit[j]),
        "resistance": d("motor", "resistance"),
        "inductance": d("motor", "inductance"),
        "bus_voltage": d("motor", "bus_voltage"),
        "current_kp": d("current_loop", "kp"),
        "current_tn": d("current_loop", "tn"),
        "speed_kp": d("speed_loop", "kp"),
        "speed_tn": d("speed_loop", "tn"),
        "speed_filter_time": d("tuning", "speed_filter_time"),
        "position_kv": d("position_loop", "kv"),
        "speed_feedforward_gain": d("position_loop", "speed_feedforward_gain"),
        "current_sample_time": d("sample_times", "current"),
        "speed_sample_time": d("sample_times", "speed"),
        "position_sample_time": d("sample_times", "position"),
        "quick_stop_deceleration": d("stops", "quick_stop_deceleration"),
        "fault_reaction_deceleration": d("stops", "fault_reaction_deceleration"),
        "following_error_window": d("protection", "following_error_window"),
        "standstill_velocity": d("stops", "standstill_velocity"),
        "standstill_time": d("stops", "standstill_time"),
        "brake_holding_torque": d("brake", "holding_torque_factor") * torque_limit,
        "brake_stiffness": brake_stiffness,
        "brake_damping": 2.0 * d("brake", "damping_ratio") * math.sqrt(brake_stiffness * j_max),
        "encoder_counts_per_rev": int(robot.encoder_counts_per_motor_rev),
        "quick_stop_option_code": int(drive.get("stops", "quick_stop_option_code")),
        "brake_closing_time": d("brake", "closing_time"),
        "rated_current": d("protection", "rated_current_factor") * float(robot.rated_torque[j]) / motor_torque,
        "peak_current_time": d("protection", "peak_current_time"),
        "i2t_release": d("protection", "i2t_release"),
        "max_motor_speed": d("protection", "max_motor_speed_factor") * float(robot.velocity_limit[j]),
        "position_limit_min": float(robot.position_lower[j]) - margin,
        "position_limit_max": float(robot.position_upper[j]) + margin,
        "following_error_time": d("protection", "following_error_time"),
    }
