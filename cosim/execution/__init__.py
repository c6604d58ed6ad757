"""How a robot cell RUNS: one entry, :func:`run_cell`, whatever the execution mode.

A cell is described once (:class:`cosim.cell.description.CellDescription`) and executed by one
runner whose mode is a property of the execution, as libcosim's ``real_time_config`` and
Drake's ``set_target_realtime_rate`` make real time a property of one execution:

``in_process``
    simulated time, the whole cell on one master in this process, as fast as it goes
    (:mod:`cosim.execution.simulated`);
``paced``
    the same, held to the wall clock at the bus cycle, late cycles get the overrun policy
    (``cosim run --realtime``; :mod:`cosim.execution.paced`);
``split``
    controller and managing node in this process, drives and plant in a spawned process,
    frames over UDP (``cosim run --split``, paced too with ``--realtime``;
    :mod:`cosim.execution.split`);
``serve``
    the cell side only, paced, for a controller that is another program on the bus
    (``cosim serve``; :mod:`cosim.execution.served`); the job's controller is not run.

Each mode is a module with the same small interface (:class:`Mode`: one ``run`` function);
the modes share the cell on one master (:mod:`cosim.execution.cell_master`), the timing
(:mod:`cosim.execution.timing`: pacer, overrun policies, frame schedules, lateness statistics)
and the served cell side (:mod:`cosim.execution.cell_side`), never each other. The command
line and the API choose the mode from the scenario and the flags
(:class:`cosim.execution.config.ExecutionOptions`) and hand it down on ``RunContext.execution``
(:class:`cosim.execution.cell_execution.CellExecution`, which also reports the lateness of
paced runs after each run). What a run yields is plain data of the cell
(:class:`cosim.cell.run.CellRun`); nothing in :mod:`cosim.cell` imports this package.
:mod:`~cosim.execution.mode_runs` and :mod:`~cosim.execution.mode_pool` run the main job's
controller modes, side by side in worker processes.

This package module imports nothing heavy (the command line reads the served settings at start).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable, Protocol

if TYPE_CHECKING:
    from cosim.cell.description import CellDescription
    from cosim.cell.run import CellRun

MODES = ("in_process", "paced", "split", "serve")
"""The execution modes of :func:`run_cell`."""


class Mode(Protocol):
    """What every execution mode implements (a module with this function): run ``cell`` with
    ``controller`` from 0 to its stop time and return what it yielded, everything recorded so
    far written even when a SimulationError (failing FMU, NaN output, failing or stopped
    controller) ended it early (the error in ``CellRun.failure``). ``options`` is the
    :class:`cosim.execution.config.ExecutionOptions`; ``pacer`` a pacer to use (tests: one on a
    virtual clock), ``on_cycle(cycle, session)`` a hook of split runs; a mode ignores what it
    does not use."""

    def run(self, cell: CellDescription, controller: Any, ctx: Any, options: Any, *, pacer: Any = None,
            on_cycle: Callable[[int, Any], None] | None = None) -> CellRun: ...


def _mode(name: str) -> Callable[..., Any]:
    """The ``run`` of the mode ``name`` (imported when first used: each mode has its own weight)."""
    if name == "in_process":
        from cosim.execution.simulated import run
    elif name == "paced":
        from cosim.execution.paced import run
    elif name == "split":
        from cosim.execution.split import run
    elif name == "serve":
        from cosim.execution.served import run
    else:
        raise ValueError(f"cell execution mode {name!r}: expected one of {MODES}")
    return run


def run_cell(cell: CellDescription, controller: Any, ctx: Any, *, mode: str | None = None, options: Any = None,
             pacer: Any = None, on_cycle: Callable[[int, Any], None] | None = None) -> CellRun:
    """Run ``cell`` with ``controller`` (a :class:`controller.CellController`) from 0 to its stop
    time in ``mode`` (:data:`MODES`), or, without one, in the mode of the execution the command
    line chose (``ctx.execution``, :class:`cosim.execution.cell_execution.CellExecution`: its
    options, and its lateness report once the run has ended), else in process.

    ``options`` is a :class:`cosim.execution.config.ExecutionOptions` for ``paced``/``split``/
    ``serve`` (default: the defaults of the mode); ``pacer`` a
    :class:`~cosim.execution.timing.pacer.Pacer` to use (tests: one on a virtual clock);
    ``on_cycle(cycle, session)`` a hook of split runs.

    In process, the recorder streams to ``cell.record_file`` in the results folder as the run
    goes and ``CellRun.recording`` reads it back; paced and split runs sample into memory and
    write the file when the loop has ended (no file I/O inside a paced cycle). Whatever the mode,
    ``CellRun.protection_events`` holds the drives' and the plant's protection events of the run
    (:func:`cosim.cell.protection.protection_events`, from the recording).
    """
    from cosim.cell.protection import protection_events

    execution = None
    if mode is None:
        execution = getattr(ctx, "execution", None)
        if execution is not None and execution.active:
            mode, options = execution.mode, execution.options
        else:
            execution, mode = None, "in_process"
    run = _mode(mode)
    if options is None:
        from cosim.execution.config import ExecutionOptions

        options = ExecutionOptions(mode="split" if mode == "split" else "in_process", realtime=(mode == "paced"))
    if execution is not None:
        execution.started(cell)
    result = run(cell, controller, ctx, options, pacer=pacer, on_cycle=on_cycle)
    result.protection_events = protection_events(cell, result.recording, result.fieldbus)
    if execution is not None:
        execution.finished(cell, result, ctx)
    return result


__all__ = ["MODES", "Mode", "run_cell"]
