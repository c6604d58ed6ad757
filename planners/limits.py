"""Joint limits of a planning problem (plain data), and the error every planner raises for
malformed input. Kept apart from :mod:`planners.base` so that :mod:`planners.trajectory`
can check a trajectory against limits without importing the planner interface (which
imports the trajectory).

Units: SI, joint side (rad, rad/s, rad/s^2, rad/s^3, N m, N m/s).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from robot.parameters import N_JOINTS, load_parameters

LIMIT_KINDS: tuple[str, ...] = ("velocity", "acceleration", "jerk", "torque", "torque_rate")


class PlannerInputError(ValueError):
    """A planner problem or argument is malformed (wrong shape, negative limit, ...)."""


def _as_joint_vector(value: Any, name: str, allow_inf: bool = True) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = np.full(N_JOINTS, float(arr))
    if arr.shape != (N_JOINTS,):
        raise PlannerInputError(f"{name}: expected {N_JOINTS} values (one per joint), got shape {arr.shape}")
    if np.any(np.isnan(arr)) or (not allow_inf and not np.all(np.isfinite(arr))):
        raise PlannerInputError(f"{name}: expected finite numbers, got {arr.tolist()}")
    return arr


@dataclass(frozen=True)
class JointLimits:
    """Symmetric joint limits (|value| <= limit) plus the position range, joint side.

    velocity [rad/s], acceleration [rad/s^2], jerk [rad/s^3], torque [N m],
    torque_rate [N m/s], position_lower/position_upper [rad]. ``math.inf`` switches a
    limit off (e.g. ``limits.replace(jerk=inf, torque_rate=inf)`` for a problem that
    TOPP-RA can represent). Use :meth:`from_robot` for the RX130L values
    (URDF: position, velocity, effort; rx130l_params.toml [limits]: acceleration,
    jerk, torque_rate).
    """

    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray
    torque: np.ndarray
    torque_rate: np.ndarray
    position_lower: np.ndarray = field(default_factory=lambda: np.full(N_JOINTS, -math.inf))
    position_upper: np.ndarray = field(default_factory=lambda: np.full(N_JOINTS, math.inf))

    def __post_init__(self) -> None:
        for name in LIMIT_KINDS:
            arr = _as_joint_vector(getattr(self, name), f"JointLimits.{name}")
            if np.any(arr <= 0.0):
                raise PlannerInputError(f"JointLimits.{name}: expected positive limits, got {arr.tolist()}")
            object.__setattr__(self, name, arr)
        lo = _as_joint_vector(self.position_lower, "JointLimits.position_lower")
        hi = _as_joint_vector(self.position_upper, "JointLimits.position_upper")
        if np.any(lo >= hi):
            raise PlannerInputError(
                f"JointLimits: position_lower {lo.tolist()} must be below position_upper {hi.tolist()}"
            )
        object.__setattr__(self, "position_lower", lo)
        object.__setattr__(self, "position_upper", hi)

    def replace(self, **changes: Any) -> "JointLimits":
        """Return a copy with some limits replaced (scalars apply to all joints)."""
        return dataclasses.replace(self, **changes)

    def scaled(self, factor: float, kinds: tuple[str, ...] = ("velocity", "acceleration", "jerk")) -> "JointLimits":
        """Return a copy with the named limits multiplied by ``factor`` (> 0)."""
        if not factor > 0.0:
            raise PlannerInputError(f"JointLimits.scaled: factor must be > 0, got {factor!r}")
        return self.replace(**{k: getattr(self, k) * factor for k in kinds})

    def active(self, kind: str) -> bool:
        """True when at least one joint has a finite limit of this kind."""
        return bool(np.any(np.isfinite(getattr(self, kind))))

    @classmethod
    def from_robot(cls, params: Any | None = None) -> "JointLimits":
        """The RX130L limits from the robot description (URDF + rx130l_params.toml).

        ``params`` is a ``robot.parameters.RobotParameters``; by default the nominal file.
        """
        params = params or load_parameters()
        return cls(
            velocity=np.array(params.velocity_limit),
            acceleration=np.array(params.acceleration_limit),
            jerk=np.array(params.jerk_limit),
            torque=np.array(params.effort_limit),
            torque_rate=np.array(params.torque_rate_limit),
            position_lower=np.array(params.position_lower),
            position_upper=np.array(params.position_upper),
        )


__all__ = ["LIMIT_KINDS", "JointLimits", "N_JOINTS", "PlannerInputError"]
