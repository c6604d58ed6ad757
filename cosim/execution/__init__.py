"""How a robot cell RUNS: one entry, :func:`run_cell`, whatever the execution mode.

A cell is described once (:class:`cosim.cell.description.CellDescription`) and executed by
one runner whose mode - simulated time in process, paced by the wall clock, split over two
processes, served to an external controller - is a property of the execution, as libcosim's
``real_time_config`` and Drake's ``set_target_realtime_rate`` make real time a property of
one execution. What a run yields is plain data of the cell (:class:`cosim.cell.run.CellRun`);
nothing in :mod:`cosim.cell` imports this package.

Modules: :mod:`~cosim.execution.runner` (the modes on one master, the mode dispatch),
:mod:`~cosim.execution.config` (the ``[execution]``/``[realtime]`` options),
:mod:`~cosim.execution.cell_execution` (what ``cosim run`` hands the jobs, the lateness report),
:mod:`~cosim.execution.timing` (pacer, overrun policies, frame schedules, statistics),
:mod:`~cosim.execution.split` (controller and drives in two processes),
:mod:`~cosim.execution.served` and :mod:`~cosim.execution.cell_side` (the cell side for an external
controller), :mod:`~cosim.execution.mode_runs` and :mod:`~cosim.execution.mode_pool` (the main job's
controller modes, side by side in worker processes).

This package module imports nothing heavy (the command line reads the served settings at start).
"""
from __future__ import annotations

from typing import Any


def run_cell(cell: Any, controller: Any, ctx: Any, **options: Any) -> Any:
    """Run ``cell`` with ``controller`` in the execution mode given or as ``ctx.execution`` says:
    :func:`cosim.execution.runner.run_cell`."""
    from cosim.execution.runner import run_cell as run

    return run(cell, controller, ctx, **options)


__all__ = ["run_cell"]
