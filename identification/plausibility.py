"""Is an identification record in the units the format says, and is the identified model believable?

:func:`check_record_units` runs before the fit (``python -m cosim identify`` exits 2):

* joint angles outside the robot's joint limits (by more than :data:`JOINT_LIMIT_TOLERANCE_RAD`):
  degrees instead of radians when beyond 2 pi, q and tau columns swapped when the torque
  columns would fit the limits;
* torques whose size does not match the arm's gravity load: the RMS of the measured
  joint-2/3 torque against the nominal model's gravity torque at the same angles (the
  gravity load of an RX130L-class arm is hundreds of N m and dominates slow motions):
  a ratio below :data:`MIN_TORQUE_RATIO` means kN m or motor-side torques, above
  :data:`MAX_TORQUE_RATIO` N mm or another robot;
* torques beyond :data:`EFFORT_LIMIT_FACTOR` times the URDF effort limits.

:func:`check_fit` runs after the fit (exit 3, no parameter file written): a joint whose
torque the model explains with a relative residual above :data:`MAX_RELATIVE_RESIDUAL`, or a
rotor inertia, friction coefficient or last-link inertia identified negative beyond
:data:`NEGATIVE_SIGMAS` standard deviations.
"""
from __future__ import annotations

import math

import numpy as np

from identification.errors import IdentificationDataError

JOINT_LIMIT_TOLERANCE_RAD = math.radians(2.0)
"""Joint angles may exceed the URDF limits by this much (rad) before the record is refused."""

GRAVITY_JOINTS = (1, 2)
"""Joints (0-based: axes 2 and 3) whose gravity torque sets the expected torque scale."""

MIN_GRAVITY_RMS_NM = 20.0
"""A gravity joint is used for the scale check when its nominal gravity torque RMS is above this (N m)."""

MIN_TORQUE_RATIO = 0.1
"""Smallest accepted RMS(measured torque) / RMS(nominal gravity torque) on axes 2-3: payloads and
friction change the load by tens of percent, kN m or motor-side torques (gear ratio ~100) by 100-1000x."""

MAX_TORQUE_RATIO = 10.0
"""Largest accepted ratio (fast motions add inertial torque, but not tenfold the gravity load on average)."""

EFFORT_LIMIT_FACTOR = 3.0
"""Measured |tau| above this many times the URDF effort limit is refused (N m)."""

MAX_RELATIVE_RESIDUAL = 0.5
"""Largest accepted RMS(torque residual) / RMS(torque) of a joint after the fit."""

NON_NEGATIVE_PREFIXES = ("Ia", "fv", "fc")
"""Base parameters that are single physical quantities which cannot be negative: rotor inertias,
viscous and Coulomb friction coefficients."""

NON_NEGATIVE_NAMES = ("Izz6",)
"""Further base parameters that are one non-negative quantity (the last link's inertia about its axis)."""

NEGATIVE_SIGMAS = 3.0
"""A non-negative parameter is refused when it is below zero by more than this many standard deviations."""

SCALE_SAMPLES = 400
"""Samples (evenly spread) used for the gravity-scale check."""


def _limits():
    from robot.kinematics import FlangeKinematics

    kin = FlangeKinematics()
    return kin.lower, kin.upper, np.asarray(kin.model.effortLimit, dtype=float)


def check_record_units(record, where: str) -> None:
    """Raise IdentificationDataError naming ``where`` when the record's angles or torques are implausible."""
    lower, upper, effort = _limits()
    q, tau = np.asarray(record.q, dtype=float), np.asarray(record.tau, dtype=float)
    bad = (q < lower - JOINT_LIMIT_TOLERANCE_RAD) | (q > upper + JOINT_LIMIT_TOLERANCE_RAD)
    if np.any(bad):
        row, col = (int(v) for v in np.argwhere(bad)[0])
        value = q[row, col]
        tau_fits = np.all((tau >= lower - JOINT_LIMIT_TOLERANCE_RAD) & (tau <= upper + JOINT_LIMIT_TOLERANCE_RAD))
        if tau_fits and np.any(np.abs(q) > 10.0):
            cause = "the q and tau columns look swapped (the tau columns hold values like joint angles)"
        elif np.max(np.abs(q)) > 2 * math.pi:
            cause = "the angles look like degrees; expected radians"
        else:
            cause = "the record leaves the robot's joint range"
        raise IdentificationDataError(
            f"{where}: column 'q{col + 1}' has {value:.6g} at sample {row} (t = {record.t[row]:.6g} s), outside the "
            f"joint limits [{lower[col]:.4g}, {upper[col]:.4g}] rad: {cause}")
    over = np.abs(tau) > EFFORT_LIMIT_FACTOR * effort
    if np.any(over):
        row, col = (int(v) for v in np.argwhere(over)[0])
        raise IdentificationDataError(
            f"{where}: column 'tau{col + 1}' has {tau[row, col]:.6g} at sample {row}, more than "
            f"{EFFORT_LIMIT_FACTOR:g}x the joint's effort limit {effort[col]:.4g} N m: expected joint-side torques "
            f"in N m (N mm? motor-side current?)")
    from robot.dynamics import RobotDynamics

    picks = np.linspace(0, len(q) - 1, min(len(q), SCALE_SAMPLES)).astype(int)
    nominal = RobotDynamics()
    gravity = np.array([nominal.gravity(q[k]) for k in picks])
    for j in GRAVITY_JOINTS:
        g = float(np.sqrt(np.mean(gravity[:, j] ** 2)))
        if g < MIN_GRAVITY_RMS_NM:
            continue
        m = float(np.sqrt(np.mean(tau[picks, j] ** 2)))
        ratio = m / g
        if ratio < MIN_TORQUE_RATIO:
            raise IdentificationDataError(
                f"{where}: column 'tau{j + 1}' has an RMS of {m:.4g}, but the arm's gravity load alone needs "
                f"{g:.4g} N m at these angles (ratio {ratio:.3g} < {MIN_TORQUE_RATIO:g}): the torques look like kN m "
                f"or motor-side values; expected joint-side torques in N m")
        if ratio > MAX_TORQUE_RATIO:
            raise IdentificationDataError(
                f"{where}: column 'tau{j + 1}' has an RMS of {m:.4g}, {ratio:.3g}x the arm's gravity load "
                f"({g:.4g} N m) at these angles: the torques look like N mm or belong to another robot; "
                f"expected joint-side torques in N m")


def check_fit(result, record, where: str) -> str | None:
    """None when every joint's torque is explained by the identified model, else the reason."""
    estimate = result.estimate
    tau = np.asarray(record.tau, dtype=float)
    spread = np.sqrt(np.mean((tau - tau.mean(axis=0)) ** 2, axis=0))
    residual = np.asarray(estimate.residual_rms, dtype=float)
    values = np.asarray(estimate.values, dtype=float)
    std = np.asarray(estimate.std, dtype=float)
    for k, name in enumerate(estimate.names):
        if name.startswith(NON_NEGATIVE_PREFIXES) or name in NON_NEGATIVE_NAMES:
            margin = NEGATIVE_SIGMAS * (std[k] if math.isfinite(std[k]) else 0.0)
            if values[k] < -margin:
                return (f"{where}: the identified {name} = {values[k]:.4g} is negative beyond {NEGATIVE_SIGMAS:g} "
                        f"standard deviations ({std[k]:.3g}): physically impossible (a rotor inertia, a friction "
                        f"coefficient or the last link's inertia cannot be negative); angles in degrees, "
                        f"torques in the wrong unit or swapped columns are the usual causes")
    for j in range(tau.shape[1]):
        if not math.isfinite(residual[j]):
            return f"{where}: the fit of joint {j + 1} gave a non-finite residual"
        scale = max(float(np.sqrt(np.mean(tau[:, j] ** 2))), 1e-9)
        if spread[j] > 1e-6 and residual[j] / scale > MAX_RELATIVE_RESIDUAL:
            return (f"{where}: the identified model leaves {100 * residual[j] / scale:.3g} % of joint {j + 1}'s "
                    f"torque unexplained (at most {100 * MAX_RELATIVE_RESIDUAL:g} %): the torque and angle columns "
                    f"may not belong together (column order, time shift, units)")
    return None


__all__ = ["EFFORT_LIMIT_FACTOR", "JOINT_LIMIT_TOLERANCE_RAD", "MAX_RELATIVE_RESIDUAL", "MAX_TORQUE_RATIO",
           "MIN_TORQUE_RATIO", "check_fit", "check_record_units"]
