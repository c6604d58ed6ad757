"""``python -m cosim bench [--out DIR] [--quick] [--section NAME ...]``: the performance suite.

Runs ``benchmarks/suite.py`` (closed-loop real-time factor in one process and split,
controller compute, bus cost per cycle, FMU steps, planners against their baselines,
calibration selection, identification, a paced run), prints a table and writes
``bench.json`` to DIR (default ``results/bench``). Exit code 0 when every figure was
measured, 1 when a section failed or a figure is missing.
"""
from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

NAME = "bench"
HELP = ("Run the performance suite (benchmarks/suite.py): medians of every performance figure with the machine "
        "described and the ratios against the baselines; prints a table, writes bench.json.")

SUITE_PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "suite.py"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """--out, --quick, --section."""
    parser.add_argument("--out", type=Path, default=Path("results") / "bench", help="folder of bench.json")
    parser.add_argument("--quick", action="store_true",
                        help="one repetition of tiny problems (checks that every figure is produced; not for numbers)")
    parser.add_argument("--section", action="append", default=None, metavar="NAME",
                        help="run only this section (repeatable); names: closed_loop, closed_loop_elastic, "
                             "closed_loop_split, paced, bus, fmu, planners, calibration, identification, hil, "
                             "memory, main_job, output, report")


def load_suite():
    """The suite module (benchmarks/ is a folder of scripts, not a package)."""
    if not SUITE_PATH.exists():
        raise FileNotFoundError(f"{SUITE_PATH}: the benchmark suite is not there (a source checkout is needed)")
    spec = importlib.util.spec_from_file_location("cosim_bench_suite", SUITE_PATH)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def run(args: argparse.Namespace) -> int:
    """Run the suite, print the table, write bench.json."""
    suite = load_suite()
    if args.section:
        unknown = [s for s in args.section if s not in suite.SECTIONS]
        if unknown:
            print(f"error: --section {unknown[0]!r}: expected one of {', '.join(suite.SECTIONS)}", file=sys.stderr)
            return 2
    result = suite.run_suite(args.out, quick=args.quick, sections=args.section,
                             log=lambda text: print(text, file=sys.stderr, flush=True))
    print(suite.format_table(result))
    print(f"bench.json written to {args.out}/", file=sys.stderr)
    if result["errors"] or result["missing"]:
        if result["missing"]:
            print(f"missing figures: {', '.join(result['missing'])}", file=sys.stderr)
        return 1
    return 0
