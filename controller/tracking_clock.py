"""Building blocks for a user's cell controller: CiA 402 enabling, settling, trajectory time
and the joint reference at the time an output acts.

A controller that follows the cell's reference (``info.reference``) needs what the
built-in controller does around its control law; :class:`TrackingClock` gives it::

    class MyPD:
        def setup(self, info):
            self.clock = TrackingClock(info, settle_time_s=0.2)
            self.out = ControllerOutput.zeros(info.n_joints)
        def step(self, inputs):
            tau = self.clock.update(inputs, self.out.controlword)   # controlwords written, tau or None
            q_d, qd_d, qdd_d = self.clock.reference(tau)            # start pose while tau is None
            ...                                                     # the control law
            return self.out
        def close(self): pass
        motion_start_s = property(lambda self: self.clock.motion_start_s)
        stop_reason = property(lambda self: self.clock.stop_reason)
        stopped_at_s = property(lambda self: self.clock.stopped_at_s)

Phases as the built-in controller's (:class:`controller.Phase`): enabling (the CiA 402
enable sequence per drive, :class:`fieldbus.EnableSequencer`), settling (all drives in
Operation enabled; ``settle_time_s``), tracking (trajectory time ``tau`` of the output
computed in cycle k is ``(k - k_start) T``; the drives apply it at ``t_k + lead``),
finished (``tau`` held at the end), stopped (a drive in Fault / Fault reaction / Quick
stop active, or a node fault: quick stop 0x0002 to every drive, the reason kept).
"""
from __future__ import annotations

import numpy as np

from controller.contract import ControllerInfo, ControllerInput
from controller.controller import STOP_STATES
from controller.joint_reference import CartesianToJoint
from controller.reference import JointTrajectory, TcpTrajectory
from fieldbus import Command, EnableSequencer, decode_statusword



class TrackingClock:
    """Enable, settle and time the reference for a user controller (see the module docstring).

    Attributes: ``motion_start_s`` (s, when the drives apply trajectory time 0; None before),
    ``stop_reason``/``stopped_at_s`` (None while running), ``finished`` (the reference ended).
    """

    def __init__(self, info: ControllerInfo, settle_time_s: float = 0.2, enable_timeout_s: float = 0.5) -> None:
        self.info = info
        self.period_s = info.period_s
        self.settle_cycles = int(round(settle_time_s / info.period_s))
        self.enable_timeout_s = enable_timeout_s
        self.sequencers = [EnableSequencer() for _ in range(info.n_joints)]
        self.q_start = np.asarray(info.q_start, dtype=float).copy()
        self.reference_trajectory = info.reference
        self._ik = None
        if isinstance(info.reference, TcpTrajectory):
            self._ik = CartesianToJoint(info.kinematic_model)
            self._ik.reset(self.q_start)
        self.motion_start_s: float | None = None
        self.stop_reason: str | None = None
        self.stopped_at_s: float | None = None
        self.finished = False
        self._first_t: float | None = None
        self._settle_until: int | None = None
        self._start_cycle: int | None = None
        self._zeros = np.zeros(info.n_joints)

    def update(self, inputs: ControllerInput, controlword: np.ndarray) -> float | None:
        """Write this cycle's controlwords into ``controlword``; return the trajectory time (s) of
        the output computed now, or None while enabling, settling and after a stop."""
        t = inputs.time_s
        if self._first_t is None:
            self._first_t = t
        if self.stop_reason is None:
            problem = self._problem(inputs, enabling=self._settle_until is None)
            if problem is not None:
                self.stop_reason, self.stopped_at_s = problem, t
        if self.stop_reason is not None:
            controlword[:] = int(Command.QUICK_STOP)
            return None
        statuswords = inputs.statusword.tolist()
        if self._settle_until is None:
            fresh = inputs.fresh.tolist()
            for i, status in enumerate(statuswords):
                if fresh[i]:
                    controlword[i] = self.sequencers[i].next_controlword(int(status))
            if all(fresh) and all((int(s) & 0x6F) == 0x27 for s in statuswords):
                self._settle_until = inputs.cycle + self.settle_cycles
            elif t - self._first_t > self.enable_timeout_s:
                states = [decode_statusword(int(s)).value for s in statuswords]
                self.stop_reason, self.stopped_at_s = (f"the drives did not reach Operation enabled within "
                                                       f"{self.enable_timeout_s} s (states {states})"), t
                controlword[:] = int(Command.QUICK_STOP)
            return None
        controlword[:] = int(Command.ENABLE_OPERATION)
        if inputs.cycle < self._settle_until:
            return None
        if self._start_cycle is None:
            self._start_cycle = inputs.cycle
            self.motion_start_s = t + self.info.lead_cycles * self.period_s
        tau = (inputs.cycle - self._start_cycle) * self.period_s
        ref = self.reference_trajectory
        duration = ref.duration if ref is not None else 0.0
        if tau >= duration:
            self.finished = True
            tau = duration
        return tau

    def reference(self, tau: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint reference (q, qd, qdd; rad, rad/s, rad/s^2) at trajectory time ``tau`` (s); the start
        pose at rest for None. A Cartesian reference goes through the controller's IK
        (:class:`controller.joint_reference.CartesianToJoint`, warm started)."""
        ref = self.reference_trajectory
        if tau is None or ref is None:
            return self.q_start, self._zeros, self._zeros
        sample = ref.sample(ref.t_start + tau)
        if isinstance(ref, JointTrajectory):
            return sample.q, sample.qd, sample.qdd
        return self._ik.solve(sample.target, sample.twist, sample.acceleration, self.period_s)

    @staticmethod
    def _problem(inputs: ControllerInput, enabling: bool) -> str | None:
        faults = inputs.node_fault.tolist()
        if any(faults):
            nodes = [i + 1 for i, f in enumerate(faults) if f]
            return f"fieldbus node fault (threshold counter reached) on node(s) {nodes}"
        if enabling:
            return None  # the enable sequence resets faults itself
        fresh = inputs.fresh.tolist()
        for i, status in enumerate(inputs.statusword.tolist()):
            if fresh[i] and (int(status) & 0x6F) != 0x27:
                state = decode_statusword(int(status))
                if state in STOP_STATES:
                    return f"drive {i + 1} reports {STOP_STATES[state]}"
        return None
