"""``python -m cosim sweep SWEEP.toml [--scheduler ADDRESS] [--workers N] [--out DIR]``: run a sweep on Dask."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

NAME = "sweep"
HELP = ("Validate a sweep file (a base scenario and the axes to vary: grid values, Monte Carlo draws), then run "
        "every variant as a Dask task (embedded local cluster of worker processes, or --scheduler) and write "
        "sweep.csv, the [report] figure and one results folder per variant to results/<sweep name>/ (or --out).")

#: Exit codes: 0 every variant ok, 1 some variants failed, 2 invalid sweep file, 130 interrupted.
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
    parser.add_argument("sweep", type=Path, help="sweep TOML file (see docs/sweeps.md)")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="address of an existing Dask scheduler (e.g. tcp://10.0.0.5:8786); "
                        "default: an embedded LocalCluster on this machine")
    parser.add_argument("--workers", type=_positive_int, default=None, metavar="N",
                        help="worker processes of the embedded cluster (default: CPU count; one thread each)")
    parser.add_argument("--out", type=Path, default=None, help="results folder (default: results/<sweep name>/)")
    parser.add_argument("--fresh", action="store_true",
                        help="run every variant again (default: skip variants finished by an earlier run)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    """Validate (nothing runs on an invalid file), run the variants, print where the results are."""
    from cosim.scenario import ScenarioError
    from cosim.sweep import load_sweep, run_sweep

    if args.scheduler and args.workers:
        print("error: --workers applies to the embedded cluster only; an existing cluster (--scheduler) "
              "has its own workers", file=sys.stderr)
        return EXIT_INVALID
    try:
        sweep = load_sweep(args.sweep)
    except ScenarioError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_INVALID
    if not args.quiet:
        print(f"sweep {sweep.name}: {len(sweep.variants)} variants of {sweep.base.path} (job {sweep.job!r}) over "
              f"{', '.join(sweep.parameters)}", file=sys.stderr)
    try:
        result = run_sweep(sweep, args.out, workers=args.workers, scheduler=args.scheduler,
                           progress=not args.quiet, resume=not args.fresh)
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
