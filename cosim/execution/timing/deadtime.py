"""The fieldbus dead time measured from a CAN log (what a bus analyser would see).

The dead time is the number of cycles from the cycle whose PReq carries a set-point to
the SoC at which the drive applies it (``[fieldbus] dead_time_cycles``). The log shows
it through the CiA 402 handshake: when the controlword a PReq carries to node n changes
(cycle j), the drive applies it at the SoC of cycle j + d, its state machine switches
within its next step, and the controlled node latches the new statusword at the
following SoC, so the first PRes of node n with a changed statusword is in cycle
j + d + 1. :func:`handshake_dead_times` returns ``m - j - 1`` for every controlword
change followed by a statusword change (m = that PRes cycle).

Frames are assigned to cycles by their simulated timestamp: cycle = floor((t - t0) / T).
"""
from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

from fieldbus.canlog import open_log
from fieldbus.telegrams import RPDO1_BASE, TPDO1_BASE


def _cycles_and_words(path: str | Path, base: int, nodes: int, cycle_time_s: float, start_time_s: float):
    """{node: [(cycle, first uint16 of the payload), ...]} of the frames with id base + node."""
    out: dict[int, list[tuple[int, int]]] = defaultdict(list)
    for msg in open_log(path):  # columnar (.parquet) or BLF/ASC
        node = msg.arbitration_id - base
        if 1 <= node <= nodes and not msg.is_error_frame and len(msg.data) >= 2:
            cycle = math.floor((msg.timestamp - start_time_s) / cycle_time_s + 1e-9)
            out[node].append((cycle, int.from_bytes(bytes(msg.data[:2]), "little")))
    for frames in out.values():
        frames.sort()
    return out


def handshake_dead_times(path: str | Path, cycle_time_s: float, nodes: int = 6,
                         start_time_s: float = 0.0) -> list[tuple[int, int, int]]:
    """``(node, controlword cycle j, dead time m - j - 1)`` for each controlword change in the
    log's PReqs that is followed by a statusword change in the node's PRes (cycle m)."""
    preqs = _cycles_and_words(path, RPDO1_BASE, nodes, cycle_time_s, start_time_s)
    pres = _cycles_and_words(path, TPDO1_BASE, nodes, cycle_time_s, start_time_s)
    found = []
    for node, frames in preqs.items():
        status = dict(pres.get(node, []))
        previous = None
        for j, cw in frames:
            if previous is not None and cw != previous and j in status:
                before = status[j]
                later = [m for m in sorted(status) if m > j and status[m] != before]
                if later:
                    found.append((node, j, later[0] - j - 1))
            previous = cw
    return found
