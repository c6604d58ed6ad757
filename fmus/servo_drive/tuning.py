"""Tuning rules of the drive's cascade: gains from sample times, motor data and inertia.

The values in ``drive_params.toml`` are the output of these rules;
``tests/fmus/test_drive_tuning.py`` checks that they agree, so the file stays the one
place for the numbers while the derivation stays executable.

Rules (Schroeder, *Elektrische Antriebe - Regelung von Antriebssystemen*; Preitl &
Precup 1999 for the extended symmetric optimum):

- current loop, technical optimum on ``1 / (R (1 + s L/R))`` with the small time
  constant ``T_si = c * T_s,i`` (computation delay + hold):
  ``Kp_i = L / (2 T_si)``, ``Tn_i = L / R``; closed loop ~ ``1 / (1 + 2 T_si s)``.
- speed loop, extended symmetric optimum on ``k_t / (J_m s)`` with
  ``T_sw = 2 T_si + T_s,w / 2 + T_filter``: ``Kp_w = J_m / (a T_sw k_t)``,
  ``Tn_w = a^2 T_sw``, ``J_m = J_design / N^2`` (motor side). The axis inertia
  varies between ``J_min`` and ``J_max`` with the configuration; with the design
  inertia at their geometric mean, ``r = sqrt(J_max / J_min)``, the crossover moves by
  ``r`` either way and the phase margin at both ends is ``phi`` with
  ``tan(phi) = r (a^2 - 1) / (a (1 + r^2))``. ``a`` is the root of that equation
  for the required ``phi`` (r = 1, phi = 36.9 deg gives the classic a = 2).
- position loop, technical optimum on an integrator behind the slowest closed speed
  loop (~ ``a r T_sw``, at ``J_max``) and the hold of the position sample:
  ``Kv = 1 / (2 (a r T_sw + T_s,p / 2))``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fmus.servo_drive.params import DriveParameters, load_drive_parameters
from robot.parameters import RobotParameters, load_parameters


@dataclass(frozen=True)
class CascadeGains:
    """Gains of the three loops, arrays of shape (6,).

    ``current_kp`` V/A, ``current_tn`` s, ``speed_kp`` A s/rad per MOTOR speed,
    ``speed_tn`` s, ``position_kv`` 1/s; ``speed_small_time_constant`` s; ``symmetric_optimum_a`` 1.
    """

    current_kp: np.ndarray
    current_tn: np.ndarray
    speed_kp: np.ndarray
    speed_tn: np.ndarray
    position_kv: np.ndarray
    speed_small_time_constant: float
    symmetric_optimum_a: np.ndarray


def cascade_gains(drive: DriveParameters | None = None, robot: RobotParameters | None = None) -> CascadeGains:
    """Apply the tuning rules to the tuning inputs of ``drive_params.toml``."""
    drive = drive or load_drive_parameters()
    robot = robot or load_parameters()
    ts_i = drive.get("sample_times", "current")
    ts_w = drive.get("sample_times", "speed")
    ts_p = drive.get("sample_times", "position")
    inductance = drive.get("motor", "inductance")
    resistance = drive.get("motor", "resistance")
    j_min, j_max = drive.get("tuning", "inertia_min"), drive.get("tuning", "inertia_max")
    r = np.sqrt(j_max / j_min)
    a = symmetric_optimum_a(r, drive.get("tuning", "phase_margin"))
    t_sigma_i = drive.get("tuning", "current_delay_factor") * ts_i
    t_sigma_w = 2.0 * t_sigma_i + ts_w / 2.0 + drive.get("tuning", "speed_filter_time")
    motor_inertia = np.sqrt(j_min * j_max) / robot.gear_ratio**2
    return CascadeGains(
        current_kp=inductance / (2.0 * t_sigma_i),
        current_tn=inductance / resistance,
        speed_kp=motor_inertia / (a * t_sigma_w * robot.torque_constant),
        speed_tn=a * a * t_sigma_w,
        position_kv=1.0 / (2.0 * (a * r * t_sigma_w + ts_p / 2.0)),
        speed_small_time_constant=t_sigma_w,
        symmetric_optimum_a=a,
    )


def symmetric_optimum_a(inertia_spread: np.ndarray | float, phase_margin_deg: float) -> np.ndarray:
    """``a`` giving ``phase_margin_deg`` at both ends of an inertia spread ``r`` (>= 1).

    Positive root of ``r a^2 - c (1 + r^2) a - r = 0`` with ``c = tan(phase margin)``.
    """
    r = np.asarray(inertia_spread, dtype=float)
    c = np.tan(np.radians(phase_margin_deg))
    b = c * (1.0 + r * r)
    return (b + np.sqrt(b * b + 4.0 * r * r)) / (2.0 * r)


def inertia_range(robot: RobotParameters | None = None, samples: int = 20000,
                  seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``(J_min, J_max)``: rotor inertia + min / max of diag M_rb(q) over the joint ranges (kg m^2).

    ``samples`` uniform configurations within the URDF limits (no payload), pinocchio CRBA.
    """
    import pinocchio as pin

    from robot.description import load_model

    robot = robot or load_parameters()
    model = load_model(robot.urdf_path)
    data = model.createData()
    rng = np.random.default_rng(seed)
    lo, hi = np.full(6, np.inf), np.zeros(6)
    for q in rng.uniform(model.lowerPositionLimit, model.upperPositionLimit, size=(samples, 6)):
        diagonal = np.diag(pin.crba(model, data, q))
        lo, hi = np.minimum(lo, diagonal), np.maximum(hi, diagonal)
    return lo + robot.rotor_inertia, hi + robot.rotor_inertia


def elastic_axis_speed_kp(drive: DriveParameters | None = None, robot: RobotParameters | None = None) -> np.ndarray:
    """Speed-loop gain (A s/rad per MOTOR speed, (6,)) for axes with ELASTIC gears (the plant's
    ``elastic_joints = 1``): the geometric mean of the rigid design (:func:`cascade_gains`,
    total inertia ``sqrt(J_min J_max)``) and the same extended symmetric optimum for the
    rotor alone (``rotor_inertia``, inertia spread 1), i.e. the rigid gain scaled by
    ``sqrt(J_rotor a_rigid / (J_design a_rotor))``. Above the gear resonance the speed loop
    sees only the rotor: with the rigid gain its crossover moves ~14x higher (axis 2), past
    the loop's delays, and the current saturates in a limit cycle; with the rotor-only gain
    the loop is too soft to hold the link (TCP vibration of ~20 mm on the ISO path). The
    geometric mean keeps both in check (docs/explanation/fmus.md, elastic plant)."""
    drive = drive or load_drive_parameters()
    robot = robot or load_parameters()
    rigid = cascade_gains(drive, robot)
    a_rotor = symmetric_optimum_a(np.ones(len(robot.gear_ratio)), drive.get("tuning", "phase_margin"))
    rotor_only = (robot.rotor_inertia / robot.gear_ratio**2) / (
        a_rotor * rigid.speed_small_time_constant * robot.torque_constant)
    return np.sqrt(rigid.speed_kp * rotor_only)
