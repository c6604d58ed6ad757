"""A CANopen master for the served cell, written with the ``canopen`` library and python-can only.

What a control engineer does with six new drives on a CAN bus, in order:

1. load each drive's EDS (``python -m cosim device-files DIR`` writes servo_drive_node<N>.eds),
2. reset the nodes' communication (NMT) and wait for their boot-up messages,
3. read the identity (0x1018) and the device name over SDO, and the cycle period 0x1006,
4. change a limit (0x6072 max torque) and a gain (0x2001 position loop gain) over SDO and read
   them back, as every other object this script writes (heartbeat time, modes of operation,
   the PDO communication and mapping parameters),
5. map the PDOs for cyclic synchronous position on classic CAN (RPDO1: controlword, target
   position, torque offset; TPDO1: statusword, position actual, torque actual; TPDO2: velocity
   actual, modes of operation display), all synchronous (transmission type 1),
6. switch the nodes to NMT operational and start the cycle: a thread sends the SYNC, then each
   node's RPDO1, every cycle (frame by frame, nothing batched),
7. enable the six drives with the library's CiA 402 state machine (``BaseNode402``) in cyclic
   synchronous position mode, move every axis out and back, disable them,
8. with ``--probe-errors``, ask for what a drive must refuse (a value out of range, an object
   that does not exist, a malformed SDO request, an NMT command to a node that is not there)
   and note the answers.

It prints one JSON report: identity, SDO round trips, the states reached, the cycle time the
master held (its SYNC intervals), the following error of the motion, the abort codes.

    python examples/canopen_master.py --eds drives/ --interface udp_multicast --channel 239.74.163.2 \\
        --endpoint results/can_master/hil_endpoint.json

Imports: the standard library, ``can`` and ``canopen`` only (nothing of this project).
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import threading
import time
from pathlib import Path

import can
import canopen
from canopen.profiles.p402 import BaseNode402
from canopen.sdo.exceptions import SdoAbortedError

CSP = "CYCLIC SYNCHRONOUS POSITION"


def bus_options(items):
    out = {}
    for item in items:
        key, _, text = item.partition("=")
        value = text
        if text.lower() in ("true", "false"):
            value = text.lower() == "true"
        else:
            for kind in (int, float):
                try:
                    value = kind(text)
                    break
                except ValueError:
                    pass
        out[key] = value
    return out


def percentiles_us(values):
    if not values:
        return {"p50_us": None, "p99_us": None, "max_us": None}
    s = sorted(values)

    def at(p):
        return s[min(len(s) - 1, int(round(p / 100.0 * (len(s) - 1))))] * 1e6

    return {"p50_us": at(50), "p99_us": at(99), "max_us": s[-1] * 1e6}


class Cycle(threading.Thread):
    """The master's cycle: SYNC, then each node's RPDO1, every ``period`` seconds (own clock).
    ``targets(k)``, if set, gives the target positions (counts) sent in cycle k."""

    def __init__(self, network, nodes, period):
        super().__init__(daemon=True)
        self.network, self.nodes, self.period = network, nodes, period
        self.k = 0
        self.sent_at = []  # wall time of each SYNC
        self.sent_targets = {}  # cycle -> target positions sent after its SYNC (applied at the next)
        self.targets = None
        self.stop_flag = threading.Event()
        self.lock = threading.Lock()

    def run(self):
        start = time.perf_counter()
        while not self.stop_flag.is_set():
            due = start + self.k * self.period
            delay = due - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            elif delay < -self.period:  # fell behind by more than a cycle: skip to now, do not burst
                start += (-delay // self.period) * self.period
            with self.lock:
                k = self.k
                self.sent_at.append(time.perf_counter())
                self.network.sync.transmit()
                targets = self.targets(k) if self.targets is not None else None
                for i, node in enumerate(self.nodes):
                    rpdo = node.rpdo[1]
                    if targets is not None:
                        rpdo["Target position"].raw = targets[i]
                    rpdo.transmit()
                if targets is not None:
                    self.sent_targets[k] = targets
                self.k = k + 1

    def stop(self):
        self.stop_flag.set()
        self.join(timeout=2.0)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--eds", type=Path, required=True, help="folder with servo_drive_node<N>.eds")
    parser.add_argument("--interface", required=True, help="python-can interface, e.g. udp_multicast, pcan, socketcan")
    parser.add_argument("--channel", required=True, help="its channel, e.g. 239.74.163.2, PCAN_USBBUS1, can0")
    parser.add_argument("--bitrate", type=int, default=None, help="bit/s (hardware adapters)")
    parser.add_argument("--bus-option", action="append", default=[], metavar="KEY=VALUE",
                        help="another can.Bus keyword, e.g. port=43113")
    parser.add_argument("--nodes", type=int, default=6, help="node ids 1..N (default 6)")
    parser.add_argument("--endpoint", type=Path, default=None,
                        help="the cell's hil_endpoint.json (gives counts per rad: amplitude and errors in rad)")
    parser.add_argument("--amplitude", type=float, default=0.05,
                        help="move of each axis, rad with --endpoint, else thousands of counts (default 0.05)")
    parser.add_argument("--duration", type=float, default=2.0, help="duration of the out-and-back move, s")
    parser.add_argument("--probe-errors", action="store_true",
                        help="also send what the drives must refuse and report their answers")
    parser.add_argument("--report", type=Path, default=None, help="also write the JSON report here")
    args = parser.parse_args(argv)

    counts_per_rad = None
    if args.endpoint is not None:
        endpoint = json.loads(args.endpoint.read_text())
        counts_per_rad = endpoint.get("counts_per_rad")
    report = {"sdo_round_trips": [], "identity": {}, "boot_up": {}, "states": {}, "aborts": {}}
    ids = list(range(1, args.nodes + 1))

    kwargs = bus_options(args.bus_option)
    if args.bitrate:
        kwargs["bitrate"] = args.bitrate
    # the EDS's default RPDO1 is a 20-byte CAN FD PDO, which the library warns about while it reads
    # it (it expects classic CAN's 8 bytes); it is remapped to 8 bytes below
    logging.getLogger("canopen.pdo.base").setLevel(logging.ERROR)
    network = canopen.Network()
    network.connect(interface=args.interface, channel=args.channel, **kwargs)
    try:
        nodes = []
        for n in ids:
            node = BaseNode402(n, str(args.eds / f"servo_drive_node{n}.eds"))
            # a simulated cell on a shared machine may answer later than a drive on its own core:
            # more time for an SDO answer and a CiA 402 state change than the library's defaults
            node.sdo.RESPONSE_TIMEOUT = 1.0
            node.TIMEOUT_SWITCH_STATE_SINGLE = 1.0
            node.TIMEOUT_SWITCH_STATE_FINAL = 3.0
            node.TIMEOUT_SWITCH_OP_MODE = 1.0
            node.TIMEOUT_CHECK_TPDO = 0.5
            network.add_node(node)
            nodes.append(node)

        # --- NMT: reset communication, wait for every boot-up
        booted = {}

        def on_boot(can_id, data, timestamp):
            if len(data) == 1 and data[0] == 0:
                booted[can_id - 0x700] = timestamp

        for n in ids:
            network.subscribe(0x700 + n, on_boot)
        network.nmt.state = "RESET COMMUNICATION"
        deadline = time.monotonic() + 5.0
        while len(booted) < len(ids) and time.monotonic() < deadline:
            time.sleep(0.01)
        report["boot_up"] = {str(n): n in booted for n in ids}

        def write(node, index, sub, value):
            """SDO download, then upload: the round trip of one object."""
            var = node.sdo[index] if sub is None else node.sdo[index][sub]
            var.raw = value
            back = var.raw
            same = math.isclose(back, value, rel_tol=1e-6) if isinstance(value, float) else back == value
            report["sdo_round_trips"].append({"node": node.id, "index": f"0x{index:04X}", "sub": sub or 0,
                                              "written": value, "read": back, "ok": bool(same)})
            return back

        # --- identity, cycle period
        for node in nodes:
            ident = node.sdo[0x1018]
            report["identity"][str(node.id)] = {
                "device_type": f"0x{node.sdo[0x1000].raw:08X}", "name": node.sdo[0x1008].raw,
                "vendor_id": f"0x{ident[1].raw:08X}", "product_code": f"0x{ident[2].raw:08X}",
                "revision": f"0x{ident[3].raw:08X}", "serial": f"0x{ident[4].raw:08X}"}
        period = nodes[0].sdo[0x1006].raw * 1e-6
        report["cycle_time_s"] = period

        # --- a limit and a gain, the heartbeat, the mode: written and read back
        for node in nodes:
            max_torque = node.sdo[0x6072].raw
            write(node, 0x6072, None, max_torque - 50)  # 5 % of rated torque less
            gain = node.sdo[0x2001].raw
            write(node, 0x2001, None, float(gain) * 0.9)
            write(node, 0x1017, None, 100)  # heartbeat every 100 ms
            write(node, 0x6060, None, 8)  # cyclic synchronous position

        # --- PDO mapping for classic CAN, synchronous
        for node in nodes:
            node.rpdo.read()
            node.tpdo.read()
            rpdo = node.rpdo[1]
            rpdo.clear()
            rpdo.add_variable(0x6040)
            rpdo.add_variable(0x607A)
            rpdo.add_variable(0x60B2)
            rpdo.trans_type = 1
            rpdo.enabled = True
            tp1, tp2 = node.tpdo[1], node.tpdo[2]
            tp1.clear()
            for index in (0x6041, 0x6064, 0x6077):
                tp1.add_variable(index)
            tp2.clear()
            for index in (0x606C, 0x6061):
                tp2.add_variable(index)
            for tpdo in (tp1, tp2):
                tpdo.trans_type = 1
                tpdo.enabled = True
            node.rpdo.save()
            node.tpdo.save()
            for pdo in (rpdo, tp1, tp2):  # read the configuration back over SDO
                com, mapping = pdo.com_record, pdo.map_array
                expect = [(com.od.index, 1, pdo.cob_id), (com.od.index, 2, 1), (mapping.od.index, 0, len(pdo.map))]
                expect += [(mapping.od.index, k + 1, v.index << 16 | v.subindex << 8 | v.length)
                           for k, v in enumerate(pdo.map)]
                for index, sub, value in expect:
                    back = node.sdo[index][sub].raw
                    if sub == 1 and index == com.od.index:
                        back &= 0x3FFFFFFF & ~(1 << 30)  # the COB-ID without its valid / RTR bits
                    report["sdo_round_trips"].append({"node": node.id, "index": f"0x{index:04X}", "sub": sub,
                                                      "written": value, "read": back, "ok": back == value})
            node.setup_402_state_machine(read_pdos=False)

        # --- operational, the cycle runs
        network.nmt.state = "OPERATIONAL"
        cycle = Cycle(network, nodes, period)
        following = {"max_counts": [0] * len(nodes), "samples": 0}
        first_pos = {}

        def on_tpdo1(index):
            def callback(pdo):
                k = cycle.k - 1  # the TPDO answers the newest SYNC
                pos = pdo["Position actual value"].raw
                first_pos.setdefault(index, pos)
                target = cycle.sent_targets.get(k - 1)
                if target is not None:
                    err = abs(target[index] - pos)
                    if err > following["max_counts"][index]:
                        following["max_counts"][index] = err
                    following["samples"] += 1
            return callback

        for i, node in enumerate(nodes):
            node.tpdo[1].add_callback(on_tpdo1(i))
        cycle.start()
        time.sleep(5 * period)
        for node in nodes:  # hold where the drive is: the target starts at the actual position
            if node.tpdo[1].wait_for_reception(2.0) is None:
                raise SystemExit(f"node {node.id}: no TPDO1 within 2 s of NMT operational")
            node.rpdo[1]["Target position"].raw = node.tpdo[1]["Position actual value"].raw
        report["start_counts"] = [node.rpdo[1]["Target position"].raw for node in nodes]
        report["nmt"] = {str(n.id): n.nmt.state for n in nodes}

        # --- CiA 402: enable every drive in cyclic synchronous position
        enabled_at = {}
        for node in nodes:
            node.op_mode = CSP
            report["states"].setdefault("mode", {})[str(node.id)] = node.op_mode
            node.state = "OPERATION ENABLED"
            enabled_at[node.id] = time.monotonic()
            report["states"].setdefault("enabled", {})[str(node.id)] = node.state

        # --- the motion: every axis out and back, a raised cosine in position
        hold = [node.rpdo[1]["Target position"].raw for node in nodes]
        scale = counts_per_rad or [1.0] * len(nodes)
        amplitude = [args.amplitude * scale[i] * (1 if counts_per_rad else 1000.0) for i in range(len(nodes))]
        steps = max(2, int(round(args.duration / period)))
        k0 = cycle.k + 2

        def targets(k):
            s = min(max((k - k0) / steps, 0.0), 1.0)
            shape = 0.5 * (1.0 - math.cos(2.0 * math.pi * s))
            return [int(round(h + a * shape)) for h, a in zip(hold, amplitude)]

        with cycle.lock:
            cycle.targets = targets
        moved_from = cycle.k
        time.sleep((steps + 10) * period)
        report["motion"] = {"cycles": steps, "duration_s": steps * period, "amplitude_rad": args.amplitude
                            if counts_per_rad else None, "first_cycle": k0, "from_cycle": moved_from}
        report["states"]["after_motion"] = {str(n.id): n.state for n in nodes}

        # --- disable
        for node in nodes:
            node.state = "SWITCH ON DISABLED"
            report["states"].setdefault("disabled", {})[str(node.id)] = node.state
        cycle.stop()
        intervals = [b - a for a, b in zip(cycle.sent_at, cycle.sent_at[1:])]
        late = [x for x in intervals if x > 1.5 * period]
        report["cycle"] = {"syncs": len(cycle.sent_at), "period_s": period, "interval": percentiles_us(intervals),
                           "mean_interval_us": sum(intervals) / len(intervals) * 1e6 if intervals else None,
                           "late": len(late)}
        fe = following["max_counts"]
        report["following_error"] = {"max_counts": fe, "samples": following["samples"],
                                     "max_rad": [e / c for e, c in zip(fe, counts_per_rad)] if counts_per_rad else None}
        network.nmt.state = "PRE-OPERATIONAL"

        # --- what the drives must refuse
        if args.probe_errors:
            node = nodes[0]
            probes = {"out_of_range_0x6060_11": lambda: node.sdo.download(0x6060, 0, bytes([11])),
                      "out_of_range_0x6060_3": lambda: node.sdo.download(0x6060, 0, bytes([3])),
                      "unknown_index_0x5FFF": lambda: node.sdo.upload(0x5FFF, 0),
                      "read_only_0x6041": lambda: node.sdo.download(0x6041, 0, bytes([0, 0]))}
            for name, probe in probes.items():
                try:
                    probe()
                    report["aborts"][name] = None
                except SdoAbortedError as exc:
                    report["aborts"][name] = f"0x{exc.code:08X}"
            # NMT start to node 42, which is not on the bus; a 2-byte SDO request (malformed)
            network.bus.send(can.Message(arbitration_id=0x000, data=[0x01, 42], is_extended_id=False))
            network.bus.send(can.Message(arbitration_id=0x600 + ids[-1], data=[0x40, 0x00], is_extended_id=False))
            time.sleep(0.1)
    finally:
        network.disconnect()
    text = json.dumps(report, indent=1)
    if args.report is not None:
        args.report.write_text(text)
    print(text)
    ok = all(r["ok"] for r in report["sdo_round_trips"]) and \
        all(s == "OPERATION ENABLED" for s in report["states"].get("enabled", {}).values())
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
