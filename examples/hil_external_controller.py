"""A minimal external controller for ``python -m cosim serve``: python-can and the
documented telegram layout only (no import of the project's packages). It asks for SCHED_FIFO
(priority 10, the cell's) when the OS grants it, as a real-time controller would.

It reads the cell's endpoint description (``hil_endpoint.json``, written by ``cosim
serve`` before its first cycle), joins the bus through python-can's ``udpcycle``
interface, enables the six drives through CiA 402 (a fault first reset by a rising edge of
bit 7, 0x80; then shutdown 0x06 -> switch on 0x07 -> enable operation 0x0F, each when the
statusword shows the state before it) holding each drive at its position actual, moves every
joint from there along a smooth cosine out and back in cyclic synchronous position mode, rests
0.5 s, disables the drives (shutdown 0x06: Ready to switch on, power stage off, brakes
closed) and keeps the bus cycling, as a managing node does, until the cell stops: the run
ends without a communication fault. Going silent instead (``--stop-after``, or
``--exit-when-disabled``) is a loss of SoC/PReq to the cell's threshold counters. Started again after the cell's drives reacted to its silence, it resets their faults
and does the same from where the arm stopped.

Timing: the cell keeps the time; this program follows it. Every cycle the cell sends
its PRes frames (TPDO1 0x180+n, TPDO2 0x280+n); after each batch of them this program
sends one datagram: the SoC (SYNC 0x080, counter 1..240) and one PReq (RPDO1 0x200+n)
per drive. The SoC counter is the cell's cycle (as the number of PRes batches seen)
plus one, modulo 240, plus one: a batch that is missed or answered too late costs that
cycle's set-points (the cell's threshold counters count it).

A drive that reacts during the run (a fault reaction, e.g. the cell's threshold counters
tripping on lost cycles) stops the motion: the program holds and cycles on until the cell
stops. Exit codes: 0 the run went through, 2 no cell or the drives never enabled, 3 the drives
were not enabled within --enable-timeout, 4 a drive faulted during the run.

Usage::

    python -m cosim serve scenarios/hil.toml --out results/hil --wait-for-controller 60 &
    python examples/hil_external_controller.py results/hil/hil_endpoint.json --amplitude 0.2 --duration 2
"""
from __future__ import annotations

import argparse
import json
import math
import os
import struct
import sys
import time

import can

SYNC_ID, RPDO1_BASE, TPDO1_BASE, TPDO2_BASE = 0x080, 0x200, 0x180, 0x280
RPDO1 = struct.Struct("<Hih")  # controlword, target position [counts], torque offset [0.1 % rated]
TPDO1 = struct.Struct("<Hih")  # statusword, position actual [counts], torque actual [0.1 % rated]
TPDO2 = struct.Struct("<iH")  # velocity actual [counts/s], error code

SHUTDOWN, SWITCH_ON, ENABLE_OPERATION, FAULT_RESET = 0x06, 0x07, 0x0F, 0x80


def state(statusword: int) -> str:
    """CiA 402 state from the statusword bits (0x006F mask; 0x004F for the first two)."""
    if statusword & 0x4F == 0x40:
        return "switch_on_disabled"
    if statusword & 0x6F == 0x21:
        return "ready_to_switch_on"
    if statusword & 0x6F == 0x23:
        return "switched_on"
    if statusword & 0x6F == 0x27:
        return "operation_enabled"
    if statusword & 0x4F in (0x08, 0x0F):
        return "fault"
    return "other"


def next_controlword(statusword: int, previous: int) -> int:
    """The controlword that moves a drive one step towards 'operation enabled'."""
    s = state(statusword)
    if s == "fault":
        return 0x00 if previous & FAULT_RESET else FAULT_RESET  # rising edge of bit 7
    return {"switch_on_disabled": SHUTDOWN, "ready_to_switch_on": SWITCH_ON,
            "switched_on": ENABLE_OPERATION}.get(s, ENABLE_OPERATION)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("endpoint", help="hil_endpoint.json written by cosim serve")
    parser.add_argument("--amplitude", type=float, default=0.2, help="joint excursion, rad")
    parser.add_argument("--duration", type=float, default=2.0, help="time out and back, s")
    parser.add_argument("--enable-timeout", type=float, default=5.0, help="s to wait for all drives enabled")
    parser.add_argument("--exit-when-disabled", action="store_true",
                        help="exit once the drives are disabled instead of cycling on until the cell stops")
    parser.add_argument("--stop-after", type=float, default=None,
                        help="go silent this many seconds into the motion (to show the cell's reaction)")
    parser.add_argument("--normal-scheduling", action="store_true",
                        help="do not ask for SCHED_FIFO (by default the controller runs real-time when the OS grants "
                             "it, as the cell does: a normally scheduled process on a loaded machine misses cycles)")
    args = parser.parse_args(argv)
    if not args.normal_scheduling and hasattr(os, "sched_setscheduler"):
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))  # the cell's priority (cosim serve)
        except OSError:
            print("SCHED_FIFO not granted: running normally scheduled", file=sys.stderr)
    with open(args.endpoint, encoding="utf-8") as file:
        desc = json.load(file)
    n = desc["nodes"]
    cpr = desc["counts_per_rad"]  # per node
    q_start = desc["q_start_rad"]
    cycle_s = desc["cycle_time_s"]
    bus = can.Bus(interface="udpcycle", channel=desc["controller_channel"], peer=desc["cell_channel"],
                  busy_poll_s=desc.get("busy_poll_s", 0.0))
    status = [0] * n
    position = [round(q * c) for q, c in zip(q_start, cpr)]  # counts, until the drives report theirs
    controlword = [0] * n
    target = base = list(position)
    counter = 0
    cycles_seen = 0
    enabled_at = None
    disabled_at = None
    faulted_at = None
    motion_cycles = int(round(args.duration / cycle_s))
    started = time.monotonic()

    def send(frames: list) -> None:
        send_many = getattr(bus, "send_many", None)
        if send_many is not None:
            send_many(frames)  # one datagram
        else:
            for frame in frames:
                bus.send(frame)

    def hold_frames(count: int) -> list:
        """SoC + PReqs that keep every drive disabled where it is (announces this program)."""
        return [can.Message(arbitration_id=SYNC_ID, data=bytes([count]), is_extended_id=False)] + \
            [can.Message(arbitration_id=RPDO1_BASE + i + 1, is_extended_id=False,
                         data=RPDO1.pack(0, round(q_start[i] * cpr[i]), 0)) for i in range(n)]

    try:
        # the cell answers whoever talks to it: say hello until its PRes frames come
        msg = None
        while msg is None:
            send(hold_frames(1))
            msg = bus.recv(0.1)
            if msg is None and time.monotonic() - started > 20.0:
                print("no PRes from the cell for 20 s: is `cosim serve` running?", file=sys.stderr)
                return 2
        pending = [msg]
        while True:
            # one batch of PRes frames = one cell cycle
            msg = pending.pop() if pending else bus.recv(0.5)
            if msg is None:
                print("no PRes from the cell for 0.5 s: the cell stopped", file=sys.stderr)
                if enabled_at is not None and disabled_at is None and faulted_at is None:
                    print("the cell stopped before the motion ended (the drives were not disabled)", file=sys.stderr)
                if faulted_at is not None:
                    return 4
                return 0 if enabled_at is not None else 2
            batch = [msg]
            msg = bus.recv(0)
            while msg is not None:
                batch.append(msg)
                msg = bus.recv(0)
            batches = 0
            for frame in batch:
                node = frame.arbitration_id & 0x7F
                if frame.arbitration_id & ~0x7F == TPDO1_BASE and 1 <= node <= n:
                    status[node - 1], position[node - 1], _ = TPDO1.unpack(bytes(frame.data))
                    batches += node == 1
            cycles_seen += max(batches, 1)
            counter = cycles_seen % 240 + 1
            if args.stop_after is not None and enabled_at is not None and \
                    (cycles_seen - enabled_at) * cycle_s > args.stop_after:
                return 0  # go silent mid-motion: the cell's counters must trip and the drives stop the arm
            all_enabled = all(state(s) == "operation_enabled" for s in status)
            if all_enabled and enabled_at is None:
                enabled_at = cycles_seen
                base = list(target)  # the motion starts where the drives were enabled
                print(f"all {n} drives enabled at cycle {cycles_seen}: moving", flush=True)
            if enabled_at is None:
                if time.monotonic() - started > args.enable_timeout:
                    print(f"drives not enabled after {args.enable_timeout} s: statuswords "
                          f"{[hex(s) for s in status]}", file=sys.stderr)
                    return 3
                controlword = [next_controlword(s, c) for s, c in zip(status, controlword)]
                # hold where each drive is (its position actual): after a stop mid-motion that is not
                # where the run started, and a jump would be a following-error fault on enabling
                target = list(position)
            else:
                k = cycles_seen - enabled_at
                rest = int(0.5 / cycle_s)
                if faulted_at is None and any(state(s) == "fault" or s & 0x4F == 0x0F for s in status):
                    faulted_at = cycles_seen  # a drive reacted (e.g. lost cycles): stop commanding motion
                    print(f"drive fault at cycle {cycles_seen} (statuswords {[hex(s) for s in status]}): motion "
                          f"stopped, holding until the cell stops", file=sys.stderr, flush=True)
                if faulted_at is not None:
                    k = motion_cycles + rest + 1  # no more motion: hold, disable what is still enabled
                if k > motion_cycles + rest:  # motion done and 0.5 s of rest: disable the drives
                    controlword = [SHUTDOWN] * n  # Ready to switch on: power stage off, brakes closed
                    if disabled_at is None and faulted_at is None and \
                            all(state(s) == "ready_to_switch_on" for s in status):
                        disabled_at = cycles_seen
                        print(f"all {n} drives disabled at cycle {cycles_seen}", flush=True)
                    if disabled_at is not None and args.exit_when_disabled:
                        return 0  # (the cell's counters then count the silence: a communication fault)
                    # keep the bus cycling (as a managing node does) until the cell stops
                else:
                    phase = min(k / motion_cycles, 1.0)
                    offset = args.amplitude * 0.5 * (1.0 - math.cos(2.0 * math.pi * phase))
                    controlword = [ENABLE_OPERATION] * n
                    target = [b + round(offset * c) for b, c in zip(base, cpr)]
            frames = [can.Message(arbitration_id=SYNC_ID, data=bytes([counter]), is_extended_id=False)]
            frames += [can.Message(arbitration_id=RPDO1_BASE + i + 1, is_extended_id=False,
                                   data=RPDO1.pack(controlword[i], target[i], 0)) for i in range(n)]
            send(frames)
    finally:
        bus.shutdown()


if __name__ == "__main__":
    sys.exit(main())
