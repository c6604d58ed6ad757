"""``python -m cosim bench [--out DIR] [--quick] [--section NAME ...]``: the performance suite.

Runs ``benchmarks/suite.py`` (closed-loop real-time factor in one process and split,
controller compute, bus cost per cycle, FMU steps, planners against their baselines,
calibration selection, identification, a paced run), prints a table and writes
``bench.json`` and the results page ``RESULTS.md`` (every figure, the machine, its load, the
date and commit) to DIR (default ``results/bench``); a full run of every section also writes
the page to ``benchmarks/RESULTS.md`` (the docs site's "Benchmark results"), or to ``--page``.
``--page-from BENCH_JSON`` only writes the page of an earlier run. Exit code 0 when every figure
was measured, 1 when a section failed or a figure is missing, 2 on bad arguments or a
``bench.json`` that cannot be read.
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
    parser.add_argument("--page", type=Path, default=None, metavar="PATH",
                        help="also write the results page here (default: benchmarks/RESULTS.md after a full run "
                             "of every section; always DIR/RESULTS.md)")
    parser.add_argument("--page-from", type=Path, default=None, metavar="BENCH_JSON",
                        help="run nothing: write the results page of this bench.json (to --page, else "
                             "RESULTS.md beside it)")


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
    """Run the suite, print the table, write bench.json and the results page."""
    suite = load_suite()
    if args.page_from is not None:
        return _page_from(suite, args.page_from, args.page)
    if args.section:
        unknown = [s for s in args.section if s not in suite.SECTIONS]
        if unknown:
            print(f"error: --section {unknown[0]!r}: expected one of {', '.join(suite.SECTIONS)}", file=sys.stderr)
            return 2
    result = suite.run_suite(args.out, quick=args.quick, sections=args.section,
                             log=lambda text: print(text, file=sys.stderr, flush=True))
    print(suite.format_table(result))
    pages = [suite.write_results_page(result, Path(args.out) / "RESULTS.md")]
    if args.page is not None or (not args.quick and not args.section):
        pages.append(suite.write_results_page(result, args.page or suite.RESULTS_PAGE))
    print(f"bench.json written to {args.out}/, results page to {', '.join(str(p) for p in pages)}", file=sys.stderr)
    if result["errors"] or result["missing"]:
        if result["missing"]:
            print(f"missing figures: {', '.join(result['missing'])}", file=sys.stderr)
        return 1
    return 0


def _page_from(suite, source: Path, page: Path | None) -> int:
    """Write the results page of an earlier run's bench.json."""
    import json

    try:
        result = json.loads(source.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        print(f"error: --page-from {source}: not readable as JSON ({type(exc).__name__}: {exc}); expected the "
              f"bench.json of python -m cosim bench", file=sys.stderr)
        return 2
    if not isinstance(result, dict) or not isinstance(result.get("figures"), dict) or "machine" not in result:
        print(f"error: --page-from {source}: not a bench.json (expected an object with 'machine' and 'figures')",
              file=sys.stderr)
        return 2
    out = suite.write_results_page(result, page or source.with_name("RESULTS.md"))
    print(out)
    return 0
