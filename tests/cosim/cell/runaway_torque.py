"""A user's torque-mode controller with a units bug: PD + gravity on every joint, but joint 3 gets
1e6 N·m (meant as N·mm, say) in cyclic synchronous torque (CiA 402 mode 10). Written as a user
would, after examples/pd_gravity_controller.py: it imports only the controller contract and
controller.tracking_clock.TrackingClock, and does not clip its torques."""
from __future__ import annotations

import numpy as np

from controller import MODE_CST, ControllerInfo, ControllerInput, ControllerOutput
from controller.tracking_clock import TrackingClock

KP = np.array([1.07e5, 1.41e5, 7.86e4, 1.54e3, 1.85e3, 2.01e2])   # N m / rad
KD = np.array([3.40e3, 4.50e3, 2.50e3, 49.0, 59.0, 6.38])         # N m s / rad


class RunawayTorque:
    def __init__(self, joint: int = 3, torque: float = 1e6, settle_time: float = 0.05) -> None:
        self.joint, self.torque, self.settle_time = int(joint), float(torque), float(settle_time)
        self.clock = None

    motion_start_s = property(lambda self: self.clock.motion_start_s if self.clock else None)
    stop_reason = property(lambda self: self.clock.stop_reason if self.clock else None)
    stopped_at_s = property(lambda self: self.clock.stopped_at_s if self.clock else None)

    def setup(self, info: ControllerInfo) -> None:
        self.clock = TrackingClock(info, settle_time_s=self.settle_time)
        self.dynamics = info.dynamics
        self.out = ControllerOutput.zeros(info.n_joints, mode=MODE_CST)

    def step(self, inputs: ControllerInput) -> ControllerOutput:
        out = self.out
        tau_traj = self.clock.update(inputs, out.controlword)
        if self.clock.stop_reason is not None:
            out.target_torque[:] = 0.0
            return out
        q_d, qd_d, _ = self.clock.reference(tau_traj)
        tau = KP * (q_d - inputs.position) + KD * (qd_d - inputs.velocity) + self.dynamics.gravity(inputs.position)
        if tau_traj is not None:
            tau[self.joint - 1] = self.torque
        out.target_torque[:] = tau
        out.modes_of_operation[:] = MODE_CST
        return out

    def close(self) -> None:
        pass
