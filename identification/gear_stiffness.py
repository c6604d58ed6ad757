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

Gear damping ``beta`` (``tau_g = k d + beta d'``) adds, to first order,
``-J(th) (q - th) = ... - beta_j c_j^2 J[:, j] tau_g,j'``: with ``tau_gear_rate`` the fit has a
second column per axis, ``e_j = beta_j c_j^2``, and ``beta_j = e_j / c_j^2``.

The measured point need not be the flange centre: ``reflector`` (m in the frame) is where the
tracker's reflector sits on the tool. It must be off the axis of joint 6 for that gear's twist
to be seen at all (the flange centre lies on the axis: ``J[:, 5]`` of the flange centre is
zero up to the geometric errors).

:func:`identify_gear_stiffness_periodic` is the campaign's version: one averaged period of
the motor angles and of the tracker, the gear torques from the identified rigid-body base
parameters (:func:`link_side_base_values`), and the same harmonics dropped from every column
and from the measured deviation (parallel filtering, as in the rigid-body identification).

Assumptions (say so when you use it): the kinematic model is calibrated (``f_DK`` and
``J`` of the true geometry - uncalibrated errors of ~1 mm would bias the result), the
deflection is quasi-static below the filter's cut-off (the gear's own ringing above it is
filtered out), linear gears (no backlash, no stiffening).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike
from scipy.signal import savgol_filter

from robot.dynamics import COULOMB_SLICE, ROTOR_INERTIA_SLICE, VISCOUS_SLICE
from robot.joints import N_JOINTS


@dataclass(frozen=True)
class StiffnessEstimate:
    """Identified gear stiffness per axis (N m/rad; NaN where not identifiable), its
    standard error (N m/rad), the identifiable mask, the condition number of the scaled
    regressor and the RMS residual (m); with a damping fit also the gear damping per axis
    (N m s/rad; NaN where not identifiable), its standard error and mask."""

    stiffness: np.ndarray
    stiffness_std: np.ndarray
    identifiable: np.ndarray
    condition_number: float
    residual_rms_m: float
    samples: int
    damping: np.ndarray | None = None
    damping_std: np.ndarray | None = None
    damping_identifiable: np.ndarray | None = None

    def to_dict(self, true_stiffness: ArrayLike | None = None, true_damping: ArrayLike | None = None) -> dict:
        """Plain data for a summary; with the true values also the relative errors (%)."""
        def listed(x):
            return None if x is None else [None if not np.isfinite(v) else float(v) for v in np.asarray(x)]

        out = {"stiffness_Nm_per_rad": listed(self.stiffness), "stiffness_std_Nm_per_rad": listed(self.stiffness_std),
               "stiffness_identifiable": [bool(b) for b in self.identifiable],
               "damping_Nms_per_rad": listed(self.damping), "damping_std_Nms_per_rad": listed(self.damping_std),
               "damping_identifiable": None if self.damping_identifiable is None
               else [bool(b) for b in self.damping_identifiable],
               "condition_number": self.condition_number, "residual_rms_m": self.residual_rms_m,
               "samples": self.samples}
        if true_stiffness is not None:
            true_k = np.asarray(true_stiffness, dtype=float)
            out["true_stiffness_Nm_per_rad"] = true_k.tolist()
            out["stiffness_error_percent"] = listed(100.0 * (self.stiffness / true_k - 1.0))
            out["stiffness_std_percent"] = listed(100.0 * self.stiffness_std / true_k)
        if true_damping is not None and self.damping is not None:
            true_b = np.asarray(true_damping, dtype=float)
            out["true_damping_Nms_per_rad"] = true_b.tolist()
            out["damping_error_percent"] = listed(100.0 * (self.damping / true_b - 1.0))
            out["damping_std_percent"] = listed(100.0 * self.damping_std / true_b)
        return out


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
                            max_relative_std: float = 0.15, *, tau_gear_rate: np.ndarray | None = None,
                            reflector: ArrayLike = (0.0, 0.0, 0.0), column_filter=None,
                            iterations: int = 3) -> StiffnessEstimate:
    """Least-squares gear stiffness from motor angles (n, 6) rad, measured positions of the
    reflector (n, 3) m (``reflector``: m in ``frame``; default its origin) and gear torques
    (n, 6) N m (see module docstring); every ``decimate``-th sample is used.

    ``tau_gear_rate`` (n, 6) N m/s: also fit the gear damping. ``column_filter``: a function
    applied along axis 0 to the measured deviation and to every regressor column at the full
    rate before decimating (parallel filtering; e.g. a periodic low-pass). ``iterations``:
    Gauss-Newton passes, each linearising the kinematics about the link angles of the previous
    estimate (the first about the motor angles): with the main axes' deflections of ~2 mrad
    the second-order terms are several µm at the reflector and bias the small wrist
    deflections by a few % in a single pass."""
    th = np.asarray(motor_angles, dtype=float)
    meas = np.asarray(tcp_measured, dtype=float)
    tau = np.asarray(tau_gear, dtype=float)
    rate = None if tau_gear_rate is None else np.asarray(tau_gear_rate, dtype=float)
    if th.shape[1:] != (N_JOINTS,) or meas.shape != (th.shape[0], 3) or tau.shape != th.shape or (
            rate is not None and rate.shape != th.shape):
        raise ValueError(f"motor_angles {th.shape}, tcp_measured {meas.shape}, tau_gear {tau.shape}"
                         + ("" if rate is None else f", tau_gear_rate {rate.shape}")
                         + ": expected (n, 6), (n, 3), (n, 6)" + ("" if rate is None else ", (n, 6)"))
    if column_filter is None:
        th, meas, tau = th[::decimate], meas[::decimate], tau[::decimate]
        rate = None if rate is None else rate[::decimate]
    point = np.asarray(reflector, dtype=float)
    data = kinematic_model.createData()
    fid = kinematic_model.getFrameId(frame)
    n_cols = 2 * N_JOINTS if rate is not None else N_JOINTS
    x = np.zeros(n_cols)
    active = np.ones(n_cols, dtype=bool)
    for _ in range(max(int(iterations), 1)):
        # linearise about the link angles of the current estimate (the first pass: the motor angles)
        known = np.where(active, np.nan_to_num(x), 0.0)
        shift = -tau * known[:N_JOINTS] + (rate * known[N_JOINTS:] if rate is not None else 0.0)
        jacobians, deviation = _reflector_kinematics(kinematic_model, data, fid, th + shift, point)
        deviation = meas - deviation + np.einsum("kij,kj->ki", jacobians, shift)
        columns = [-jacobians * tau[:, None, :]]
        if rate is not None:
            columns.append(jacobians * rate[:, None, :])
        a3 = np.concatenate(columns, axis=2)  # (n, 3, 6 or 12)
        if column_filter is not None:
            a3 = column_filter(a3.reshape(a3.shape[0], -1)).reshape(a3.shape)[::decimate]
            deviation = column_filter(deviation)[::decimate]
        a = a3.reshape(-1, a3.shape[2])
        b = deviation.reshape(-1)
        norms = np.linalg.norm(a, axis=0)
        active = norms > 1e-12 * max(norms.max(), 1e-300)
        while True:
            scaled = a[:, active] / norms[active]
            coef, *_ = np.linalg.lstsq(scaled, b, rcond=None)
            residual = b - scaled @ coef
            sigma2 = float(residual @ residual) / max(b.size - coef.size, 1)
            cov = sigma2 * np.linalg.inv(scaled.T @ scaled)
            x = np.full(a.shape[1], np.nan)
            x_std = np.full(a.shape[1], np.nan)
            x[active] = coef / norms[active]
            x_std[active] = np.sqrt(np.diag(cov)) / norms[active]
            relative = np.where(active & (x > 0), x_std / np.abs(np.where(active, x, 1.0)), np.inf)
            relative[~active] = 0.0
            if np.all(relative <= max_relative_std) or active.sum() == 1:
                break
            # drop the worst-determined column (a stiffness column takes its damping column with it)
            worst = int(np.argmax(relative))
            active[worst] = False
            if worst < N_JOINTS and a.shape[1] > N_JOINTS:
                active[worst + N_JOINTS] = False
    compliance, compliance_std = x[:N_JOINTS], x_std[:N_JOINTS]
    identifiable = active[:N_JOINTS].copy()
    stiffness = np.where(identifiable, 1.0 / np.where(identifiable, compliance, 1.0), np.nan)
    stiffness_std = np.where(identifiable, compliance_std / np.where(identifiable, compliance, 1.0) ** 2, np.nan)
    damping = damping_std = damping_ok = None
    if rate is not None:
        damping_ok = active[N_JOINTS:] & identifiable
        c = np.where(damping_ok, compliance, 1.0)
        e, e_std = x[N_JOINTS:], x_std[N_JOINTS:]
        damping = np.where(damping_ok, e / c**2, np.nan)
        # first order in both relative errors (e and c are nearly uncorrelated columns)
        damping_std = np.where(damping_ok, np.abs(damping) * np.hypot(e_std / np.where(damping_ok, e, 1.0),
                                                                     2.0 * compliance_std / c), np.nan)
    return StiffnessEstimate(stiffness, stiffness_std, identifiable, float(np.linalg.cond(scaled)),
                             float(np.sqrt(np.mean(residual ** 2))), int(deviation.shape[0]),
                             damping, damping_std, damping_ok)


def _reflector_kinematics(model: pin.Model, data, fid: int, angles: np.ndarray, point: np.ndarray):
    """Positions (n, 3) and translational Jacobians (n, 3, 6) of ``point`` (in frame ``fid``)."""
    jacobians = np.empty((angles.shape[0], 3, N_JOINTS))
    positions = np.empty((angles.shape[0], 3))
    for k, q in enumerate(angles):
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        placement = data.oMf[fid]
        jac = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
        offset = placement.rotation @ point
        jacobians[k] = jac[:3] - np.cross(offset, jac[3:].T).T  # velocity of the point
        positions[k] = placement.act(point)
    return jacobians, positions


def link_side_base_values(base, values: ArrayLike, rotor_inertia: ArrayLike,
                          motor_friction_share: ArrayLike) -> np.ndarray:
    """The base parameters of the links alone (what the gears drive) from identified base
    parameters ``values`` of the whole drive train: a rotor inertia that is a base parameter
    by itself (Ia3..Ia6) is removed; one regrouped with link inertias (Ia1 in Izz1R, Ia2 in
    Iyy2R: only the sum is identifiable) is removed with its value ``rotor_inertia`` (the
    motor's catalogue value, kg m^2 joint side); the motor share of the viscous and Coulomb
    friction (``motor_friction_share``, 1) is removed from every fv, fc (base parameters by
    themselves)."""
    values = np.asarray(values, dtype=float)
    share = np.asarray(motor_friction_share, dtype=float)
    rotor_inertia = np.asarray(rotor_inertia, dtype=float)
    kmap = np.column_stack([base.base_values(e) for e in np.eye(78)])  # (n_base, 78): p_b = K p
    terms = np.abs(kmap) > 1e-12
    link = values.copy()
    for j in range(N_JOINTS):
        rotor = ROTOR_INERTIA_SLICE.start + j
        for row in np.flatnonzero(terms[:, rotor]):
            link[row] = 0.0 if terms[row].sum() == 1 else link[row] - kmap[row, rotor] * rotor_inertia[j]
        for friction in (VISCOUS_SLICE.start + j, COULOMB_SLICE.start + j):
            for row in np.flatnonzero(terms[:, friction]):
                if terms[row].sum() != 1:
                    raise ValueError(f"base parameter {base.base_names[row]} mixes friction with other terms")
                link[row] = (1.0 - share[j]) * values[row]
    return link


def identify_gear_stiffness_periodic(base, base_values: ArrayLike, motor_period: np.ndarray, sample_time: float,
                                     tracker_period: np.ndarray, tracker_sample_time: float, tracker_phase: float,
                                     kinematic_model: pin.Model, *, rotor_inertia: ArrayLike,
                                     motor_friction_share: ArrayLike, cutoff_hz: float,
                                     reflector: ArrayLike = (0.0, 0.0, 0.0), frame: str = "tool0",
                                     decimate: int = 2, max_relative_std: float = 0.15,
                                     damping: bool = True) -> StiffnessEstimate:
    """Gear stiffness (and damping) from ONE averaged period of a periodic excitation.

    ``motor_period`` (n, 6) rad: the averaged motor angles (encoder / gear ratio) sampled every
    ``sample_time`` s from the period's start; ``tracker_period`` (m, 3) m: the averaged
    tracker readings of the reflector, sample k at ``tracker_phase + k tracker_sample_time`` s
    after the same start; ``base``/``base_values``: the identified rigid-body base parameters
    of the whole drive train (the links' share by :func:`link_side_base_values`). The motor
    motion is evaluated at the tracker's instants from its Fourier series up to ``cutoff_hz``;
    the gear torques follow from the link-side base parameters; the same harmonics are dropped
    from the regressor columns and from the measured deviation (parallel filtering)."""
    from identification.identify import base_regressor
    from identification.signals import periodic_derivatives, periodic_evaluate, periodic_lowpass

    tracker_period = np.asarray(tracker_period, dtype=float)
    times = tracker_phase + np.arange(tracker_period.shape[0]) * tracker_sample_time
    th, thd, thdd = (periodic_evaluate(motor_period, sample_time, cutoff_hz, times, d) for d in range(3))
    link = link_side_base_values(base, base_values, rotor_inertia, motor_friction_share)
    tau = np.einsum("kjn,n->kj", base_regressor(base, th, thd, thdd), link)
    tau, rate, _ = periodic_derivatives(tau, tracker_sample_time, cutoff_hz)
    return identify_gear_stiffness(th, tracker_period, tau, kinematic_model, frame, decimate, max_relative_std,
                                   tau_gear_rate=rate if damping else None, reflector=reflector,
                                   column_filter=lambda x: periodic_lowpass(x, tracker_sample_time, cutoff_hz))
