"""What the two processes of a split run agree on besides the POWERLINK telegrams.

**Cycle marker.** Before the SoC of every cycle k the controller side sends a cycle
marker ``<cycle:uint32><flags:uint8>`` through the pipe it shares with the drive
process (the simulator's own clock signal, not bus traffic). The drive side waits for
it before it runs cycle k, so it knows

* ``LOST`` - the PReqs of cycle k are lost frames (overrun policy ``lost_frame``): its
  fault plan drops them exactly as the controller side's does, and it does not wait
  for them;
* ``END`` - the run ends before cycle k (the controller stopped, or the controller
  side ends early): the drive side's master stops there.

* ``ASYNC`` - the managing node offers a frame for the asynchronous slot of cycle k (an SDO
  request or an NMT command, ``fieldbus.asynchronous``): the marker carries it after the flags
  as ``<cob_id:uint16><data: 0..8 bytes>``. The drive side, which runs the nodes' half of the
  slot (:class:`fieldbus.asynchronous.AsyncNodes`), sends ``("async", k, kind, answer)``
  through the pipe after its cycle k whenever the marker carried a frame or a node owed an
  answer in that slot; the controller side, whose SDO client knows the same, reads it after the
  PRes of cycle k. Cycles without SDO/NMT traffic carry nothing extra.

**Acknowledgement.** Lock-step normally needs no extra message: the controller side
waits for the PRes frames of cycle k before it sends anything of cycle k+1. In a cycle
in which it expects no PRes at all (every PReq lost, every node silent, ...; both
sides derive this from the same fault plan, :func:`pres_expected`) the drive side
sends ``("ack", k)`` through the pipe after its cycle and the controller side waits
for it, so frames of cycle k+1 never reach the drive side while it is still in cycle k.

**Buses.** Both sides use python-can's ``udp_multicast`` on loopback, one multicast
port per direction (fresh ephemeral ports per run, so concurrent runs do not hear each
other): the controller side sends on the *down* port and listens on the *up* port, the
drive side the other way round (:class:`DirectionalBus`). With one port for both
directions every socket would also receive its own frames back (multicast loopback is
what delivers them to the other process) and python-can would unpack and discard each
of them: about 20 wasted receives per cycle.
"""
from __future__ import annotations

import dataclasses
import socket
import struct

import can

from fieldbus import FieldbusConfig
from fieldbus.faults import CycleFaults

MARKER = struct.Struct("<IB")
LOST = 0x01
END = 0x02
ASYNC = 0x04
OFFER = struct.Struct("<H")
MULTICAST_GROUP = "239.74.164.1"


def pack_marker(cycle: int, flags: int = 0, offer: tuple[int, bytes] | None = None) -> bytes:
    """The cycle marker of ``cycle`` with ``flags`` (LOST, END) and the MN's asynchronous
    frame ``offer`` (COB-ID, data; sets ASYNC)."""
    if offer is None:
        return MARKER.pack(cycle, flags)
    return MARKER.pack(cycle, flags | ASYNC) + OFFER.pack(offer[0]) + bytes(offer[1])


def unpack_marker(data: bytes) -> tuple[int, int]:
    """(cycle, flags) of a cycle marker."""
    return unpack_marker_offer(data)[:2]  # type: ignore[return-value]


def unpack_marker_offer(data: bytes) -> tuple[int, int, tuple[int, bytes] | None]:
    """(cycle, flags, offered asynchronous frame or None) of a cycle marker."""
    if len(data) < MARKER.size or (len(data) != MARKER.size and not data[MARKER.size - 1] & ASYNC) \
            or len(data) > MARKER.size + OFFER.size + 8 or MARKER.size < len(data) < MARKER.size + OFFER.size:
        raise ValueError(f"cycle marker of {len(data)} bytes: expected {MARKER.size} (or up to "
                         f"{MARKER.size + OFFER.size + 8} with an asynchronous frame)")
    cycle, flags = MARKER.unpack_from(data)
    if not flags & ASYNC:
        return cycle, flags, None
    return cycle, flags, (OFFER.unpack_from(data, MARKER.size)[0], bytes(data[MARKER.size + OFFER.size:]))


def pres_expected(faults: CycleFaults | None, nodes: int) -> bool:
    """True when the managing node waits for at least one PRes in a cycle with ``faults``
    (a node answers a PReq that reached it, unless silent, and the medium may lose the PRes)."""
    if faults is None:
        return True
    kinds = faults.kinds
    return any(kinds.get(n) not in ("loss", "corrupt") and kinds.get(nodes + n) not in ("silent", "loss")
               for n in range(1, nodes + 1))


def free_udp_port() -> int:
    """An ephemeral UDP port number that is free right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def side_configs(config: FieldbusConfig, port: int, receive_timeout_s: float,
                 group: str = MULTICAST_GROUP) -> FieldbusConfig:
    """The configuration both sides use: ``config`` on ``udp_multicast`` at ``group``:``port``
    with ``receive_timeout_s`` of wall time per wait for frames that were sent."""
    options = dict(config.bus.options)
    options.pop("can_filters", None)
    options["port"] = port
    bus = dataclasses.replace(config.bus, interface="udp_multicast", channel=group,
                              receive_timeout_s=receive_timeout_s, options=options)
    return dataclasses.replace(config, bus=bus)


class DirectionalBus:
    """A python-can bus pair used as one: ``send`` on ``out_bus``, ``recv`` from ``in_bus``
    (what a fieldbus endpoint calls on its ``bus``)."""

    def __init__(self, out_bus: can.BusABC, in_bus: can.BusABC) -> None:
        self.out_bus = out_bus
        self.in_bus = in_bus
        self.channel_info = f"out {out_bus.channel_info}, in {in_bus.channel_info}"

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.out_bus.send(msg, timeout)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        return self.in_bus.recv(timeout)

    def shutdown(self) -> None:
        try:
            self.out_bus.shutdown()
        finally:
            self.in_bus.shutdown()


def use_directional_bus(endpoint, side: str, group: str, down_port: int, up_port: int) -> None:
    """Replace ``endpoint.bus`` (opened on one port) by a :class:`DirectionalBus`: side 'mn'
    sends on ``down_port`` and receives on ``up_port``, side 'cn' the reverse."""
    out_port, in_port = (down_port, up_port) if side == "mn" else (up_port, down_port)
    out_bus = can.Bus(interface="udp_multicast", channel=group, port=out_port)
    try:
        in_bus = can.Bus(interface="udp_multicast", channel=group, port=in_port)
    except Exception:
        out_bus.shutdown()
        raise
    endpoint.bus.shutdown()
    endpoint.bus = DirectionalBus(out_bus, in_bus)
