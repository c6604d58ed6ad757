"""``python -m cosim export-pcap RESULTS``: a run's bus traffic as pcapng captures Wireshark dissects."""
from __future__ import annotations

import argparse
from pathlib import Path

NAME = "export-pcap"
HELP = ("Write a run's CAN logs (can_<mode>.parquet, or a results folder's every one) as pcapng captures: "
        "POWERLINK frames (EtherType 0x88AB: SoC, PReq, PRes, SoA, ASnd) and SocketCAN frames (CANopen), "
        "for Wireshark/tshark.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("results", help="a results folder (every can_*.parquet in it) or one can_<mode>.parquet")
    parser.add_argument("-o", "--out", type=Path, default=None,
                        help="folder for the captures (default: beside each log): powerlink_<mode>.pcapng and "
                             "can_<mode>.pcapng")
    parser.add_argument("--only", choices=("powerlink", "can"), default=None, help="write only one of the two")


def run(args: argparse.Namespace) -> int:
    from cosim.results.exits import CommandError
    from fieldbus.canlog import resolve
    from fieldbus.capture import write_can, write_powerlink

    source = Path(args.results)
    if source.is_dir():
        logs = sorted(source.glob("can_*.parquet"))
        if not logs:
            raise CommandError(f"{source}: no columnar CAN log (can_*.parquet) in this folder; expected a results "
                               "folder of a run with [results] can_log = true")
    elif source.name.endswith(".parquet") and resolve(source).exists():
        logs = [source]
    else:
        raise CommandError(f"{source}: no such CAN log (expected a results folder or a can_<mode>.parquet file)")
    for log in logs:
        folder = args.out or log.parent
        mode = log.name[len("can_"):-len(".parquet")] if log.name.startswith("can_") else log.stem
        try:
            folder.mkdir(parents=True, exist_ok=True)
            for kind, writer in (("powerlink", write_powerlink), ("can", write_can)):
                if args.only and args.only != kind:
                    continue
                target = folder / f"{kind}_{mode}.pcapng"
                counts = writer(log, target)
                frames = ", ".join(f"{n} {k}" for k, n in counts.frames.items())
                left = f"; {counts.left_out_error_frames} corrupted frames left out" if counts.left_out_error_frames else ""
                print(f"{log} -> {target}: {counts.cycles} cycles, {frames}{left}")
        except (ValueError, OSError) as exc:
            raise CommandError(f"{log}: {exc}") from None
    return 0
