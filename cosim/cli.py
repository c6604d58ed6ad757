"""Command-line interface: ``python -m cosim COMMAND ...``.

Each command lives in its own module under ``cosim/commands/`` exposing
``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
Register a new command by adding its module name to ``COMMAND_MODULES``.
"""
from __future__ import annotations

import argparse
import importlib
from collections.abc import Sequence

COMMAND_MODULES: tuple[str, ...] = (
    "cosim.commands.robot_info",
    "cosim.commands.build_fmus",
    "cosim.commands.run",
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
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for module_name in COMMAND_MODULES:
        module = importlib.import_module(module_name)
        cmd = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(cmd)
        cmd.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Parse ``argv`` and run the chosen command; return the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    return int(args._run(args) or 0)
