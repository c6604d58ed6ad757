"""A POWERLINK network held to the wall clock: pacing + overrun policy around ``run_cycle``.

:class:`PacedNetwork` has the ``run_cycle(cycle, setpoints, actuals)`` of
:class:`fieldbus.PowerlinkNetwork`, so the robot cell's bus-cycle task
(:class:`cosim.cell.link.FieldbusLink`) drives it unchanged: before the cycle's
frames go out it waits for the cycle's wall deadline (:class:`Pacer`); a late cycle
gets the scenario's overrun policy (:mod:`cosim.execution.timing.policy`).
"""
from __future__ import annotations

import dataclasses
from typing import Any

from cosim.execution.timing.pacer import Pacer, realtime_scheduling
from cosim.execution.timing.policy import SetpointGate, install_overrun_plan
from cosim.execution.timing.schedule import precompute_schedules
from fieldbus import DriveActuals, FieldbusConfig, PowerlinkNetwork, Setpoints
from fieldbus.process_data import CycleResult

#: The CAN log is handed to python-can's Logger only when the run ends (in-loop hand-overs
#: encode thousands of frames at once: milliseconds of stall).
DEFERRED_FLUSH_CYCLES = 1 << 40


def deferred_recording(config: FieldbusConfig) -> FieldbusConfig:
    """``config`` with the CAN log buffered for the whole run (paced runs)."""
    return dataclasses.replace(config, recording=dataclasses.replace(config.recording,
                                                                     flush_every_cycles=DEFERRED_FLUSH_CYCLES))


def auto_tolerance_s(layout) -> float:
    """The default overrun tolerance, s: the cycle time minus the isochronous phase (SoC, then
    PReq/PRes of every node until the last PRes is at the managing node). A cycle that starts
    later than this has telegrams that are not all on the bus by the next SoC: an overrun."""
    return float(layout.cycle_time - layout.nominal_end_of_isochronous)


def lateness_thresholds(layout) -> dict[str, float]:
    """Lateness thresholds reported besides the tolerance (s): the first PReq's slot (stricter:
    fresh set-points miss the first PReq), the isochronous phase's end (the default
    tolerance) and a whole cycle (a wall tick missed)."""
    return {"first_preq_slot": float(layout.nominal_soc_to_preq[1]), "isochronous_phase": auto_tolerance_s(layout),
            "whole_cycle": float(layout.cycle_time)}


class PacedNetwork:
    """``network`` (one process) paced by ``pacer`` with overrun ``policy``; with ``cycles``
    the frame timestamps of cycles 0..cycles-1 are computed at construction.

    Attributes:
        pacer: the :class:`Pacer` (its ``log`` holds the lateness of every cycle).
        gate: the :class:`SetpointGate` (managing-node side of ``hold``/``skip``).
        plan: the :class:`OverrunFaultPlan` both endpoints use (``lost_frame``).
    """

    def __init__(self, network: PowerlinkNetwork, pacer: Pacer, policy: str, cycles: int | None = None) -> None:
        self.network = network
        self.pacer = pacer
        self.policy = policy
        self.gate = SetpointGate(policy, network.config.nodes)
        self.plan = install_overrun_plan(network.mn_side, network.drive_side)
        self.config = network.config
        self.last_late = False
        self.last_lost = False
        if cycles is not None:  # frame timestamps of the whole run now, not in the loop
            precompute_schedules((network.mn_side, network.drive_side), cycles, policy == "lost_frame")

    def run_cycle(self, cycle: int, setpoints: Setpoints, actuals: DriveActuals) -> CycleResult:
        """Wait for the wall deadline of ``cycle``, apply the policy if it is late, run the cycle."""
        late = self.pacer.wait(cycle)
        lost = late and self.policy == "lost_frame"
        if lost:
            self.plan.mark_lost(cycle)
        # what the controller is told in this cycle (controller.contract.ControllerInput)
        self.last_late = late and not lost
        self.last_lost = lost
        return self.network.run_cycle(cycle, self.gate.send(setpoints, late), actuals)

    def summary(self) -> dict[str, Any]:
        return self.network.summary()

    def close(self) -> None:
        self.network.close()


class Pacing:
    """How a cell on one master is held to the wall clock (the paced mode of
    :func:`cosim.execution.run_cell`; :func:`cosim.execution.cell_master.run_on_master` asks it):
    the CAN log buffered for the run (:meth:`fieldbus`), the network wrapped in a
    :class:`PacedNetwork` with its :class:`Pacer` and the loop's scheduling (:meth:`bus`).
    ``settings`` is a :class:`cosim.execution.config.RealtimeSettings`; ``pacer`` a Pacer to use
    (tests: one on a virtual clock), else one is made for the run (:attr:`pacer` afterwards)."""

    def __init__(self, settings: Any, pacer: Pacer | None = None) -> None:
        self.settings = settings
        self.pacer = pacer

    def fieldbus(self, config: FieldbusConfig) -> FieldbusConfig:
        return deferred_recording(config)

    def bus(self, network: PowerlinkNetwork, period: float, stop_time: float) -> tuple[PacedNetwork, Any]:
        """The paced network around ``network`` and the scheduling context of the loop."""
        settings = self.settings
        tolerance = settings.tolerance_s if settings.tolerance_s is not None else auto_tolerance_s(network.layout)
        if self.pacer is None:
            self.pacer = Pacer(period, settings.spin_s, tolerance, capacity=int(stop_time / period) + 16)
        self.pacer.thresholds = lateness_thresholds(network.layout)
        bus = PacedNetwork(network, self.pacer, settings.overrun_policy, cycles=int(round(stop_time / period)) + 1)
        return bus, realtime_scheduling(settings.scheduling, settings.fifo_priority, settings.cpu)
