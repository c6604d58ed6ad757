"""``python -m cosim export-blf``: write a columnar CAN log (``can_<mode>.parquet``) as BLF."""
from __future__ import annotations

import argparse
from pathlib import Path

NAME = "export-blf"
HELP = ("Write a run's columnar CAN log (can_<mode>.parquet, or a results folder's every one) as BLF: "
        "byte for byte the file python-can's BLFWriter writes for the same frames.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", help="a can_<mode>.parquet file or a results folder (every can_*.parquet in it)")
    parser.add_argument("-o", "--out", default=None,
                        help="the BLF file (for one log) or folder (for a results folder; default: beside each log, suffix .blf)")


def run(args: argparse.Namespace) -> int:
    from cosim.results.exits import CommandError
    from fieldbus.blf import to_blf
    from fieldbus.canlog import resolve

    source = Path(args.log)
    if source.is_dir():
        logs = sorted(source.glob("can_*.parquet"))
        if not logs:
            raise CommandError(f"{source}: no columnar CAN log (can_*.parquet) in this folder")
    elif resolve(source).exists() and source.name.endswith(".parquet"):
        logs = [source]
    else:
        raise CommandError(f"{source}: no such CAN log (expected a can_<mode>.parquet file or a results folder)")
    out = Path(args.out) if args.out else None
    for log in logs:
        if out is None:
            target = log.with_suffix(".blf")
        elif source.is_dir() or out.is_dir():
            out.mkdir(parents=True, exist_ok=True)
            target = out / log.with_suffix(".blf").name
        else:
            target = out
        try:
            to_blf(log, target)
        except (ValueError, OSError) as exc:
            raise CommandError(f"{log}: {exc}") from None
        print(f"{log} -> {target}")
    return 0
