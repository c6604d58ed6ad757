"""``python -m cosim view RESULTS [RESULTS ...] [-o OUT] [--open]``: write the interactive report of runs."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

NAME = "view"
HELP = ("Write report.html, one self-contained HTML file (works offline, from the file system) of one or more "
        "results folders: summary, the arm in 3D replaying the run, TCP path coloured by the TCP error, linked "
        "plots on one timeline, several folders overlaid (docs/how-to/view_results.md).")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("results", nargs="+", type=Path, help="results folder(s) of cosim run / serve (summary.json, "
                                                               "time series)")
    parser.add_argument("-o", "--out", type=Path, default=None,
                        help="the HTML file to write (default: RESULTS/report.html for one folder, ./report.html for "
                             "several)")
    parser.add_argument("--open", action="store_true", help="open the report in the default web browser")


def run(args: argparse.Namespace) -> int:
    from cosim.results.exits import CommandError
    from cosim.results.report import ReportError, write_report

    try:
        out = write_report(list(args.results), args.out)
    except ReportError as exc:
        raise CommandError(str(exc)) from None
    except OSError as exc:
        from cosim.results.exits import describe_os_error

        raise CommandError(describe_os_error(exc, f"writing the report {args.out or ''}".strip())) from None
    print(f"{out}", file=sys.stdout)
    if args.open:
        import webbrowser

        webbrowser.open(out.resolve().as_uri())
    return 0
