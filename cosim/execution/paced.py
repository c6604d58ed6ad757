"""The paced mode (``cosim run --realtime``): the whole cell on one master in this process, held
to the wall clock at the bus cycle. Every bus cycle waits for its wall deadline
(:class:`cosim.execution.timing.network.PacedNetwork`), late cycles get the overrun policy
(:mod:`cosim.execution.timing.policy`); the recording and the CAN log stay in memory until the
loop has ended (no file I/O inside a paced cycle); the loop runs without cyclic GC, pinned and,
when granted, under SCHED_FIFO (:func:`cosim.execution.timing.pacer.realtime_scheduling`).
"""
from __future__ import annotations

from typing import Any

from controller import CellController
from cosim.cell.description import CellDescription
from cosim.cell.run import CellRun
from cosim.execution.cell_master import run_on_master
from cosim.execution.timing.network import Pacing
from cosim.scenario.context import RunContext


def run(cell: CellDescription, controller: CellController, ctx: RunContext, options: Any, *, pacer: Any = None,
        on_cycle: Any = None) -> CellRun:
    """The :class:`cosim.execution.Mode` ``run`` of the paced mode: ``options.settings`` (the
    ``[realtime]`` table) say how; ``pacer`` is a :class:`cosim.execution.timing.pacer.Pacer` to
    use (tests: one on a virtual clock), else one is made; ``CellRun.pacer`` holds it."""
    return run_on_master(cell, controller, ctx, pacing=Pacing(options.settings, pacer))
