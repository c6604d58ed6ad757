"""Is a geometric calibration believable? Checks of its inputs and of the fit, with the likely cause.

A least-squares fit always returns numbers. ``python -m cosim calibrate`` writes a URDF
only when :func:`assess_calibration` finds nothing wrong; otherwise it fails (exit 3)
with the problems and the likely cause found by :func:`likely_cause`:

* the fit did not converge;
* the normalised residual ``sigma_hat`` (weighted residual RMS over the declared
  tracker noise, ~1 for a correct model and noise) is above :data:`MAX_SIGMA_HAT`;
* an identified error is far beyond what an assembled arm has: above
  :data:`MAX_LENGTH_ERROR_M` for a length / base offset, :data:`MAX_ANGLE_ERROR_RAD` for
  an encoder offset or tilt (a calibrated arm deviates by millimetres and tenths of a
  degree, robot/geometric_errors.py ErrorMagnitudes);
* joint angles outside the joint limits of the robot description.

The likely cause is found by trying the usual mistakes on the nominal model: two
position columns swapped, two joint columns swapped, poses beyond the arm's reach
(the measured point farther from the base than :data:`REACH_MARGIN` times the
farthest flange position), a missing base registration (a large constant offset).
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

MAX_SIGMA_HAT = 10.0
"""Largest accepted normalised residual: the fit's weighted residual RMS is at most ten times the
declared tracker noise (a correct fit gives ~1; a noisier tracker than declared: give
--position-sigma-mm)."""

MAX_LENGTH_ERROR_M = 0.05
"""Largest believable identified length or base error, m (50 mm: 50x the assembly tolerance of
robot/geometric_errors.py ErrorMagnitudes.length_mm, 25x its base_mm)."""

MAX_ANGLE_ERROR_RAD = math.radians(5.0)
"""Largest believable identified encoder offset or axis tilt, rad (5 deg: 25x the 0.2 deg zeroing
tolerance, 50x the 0.1 deg tilt tolerance of ErrorMagnitudes)."""

JOINT_LIMIT_TOLERANCE_RAD = math.radians(1.0)
"""Joint angles may exceed the URDF limits by this much (encoder offsets, rounding), rad."""

REACH_MARGIN = 1.25
"""A measured flange point farther from the base origin than this times the farthest flange point of
the arm (over its joint ranges) is out of reach."""

IMPROVEMENT_FACTOR = 5.0
"""A guessed mistake explains the data when undoing it lowers the nominal-model residual this much."""


@dataclass(frozen=True)
class Assessment:
    """``problems``: what is wrong (empty: plausible); ``cause``: the likely cause in words ("" if none found)."""

    problems: tuple[str, ...]
    cause: str

    @property
    def ok(self) -> bool:
        return not self.problems

    def message(self) -> str:
        """One line: the problems, then the likely cause."""
        text = "; ".join(self.problems)
        return text + (f". Likely cause: {self.cause}" if self.cause else "")


def _rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(np.asarray(a) ** 2, axis=1))))


def _reach(model) -> float:
    """Farthest flange distance from the base origin over random configurations within the limits (m)."""
    from robot.kinematics import FlangeKinematics

    kin = FlangeKinematics(model.nominal_model)
    q = np.random.default_rng(0).uniform(kin.lower, kin.upper, size=(2000, 6))
    p = model.flange_transforms(q, np.zeros(len(model.parameter_names)))[:, :3, 3]
    return float(np.linalg.norm(p, axis=1).max())


def likely_cause(q: np.ndarray, positions: np.ndarray, model) -> str:
    """The likely mistake behind measurements ``q`` (n, 6 rad) / ``positions`` (n, 3 m) that the
    nominal ``model`` does not explain; "" when none of the usual ones fits."""
    zero = np.zeros(len(model.parameter_names))
    nominal = model.flange_transforms(q, zero)[:, :3, 3]
    base = _rms(positions - nominal)
    distance = np.linalg.norm(positions, axis=1)
    reach = _reach(model)
    far = distance > REACH_MARGIN * reach
    if np.any(far):
        k = int(np.argmax(distance))
        return (f"out-of-reach poses: {int(far.sum())} of {len(q)} measured points are farther from the base than "
                f"the arm reaches ({distance[k]:.3g} m in row {k + 1}, reach {reach:.3g} m): wrong units, a tracker "
                f"frame not registered to the robot base, or positions of another robot")
    names = ("x", "y", "z")
    best = ("", base)
    for perm in itertools.permutations(range(3)):
        if perm == (0, 1, 2):
            continue
        r = _rms(positions[:, perm] - nominal)
        if r < best[1]:
            moved = [names[i] for i in range(3) if perm[i] != i]
            best = (f"position columns {' and '.join(moved)} swapped (undoing it lowers the uncalibrated residual "
                    f"from {base * 1e3:.3g} mm to {r * 1e3:.3g} mm)", r)
    for i, j in itertools.combinations(range(6), 2):
        swapped = q.copy()
        swapped[:, [i, j]] = swapped[:, [j, i]]
        r = _rms(positions - model.flange_transforms(swapped, zero)[:, :3, 3])
        if r < best[1]:
            best = (f"joint columns q{i + 1} and q{j + 1} swapped (undoing it lowers the uncalibrated residual from "
                    f"{base * 1e3:.3g} mm to {r * 1e3:.3g} mm)", r)
    if best[0] and best[1] * IMPROVEMENT_FACTOR < base:
        return best[0]
    offset = np.mean(positions - nominal, axis=0)
    if np.linalg.norm(offset) > 0.05 and _rms(positions - nominal - offset) * IMPROVEMENT_FACTOR < base:
        return (f"a constant offset of {np.linalg.norm(offset) * 1e3:.3g} mm between the tracker and robot base "
                f"frames: register the tracker to the base first")
    return ("the positions do not match the joint angles (uncalibrated residual "
            f"{base * 1e3:.3g} mm RMS): check that each row's q and x, y, z belong to the same pose, the "
            f"column order and the units")


def assess_calibration(measurements, result, model) -> Assessment:
    """Check a calibration ``result`` (calibration.solver.CalibrationResult) of
    ``measurements`` with the error ``model``; see the module docstring."""
    problems: list[str] = []
    q = np.asarray(measurements.q, dtype=float)
    from robot.kinematics import FlangeKinematics

    kin = FlangeKinematics(model.nominal_model)
    low = q < kin.lower - JOINT_LIMIT_TOLERANCE_RAD
    high = q > kin.upper + JOINT_LIMIT_TOLERANCE_RAD
    if np.any(low | high):
        row, col = (int(v) for v in np.argwhere(low | high)[0])
        problems.append(f"joint angle q{col + 1} = {q[row, col]:.4g} rad in row {row + 1} is outside the joint "
                        f"limits [{kin.lower[col]:.4g}, {kin.upper[col]:.4g}] rad")
    if not result.converged:
        problems.append(f"the fit did not converge in {result.iterations} iterations")
    if not math.isfinite(result.sigma_hat) or result.sigma_hat > MAX_SIGMA_HAT:
        stats = result.residual_statistics()
        problems.append(f"normalised residual sigma_hat = {result.sigma_hat:.3g} (expected about 1, at most "
                        f"{MAX_SIGMA_HAT:g}; position residual RMS {stats['position_norm']['rms']:.3g} mm)")
    names = list(result.parameter_names)
    errors = np.asarray(result.errors, dtype=float)
    worst = None
    for k in np.asarray(result.identified, dtype=int):
        name = names[k]
        angle = not name.startswith(("len", "base_")) and name not in ("flange_x", "flange_y", "flange_z")
        limit = MAX_ANGLE_ERROR_RAD if angle else MAX_LENGTH_ERROR_M
        ratio = abs(errors[k]) / limit if math.isfinite(errors[k]) else math.inf
        if ratio > 1.0 and (worst is None or ratio > worst[0]):
            shown = f"{math.degrees(errors[k]):.4g} deg" if angle else f"{errors[k] * 1e3:.4g} mm"
            bound = f"{math.degrees(limit):g} deg" if angle else f"{limit * 1e3:g} mm"
            worst = (ratio, f"identified error {name} = {shown} is physically implausible (an assembled arm "
                            f"deviates by at most about {bound})")
    if worst is not None:
        problems.append(worst[1])
    if not problems:
        return Assessment((), "")
    positions = np.asarray(measurements.positions, dtype=float)
    return Assessment(tuple(problems), likely_cause(q, positions, model))


__all__ = ["Assessment", "IMPROVEMENT_FACTOR", "JOINT_LIMIT_TOLERANCE_RAD", "MAX_ANGLE_ERROR_RAD",
           "MAX_LENGTH_ERROR_M", "MAX_SIGMA_HAT", "REACH_MARGIN", "assess_calibration", "likely_cause"]
