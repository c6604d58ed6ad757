"""Load and validate the drive-train parameter file ``rx130l_params.toml``.

Every quantity in the file is a TOML table ``{value, unit, source}``. This module
checks the shape, type and sign of every value and that each carries a unit and a
source, and returns one frozen :class:`RobotParameters`. For convenience the joint
position, velocity and effort limits of the URDF named in ``[meta] urdf`` are
attached too, so a caller needs a single object for all robot numbers.

All joint quantities are joint side (torques in N m, speeds in rad/s, inertias in
kg m^2) unless the name says motor side; arrays have shape (6,), joint 1 first.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from robot.description import PARAMS_PATH, RobotDescriptionError, load_model
from robot.joints import N_JOINTS


class ParameterFileError(ValueError):
    """The parameter file is missing, unreadable or holds a malformed value."""


@dataclass(frozen=True)
class _Spec:
    """What one ``[section] key`` entry must hold."""

    section: str
    key: str
    field: str
    length: int | None  # None: a scalar
    rule: str  # "positive", "nonnegative", "finite" or "positive_int"


_SPECS: tuple[_Spec, ...] = (
    _Spec("drive_train", "gear_ratio", "gear_ratio", N_JOINTS, "positive"),
    _Spec("drive_train", "rotor_inertia", "rotor_inertia", N_JOINTS, "nonnegative"),
    _Spec("drive_train", "torque_constant", "torque_constant", N_JOINTS, "positive"),
    _Spec("drive_train", "rated_torque", "rated_torque", N_JOINTS, "positive"),
    _Spec("drive_train", "current_limit", "current_limit", N_JOINTS, "positive"),
    _Spec("drive_train", "encoder_counts_per_motor_rev", "encoder_counts_per_motor_rev", None,
          "positive_int"),
    _Spec("friction", "viscous", "viscous", N_JOINTS, "nonnegative"),
    _Spec("friction", "coulomb", "coulomb", N_JOINTS, "nonnegative"),
    _Spec("friction", "coulomb_smoothing_velocity", "coulomb_smoothing_velocity", None, "positive"),
    _Spec("limits", "acceleration", "acceleration_limit", N_JOINTS, "positive"),
    _Spec("limits", "jerk", "jerk_limit", N_JOINTS, "positive"),
    _Spec("limits", "torque_rate", "torque_rate_limit", N_JOINTS, "positive"),
    _Spec("payload", "mass", "payload_mass", None, "nonnegative"),
    _Spec("payload", "center_of_mass", "payload_com", 3, "finite"),
    _Spec("payload", "rated_mass", "payload_rated_mass", None, "positive"),
    _Spec("elastic", "stiffness", "stiffness", N_JOINTS, "positive"),
    _Spec("elastic", "stiffness_cubic", "stiffness_cubic", N_JOINTS, "nonnegative"),
    _Spec("elastic", "damping", "gear_damping", N_JOINTS, "nonnegative"),
    _Spec("elastic", "backlash", "backlash", N_JOINTS, "backlash"),
    _Spec("elastic", "motor_friction_share", "motor_friction_share", N_JOINTS, "fraction"),
    _Spec("elastic", "stribeck_torque", "stribeck_torque", N_JOINTS, "nonnegative"),
    _Spec("elastic", "stribeck_velocity", "stribeck_velocity", N_JOINTS, "positive"),
    _Spec("end_stops", "margin", "end_stop_margin", N_JOINTS, "nonnegative"),
    _Spec("end_stops", "stiffness", "end_stop_stiffness", N_JOINTS, "positive"),
    _Spec("end_stops", "damping", "end_stop_damping", N_JOINTS, "nonnegative"),
)

MAX_BACKLASH = 1e-3
"""rad: the widest lost-motion band a precision robot reducer plausibly has (3.4 arcmin;
preloaded RV and Harmonic Drive reducers specify <= 1 arcmin)."""

_RULE_TEXT = {
    "positive": "finite numbers > 0",
    "nonnegative": "finite numbers >= 0",
    "finite": "finite numbers",
    "positive_int": "an integer > 0",
    "fraction": "numbers in [0, 1]",
    "backlash": "numbers in [0, 1e-3] rad (wider lost motion is implausible for a robot reducer)",
}


@dataclass(frozen=True)
class RobotParameters:
    """Validated contents of ``rx130l_params.toml`` plus the URDF joint limits.

    Arrays are read-only numpy float arrays of shape (6,) (``payload_com``: (3,)).
    ``units`` and ``sources`` map ``"section.key"`` to the file's unit and source text.
    """

    source_path: Path
    urdf_path: Path
    flange_frame: str
    gear_ratio: np.ndarray  # motor rev per joint rev
    rotor_inertia: np.ndarray  # kg m^2, joint side (J_motor * ratio^2)
    torque_constant: np.ndarray  # N m / A, motor side
    rated_torque: np.ndarray  # N m, joint side
    current_limit: np.ndarray  # A, motor phase current peak
    encoder_counts_per_motor_rev: int
    viscous: np.ndarray  # N m s / rad
    coulomb: np.ndarray  # N m
    coulomb_smoothing_velocity: float  # rad/s, tanh width of the Coulomb term
    acceleration_limit: np.ndarray  # rad/s^2
    jerk_limit: np.ndarray  # rad/s^3
    torque_rate_limit: np.ndarray  # N m / s
    payload_mass: float  # kg, nominal payload rigidly attached to the flange
    payload_com: np.ndarray  # m, payload centre of mass in the flange (tool0) frame
    payload_rated_mass: float  # kg
    stiffness: np.ndarray  # N m / rad, gear stiffness (joint side, elastic plant)
    stiffness_cubic: np.ndarray  # N m / rad^3, stiffening term of the gear
    gear_damping: np.ndarray  # N m s / rad, damping across the gear
    backlash: np.ndarray  # rad, total lost-motion band width of the gear
    motor_friction_share: np.ndarray  # 1, fraction of viscous/Coulomb friction on the motor side
    stribeck_torque: np.ndarray  # N m, static minus Coulomb friction (motor side, joint units)
    stribeck_velocity: np.ndarray  # rad/s, Stribeck velocity (joint side)
    end_stop_margin: np.ndarray  # rad, mechanical end stop beyond each end of the URDF range
    end_stop_stiffness: np.ndarray  # N m / rad, end-stop contact stiffness (joint side)
    end_stop_damping: np.ndarray  # N m s / rad, end-stop contact damping (joint side)
    position_lower: np.ndarray  # rad, from the URDF
    position_upper: np.ndarray  # rad, from the URDF
    velocity_limit: np.ndarray  # rad/s, from the URDF
    effort_limit: np.ndarray  # N m, from the URDF
    units: Mapping[str, str]
    sources: Mapping[str, str]

    @property
    def end_stop_lower(self) -> np.ndarray:
        """rad: the lower mechanical end stop of each joint (URDF lower limit - margin)."""
        return self.position_lower - self.end_stop_margin

    @property
    def end_stop_upper(self) -> np.ndarray:
        """rad: the upper mechanical end stop of each joint (URDF upper limit + margin)."""
        return self.position_upper + self.end_stop_margin

    @property
    def payload(self) -> np.ndarray:
        """Nominal payload as ``[mass kg, cx, cy, cz m in tool0]``, shape (4,)."""
        return np.concatenate(([self.payload_mass], self.payload_com))


def load_parameters(path: str | Path | None = None) -> RobotParameters:
    """Load and validate a parameter file (default: the nominal ``rx130l_params.toml``).

    The URDF named in ``[meta] urdf`` (relative to the parameter file) supplies the
    position, velocity and effort limits. Raises :class:`ParameterFileError` naming the
    file, the key, the value given and what was expected.
    """
    resolved = Path(path or PARAMS_PATH).resolve()
    if not resolved.is_file():
        raise ParameterFileError(f"parameter file {str(resolved)!r} does not exist")
    return _load_cached(str(resolved), resolved.stat().st_mtime_ns)


@lru_cache(maxsize=8)
def _load_cached(path: str, _mtime_ns: int) -> RobotParameters:
    try:
        with open(path, "rb") as handle:
            document = tomllib.load(handle)
    except tomllib.TOMLDecodeError as exc:
        raise ParameterFileError(f"parameter file {path!r} is not valid TOML: {exc}") from exc

    fields: dict[str, Any] = {}
    units: dict[str, str] = {}
    sources: dict[str, str] = {}
    for spec in _SPECS:
        value, unit, source = _read_entry(path, document, spec)
        fields[spec.field] = value
        units[f"{spec.section}.{spec.key}"] = unit
        sources[f"{spec.section}.{spec.key}"] = source

    meta = _section(path, document, "meta")
    urdf_name = _meta_string(path, meta, "urdf")
    flange_frame = _meta_string(path, meta, "flange_frame")
    urdf_path = (Path(path).parent / urdf_name).resolve()
    try:
        model = load_model(urdf_path)
    except RobotDescriptionError as exc:
        raise ParameterFileError(f"parameter file {path!r}: key '[meta] urdf' = {urdf_name!r}: {exc}") from exc
    if not model.existFrame(flange_frame):
        raise ParameterFileError(
            f"parameter file {path!r}: key '[meta] flange_frame' = {flange_frame!r}, "
            f"expected a frame of {str(urdf_path)!r}"
        )

    return RobotParameters(
        source_path=Path(path),
        urdf_path=urdf_path,
        flange_frame=flange_frame,
        position_lower=_frozen(model.lowerPositionLimit),
        position_upper=_frozen(model.upperPositionLimit),
        velocity_limit=_frozen(model.velocityLimit),
        effort_limit=_frozen(model.effortLimit),
        units=MappingProxyType(units),
        sources=MappingProxyType(sources),
        **fields,
    )


def _section(path: str, document: dict, name: str) -> dict:
    section = document.get(name)
    if not isinstance(section, dict):
        raise ParameterFileError(
            f"parameter file {path!r}: section [{name}] is missing or not a table "
            f"(got {section!r}), expected a [{name}] table"
        )
    return section


def _meta_string(path: str, meta: dict, key: str) -> str:
    value = meta.get(key)
    if not isinstance(value, str) or not value:
        raise ParameterFileError(
            f"parameter file {path!r}: key '[meta] {key}' = {value!r}, expected a non-empty string"
        )
    return value


def _read_entry(path: str, document: dict, spec: _Spec) -> tuple[Any, str, str]:
    where = f"parameter file {path!r}: key '[{spec.section}] {spec.key}'"
    entry = _section(path, document, spec.section).get(spec.key)
    if not isinstance(entry, dict):
        raise ParameterFileError(
            f"{where} = {entry!r}, expected a table {{ value = ..., unit = \"...\", source = \"...\" }}"
        )
    for text_key in ("unit", "source"):
        text = entry.get(text_key)
        if not isinstance(text, str) or not text.strip():
            raise ParameterFileError(f"{where}: {text_key} = {text!r}, expected a non-empty string")
    if "value" not in entry:
        raise ParameterFileError(f"{where}: no 'value' given, expected {_expected(spec)}")
    return _check_value(where, entry["value"], spec), entry["unit"], entry["source"]


def _expected(spec: _Spec) -> str:
    if spec.rule == "positive_int":
        return _RULE_TEXT[spec.rule]
    if spec.length is None:
        return "a single number: " + _RULE_TEXT[spec.rule]
    return f"a list of {spec.length} {_RULE_TEXT[spec.rule]}"


def _check_value(where: str, raw: Any, spec: _Spec) -> Any:
    bad = ParameterFileError(f"{where}: value = {raw!r}, expected {_expected(spec)}")
    if spec.rule == "positive_int":
        if isinstance(raw, bool) or not isinstance(raw, int) or raw <= 0:
            raise bad
        return raw
    items = [raw] if spec.length is None else raw
    if spec.length is not None and (not isinstance(raw, list) or len(raw) != spec.length):
        raise bad
    for item in items:
        if isinstance(item, bool) or not isinstance(item, (int, float)) or not math.isfinite(item):
            raise bad
        if spec.rule == "positive" and item <= 0 or spec.rule == "nonnegative" and item < 0:
            raise bad
        if spec.rule == "fraction" and not 0 <= item <= 1 or spec.rule == "backlash" and not 0 <= item <= MAX_BACKLASH:
            raise bad
    if spec.length is None:
        return float(raw)
    return _frozen(np.asarray(raw, dtype=float))


def _frozen(array: np.ndarray) -> np.ndarray:
    out = np.array(array, dtype=float, copy=True)
    out.setflags(write=False)
    return out
