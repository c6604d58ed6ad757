"""The simulated-time mode (``in_process``): the whole cell on one master in this process,
stepped as fast as it goes; the controller runs as the bus-cycle task
(:class:`cosim.cell.link.FieldbusLink`) in simulated time. The recorder streams to
``cell.record_file`` in the results folder as the run goes (Parquet by default, bounded
buffer; the suffix follows the run's format) and ``CellRun.recording`` reads it back.
"""
from __future__ import annotations

from typing import Any

from controller import CellController
from cosim.cell.description import CellDescription
from cosim.cell.run import CellRun
from cosim.execution.cell_master import run_on_master
from cosim.scenario.context import RunContext


def run(cell: CellDescription, controller: CellController, ctx: RunContext, options: Any, *, pacer: Any = None,
        on_cycle: Any = None) -> CellRun:
    """The :class:`cosim.execution.Mode` ``run`` of the simulated mode (``options``, ``pacer`` and
    ``on_cycle`` are not used: nothing is paced, nothing split)."""
    return run_on_master(cell, controller, ctx)
