"""Run a loaded scenario's job into a results folder: lock the folder, check the budget, run the
job, finish ``summary.json`` (ok, a verdict, failed with the reason and where, interrupted) and
write report.html. :func:`run` (validate and run, :class:`~cosim.runs.result.RunFailed` on a
failed run) and :func:`execute` (the layer under ``cosim run``, ``cosim serve`` and every sweep
variant) return the :class:`~cosim.runs.result.RunResult`.

Part of :mod:`cosim.runs` (one run of a scenario), re-exported by :mod:`cosim.api`, the public
module for scripts (docs/how-to/scripting.md).
"""
from __future__ import annotations

import dataclasses
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from cosim.runs.result import RunFailed, RunResult
from cosim.runs.scenario import Scenario, _is_label, load_scenario
from cosim.scenario.errors import ScenarioError

def run(scenario: "str | Path | Mapping[str, Any] | Scenario", out: str | Path | None = None,
        overrides: Mapping[str, Any] | None = None, *, quiet: bool = True, realtime: bool = False,
        split: bool = False, check: bool = True, timeseries: str | None = None,
        max_output: str | float | None = None, max_memory: str | float | None = None,
        ignore_budget: bool = False) -> RunResult:
    """Validate and run a scenario; return its :class:`RunResult`.

    Args:
        scenario: as for :func:`load_scenario`.
        out: the results folder (created; files in it are replaced; locked while the run goes).
            None: a new temporary folder (``RunResult.temporary``; kept until :meth:`RunResult.cleanup`).
        overrides: ``{"key.path": value}`` applied before validation.
        quiet: no progress bar on stderr.
        realtime, split: pace the robot cell at the wall clock / run controller and drives in two
            processes (as ``cosim run --realtime/--split``; docs/how-to/served_cell.md).
        check: raise :class:`RunFailed` when the run ends ``failed`` (False: return the result).
            A run that completed with verdict ``limit`` or ``fault`` is returned, not raised:
            ``result.status`` says so (and ``result.summary["verdicts"]`` per cell run).
        timeseries: ``"parquet"`` (default, or ``$COSIM_TIMESERIES``) or ``"csv"``: the format
            of the time-series files.
        max_output, max_memory, ignore_budget: the run's budget (``cosim.results.budget``:
            sizes like ``"5 GB"``; default: free disk space, half the RAM); a run estimated
            above it raises :class:`cosim.results.budget.BudgetError` before anything runs.

    Raises:
        ScenarioError: invalid scenario or override (nothing is written, no folder is made).
        OutputFolderError: ``out`` cannot be used (a file, not writable, locked by another run).
        RunFailed: the run failed (``check=True``); summary.json in the folder says why and where.
        KeyboardInterrupt: Ctrl-C (or SIGTERM under the CLI), passed on after summary.json is
            finished as ``interrupted`` (with the signal and where it stopped).
    """
    sc = load_scenario(scenario, overrides)
    options = _execution_options(sc, realtime, split)
    if out is None:
        out_dir, temporary = Path(tempfile.mkdtemp(prefix=f"cosim-{sc.name}-")), True
    else:
        out_dir, temporary = Path(out), False
    result = _execute_into(sc, out_dir, options, quiet=quiet, origin="out", temporary=temporary,
                           timeseries=timeseries, budget=None if ignore_budget else (max_output, max_memory))
    if check and result.status == "failed":
        raise RunFailed(result) from result.error
    return result


def execute(scenario: Scenario, out: str | Path, *, quiet: bool = True, realtime: bool = False,
            split: bool = False, origin: str = "out", timeseries: str | None = None, serve: Any = None,
            max_output: str | float | None = None, max_memory: str | float | None = None,
            ignore_budget: bool = False, clock_from_process_start: bool = False,
            report: bool | None = None) -> RunResult:
    """Run an already loaded scenario into ``out`` and return the result whatever its status
    (the layer under :func:`run` and ``cosim run``; ``origin`` names where ``out`` came from in
    an OutputFolderError, e.g. ``"--out"``). ``serve`` (a :class:`cosim.execution.serve_settings.ServeSettings`):
    run only the cell side of each robot-cell run, paced, for a controller elsewhere on the bus
    (``cosim serve``). ``max_output``, ``max_memory``, ``ignore_budget``: as for :func:`run`.
    ``clock_from_process_start``: summary.json's ``wall_time_s`` and ``realtime_factor`` count
    from this process's start (``cosim run``: the whole command, interpreter start and imports
    included; ``wall_time_from = "process start"``) instead of from this call. ``report``: write
    report.html (None: unless the scenario's ``[results] report`` is false; docs/how-to/view_results.md).
    Raises ScenarioError, OutputFolderError, KeyboardInterrupt as :func:`run` does (and
    BudgetError); never RunFailed."""
    if serve is not None:
        options = _execution_options(scenario, True, False)
        options = dataclasses.replace(options, mode="serve", realtime=True, serve=serve)
    else:
        options = _execution_options(scenario, realtime, split)
    return _execute_into(scenario, Path(out), options, quiet=quiet, origin=origin, temporary=False,
                         timeseries=timeseries, budget=None if ignore_budget else (max_output, max_memory),
                         clock_from_process_start=clock_from_process_start, report=report)


def _execution_options(sc: Scenario, realtime: bool, split: bool):
    """The cell execution options, or None (one process, unpaced); ScenarioError for a job without a cell."""
    from cosim.execution.config import execution_options
    from cosim.execution.cell_execution import CELL_JOBS

    options = execution_options(sc.data, realtime=realtime or None, split=split or None)
    if not options.active:
        return None
    if sc.job not in CELL_JOBS:
        raise ScenarioError(sc.source if _is_label(sc.source) else sc.path, "execution",
                            f"a job that runs a robot cell ({', '.join(sorted(CELL_JOBS))}) for realtime, split and "
                            f"[execution] realtime/mode = 'split'", sc.job,
                            problem=f"job {sc.job!r} runs no robot cell")
    return options


def _execute_into(sc: Scenario, out_dir: Path, options, *, quiet: bool, origin: str, temporary: bool,
                  timeseries: str | None = None, budget: tuple | None = (None, None),
                  clock_from_process_start: bool = False, report: bool | None = None) -> RunResult:
    """Lock ``out_dir``, run the job, finish summary.json, write report.html (``report``: None = as the
    scenario's ``[results] report`` says; never for a temporary folder); the result (``error``: what
    failed the run)."""
    wall_origin, wall_time_from = None, "run call"
    if clock_from_process_start:
        from cosim.results.summary import process_started_perf_counter

        wall_origin = process_started_perf_counter()
        if wall_origin is not None:
            wall_time_from = "process start"
    from cosim.results.exits import describe_os_error
    from cosim.results.outdir import OutputFolderError, open_results_folder
    from cosim.scenario import RunContext

    execution = None
    if options is not None:
        from cosim.execution.cell_execution import CellExecution

        execution = CellExecution(options)
    with open_results_folder(out_dir, origin):
        if budget is not None:  # the folder is usable: the estimate, before anything runs or is written
            from cosim.results.budget import check_budget, estimate_run
            from cosim.results.timeseries import default_format

            held = execution is not None and bool(getattr(execution, "active", False))
            check_budget(estimate_run(sc.data, timeseries or default_format(), in_memory=held), out_dir, *budget)
        try:
            ctx = RunContext(sc.validated, out_dir, quiet=quiet, execution=execution, timeseries_format=timeseries,
                             wall_origin=wall_origin, wall_time_from=wall_time_from)
        except OSError as exc:
            raise OutputFolderError(describe_os_error(exc, f"{origin} {str(out_dir)!r}: cannot write summary.json"))\
                from None
        try:
            error = _run_job(sc, ctx)
        except BaseException:
            from cosim.results import report as report_module

            report_module.cancel(out_dir)  # interrupted: 'cosim view' shows what is there
            raise
        if report is None:
            from cosim.results import report as report_module

            report = not temporary and report_module.wanted(sc.data)
        _write_report(out_dir, report)
    return RunResult(out_dir, sc, temporary, error)


def _write_report(out_dir: Path, wanted: bool) -> None:
    """report.html in the results folder (``[results] report``, docs/how-to/view_results.md); a report that cannot
    be written is a warning line, never a failed run (``cosim view`` writes it later)."""
    import sys

    from cosim.results import report

    if not wanted:
        report.cancel(out_dir)
        return
    try:
        report.finish(out_dir)
    except Exception as exc:  # noqa: BLE001 - the run's results are complete without it
        report.cancel(out_dir)
        print(f"warning: {out_dir / report.REPORT_NAME} not written ({type(exc).__name__}: {exc}); "
              f"'python -m cosim view {out_dir}' writes it", file=sys.stderr)


def _run_job(sc: Scenario, ctx) -> BaseException | None:
    """Run the job in ``ctx`` and write the final status (ok, failed with the reason and where,
    interrupted); return the exception that failed the run, or None."""
    from cosim.results.interrupts import defer_signals, interrupt_raised
    from cosim.results.exits import describe_os_error, is_disk_full, signal_name_of
    from cosim.master import SimulationError

    try:
        fields = sc.validated.job.runner(sc.validated, ctx) or {}
        status, reason, verdict_fields = _job_verdict(ctx)
        ctx.summary.finish_verdict(status, ctx.sim_time_s, reason, **fields, **verdict_fields)
        return None
    except KeyboardInterrupt as exc:  # SIGINT, or SIGTERM through the CLI's handler
        with defer_signals():
            if getattr(ctx, "verdicts", None):
                ctx.summary.data["verdicts"] = dict(ctx.verdicts)
            ctx.summary.finish_interrupted(signal_name_of(exc), ctx.stopped_at_s, ctx.sim_time_s,
                                           mode=ctx.label or None, interrupted_in=ctx.label or None)
        raise
    except Exception as exc:
        interrupt = interrupt_raised()
        if interrupt is not None:  # Ctrl-C raised inside code that turned it into this error (a Python FMU)
            with defer_signals():
                ctx.summary.finish_interrupted(interrupt.signal_name, ctx.stopped_at_s, ctx.sim_time_s,
                                               mode=ctx.label or None, interrupted_in=ctx.label or None)
            raise interrupt from exc
        with defer_signals():
            extra: dict[str, Any] = {}
            if isinstance(exc, SimulationError):
                reason, stopped = str(exc), exc.time
                extra = {"failed_component": exc.component, "fmu_messages": exc.messages}
                if is_disk_full(exc):
                    reason = "disk full: " + _first_line(str(exc))
            elif isinstance(exc, OSError):
                reason = (("disk full: " if is_disk_full(exc) else "")
                          + describe_os_error(exc, "" if exc.filename else f"writing the results in {ctx.out_dir}"))
                stopped = ctx.stopped_at_s
            elif isinstance(exc, ValueError):
                reason, stopped = _first_line(str(exc)), ctx.stopped_at_s
            else:
                reason, stopped = f"internal error: {type(exc).__name__}: {exc}", ctx.stopped_at_s
            if getattr(ctx, "verdicts", None):
                extra["verdicts"] = dict(ctx.verdicts)
            ctx.summary.finish_failed(reason, stopped, ctx.sim_time_s, failed_in=ctx.label or None,
                                      mode=ctx.label or None, **extra)
        return exc


def _job_verdict(ctx) -> tuple[str, str | None, dict[str, Any]]:
    """The job's status (the most severe verdict of its cell runs, ``ok`` without any), the
    reason naming the first such run and its first violation, and the summary fields
    ``verdicts`` (per run) and ``first_violation`` (of the run the status comes from)."""
    from cosim.cell.verdict import describe_violation, most_severe

    verdicts = dict(getattr(ctx, "verdicts", None) or {})
    if not verdicts:
        return "ok", None, {}
    status = most_severe([v["verdict"] for v in verdicts.values()])
    fields: dict[str, Any] = {"verdicts": verdicts}
    if status == "ok":
        return status, None, fields
    label, worst = next((k, v) for k, v in verdicts.items() if v["verdict"] == status)
    first = worst.get("first_violation")
    fields["first_violation"] = first
    others = [k for k, v in verdicts.items() if v["verdict"] != "ok" and k != label]
    reason = f"{label}: {status}" + (f": {describe_violation(first)}" if first else "")
    if others:
        reason += f" (also not ok: {', '.join(others)})"
    return status, reason, fields


def _first_line(text: str) -> str:
    return text.strip().splitlines()[0] if text.strip() else text


__all__ = ["execute", "run"]
