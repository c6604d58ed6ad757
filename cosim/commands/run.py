"""``python -m cosim run SCENARIO [--out DIR] [--quiet] [--realtime] [--split]``: validate a scenario file and run its job."""
from __future__ import annotations

import argparse
import sys
import traceback
from pathlib import Path

NAME = "run"
HELP = ("Validate a scenario TOML file, then run its job ([scenario] job, e.g. 'fmus') and write "
        "summary.json and time series to results/<scenario name>/ (or --out DIR).")

#: Exit codes (cosim/results/exits.py, docs/reference/verdicts.md): 0 ok, 2 invalid scenario or unusable results
#: folder, 3 the run failed (summary.json "failed"), 4 a run hit a limit ("limit"), 5 a run faulted
#: ("fault"), 130 interrupted (summary.json "interrupted").
EXIT_OK, EXIT_INVALID, EXIT_FAILED, EXIT_INTERRUPTED = 0, 2, 3, 130
EXIT_INTERNAL = EXIT_FAILED  # an unexpected error is a failed run too


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """SCENARIO, --out, --quiet, --realtime, --split."""
    parser.add_argument("scenario", type=Path, help="scenario TOML file (see docs/reference/scenario_keys.md)")
    parser.add_argument("--out", type=Path, default=None,
                        help="results folder (default: [output] dir of the scenario, else results/<scenario name>/)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--realtime", action="store_true",
                        help="pace the run at the controller cycle (wall clock); see docs/how-to/served_cell.md")
    parser.add_argument("--split", action="store_true",
                        help="controller in this process, drives and plant in another: in lock-step over python-can "
                             "udp_multicast; with --realtime both paced, the cell served over udpcycle (docs/how-to/served_cell.md)")
    parser.add_argument("--max-output", default=None, metavar="SIZE",
                        help="refuse a run estimated to write more (e.g. '5 GB'; default: $COSIM_MAX_OUTPUT, else the "
                             "free disk space)")
    parser.add_argument("--max-memory", default=None, metavar="SIZE",
                        help="refuse a run estimated to hold more in memory (default: $COSIM_MAX_MEMORY, else half "
                             "the RAM)")
    parser.add_argument("--ignore-budget", action="store_true", help="run even above --max-output/--max-memory")
    parser.add_argument("--timeseries", choices=("parquet", "csv"), default=None,
                        help="format of the time-series files (default: parquet, or $COSIM_TIMESERIES); "
                             "see docs/reference/output_files.md")


def run(args: argparse.Namespace) -> int:
    """:func:`_run` (for a job that draws its figures in a process forked first,
    :data:`EARLY_FIGURES`, that process is started before anything else and ended after);
    then the objects of the run are frozen for the garbage collector
    (``gc.freeze``): the process ends next, and Python's last collections at exit would walk
    every object the run created (0.3-1 s of the main job's wall time, after its final
    status). Files are closed by then; memory goes back with the process."""
    import gc

    from cosim.results import figure_process

    _start_figure_process(args)
    try:
        return _run(args)
    finally:
        figure_process.stop()
        gc.freeze()


#: Jobs whose figures a process forked at the command's start draws
#: (:mod:`cosim.results.figure_process`): job name -> its warm-up, ``"module:function"``.
EARLY_FIGURES = {"iso9283": "cosim.jobs.iso9283_figures:warm_up"}


def _start_figure_process(args: argparse.Namespace) -> None:
    """Fork the figure process before anything heavy is imported, when the scenario file's job
    draws its figures there (:data:`EARLY_FIGURES`) and ``[results] figures`` is not false; in
    process runs only (not ``--realtime``/``--split``). A file that cannot be read or parsed
    starts nothing (loading it reports the error)."""
    if getattr(args, "realtime", False) or getattr(args, "split", False):
        return
    import tomllib

    try:
        document = tomllib.loads(Path(args.scenario).read_text(encoding="utf-8"))
        warm_up = EARLY_FIGURES.get(document.get("scenario", {}).get("job"))
        wanted = document.get("results", {}).get("figures", True) is not False
    except (OSError, ValueError, AttributeError, TypeError):
        return
    if warm_up is not None and wanted:
        from cosim.results import figure_process

        figure_process.start(warm_up)


def _run(args: argparse.Namespace) -> int:
    """Load and validate (nothing runs on an invalid file), then run through the public API
    (:func:`cosim.api.execute`: results-folder lock, final status ``ok``, ``failed`` or
    ``interrupted``) and turn the outcome into messages and the exit code."""
    from cosim.api import OutputFolderError, ScenarioError, execute, load_scenario
    from cosim.results.exits import InvalidInput
    from cosim.master import SimulationError

    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as exc:
        raise InvalidInput(str(exc)) from None
    requests = (scenario.data.get("fieldbus") or {}).get("asynchronous")
    if requests and getattr(args, "realtime", False) and getattr(args, "split", False):
        raise InvalidInput(str(ScenarioError(
            args.scenario, "fieldbus.asynchronous", "no scripted SDO/NMT requests with --realtime --split (the "
            "paced split run's served cell carries the cyclic telegrams only); run them in process, with "
            "--realtime or with --split", given=f"{len(requests)} request(s)")))
    if args.out is not None:
        out_dir, origin = args.out, "--out"
    elif scenario.data.get("output", {}).get("dir"):
        out_dir, origin = Path(scenario.data["output"]["dir"]), f"{args.scenario}: output.dir"
    else:
        out_dir, origin = Path("results") / scenario.name, "results folder"
    try:
        result = execute(scenario, out_dir, quiet=args.quiet, realtime=getattr(args, "realtime", False),
                         split=getattr(args, "split", False), origin=origin,
                         timeseries=getattr(args, "timeseries", None), max_output=getattr(args, "max_output", None),
                         max_memory=getattr(args, "max_memory", None),
                         ignore_budget=getattr(args, "ignore_budget", False), clock_from_process_start=True)
    except (ScenarioError, OutputFolderError) as exc:
        raise InvalidInput(str(exc)) from None
    except ValueError as exc:  # BudgetError (estimate above the budget), a bad size, $COSIM_TIMESERIES
        raise InvalidInput(f"{args.scenario}: {exc}") from None
    except KeyboardInterrupt as exc:  # SIGINT, or SIGTERM through the CLI's handler
        from cosim.api import RunResult
        from cosim.results.exits import signal_name_of

        summary = RunResult(out_dir).summary
        print(f"{scenario.name}: interrupted by {signal_name_of(exc)}{_where(summary)}; results so far in "
              f"{out_dir}/", file=sys.stderr)
        return EXIT_INTERRUPTED
    summary = result.summary
    print_run_lines(summary.raw, args.quiet)
    if result.ok:
        data = summary.raw
        if not args.quiet:
            print(f"{scenario.name}: ok, {data['sim_time_s']:.6g} s simulated in {data['wall_time_s']:.3g} s "
                  f"({data['realtime_factor']:.3g}x real time); results in {out_dir}/", file=sys.stderr)
        return EXIT_OK
    if summary.status in ("limit", "fault"):
        from cosim.cell.verdict import exit_code

        data = summary.raw
        print(f"{scenario.name}: {summary.status}: {_first_line(summary.reason or '')}; "
              f"{data['sim_time_s']:.6g} s simulated; results in {out_dir}/ (summary.json: {summary.status}, "
              f"exit code {exit_code(summary.status)}, docs/reference/verdicts.md)", file=sys.stderr)
        return exit_code(summary.status)
    exc = result.error
    debug = getattr(args, "debug", False)
    if debug and exc is not None:
        traceback.print_exception(exc)
    print(f"error: {scenario.name}: run failed{_where(summary)}: {_first_line(summary.reason or '')}",
          file=sys.stderr)
    if isinstance(exc, SimulationError) and exc.messages:
        print("\n".join(f"  FMU log: {m}" for m in exc.messages[-5:]), file=sys.stderr)
    print(f"results so far in {out_dir}/ (summary.json: failed)"
          + ("" if debug or isinstance(exc, (SimulationError, OSError, ValueError))
             else "; run with --debug for the traceback"), file=sys.stderr)
    return EXIT_FAILED


def print_run_lines(data: dict, quiet: bool = False) -> None:
    """One console line per cell run of the job (``label: verdict[: first violation]``) and one
    per warning (e.g. chronic compute-budget overruns); with ``quiet`` only the runs that are not
    ok and the warnings."""
    from cosim.cell.verdict import describe_violation, run_line

    verdicts = data.get("verdicts") or {}
    if len(verdicts) <= 1 and data.get("status") == "ok" and not any(v.get("warnings") for v in verdicts.values()):
        return  # one run, ok: the command's line says it all
    for label, v in verdicts.items():
        if not quiet or v.get("verdict") != "ok":
            print(f"  {run_line(label, v)}", file=sys.stderr)
        for warning in v.get("warnings") or ():
            print(f"  warning: {label}: {describe_violation(warning)}", file=sys.stderr)


def _first_line(text: str) -> str:
    return text.strip().splitlines()[0] if text.strip() else text


def _where(summary) -> str:
    """`` (mode x, t = 1.2 s)`` from a summary's ``mode`` and ``stopped_at_s``."""
    parts = []
    if summary.raw.get("mode"):
        parts.append(f"mode {summary.raw['mode']}")
    if summary.stopped_at_s is not None:
        parts.append(f"t = {summary.stopped_at_s:.6g} s")
    return f" ({', '.join(parts)})" if parts else ""
