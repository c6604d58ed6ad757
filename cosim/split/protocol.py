"""What the two processes of a split run agree on besides the POWERLINK telegrams.

**Cycle marker.** Before the SoC of every cycle k the controller side sends one CAN
frame with COB-ID 0x100 (the CANopen TIME object's identifier, used here for the
simulator's own clock): payload ``<cycle:uint32><flags:uint8>``. The drive side waits
for it before it runs cycle k, so it knows

* ``LOST`` - the PReqs of cycle k are lost frames (overrun policy ``lost_frame``): its
  fault plan drops them exactly as the controller side's does, and it does not wait
  for them;
* ``END`` - the run ends before cycle k (the controller stopped, or the controller
  side ends early): the drive side's master stops there.

**Buses.** Both sides use ``udp_multicast`` on loopback with the same group and port
(a fresh ephemeral port per run, so concurrent runs do not hear each other); the drive
side's filter also passes the marker.
"""
from __future__ import annotations

import dataclasses
import socket
import struct

import can

from fieldbus import FieldbusConfig
from fieldbus.telegrams import RPDO1_BASE, SYNC_ID

MARKER_ID = 0x100
MARKER = struct.Struct("<IB")
LOST = 0x01
END = 0x02
MULTICAST_GROUP = "239.74.164.1"


def marker_message(cycle: int, flags: int = 0) -> can.Message:
    """The cycle marker frame of ``cycle`` (simulated timestamp: none; the marker is not POWERLINK traffic)."""
    return can.Message(arbitration_id=MARKER_ID, is_extended_id=False, data=MARKER.pack(cycle, flags))


def parse_marker(msg: can.Message) -> tuple[int, int] | None:
    """(cycle, flags) of a marker frame, None for any other frame."""
    if msg.arbitration_id != MARKER_ID or msg.is_error_frame or len(msg.data) != MARKER.size:
        return None
    cycle, flags = MARKER.unpack(bytes(msg.data))
    return cycle, flags


def free_udp_port() -> int:
    """An ephemeral UDP port number that is free right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def side_configs(config: FieldbusConfig, port: int, receive_timeout_s: float,
                 group: str = MULTICAST_GROUP) -> tuple[FieldbusConfig, FieldbusConfig]:
    """(controller side, drive side) configurations: ``config`` on ``udp_multicast`` at
    ``group``:``port`` with ``receive_timeout_s`` of wall time per wait; the drive side's
    receive filter also passes the cycle marker."""
    nodes = config.nodes
    cn_ids = [SYNC_ID, MARKER_ID] + [RPDO1_BASE + k for k in range(1, nodes + 1)]
    base = dict(config.bus.options)
    base.pop("can_filters", None)
    base["port"] = port
    mn_bus = dataclasses.replace(config.bus, interface="udp_multicast", channel=group,
                                 receive_timeout_s=receive_timeout_s, options=dict(base))
    cn_bus = dataclasses.replace(mn_bus, options={**base, "can_filters": [
        {"can_id": i, "can_mask": 0x7FF, "extended": False} for i in cn_ids]})
    return dataclasses.replace(config, bus=mn_bus), dataclasses.replace(config, bus=cn_bus)
