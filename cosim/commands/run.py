"""``python -m cosim run SCENARIO [--out DIR] [--quiet] [--realtime] [--split]``: validate a scenario file and run its job."""
from __future__ import annotations

import argparse
import sys
import traceback
from pathlib import Path

NAME = "run"
HELP = ("Validate a scenario TOML file, then run its job ([scenario] job, e.g. 'fmus') and write "
        "summary.json and time series to results/<scenario name>/ (or --out DIR).")

#: Exit codes: 0 ok, 1 simulation failed, 2 invalid scenario, 3 internal error.
EXIT_OK, EXIT_FAILED, EXIT_INVALID, EXIT_INTERNAL = 0, 1, 2, 3


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
    parser.add_argument("--max-output", default=None, metavar="SIZE",
                        help="refuse a run estimated to write more (e.g. '5 GB'; default: $COSIM_MAX_OUTPUT, else the "
                             "free disk space)")
    parser.add_argument("--max-memory", default=None, metavar="SIZE",
                        help="refuse a run estimated to hold more in memory (default: $COSIM_MAX_MEMORY, else half "
                             "the RAM)")
    parser.add_argument("--ignore-budget", action="store_true", help="run even above --max-output/--max-memory")
    parser.add_argument("--timeseries", choices=("parquet", "csv"), default=None,
                        help="format of the time-series files (default: parquet, or $COSIM_TIMESERIES); "
                             "see docs/ARCHITECTURE.md")


def run(args: argparse.Namespace) -> int:
    """Load and validate (nothing runs on an invalid file), run the job, finish summary.json."""
    from cosim.master import SimulationError
    from cosim.scenario import RunContext, ScenarioError, load_scenario

    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_INVALID
    from cosim.realtime.execution import CELL_JOBS, CellExecution
    from cosim.realtime.config import execution_options

    options = execution_options(scenario.data, realtime=getattr(args, "realtime", False) or None,
                                split=getattr(args, "split", False) or None)
    if options.active and scenario.job.name not in CELL_JOBS:
        print(f"error: {args.scenario}: job {scenario.job.name!r} runs no robot cell; --realtime, --split and "
              f"[execution] realtime/mode = 'split' apply to the jobs {sorted(CELL_JOBS)}", file=sys.stderr)
        return EXIT_INVALID
    out_dir = args.out or Path(scenario.data.get("output", {}).get("dir") or Path("results") / scenario.name)
    if not getattr(args, "ignore_budget", False):
        from cosim.results.budget import check_budget, estimate_run
        from cosim.results.timeseries import default_format

        try:
            fmt = getattr(args, "timeseries", None) or default_format()
            check_budget(estimate_run(scenario.data, fmt), out_dir, getattr(args, "max_output", None),
                         getattr(args, "max_memory", None))
        except ValueError as exc:  # BudgetError, or a bad size / $COSIM_TIMESERIES
            print(f"error: {args.scenario}: {exc}", file=sys.stderr)
            return EXIT_INVALID
    ctx = RunContext(scenario, out_dir, quiet=args.quiet, execution=CellExecution(options) if options.active else None,
                     timeseries_format=getattr(args, "timeseries", None))
    try:
        fields = scenario.job.runner(scenario, ctx) or {}
    except SimulationError as exc:
        ctx.summary.finish_failed(str(exc), exc.time, ctx.sim_time_s, failed_component=exc.component,
                                  fmu_messages=exc.messages, failed_in=ctx.label or None)
        print(f"simulation failed: {exc}\nresults so far in {out_dir}/", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        ctx.summary.finish_failed("interrupted by the user", None, ctx.sim_time_s)
        print(f"interrupted; results so far in {out_dir}/", file=sys.stderr)
        return EXIT_FAILED
    except Exception as exc:
        ctx.summary.finish_failed(f"internal error: {type(exc).__name__}: {exc}", None, ctx.sim_time_s)
        traceback.print_exc()
        return EXIT_INTERNAL
    ctx.summary.finish_ok(ctx.sim_time_s, **fields)
    data = ctx.summary.data
    if not args.quiet:
        print(f"{scenario.name}: ok, {data['sim_time_s']:.6g} s simulated in {data['wall_time_s']:.3g} s "
              f"({data['realtime_factor']:.3g}x real time); results in {out_dir}/", file=sys.stderr)
    return EXIT_OK
