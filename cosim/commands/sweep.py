"""``python -m cosim sweep SWEEP.toml [--scheduler ADDRESS] [--workers N] [--out DIR]``: run a sweep on Dask."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

NAME = "sweep"
HELP = ("Validate a sweep file (a base scenario and the axes to vary: grid values, Monte Carlo draws), then run "
        "every variant as a Dask task (embedded local cluster of worker processes, or --scheduler) and write "
        "sweep.csv, the [report] figure and one results folder per variant to results/<sweep name>/ (or --out).")

#: Exit codes (cosim/results/exits.py): 0 every variant ok, 1 some variants failed, 2 invalid sweep file,
#: unusable --out or an unreachable --scheduler, 130 interrupted.
EXIT_OK, EXIT_SOME_FAILED, EXIT_INVALID, EXIT_INTERRUPTED = 0, 1, 2, 130


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"--workers: expected an integer >= 1, got {text!r}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """SWEEP, --scheduler, --workers, --out, --fresh, --quiet."""
    parser.add_argument("sweep", type=Path, help="sweep TOML file (see docs/how-to/sweep_cluster.md)")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="address of an existing Dask scheduler (e.g. tcp://10.0.0.5:8786); "
                        "default: an embedded LocalCluster on the local machine")
    parser.add_argument("--workers", type=_positive_int, default=None, metavar="N",
                        help="worker processes of the embedded cluster (default: CPU count; one thread each)")
    parser.add_argument("--out", type=Path, default=None, help="results folder (default: results/<sweep name>/)")
    parser.add_argument("--fresh", action="store_true",
                        help="run every variant again (default: skip variants finished by an earlier run)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def estimate_variant_seconds(sweep) -> tuple[float, str] | None:
    """Wall seconds one variant takes, from the last finished run of the base scenario
    (``results/<name>/summary.json`` or its ``[output] dir``), and where that came from; None if unknown."""
    import json

    base = sweep.base
    folder = Path(base.data.get("output", {}).get("dir") or Path("results") / base.name)
    summary = folder / "summary.json"
    try:
        data = json.loads(summary.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    wall = data.get("wall_time_s")
    if data.get("status") != "ok" or not isinstance(wall, (int, float)) or wall <= 0:
        return None
    return float(wall), str(summary)


def run(args: argparse.Namespace) -> int:
    """Validate (nothing runs on an invalid file), run the variants, print where the results are."""
    import os

    from cosim.results.exits import InvalidInput
    from cosim.api import ScenarioError, load_sweep, run_sweep   # the public API; this command only talks
    from cosim.sweep.execute import SchedulerUnreachable

    if args.scheduler and args.workers:
        raise InvalidInput("--workers applies to the embedded cluster only; an existing cluster (--scheduler) "
                           "has its own workers")

    def announce(count: int) -> None:
        if not args.quiet:
            print(f"sweep {args.sweep}: {count} variants; validating them", file=sys.stderr, flush=True)

    try:
        sweep = load_sweep(args.sweep, on_count=announce)
    except ScenarioError as exc:
        raise InvalidInput(str(exc)) from None
    if not args.quiet:
        workers = args.workers or (None if args.scheduler else os.cpu_count() or 1)
        estimate = estimate_variant_seconds(sweep)
        if estimate is not None and workers:
            per, source = estimate
            total = per * len(sweep.variants) / workers
            guess = (f"estimated {total / 60:.3g} min at {per:.3g} s per variant ({source}) on {workers} worker(s); "
                     f"variants finished earlier are reused")
        else:
            guess = "no time estimate yet (run the base scenario once; the progress bar estimates as variants finish)"
        print(f"sweep {sweep.name}: {len(sweep.variants)} variants of {sweep.base.path} (job {sweep.job!r}) over "
              f"{', '.join(sweep.parameters)}; {guess}", file=sys.stderr)
    try:
        result = run_sweep(sweep, args.out, workers=args.workers, scheduler=args.scheduler,
                           progress=not args.quiet, resume=not args.fresh)
    except SchedulerUnreachable as exc:
        raise InvalidInput(str(exc)) from None
    except KeyboardInterrupt:
        print("interrupted; finished variants are kept and skipped when the sweep is run again", file=sys.stderr)
        return EXIT_INTERRUPTED
    for note in result.notes:
        print(note, file=sys.stderr)
    print(f"sweep {sweep.name}: {result.ok} ok, {result.failed} failed ({result.ran} run on {result.workers} "
          f"worker(s), {result.reused} reused) in {result.wall_time_s:.1f} s; table {result.table}"
          + (f", figure {result.figure}" if result.figure else ""), file=sys.stderr)
    for row in result.rows:
        if row["status"] != "ok":
            print(f"  {row['variant']} failed: {row['reason']}", file=sys.stderr)
    return EXIT_OK if result.failed == 0 else EXIT_SOME_FAILED
