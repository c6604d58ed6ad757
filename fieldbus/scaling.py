"""Scaling and quantisation between SI joint quantities and CiA 402 telegram units.

The one place where rad, rad/s and N·m become encoder counts and per-mille torque:

* position: ``counts = round(q * counts_per_rad)`` with
  ``counts_per_rad = encoder_counts_per_motor_rev * gear_ratio / (2 pi)`` (the encoder
  sits on the motor; ``q`` is the joint angle in rad). INT32 (0x607A, 0x6064).
* velocity: the same counts per second (0x606C, INT32).
* torque: ``units = round(tau / rated_torque * torque_units_per_rated)``; with the
  CiA 402 default of 1000 units per rated torque one unit is 0.1 % of rated torque
  (0x60B2 torque offset, 0x6077 torque actual, INT16). ``tau`` and ``rated_torque`` are
  joint side; the percentage is the same on the motor side (gear losses neglected).

Rounding is to the nearest integer, ties upwards (``floor(x + 0.5)``, the same in the
vector and the scalar encoders), so a value decoded and encoded again returns the same
integer, and ``decode(encode(x))`` is within half a count of ``x``. Values beyond the integer range saturate at its limits; the
``*_saturations`` counters of :class:`JointScaling` say how often that happened.

The gear ratios, encoder resolution and rated torques come from the caller
(robot/rx130l_params.toml, loaded by the robot package): fieldbus imports no robot code.
"""
from __future__ import annotations

import math
from math import floor
from collections.abc import Sequence

import numpy as np

from fieldbus.errors import ScalingError
from fieldbus.telegrams import INT16_MAX, INT16_MIN, INT32_MAX, INT32_MIN

DEFAULT_TORQUE_UNITS_PER_RATED = 1000  # CiA 402: per thousand of rated torque


def _vector(name: str, values: float | Sequence[float] | np.ndarray, joints: int | None) -> np.ndarray:
    array = np.atleast_1d(np.asarray(values, dtype=float))
    if array.ndim != 1:
        raise ScalingError(f"{name} = {values!r}: expected a number or one number per joint")
    if joints is not None and array.size == 1:
        array = np.full(joints, float(array[0]))
    if joints is not None and array.size != joints:
        raise ScalingError(f"{name} has {array.size} entries: expected {joints} (one per joint)")
    if not np.all(np.isfinite(array)):
        raise ScalingError(f"{name} = {values!r}: expected finite numbers")
    return array


class JointScaling:
    """Per-joint conversion between SI units and telegram integers.

    Parameters (one value per joint, joint 1 first; scalars are broadcast):
        gear_ratio: motor revolutions per joint revolution (sign = direction), != 0.
        encoder_counts_per_motor_rev: encoder counts per motor revolution, > 0.
        rated_torque: joint-side rated torque in N·m, > 0 (base of the 0.1 % unit).
        torque_units_per_rated: telegram units per rated torque (CiA 402: 1000).
    """

    def __init__(self, gear_ratio: float | Sequence[float] | np.ndarray,
                 encoder_counts_per_motor_rev: float | Sequence[float] | np.ndarray,
                 rated_torque: float | Sequence[float] | np.ndarray,
                 torque_units_per_rated: int = DEFAULT_TORQUE_UNITS_PER_RATED) -> None:
        ratio = _vector("gear_ratio", gear_ratio, None)
        joints = ratio.size
        counts = _vector("encoder_counts_per_motor_rev", encoder_counts_per_motor_rev, joints)
        rated = _vector("rated_torque", rated_torque, joints)
        if np.any(ratio == 0.0):
            raise ScalingError(f"gear_ratio = {ratio.tolist()}: expected non-zero ratios")
        if np.any(counts <= 0.0):
            raise ScalingError(f"encoder_counts_per_motor_rev = {counts.tolist()}: expected > 0")
        if np.any(rated <= 0.0):
            raise ScalingError(f"rated_torque = {rated.tolist()}: expected > 0 N m")
        if not isinstance(torque_units_per_rated, int) or not 0 < torque_units_per_rated <= INT16_MAX:
            raise ScalingError(f"torque_units_per_rated = {torque_units_per_rated!r}: expected an integer in [1, 32767]")
        self.joints = joints
        self.gear_ratio = ratio
        self.encoder_counts_per_motor_rev = counts
        self.rated_torque = rated
        self.torque_units_per_rated = torque_units_per_rated
        #: encoder counts per joint radian, shape (joints,)
        self.counts_per_rad = counts * ratio / (2.0 * math.pi)
        #: joint radians per count
        self.rad_per_count = 1.0 / self.counts_per_rad
        #: torque units per N·m and N·m per unit
        self.units_per_newton_metre = torque_units_per_rated / rated
        self.newton_metre_per_unit = rated / torque_units_per_rated
        self.position_saturations = 0
        self.velocity_saturations = 0
        self.torque_saturations = 0
        # plain-float copies for the scalar hot path
        self._cpr = self.counts_per_rad.tolist()
        self._rpc = self.rad_per_count.tolist()
        self._upn = self.units_per_newton_metre.tolist()
        self._npu = self.newton_metre_per_unit.tolist()

    @classmethod
    def from_mapping(cls, table: dict, joints: int | None = None) -> "JointScaling":
        """Build from ``{"gear_ratio": [...], "encoder_counts_per_motor_rev": n,
        "rated_torque": [...]}`` (bare values, e.g. taken from rx130l_params.toml)."""
        missing = {"gear_ratio", "encoder_counts_per_motor_rev", "rated_torque"} - set(table)
        if missing:
            raise ScalingError(f"scaling table lacks {sorted(missing)}: expected gear_ratio, "
                               "encoder_counts_per_motor_rev, rated_torque")
        scaling = cls(table["gear_ratio"], table["encoder_counts_per_motor_rev"],
                      table["rated_torque"],
                      table.get("torque_units_per_rated", DEFAULT_TORQUE_UNITS_PER_RATED))
        if joints is not None and scaling.joints != joints:
            raise ScalingError(f"scaling has {scaling.joints} joints: expected {joints}")
        return scaling

    # ---------------------------------------------------------------- limits
    @property
    def max_position(self) -> np.ndarray:
        """Largest |joint angle| in rad that the INT32 position telegram can carry."""
        return INT32_MAX * np.abs(self.rad_per_count)

    @property
    def max_torque(self) -> np.ndarray:
        """Largest |torque| in N·m that the INT16 torque telegram can carry."""
        return INT16_MAX * self.newton_metre_per_unit

    # ---------------------------------------------------------------- vectors
    def _encode(self, values: np.ndarray, per_si: np.ndarray, low: int, high: int, counter: str) -> np.ndarray:
        """``floor(values * per_si + 0.5)`` clipped to [low, high] (int64 array); clipped
        entries are added to the saturation counter named ``counter``."""
        raw = np.floor(np.asarray(values, dtype=float) * per_si + 0.5)
        if not np.all(np.isfinite(raw)):
            raise ScalingError(f"cannot encode {raw.tolist()}: expected finite values")
        clipped = np.clip(raw, low, high)
        hits = int(np.count_nonzero(clipped != raw))
        if hits:
            setattr(self, counter, getattr(self, counter) + hits)
        return clipped.astype(np.int64)

    def position_to_counts(self, q: np.ndarray) -> np.ndarray:
        """Joint angles (rad, shape (joints,)) -> INT32 counts (int64 array), saturating."""
        return self._encode(q, self.counts_per_rad, INT32_MIN, INT32_MAX, "position_saturations")

    def counts_to_position(self, counts: np.ndarray) -> np.ndarray:
        """INT32 counts -> joint angles in rad."""
        return np.asarray(counts, dtype=float) * self.rad_per_count

    def velocity_to_counts(self, qd: np.ndarray) -> np.ndarray:
        """Joint velocities (rad/s) -> INT32 counts/s, saturating."""
        return self._encode(qd, self.counts_per_rad, INT32_MIN, INT32_MAX, "velocity_saturations")

    def counts_to_velocity(self, counts_per_s: np.ndarray) -> np.ndarray:
        """INT32 counts/s -> joint velocities in rad/s."""
        return np.asarray(counts_per_s, dtype=float) * self.rad_per_count

    def torque_to_units(self, tau: np.ndarray) -> np.ndarray:
        """Joint torques (N·m) -> INT16 units of rated torque, saturating."""
        return self._encode(tau, self.units_per_newton_metre, INT16_MIN, INT16_MAX, "torque_saturations")

    def units_to_torque(self, units: np.ndarray) -> np.ndarray:
        """INT16 torque units -> joint torques in N·m."""
        return np.asarray(units, dtype=float) * self.newton_metre_per_unit

    def quantise_position(self, q: np.ndarray) -> np.ndarray:
        """What a joint angle becomes after a trip through the position telegram (rad)."""
        return self.counts_to_position(self.position_to_counts(q))

    def quantise_torque(self, tau: np.ndarray) -> np.ndarray:
        """What a torque becomes after a trip through the torque telegram (N·m)."""
        return self.units_to_torque(self.torque_to_units(tau))

    # ---------------------------------------------------------------- scalars
    def _encode_one(self, value: float, per_si: float, low: int, high: int, counter: str) -> int:
        """Scalar :meth:`_encode` (the nodes' fallback when a value leaves the telegram range)."""
        code = floor(value * per_si + 0.5)
        if low <= code <= high:
            return code
        setattr(self, counter, getattr(self, counter) + 1)
        return high if code > 0 else low

    def position_count(self, index: int, q: float) -> int:
        """Scalar ``position_to_counts`` for joint ``index`` (0-based)."""
        return self._encode_one(q, self._cpr[index], INT32_MIN, INT32_MAX, "position_saturations")

    def velocity_count(self, index: int, qd: float) -> int:
        """Scalar ``velocity_to_counts`` for joint ``index`` (0-based)."""
        return self._encode_one(qd, self._cpr[index], INT32_MIN, INT32_MAX, "velocity_saturations")

    def torque_unit(self, index: int, tau: float) -> int:
        """Scalar ``torque_to_units`` for joint ``index`` (0-based)."""
        return self._encode_one(tau, self._upn[index], INT16_MIN, INT16_MAX, "torque_saturations")

    def saturations(self) -> dict[str, int]:
        """How many values were clipped to the telegram range, per quantity."""
        return {"position": self.position_saturations, "velocity": self.velocity_saturations,
                "torque": self.torque_saturations}
