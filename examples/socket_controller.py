"""An external controller for ``cosim serve`` in the standard library alone (``socket`` and
``struct``), nothing of the project: the udpcycle wire format and the frames of the fieldbus
reference, written out so that a controller in C, Rust or a PLC language can follow it line by
line (docs/how-to/served_cell.md).

    python examples/socket_controller.py CELL_HOST:PORT BIND_HOST:PORT NODES FIRST_COUNTER HOLD_CYCLES OUT

It speaks first (a SoC with FIRST_COUNTER and one 8-byte PReq per node holding the drives
disabled), then answers every PRes datagram with the next cycle's group (counter + 1, 1..240),
enables the drives through CiA 402, holds them at their position actual for HOLD_CYCLES,
disables them (shutdown 0x06) and keeps cycling until the cell stops (no PRes for 1 s).
OUT gets one line per datagram received: ``R <statuswords...> <positions...>``, and one per
group sent: ``S <counter>``.
"""
import socket
import struct
import sys
import time

HEADER = struct.Struct(">4sBBHIIQ")  # magic, version, flags, frames, sender id, sequence, send time ns
FRAME = struct.Struct(">IBBHd")  # can id, length, flags, reserved, timestamp
TPDO1 = struct.Struct("<Hih")  # statusword, position actual, torque actual
RPDO1 = struct.Struct("<Hih")  # controlword, target position, torque offset (8-byte classic CSP telegram)


def address(text):
    host, _, port = text.rpartition(":")
    return host, int(port)


def datagram(sequence, frames):
    body = b"".join(FRAME.pack(can_id, len(data), 0, 0, 0.0) + data for can_id, data in frames)
    return HEADER.pack(b"RXCB", 1, 0, len(frames), 0xC0FFEE, sequence, time.time_ns()) + body


def parse(payload):
    magic, version, _, count, _, _, _ = HEADER.unpack_from(payload, 0)
    assert magic == b"RXCB" and version == 1
    frames, at = [], HEADER.size
    for _ in range(count):
        can_id, length, _, _, _ = FRAME.unpack_from(payload, at)
        at += FRAME.size
        frames.append((can_id & 0x1FFFFFFF, payload[at:at + length]))
        at += length
    return frames


def state(sw):
    if sw & 0x4F == 0x40:
        return "switch_on_disabled"
    return {0x21: "ready", 0x23: "switched_on", 0x27: "enabled"}.get(sw & 0x6F, "fault" if sw & 0x08 else "other")


def main():
    cell, bind, nodes, first, hold, out = (address(sys.argv[1]), address(sys.argv[2]), int(sys.argv[3]),
                                           int(sys.argv[4]), int(sys.argv[5]), sys.argv[6])
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(bind)
    sock.settimeout(0.05)
    log = open(out, "w")
    sequence, counter = 0, first
    status, position = [0] * nodes, [0] * nodes
    controlword = [0] * nodes
    enabled_for = 0
    seen_pres = False
    started = time.monotonic()
    while True:
        try:
            payload = sock.recv(65536)
        except socket.timeout:
            if not seen_pres:  # speak first: the cell answers the sender of the first valid datagram
                sequence += 1
                sock.sendto(datagram(sequence, [(0x080, bytes([counter]))] +
                                     [(0x200 + i + 1, RPDO1.pack(0, 0, 0)) for i in range(nodes)]), cell)
                log.write(f"S {counter}\n")
                assert time.monotonic() - started < 60.0, "no PRes from the cell"
                continue
            if time.monotonic() - last > 1.0:
                break
            continue
        frames = parse(payload)
        pres = [(i, d) for i, d in frames if 0x181 <= i <= 0x180 + nodes and len(d) == 8]
        if not pres:
            continue
        seen_pres, last = True, time.monotonic()
        for can_id, data in pres:
            status[can_id - 0x181], position[can_id - 0x181], _ = TPDO1.unpack(data)
        log.write("R " + " ".join(map(str, status + position)) + "\n")
        if all(state(s) == "enabled" for s in status):
            enabled_for += 1
        for i, sw in enumerate(status):
            s = state(sw)
            if enabled_for > hold:
                controlword[i] = 0x06
            elif s == "fault":
                controlword[i] = 0x00 if controlword[i] & 0x80 else 0x80
            else:
                controlword[i] = {"switch_on_disabled": 0x06, "ready": 0x07}.get(s, 0x0F)
        counter = counter % 240 + 1  # the next cycle's counter: 1..240
        sequence += 1
        sock.sendto(datagram(sequence, [(0x080, bytes([counter]))] +
                             [(0x200 + i + 1, RPDO1.pack(controlword[i], position[i], 0)) for i in range(nodes)]),
                    cell)
        log.write(f"S {counter}\n")
    log.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
