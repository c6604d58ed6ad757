"""Command-line interface: ``python -m cosim COMMAND ...``.

Each command lives in its own module under ``cosim/commands/`` exposing
``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
Register a new command by adding its module name to ``COMMAND_MODULES``.

Errors and exit codes (cosim/results/exits.py, docs/reference/verdicts.md): whatever a command
raises becomes one ``error: ...`` line on stderr and a documented exit code (2 bad input
or unusable output folder, 3 failed run, 130 interrupted); the traceback is printed only
with ``--debug``. SIGTERM and SIGHUP are handled like Ctrl-C (SIGINT): the command stops,
flushes what it has, writes its final status and exits with 130 (cosim/results/interrupts.py).

From the command line (``main()`` without ``argv``), ``run``, ``serve`` and ``sweep`` run in a
child process watched by a supervisor that writes the final status if that process dies
without writing it (killed, out of memory, ``_exit()`` in an FMU): cosim/commands/supervisor.py.
"""
from __future__ import annotations

import argparse
import importlib
import sys
import traceback
from collections.abc import Sequence

from cosim.results.exits import (EXIT_FAILED, EXIT_INTERRUPTED, EXIT_INVALID, CommandError, describe_decode_error,
                                  describe_os_error, exit_codes_line, signal_name_of)
from cosim.results.interrupts import install_signal_handlers, restore_signal_handlers

COMMAND_MODULES: tuple[str, ...] = (
    "cosim.commands.robot_info",
    "cosim.commands.build",
    "cosim.commands.build_fmus",
    "cosim.commands.export_ssp",
    "cosim.commands.export_blf",
    "cosim.commands.device_files",
    "cosim.commands.export_pcap",
    "cosim.commands.view",
    "cosim.commands.run",
    "cosim.commands.serve",
    "cosim.commands.calibrate",
    "cosim.commands.sweep",
    "cosim.commands.identify",
    "cosim.commands.bench",
)


def build_parser() -> argparse.ArgumentParser:
    """Build the top-level parser with one sub-parser per registered command."""
    parser = argparse.ArgumentParser(
        prog="python -m cosim",
        description="RX130L-class robot co-simulation testbed (FMUs, POWERLINK fieldbus, "
        "model-based control, optimal trajectories, calibration, identification).",
    )
    parser.add_argument("--debug", action="store_true", help="print the Python traceback of an error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for module_name in COMMAND_MODULES:
        module = importlib.import_module(module_name)
        cmd = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP,
                             epilog=f"exit codes: {exit_codes_line()} (docs/reference/verdicts.md)")
        module.add_arguments(cmd)
        cmd.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                         help="print the Python traceback of an error")
        cmd.set_defaults(_run=module.run)
    return parser


def _error(text: str, code: int) -> int:
    print(f"error: {text}", file=sys.stderr)
    return code


def main(argv: Sequence[str] | None = None) -> int:
    """Parse ``argv`` and run the chosen command; return the process exit code.

    Exceptions escaping a command become one line on stderr and an exit code; with
    ``--debug`` the traceback is printed too. Without ``argv`` (the command line of ``python -m
    cosim`` or the ``cosim`` script), ``run``, ``serve`` and ``sweep`` run supervised.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    if argv is None:
        from cosim.commands import supervisor

        if supervisor.wanted(args.command):
            return supervisor.supervise(lambda: _run_command(args))
    return _run_command(args)


def _run_command(args: argparse.Namespace) -> int:
    """Run the parsed command with the signal handlers; exceptions become the line and the code."""
    debug = bool(getattr(args, "debug", False))
    previous = install_signal_handlers()
    try:
        return int(args._run(args) or 0)
    except CommandError as exc:
        if debug:
            traceback.print_exc()
        return _error(str(exc), exc.code)
    except KeyboardInterrupt as exc:
        if debug:
            traceback.print_exc()
        print(f"interrupted by {signal_name_of(exc)}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except UnicodeDecodeError as exc:
        if debug:
            traceback.print_exc()
        return _error(describe_decode_error(exc, None), EXIT_INVALID)
    except OSError as exc:
        if debug:
            traceback.print_exc()
        return _error(describe_os_error(exc), EXIT_INVALID)
    except (ValueError, OverflowError) as exc:
        if debug:
            traceback.print_exc()
        return _error(str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__, EXIT_INVALID)
    except Exception as exc:  # noqa: BLE001 - the last line of defence: no traceback without --debug
        if debug:
            traceback.print_exc()
        return _error(f"internal error in '{args.command}': {type(exc).__name__}: {exc}"
                      + ("" if debug else " (run with --debug for the traceback)"), EXIT_FAILED)
    finally:
        restore_signal_handlers(previous)
