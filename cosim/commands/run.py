"""``python -m cosim run SCENARIO [--out DIR] [--quiet] [--realtime] [--split]``: validate a scenario file and run its job."""
from __future__ import annotations

import argparse
import sys
import traceback
from pathlib import Path

NAME = "run"
HELP = ("Validate a scenario TOML file, then run its job ([scenario] job, e.g. 'fmus') and write "
        "summary.json and time series to results/<scenario name>/ (or --out DIR).")

#: Exit codes (cosim/commands/exits.py, docs/robustness.md): 0 ok, 2 invalid scenario or unusable results
#: folder, 3 the run failed (summary.json "failed"), 130 interrupted (summary.json "interrupted").
EXIT_OK, EXIT_INVALID, EXIT_FAILED, EXIT_INTERRUPTED = 0, 2, 3, 130
EXIT_INTERNAL = EXIT_FAILED  # an unexpected error is a failed run too


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """SCENARIO, --out, --quiet, --realtime, --split."""
    parser.add_argument("scenario", type=Path, help="scenario TOML file (see docs/cosim.md)")
    parser.add_argument("--out", type=Path, default=None,
                        help="results folder (default: [output] dir of the scenario, else results/<scenario name>/)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--realtime", action="store_true",
                        help="pace the run at the controller cycle (wall clock); see docs/timing.md")
    parser.add_argument("--split", action="store_true",
                        help="controller in this process, drives and plant in another (python-can udp_multicast)")


def run(args: argparse.Namespace) -> int:
    """Load and validate (nothing runs on an invalid file), lock the results folder, run the job,
    finish summary.json (``ok``, ``failed`` or ``interrupted``)."""
    from cosim.commands.exits import InvalidInput, describe_os_error
    from cosim.results.outdir import OutputFolderError, open_results_folder
    from cosim.scenario import RunContext, ScenarioError, load_scenario

    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as exc:
        raise InvalidInput(str(exc)) from None
    from cosim.realtime.execution import CELL_JOBS, CellExecution
    from cosim.realtime.config import execution_options

    try:
        options = execution_options(scenario.data, realtime=getattr(args, "realtime", False) or None,
                                    split=getattr(args, "split", False) or None)
    except ScenarioError as exc:
        raise InvalidInput(str(exc)) from None
    if options.active and scenario.job.name not in CELL_JOBS:
        raise InvalidInput(f"{args.scenario}: job {scenario.job.name!r} runs no robot cell; --realtime, --split and "
                           f"[execution] realtime/mode = 'split' apply to the jobs {sorted(CELL_JOBS)}")
    if args.out is not None:
        out_dir, origin = args.out, "--out"
    elif scenario.data.get("output", {}).get("dir"):
        out_dir, origin = Path(scenario.data["output"]["dir"]), f"{args.scenario}: output.dir"
    else:
        out_dir, origin = Path("results") / scenario.name, "results folder"
    try:
        lock = open_results_folder(out_dir, origin)
    except OutputFolderError as exc:
        raise InvalidInput(str(exc)) from None
    with lock:
        try:
            ctx = RunContext(scenario, out_dir, quiet=args.quiet,
                             execution=CellExecution(options) if options.active else None)
        except OSError as exc:
            raise InvalidInput(describe_os_error(exc, f"{origin} {str(out_dir)!r}: cannot write summary.json")) from None
        return _run_job(scenario, ctx, out_dir, args)


def _run_job(scenario, ctx, out_dir: Path, args: argparse.Namespace) -> int:
    """Run the job and write the final status; returns the exit code."""
    from cosim.cli import defer_signals
    from cosim.commands.exits import describe_os_error, is_disk_full, signal_name_of
    from cosim.master import SimulationError

    debug = getattr(args, "debug", False)
    try:
        fields = scenario.job.runner(scenario, ctx) or {}
        ctx.summary.finish_ok(ctx.sim_time_s, **fields)
    except KeyboardInterrupt as exc:  # SIGINT, or SIGTERM through the CLI's handler
        with defer_signals():
            name = signal_name_of(exc)
            ctx.summary.finish_interrupted(name, ctx.stopped_at_s, ctx.sim_time_s, mode=ctx.label or None,
                                           interrupted_in=ctx.label or None)
        print(f"{scenario.name}: interrupted by {name}"
              f"{_where(ctx)}; results so far in {out_dir}/", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BaseException as exc:
        if not isinstance(exc, Exception):
            raise
        with defer_signals():
            if isinstance(exc, SimulationError):
                reason, stopped, extra = str(exc), exc.time, {"failed_component": exc.component,
                                                               "fmu_messages": exc.messages}
                if is_disk_full(exc):
                    reason = "disk full: " + _first_line(str(exc))
            elif isinstance(exc, OSError):
                reason = (("disk full: " if is_disk_full(exc) else "")
                          + describe_os_error(exc, "" if exc.filename else f"writing the results in {out_dir}"))
                stopped, extra = ctx.stopped_at_s, {}
            elif isinstance(exc, ValueError):
                reason, stopped, extra = _first_line(str(exc)), ctx.stopped_at_s, {}
            else:
                reason, stopped, extra = f"internal error: {type(exc).__name__}: {exc}", ctx.stopped_at_s, {}
            ctx.summary.finish_failed(reason, stopped, ctx.sim_time_s, failed_in=ctx.label or None,
                                      mode=ctx.label or None, **extra)
        if debug:
            traceback.print_exc()
        first = _first_line(reason)
        print(f"error: {scenario.name}: run failed{_where(ctx)}: {first}", file=sys.stderr)
        if isinstance(exc, SimulationError) and exc.messages:
            print("\n".join(f"  FMU log: {m}" for m in exc.messages[-5:]), file=sys.stderr)
        print(f"results so far in {out_dir}/ (summary.json: failed)"
              + ("" if debug or isinstance(exc, (SimulationError, OSError, ValueError))
                 else "; run with --debug for the traceback"), file=sys.stderr)
        return EXIT_FAILED
    data = ctx.summary.data
    if not args.quiet:
        print(f"{scenario.name}: ok, {data['sim_time_s']:.6g} s simulated in {data['wall_time_s']:.3g} s "
              f"({data['realtime_factor']:.3g}x real time); results in {out_dir}/", file=sys.stderr)
    return EXIT_OK


def _first_line(text: str) -> str:
    return text.strip().splitlines()[0] if text.strip() else text


def _where(ctx) -> str:
    parts = []
    if ctx.label:
        parts.append(f"mode {ctx.label}")
    if ctx.stopped_at_s is not None:
        parts.append(f"t = {ctx.stopped_at_s:.6g} s")
    return f" ({', '.join(parts)})" if parts else ""
