"""A seeded "true" arm that differs from the nominal model the controller knows.

The true robot has its own 78 dynamic parameters (layout of :mod:`robot.dynamics`),
an optional payload on ``tool0`` and 39 geometric errors (layout of
:mod:`robot.geometric_errors`). The same seed gives the same robot on every machine.

Each link's inertial deviation keeps the body physically consistent: the mass is
scaled by a positive factor, the centre of mass is shifted, and the second moment of
the mass about the centre of mass, ``Sigma_c = tr(I_c)/2 * 1 - I_c`` (positive
semi-definite iff the inertia obeys the triangle inequalities), has its principal
values scaled by positive factors and its principal axes turned by a small rotation.
The new inertia about the joint origin follows from the parallel-axis theorem. So the
pseudo-inertia matrix stays positive definite (:func:`robot.dynamics.is_physically_consistent`).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from robot.dynamics import (
    COULOMB_SLICE, N_PARAMETERS, PARAMETER_NAMES, ROTOR_INERTIA_SLICE, VISCOUS_SLICE, DynamicParameterError,
    RobotDynamics, nominal_parameter_vector,
)
from robot.parameters import RobotParameters, load_parameters

_DYNAMICS_STREAM = 0x64796E  # mixed with the seed: the dynamic deviations' own random stream


# ---------------------------------------------------------------------------
# default deviation magnitudes: the ONE place for these numbers


@dataclass(frozen=True)
class DeviationMagnitudes:
    """Bounds of the uniformly distributed deviations of the true robot from the nominal.

    Source (modelling choice): the differences between CAD/catalogue data and an
    identified arm of this class. Link masses within about 5-10 %, centres of mass a
    few cm, inertias about 10 %; friction changes about 20 % with lubrication and
    temperature; rotor inertias known to about 10 % from motor data sheets.
    Geometric errors use the kinematics engineer's :class:`robot.geometric_errors.ErrorMagnitudes`.
    """

    mass_relative: float = 0.08
    """each link mass times (1 + U(-a, a)), a in 1 (8 %)"""
    com_shift_m: float = 0.02
    """each centre-of-mass component plus U(-a, a), m (2 cm)"""
    inertia_relative: float = 0.10
    """each principal second moment about the centre of mass times (1 + U(-a, a)), on
    top of the mass factor (the mass distribution scales with the mass), 1 (10 %)"""
    inertia_axes_rotation_deg: float = 5.0
    """principal axes turned about a random axis by U(0, a), deg"""
    rotor_inertia_relative: float = 0.10
    """each rotor inertia times (1 + U(-a, a)), 1 (10 %)"""
    viscous_relative: float = 0.20
    """each viscous friction coefficient times (1 + U(-a, a)), 1 (20 %)"""
    coulomb_relative: float = 0.20
    """each Coulomb friction torque times (1 + U(-a, a)), 1 (20 %)"""
    stiffness_relative: float = 0.10
    """each gear stiffness (``[elastic] stiffness`` of the parameter file) times (1 + U(-a, a)),
    1 (10 %): reducer catalogues give typical, not guaranteed, torsional rigidity; the unit-to-
    unit spread and the bearing and housing compliance in series make +-10 % a modest bound"""

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            relative = name.endswith("_relative")
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0.0
                    and (not relative or value < 1.0)):
                expected = "a finite number in [0, 1)" if relative else "a finite number >= 0"
                raise DynamicParameterError(f"DeviationMagnitudes.{name} = {value!r}, expected {expected}")


DEFAULT_DEVIATION_MAGNITUDES = DeviationMagnitudes()


@dataclass(frozen=True, eq=False)
class TrueRobot:
    """The true arm of one seed.

    ``dynamic_parameters``: (78,) layout of :data:`robot.dynamics.PARAMETER_NAMES`, no payload;
    ``payload``: (4,) ``[mass kg, cx, cy, cz m in tool0]``; ``geometric_errors``: (39,) m and
    rad, layout of :data:`robot.geometric_errors.ERROR_PARAMETER_NAMES`.
    """

    dynamic_parameters: np.ndarray
    payload: np.ndarray
    geometric_errors: np.ndarray
    seed: int
    magnitudes: DeviationMagnitudes = field(default=DEFAULT_DEVIATION_MAGNITUDES)
    gear_stiffness: np.ndarray | None = None
    """(6,) N m/rad, the true gears' stiffness (used by the elastic plant; None: nominal)"""

    def kinematic_model(self) -> pin.Model:
        """Pinocchio model with the geometric errors folded into the placements (nominal inertias)."""
        from robot.geometric_errors import error_model

        return error_model(self.geometric_errors)

    def dynamics(self, parameters: RobotParameters | None = None) -> RobotDynamics:
        """Numeric dynamics of the true arm: true inertias, friction, payload and geometry."""
        return RobotDynamics(self.dynamic_parameters, self.payload, model=self.kinematic_model(),
                             parameters=parameters)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary: seed, magnitudes, payload and every parameter by name."""
        from robot.geometric_errors import errors_as_dict

        return {
            "seed": self.seed,
            "magnitudes": asdict(self.magnitudes),
            "payload": {"mass_kg": float(self.payload[0]), "com_in_tool0_m": self.payload[1:].tolist()},
            "dynamic_parameters": dict(zip(PARAMETER_NAMES, self.dynamic_parameters.tolist())),
            "geometric_errors": errors_as_dict(self.geometric_errors),
            **({"gear_stiffness": self.gear_stiffness.tolist()} if self.gear_stiffness is not None else {}),
        }


def make_true_robot(seed: int, payload: ArrayLike | None = None,
                    magnitudes: DeviationMagnitudes = DEFAULT_DEVIATION_MAGNITUDES, *,
                    geometric_magnitudes: Any | None = None,
                    nominal_parameters: ArrayLike | None = None,
                    parameters: RobotParameters | None = None) -> TrueRobot:
    """Draw the true robot of ``seed`` (a non-negative int).

    ``payload`` ``[mass kg, cx, cy, cz m in tool0]`` defaults to no payload;
    ``geometric_magnitudes`` (a :class:`robot.geometric_errors.ErrorMagnitudes`) defaults to
    that module's defaults; ``nominal_parameters`` (78,) default to the nominal arm.
    The geometric errors equal ``robot.geometric_errors.random_geometric_errors(seed)``.
    """
    from robot.geometric_errors import DEFAULT_ERROR_MAGNITUDES, random_geometric_errors

    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise DynamicParameterError(f"seed = {seed!r}, expected a non-negative integer")
    seed = int(seed)
    nominal = (nominal_parameter_vector(parameters=parameters) if nominal_parameters is None
               else np.asarray(nominal_parameters, dtype=float))
    if nominal.shape != (N_PARAMETERS,) or not np.all(np.isfinite(nominal)):
        raise DynamicParameterError(
            f"nominal_parameters has shape {nominal.shape}, expected {N_PARAMETERS} finite numbers"
        )
    load = np.zeros(4) if payload is None else np.asarray(payload, dtype=float)
    if load.shape != (4,) or not np.all(np.isfinite(load)) or load[0] < 0.0:
        raise DynamicParameterError(f"payload = {payload!r}, expected [mass >= 0 kg, cx, cy, cz m in tool0]")

    rng = np.random.default_rng([seed, _DYNAMICS_STREAM])
    true_p = nominal.copy()
    for link in range(6):
        block = slice(10 * link, 10 * link + 10)
        true_p[block] = perturb_link(nominal[block], rng, magnitudes)
    true_p[ROTOR_INERTIA_SLICE] *= 1.0 + rng.uniform(-1, 1, 6) * magnitudes.rotor_inertia_relative
    true_p[VISCOUS_SLICE] *= 1.0 + rng.uniform(-1, 1, 6) * magnitudes.viscous_relative
    true_p[COULOMB_SLICE] *= 1.0 + rng.uniform(-1, 1, 6) * magnitudes.coulomb_relative
    # drawn last: the deviations above are the same as before the gears had a true stiffness
    robot = parameters or load_parameters()
    stiffness = np.asarray(robot.stiffness, dtype=float) * (
        1.0 + rng.uniform(-1, 1, 6) * magnitudes.stiffness_relative)

    geometric = random_geometric_errors(
        seed, DEFAULT_ERROR_MAGNITUDES if geometric_magnitudes is None else geometric_magnitudes)
    return TrueRobot(_read_only(true_p), _read_only(load), _read_only(np.asarray(geometric, dtype=float)),
                     seed, magnitudes, _read_only(stiffness))


def perturb_link(link_parameters_10: ArrayLike, rng: np.random.Generator,
                 magnitudes: DeviationMagnitudes = DEFAULT_DEVIATION_MAGNITUDES) -> np.ndarray:
    """A physically consistent random deviation of one link's 10 inertial parameters.

    Draws (in this order) the mass factor, the centre-of-mass shift (3), the principal
    second-moment factors (3) and the principal-axes rotation (axis 3, angle 1).
    """
    inertia = pin.Inertia.FromDynamicParameters(np.asarray(link_parameters_10, dtype=float))
    mass, com, inertia_c = inertia.mass, np.array(inertia.lever), np.array(inertia.inertia)
    if not mass > 0.0:
        raise DynamicParameterError(f"link mass = {mass!r}, expected > 0 to perturb a link")
    second_moment = 0.5 * np.trace(inertia_c) * np.eye(3) - inertia_c
    moments, axes = np.linalg.eigh(second_moment)
    if moments.min() < -1e-12 * max(moments.max(), 1e-300):
        raise DynamicParameterError(
            f"link inertia about the centre of mass {inertia_c.tolist()} breaks the triangle inequality"
        )
    moments = np.clip(moments, 0.0, None)

    mass_factor = 1.0 + rng.uniform(-1, 1) * magnitudes.mass_relative
    new_com = com + rng.uniform(-1, 1, 3) * magnitudes.com_shift_m
    new_moments = moments * mass_factor * (1.0 + rng.uniform(-1, 1, 3) * magnitudes.inertia_relative)
    direction = rng.normal(size=3)
    angle = math.radians(magnitudes.inertia_axes_rotation_deg) * rng.uniform(0, 1)
    turn = Rotation.from_rotvec(angle * direction / np.linalg.norm(direction)).as_matrix()
    new_axes = turn @ axes
    new_second_moment = new_axes @ np.diag(new_moments) @ new_axes.T
    new_inertia_c = np.trace(new_second_moment) * np.eye(3) - new_second_moment
    new_inertia_c = 0.5 * (new_inertia_c + new_inertia_c.T)
    return pin.Inertia(mass * mass_factor, new_com, new_inertia_c).toDynamicParameters()


def _read_only(array: np.ndarray) -> np.ndarray:
    out = np.array(array, dtype=float, copy=True)
    out.setflags(write=False)
    return out
