"""A user controller: joint PD + gravity compensation in cyclic synchronous torque (CiA 402 mode 10).

    tau = Kp (q_d - q) + Kd (qd_d - qd) + g(q)   [+ M(q_d) qdd_d with inertia_feedforward = true]
                                                 [+ M(q_d) qdd_d + C(q_d, qd_d) qd_d + f(qd_d)
                                                    with model_feedforward = true]

sent to every drive as its target torque (0x6071) in modes of operation 10 (CST): the drives'
position and speed loops are bypassed, the controller closes the loops itself over the
fieldbus at the bus cycle. An example of the controller contract
(``controller.CellController``: ``setup(info)``, ``step(inputs) -> ControllerOutput``,
``close()``; docs/how-to/own_controller.md). It imports only the contract's
plain-data types and the building block ``controller.tracking_clock.TrackingClock``, which
does what every tracking controller needs around its law: the CiA 402 enable sequence,
the settle time, the trajectory time and the joint reference at the time an output acts.

Timing (the contract): ``step`` at cycle k sees the actual values latched at t_k; what it
returns acts from t_k + lead_cycles * T. The reference is taken at that time; the measured
angle is extrapolated to it with the measured velocity (a predictor over the dead time).
g(q) comes from the nominal model the cell hands over in ``info.dynamics`` (URDF + parameter
file, with the declared tool load); the true robot deviates from it.

Scenario (job ``compare``)::

    controllers = ["model_based", { name = "pd_gravity", class = "pd_gravity_controller.py:PDGravity",
                                    parameters = { settle_time = 0.2 } }]
"""
from __future__ import annotations

import math

import numpy as np

from controller import MODE_CST, ControllerInfo, ControllerInput, ControllerOutput
from controller.tracking_clock import TrackingClock

# Gains per joint (joint side): a critically damped loop of bandwidth f per axis on the
# diagonal of the nominal mass matrix (rotor inertia included) at the ISO 9283 start pose
# with the 8 kg tool: Kp = J w^2, Kd = 2 J w, w = 2 pi f.
AXIS_INERTIA = (27.0, 35.8, 19.9, 0.390, 0.469, 0.0508)          # kg m^2
# The defaults: f = 10 Hz (rounded), for the rigid plant (scenarios/iso9283_rigid.toml,
# examples/compare.toml). On the elastic-gear plant (scenarios/iso9283.toml) 10 Hz is too close to
# the gears' resonance for a loop closed over 1.2 ms of bus delay on the motor encoders: use
# bandwidth_hz = 3 with model_feedforward = true there (docs/how-to/own_controller.md, "On the elastic plant").
DEFAULT_KP = (1.07e5, 1.41e5, 7.86e4, 1.54e3, 1.85e3, 2.01e2)   # N m / rad
DEFAULT_KD = (3.40e3, 4.50e3, 2.50e3, 49.0, 59.0, 6.38)          # N m s / rad


def gains_for(bandwidth_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(Kp, Kd) of a critically damped loop of ``bandwidth_hz`` per axis on :data:`AXIS_INERTIA`."""
    w = 2.0 * math.pi * float(bandwidth_hz)
    inertia = np.asarray(AXIS_INERTIA)
    return inertia * w * w, 2.0 * inertia * w


class PDGravity:
    """Joint PD + gravity compensation in CST (see the module docstring).

    kp, kd: 6 gains each (N m/rad, N m s/rad); or bandwidth_hz: the gains of a critically damped
    loop of that bandwidth per axis (:func:`gains_for`; not together with kp/kd); default the
    10 Hz gains :data:`DEFAULT_KP`, :data:`DEFAULT_KD`. settle_time: hold after enabling (s);
    inertia_feedforward: add M(q_d) qdd_d (a computed-torque flavour), default False;
    model_feedforward: add the nominal model's whole torque along the reference but gravity,
    M(q_d) qdd_d + C(q_d, qd_d) qd_d + f(qd_d) (inverse dynamics minus g(q_d)), default False.
    """

    def __init__(self, kp=None, kd=None, settle_time: float = 0.2, inertia_feedforward: bool = False,
                 bandwidth_hz: float | None = None, model_feedforward: bool = False) -> None:
        if bandwidth_hz is not None:
            if kp is not None or kd is not None:
                raise ValueError("give either bandwidth_hz or kp and kd, not both")
            if not (math.isfinite(bandwidth_hz) and bandwidth_hz > 0):
                raise ValueError(f"bandwidth_hz = {bandwidth_hz!r}: expected a frequency > 0 Hz")
            kp, kd = gains_for(bandwidth_hz)
        self.kp = np.asarray(DEFAULT_KP if kp is None else kp, dtype=float).reshape(6)
        self.kd = np.asarray(DEFAULT_KD if kd is None else kd, dtype=float).reshape(6)
        if np.any(self.kp < 0) or np.any(self.kd < 0):
            raise ValueError("kp and kd must be >= 0")
        self.settle_time = float(settle_time)
        self.inertia_feedforward = bool(inertia_feedforward)
        self.model_feedforward = bool(model_feedforward)
        self.clock: TrackingClock | None = None

    # the cell reads these (when the motion starts, why the controller stopped)
    motion_start_s = property(lambda self: self.clock.motion_start_s if self.clock else None)
    stop_reason = property(lambda self: self.clock.stop_reason if self.clock else None)
    stopped_at_s = property(lambda self: self.clock.stopped_at_s if self.clock else None)

    # -- the contract -----------------------------------------------------------
    def setup(self, info: ControllerInfo) -> None:
        if info.dynamics is None:
            raise ValueError("PDGravity needs the cell's dynamics model (info.dynamics) for g(q)")
        self.clock = TrackingClock(info, settle_time_s=self.settle_time)
        self.dynamics = info.dynamics
        self.lead_s = info.lead_cycles * info.period_s
        self.torque_max = np.asarray(info.torque_max, dtype=float)
        self.out = ControllerOutput.zeros(info.n_joints, mode=MODE_CST)

    def step(self, inputs: ControllerInput) -> ControllerOutput:
        out = self.out
        tau_traj = self.clock.update(inputs, out.controlword)     # controlwords written; None: hold the start
        if self.clock.stop_reason is not None:
            out.target_torque[:] = 0.0
            return out
        q_d, qd_d, qdd_d = self.clock.reference(tau_traj)
        q = inputs.position + inputs.velocity * self.lead_s         # predicted to when the output acts
        qd = inputs.velocity
        tau = self.kp * (q_d - q) + self.kd * (qd_d - qd) + self.dynamics.gravity(q)
        if self.model_feedforward:
            tau += self.dynamics.inverse_dynamics(q_d, qd_d, qdd_d) - self.dynamics.gravity(q_d)
        elif self.inertia_feedforward:
            tau += self.dynamics.mass_matrix(q_d) @ qdd_d
        if not math.isfinite(float(tau.sum())):
            raise FloatingPointError(f"non-finite torque at t = {inputs.time_s} s")
        np.clip(tau, -self.torque_max, self.torque_max, out=out.target_torque)
        out.modes_of_operation[:] = MODE_CST
        return out

    def close(self) -> None:
        pass
