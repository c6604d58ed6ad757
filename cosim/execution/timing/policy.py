"""What the telegrams of a late cycle carry: the overrun policies.

A cycle is an *overrun* when its telegrams (SoC, the PReqs carrying the set-points the
controller computed in the previous cycle, the PRes frames) are not all on the bus by
the next SoC: it starts later than its wall deadline by more than the tolerance (the
cycle time minus the isochronous phase, :func:`cosim.execution.timing.network.auto_tolerance_s`;
:class:`cosim.execution.timing.pacer.Pacer` judges it before the cycle's frames are sent). The
scenario chooses the reaction (``[realtime] overrun_policy``):

``hold``
    The PReqs leave on time with the set-points of the previous cycle (the managing
    node's process image was not refreshed): every drive receives a valid frame and
    keeps its last set-point for one more cycle. The late set-point is dropped. No
    error is counted.
``skip``
    The late set-point is dropped and the managing node skips it by dead reckoning:
    the PReqs carry the set-point extrapolated from the last two that were sent
    (constant joint velocity; torque offset and controlword held), so the drives
    continue along the path for that cycle. No error is counted.
``lost_frame``
    The late cycle's PReqs are lost frames on the drive side: exactly the fieldbus
    fault ``frames = "preq", kind = "loss"`` for every node in that cycle
    (:class:`OverrunFaultPlan`), so each controlled node counts a loss of PReq in its
    POWERLINK threshold counter (+8 per error, -1 per good cycle, threshold 15),
    applies its missing-set-point reaction (``[fieldbus.reaction] missing_setpoint``)
    and - having received no PReq - sends no PRes, so the managing node counts a lost
    PRes too. Two overruns within a few cycles trip the counters: the drives run their
    communication-fault reaction and the controller stops commanding motion.

:class:`SetpointGate` applies ``hold``/``skip`` on the managing-node side;
:class:`OverrunFaultPlan` wraps each endpoint's fault plan for ``lost_frame`` (in the
split mode the drive side learns the lost cycles from the cycle marker, see
:mod:`cosim.execution.split.protocol`).
"""
from __future__ import annotations

import numpy as np

from cosim.execution.config import OVERRUN_POLICIES
from fieldbus import Setpoints
from fieldbus.faults import CycleFaults


class SetpointGate:
    """Managing-node side: the set-points that go into each cycle's PReqs.

    ``send(setpoints, late)`` returns what the PReqs carry (a reused object) and
    remembers the last two sent for ``hold`` and ``skip``."""

    def __init__(self, policy: str, nodes: int) -> None:
        if policy not in OVERRUN_POLICIES:
            raise ValueError(f"overrun policy {policy!r}: expected one of {OVERRUN_POLICIES}")
        self.policy = policy
        self.nodes = nodes
        self._last = Setpoints.zeros(nodes)
        self._before = Setpoints.zeros(nodes)
        self._out = Setpoints.zeros(nodes)
        self._sent = 0
        self.substituted = 0

    def _remember(self, sp: Setpoints) -> None:
        self._before, self._last = self._last, self._before
        last = self._last
        last.controlword[:] = sp.controlword
        last.position[:] = sp.position
        last.torque_offset[:] = sp.torque_offset
        last.modes_of_operation[:] = sp.modes_of_operation
        last.target_velocity[:] = sp.target_velocity
        last.velocity_offset[:] = sp.velocity_offset
        last.target_torque[:] = sp.target_torque
        self._sent += 1

    def send(self, setpoints: Setpoints, late: bool) -> Setpoints:
        """The set-points for this cycle's PReqs: ``setpoints`` when on time (or under
        ``lost_frame``, whose frames the fault plan drops), else the policy's substitute."""
        if not late or self.policy == "lost_frame" or self._sent == 0:
            self._remember(setpoints)
            return setpoints
        out, last = self._out, self._last
        out.controlword[:] = last.controlword
        out.torque_offset[:] = last.torque_offset
        out.modes_of_operation[:] = last.modes_of_operation  # held: a late cycle never switches the mode
        out.target_velocity[:] = last.target_velocity
        out.velocity_offset[:] = last.velocity_offset
        out.target_torque[:] = last.target_torque
        if self.policy == "skip" and self._sent >= 2:
            np.subtract(2.0 * last.position, self._before.position, out=out.position)
        else:
            out.position[:] = last.position
        self.substituted += 1
        self._remember(out)
        return out


class OverrunFaultPlan:
    """A fieldbus fault plan (``endpoint.plan``) plus 'loss' of every PReq in the cycles
    marked lost (policy ``lost_frame``). Both sides of a network must use plans marked
    alike (one shared object in one process)."""

    def __init__(self, base, nodes: int) -> None:
        self.base = base
        self.nodes = nodes
        self._lost: set[int] = set()

    def mark_lost(self, cycle: int) -> None:
        """The PReqs of ``cycle`` are lost frames."""
        self._lost.add(cycle)

    def is_lost(self, cycle: int) -> bool:
        return cycle in self._lost

    def for_cycle(self, cycle: int) -> CycleFaults | None:
        faults = self.base.for_cycle(cycle)
        if cycle not in self._lost:
            return faults
        kinds = dict(faults.kinds) if faults is not None else {}
        for node in range(1, self.nodes + 1):
            kinds[node] = "loss"
        return CycleFaults(cycle, kinds)


def install_overrun_plan(*endpoints) -> OverrunFaultPlan:
    """Wrap the fault plan of the first endpoint and give the wrapper to all of them."""
    plan = OverrunFaultPlan(endpoints[0].plan, endpoints[0].config.nodes)
    for endpoint in endpoints:
        endpoint.plan = plan
    return plan
