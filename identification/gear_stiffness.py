"""Gear stiffness from closed-loop data of an elastic arm: motor encoders + laser tracker.

What a user has on a real cell: the drives' motor angles ``th`` (encoder / gear ratio,
joint units) and a laser tracker's flange positions ``m``. With elastic gears the links
lag the motors by the deflection ``d = q - th = -tau_g / k`` (per axis, ``tau_g`` the
torque the gear passes to the link), so to first order

    m - f_DK(th) = J(th) (q - th) = -sum_j J[:, j](th) tau_g,j / k_j

which is LINEAR in the compliances ``c_j = 1 / k_j``. ``tau_g`` comes from a link-side
model (links without rotor inertia, with the link share of the friction: e.g. the
identified rigid-body parameters) along the motor motion (speeds and accelerations by a
Savitzky-Golay filter). Least squares over all samples (3 equations each) gives ``c``
and its standard errors; an axis whose compliance the data do not determine (relative
standard error above ``max_relative_std``, e.g. a gear that carries no torque on the
trajectory) is reported as not identifiable and the others are solved again without it.

Assumptions (say so when you use it): the kinematic model is calibrated (``f_DK`` and
``J`` of the true geometry - uncalibrated errors of ~1 mm would bias the result), the
deflection is quasi-static (the gear's own ringing is noise here), linear gears
(no backlash, no stiffening).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.signal import savgol_filter
from robot.joints import N_JOINTS


@dataclass(frozen=True)
class StiffnessEstimate:
    """Identified gear stiffness per axis (N m/rad; NaN where not identifiable), its
    standard error (N m/rad), the identifiable mask, the condition number of the scaled
    regressor and the RMS residual (m)."""

    stiffness: np.ndarray
    stiffness_std: np.ndarray
    identifiable: np.ndarray
    condition_number: float
    residual_rms_m: float
    samples: int


def gear_torques(link_dynamics, motor_angles: np.ndarray, dt: float, window: int = 41,
                 order: int = 5) -> np.ndarray:
    """Link-side gear torques (n, 6) in N m along the motor motion: ``link_dynamics``
    (e.g. a :class:`robot.dynamics.RobotDynamics` of the links alone) inverse dynamics at the
    motor angles, with speeds and accelerations from a Savitzky-Golay filter (``window``
    samples, polynomial ``order``) of the angles sampled every ``dt`` s."""
    qd = savgol_filter(motor_angles, window, order, deriv=1, delta=dt, axis=0)
    qdd = savgol_filter(motor_angles, window, order, deriv=2, delta=dt, axis=0)
    return np.array([link_dynamics.inverse_dynamics(a, b, c) for a, b, c in zip(motor_angles, qd, qdd)])


def identify_gear_stiffness(motor_angles: np.ndarray, tcp_measured: np.ndarray, tau_gear: np.ndarray,
                            kinematic_model: pin.Model, frame: str = "tool0", decimate: int = 5,
                            max_relative_std: float = 0.15) -> StiffnessEstimate:
    """Least-squares gear stiffness from motor angles (n, 6) rad, measured flange positions
    (n, 3) m and gear torques (n, 6) N m (see module docstring); every ``decimate``-th
    sample is used."""
    th = np.asarray(motor_angles, dtype=float)[::decimate]
    meas = np.asarray(tcp_measured, dtype=float)[::decimate]
    tau = np.asarray(tau_gear, dtype=float)[::decimate]
    if th.shape[1:] != (N_JOINTS,) or meas.shape != (th.shape[0], 3) or tau.shape != th.shape:
        raise ValueError(f"motor_angles {th.shape}, tcp_measured {meas.shape}, tau_gear {tau.shape}: "
                         "expected (n, 6), (n, 3), (n, 6)")
    data = kinematic_model.createData()
    fid = kinematic_model.getFrameId(frame)
    rows, rhs = [], []
    for angles, point, torque in zip(th, meas, tau):
        pin.computeJointJacobians(kinematic_model, data, angles)
        pin.updateFramePlacements(kinematic_model, data)
        jac = pin.getFrameJacobian(kinematic_model, data, fid, pin.LOCAL_WORLD_ALIGNED)[:3]
        rows.append(-jac * torque[None, :])
        rhs.append(point - data.oMf[fid].translation)
    a = np.concatenate(rows)
    b = np.concatenate(rhs)
    norms = np.linalg.norm(a, axis=0)
    identifiable = norms > 0.0
    while True:
        scaled = a[:, identifiable] / norms[identifiable]
        coef, *_ = np.linalg.lstsq(scaled, b, rcond=None)
        residual = b - scaled @ coef
        sigma2 = float(residual @ residual) / max(b.size - coef.size, 1)
        cov = sigma2 * np.linalg.inv(scaled.T @ scaled)
        compliance = coef / norms[identifiable]
        compliance_std = np.sqrt(np.diag(cov)) / norms[identifiable]
        relative = np.where(compliance > 0, compliance_std / np.abs(compliance), np.inf)
        if np.all(relative <= max_relative_std) or identifiable.sum() == 1:
            break
        worst = np.flatnonzero(identifiable)[int(np.argmax(relative))]
        identifiable[worst] = False
    stiffness = np.full(N_JOINTS, np.nan)
    stiffness_std = np.full(N_JOINTS, np.nan)
    stiffness[identifiable] = 1.0 / compliance
    stiffness_std[identifiable] = compliance_std / compliance ** 2
    return StiffnessEstimate(stiffness, stiffness_std, identifiable, float(np.linalg.cond(scaled)),
                             float(np.sqrt(np.mean(residual ** 2))), int(th.shape[0]))
