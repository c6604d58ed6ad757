"""A run's bus traffic as pcapng captures Wireshark dissects: POWERLINK frames and SocketCAN frames.

The CAN log (``fieldbus.canlog``: every frame that reached the wire, at its simulated time) is
written twice, with the pcapng container of the ``python-pcapng`` library:

**POWERLINK** (:func:`write_powerlink`, link type Ethernet): one Ethernet II frame of EtherType
0x88AB per POWERLINK frame, in the order and at the times of the cycle schedule
(``fieldbus.timing``):

* SoC (message type 0x01) from the MN (node 240) to all (255), for every SYNC of the log: NetTime
  = the SoC's simulated time (seconds, nanoseconds), RelativeTime = the cycle's start in µs;
* PReq (0x03) from the MN to node n for every RPDO1 of the log: flag RD, PDO version 0, size and
  the RPDO1 payload (20 bytes, or 32-64 with a set-point look-ahead);
* PRes (0x04) from node n to all for every TPDO1 + TPDO2 pair of the log: NMT status
  0xFD (operational), flag RD, the payload TPDO1 followed by TPDO2 (15 or 16 bytes);
* SoA (0x05) from the MN to all after the last PRes of each cycle (time: that PRes's start + its
  wire time + propagation + the MN's turnaround): no service requested, or a StatusRequest to
  the node that sent an EMCY in that cycle;
* ASnd (0x06) StatusResponse from that node, at the EMCY's time, with one error entry: the EMCY's
  error code (device profile 402, "occurred"), its time, and the EMCY's five manufacturer bytes.
  Several EMCYs in one cycle give one ASnd each after that cycle's SoA, which invites the first
  node (a real MN would invite the others in the following cycles).
* the asynchronous slot's SDO and NMT frames (``fieldbus.asynchronous``): an NMT command (CAN id
  0x000) as the MN's ASnd NMTCommand (service 0x04; start, stop, enter pre-operational, reset
  node, reset communication as NMTStartNode 0x21, NMTStopNode 0x22, NMTEnterPreOperational2
  0x23, NMTResetNode 0x28, NMTResetCommunication 0x29) to the node (255: all) after a SoA
  without service; an SDO request (0x600 + n) as the MN's ASnd to node n after a SoA without
  service, an SDO answer (0x580 + n) as node n's ASnd to the MN after a SoA inviting it
  (UnspecifiedInvite 0xFF). Both SDO ASnds carry the 8 bytes of the CANopen SDO frame under the
  manufacturer-specific service id 0xA0: POWERLINK's own SDO (sequence and command layer)
  transfers a whole object in one frame and so does not map frame by frame onto what the CAN
  log holds; the CAN capture decodes them as CANopen SDO.

Frames lost on the wire are not in the CAN log and so not in the capture; frames corrupted on the
wire (error frames in the CAN log) are left out as well (a receiver discards a frame whose CRC is
wrong), and counted. MAC addresses: POWERLINK's multicast addresses for SoC, PRes, SoA and ASnd,
``02:00:00:00:00:<node>`` (locally administered) for each node and the MN.

**CAN** (:func:`write_can`, link type LINKTYPE_CAN_SOCKETCAN = 227): every frame of the log as a
SocketCAN ``can_frame`` (8 data bytes) or ``canfd_frame`` (64 data bytes, flag FDF) with the CAN
id in network byte order; an error frame as a SocketCAN error frame (CAN_ERR_FLAG | CAN_ERR_PROT,
CRC sequence). Wireshark decodes the CANopen telegrams with ``-d can.subdissector,canopen``
(decode as CANopen).

Timestamps are the frames' simulated times (ns resolution), so a run starts on 1970-01-01.
"""
from __future__ import annotations

import struct
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ETHERTYPE_POWERLINK = 0x88AB
LINKTYPE_ETHERNET = 1
LINKTYPE_CAN_SOCKETCAN = 227
MN_NODE_ID = 240
BROADCAST = 255
SOC, PREQ, PRES, SOA, ASND = 0x01, 0x03, 0x04, 0x05, 0x06
NMT_CS_OPERATIONAL = 0xFD
NMT_MS_OPERATIONAL = 0xFD
SOA_NO_SERVICE, SOA_STATUS_REQUEST, SOA_UNSPECIFIED_INVITE = 0x00, 0x02, 0xFF
ASND_STATUS_RESPONSE, ASND_NMT_COMMAND, ASND_CANOPEN_SDO = 0x02, 0x04, 0xA0
#: CANopen NMT command specifier -> POWERLINK NMT command id (EPSG DS 301 table 128)
EPL_NMT_COMMANDS = {0x01: 0x21, 0x02: 0x22, 0x80: 0x23, 0x81: 0x28, 0x82: 0x29}
EPL_VERSION = 0x20
MIN_PAYLOAD = 46  # Ethernet minimum payload (after the EtherType), padded with zeros
MULTICAST = {SOC: bytes.fromhex("01111e000001"), PRES: bytes.fromhex("01111e000002"),
             SOA: bytes.fromhex("01111e000003"), ASND: bytes.fromhex("01111e000004")}
CAN_ERR_FLAG, CAN_ERR_PROT, CAN_ERR_PROT_LOC_CRC_SEQ = 0x20000000, 0x00000008, 0x08
CANFD_FDF = 0x04
ERROR_ENTRY_PROFILE_402 = 0x0192
ERROR_ENTRY_MODE_OCCURRED = 0x1000


def mac(node: int) -> bytes:
    """The (locally administered) MAC address of node ``node``."""
    return bytes((0x02, 0, 0, 0, 0, node))


@dataclass
class CaptureCounts:
    """What a capture holds (frames by kind) and what it left out."""

    frames: dict[str, int] = field(default_factory=dict)
    left_out_error_frames: int = 0
    cycles: int = 0

    def add(self, kind: str) -> None:
        self.frames[kind] = self.frames.get(kind, 0) + 1


class _Writer:
    """A pcapng file with one interface (python-pcapng's blocks), packets at ns resolution."""

    def __init__(self, path: Path, link_type: int, name: str, description: str) -> None:
        from pcapng import FileWriter, blocks

        self._blocks = blocks
        self._handle = open(path, "wb")
        self._shb = blocks.SectionHeader(options={"shb_userappl": "rx130l-cosim export-pcap"})
        self._shb.new_member(blocks.InterfaceDescription, link_type=link_type, snaplen=0xFFFF,
                             options={"if_name": name, "if_description": description, "if_tsresol": b"\x09"})
        with warnings.catch_warnings():  # python-pcapng declares if_tsresol without a type and warns about itself
            warnings.filterwarnings("ignore", message='Field type should not be "None"', category=DeprecationWarning)
            self._writer = FileWriter(self._handle, self._shb)
        # one Enhanced Packet Block, refilled per packet (half the cost of a new block each time)
        self._packet = self._shb.new_member(blocks.EnhancedPacket)
        self._packet.interface_id = 0

    def write(self, t_ns: int, data: bytes) -> None:
        packet = self._packet
        packet.timestamp_high, packet.timestamp_low = (t_ns >> 32) & 0xFFFFFFFF, t_ns & 0xFFFFFFFF
        packet.packet_data = data  # sets captured and packet length
        self._writer.write_block(packet)

    def close(self) -> None:
        self._handle.close()


def _ethernet(destination: bytes, node: int, payload: bytes) -> bytes:
    frame = destination + mac(node) + struct.pack(">H", ETHERTYPE_POWERLINK) + payload
    return frame + bytes(max(0, 14 + MIN_PAYLOAD - len(frame)))


def soc_frame(t_s: float, relative_us: int) -> bytes:
    seconds = int(t_s)
    nanoseconds = min(int(round((t_s - seconds) * 1e9)), 999_999_999)
    body = struct.pack("<BBBBBBIIQ", SOC, BROADCAST, MN_NODE_ID, 0, 0, 0, seconds, nanoseconds, relative_us)
    return _ethernet(MULTICAST[SOC], MN_NODE_ID, body)


def preq_frame(node: int, payload: bytes) -> bytes:
    body = struct.pack("<BBBBBBBBH", PREQ, node, MN_NODE_ID, 0, 0x01, 0, 0, 0, len(payload)) + payload
    return _ethernet(mac(node), MN_NODE_ID, body)


def pres_frame(node: int, payload: bytes) -> bytes:
    body = struct.pack("<BBBBBBBBH", PRES, BROADCAST, node, NMT_CS_OPERATIONAL, 0x01, 0, 0, 0, len(payload)) + payload
    return _ethernet(MULTICAST[PRES], node, body)


def soa_frame(service: int, target: int) -> bytes:
    body = struct.pack("<BBBBBBBBB", SOA, BROADCAST, MN_NODE_ID, NMT_MS_OPERATIONAL, 0, 0, service, target, EPL_VERSION)
    return _ethernet(MULTICAST[SOA], MN_NODE_ID, body)


def status_response_frame(node: int, t_s: float, emcy: bytes) -> bytes:
    """ASnd StatusResponse of ``node`` carrying the EMCY ``emcy`` (8 bytes) as one error entry."""
    error_code, error_register = struct.unpack_from("<HB", emcy)
    seconds = int(t_s)
    nanoseconds = min(int(round((t_s - seconds) * 1e9)), 999_999_999)
    static_errors = bytes((error_register,)) + bytes(7)
    entry = struct.pack("<HHII", ERROR_ENTRY_PROFILE_402 | ERROR_ENTRY_MODE_OCCURRED, error_code, seconds,
                        nanoseconds) + emcy[3:8].ljust(8, b"\0")
    body = struct.pack("<BBBBBBB3x", ASND, MN_NODE_ID, node, ASND_STATUS_RESPONSE, 0, 0, NMT_CS_OPERATIONAL)
    body += static_errors + entry + bytes(20)  # a zero entry type ends the list
    return _ethernet(MULTICAST[ASND], node, body)


def nmt_command_frame(data: bytes) -> bytes:
    """The MN's ASnd NMTCommand of the CANopen NMT frame ``data`` (command specifier, node id)."""
    command, node = (data + bytes(2))[:2]
    body = struct.pack("<BBBBBB", ASND, node or BROADCAST, MN_NODE_ID, ASND_NMT_COMMAND,
                       EPL_NMT_COMMANDS.get(command, 0x21), 0)
    return _ethernet(MULTICAST[ASND], MN_NODE_ID, body)


def sdo_frame(source: int, destination: int, data: bytes) -> bytes:
    """An ASnd from ``source`` to ``destination`` carrying the CANopen SDO frame ``data``."""
    body = struct.pack("<BBBB", ASND, destination, source, ASND_CANOPEN_SDO) + bytes(data).ljust(8, b"\0")
    return _ethernet(MULTICAST[ASND], source, body)


def _cycles(frames: np.ndarray, stamps: np.ndarray):
    """Frames of the log grouped by SYNC: yields (SoC time or None, [(time, id, error, data), ...])."""
    soc, current = None, []
    width = frames["data"].shape[1] if frames.size else 0
    blob = np.ascontiguousarray(frames["data"]).tobytes()
    times = stamps.tolist()
    for k, (arbitration_id, error, length) in enumerate(zip(frames["id"].tolist(), frames["error"].tolist(),
                                                           frames["length"].tolist())):
        item = (times[k], arbitration_id, bool(error), blob[k * width:k * width + length])
        if arbitration_id == 0x080 and not error:
            if soc is not None or current:
                yield soc, current
            soc, current = item[0], []
        else:
            current.append(item)
    if soc is not None or current:
        yield soc, current


def _cycle_time(stamps: np.ndarray, ids: np.ndarray) -> float:
    sync = stamps[ids == 0x080]
    if sync.size < 2:
        return 400e-6
    return round(float(np.median(np.diff(sync))) * 1e6) / 1e6


def write_powerlink(log_path: str | Path, out: str | Path) -> CaptureCounts:
    """Write the CAN log ``log_path`` as a POWERLINK capture ``out`` (pcapng); see the module docstring."""
    from fieldbus.canlog import read_frames
    from fieldbus.config import FieldbusConfig
    from fieldbus.timing import CycleLayout, wire_time

    log = read_frames(log_path)
    stamps = log.timestamps
    cycle_time = _cycle_time(stamps, log.frames["id"])
    config = FieldbusConfig.from_dict({"cycle_time_us": cycle_time * 1e6})
    layout = CycleLayout.from_config(config)
    counts = CaptureCounts()
    writer = _Writer(Path(out), LINKTYPE_ETHERNET, "powerlink", "rx130l-cosim POWERLINK (from the CAN log)")
    try:
        for soc, items in _cycles(log.frames, stamps):
            packets: list[tuple[float, int, bytes, str]] = []  # (time, order, frame, kind)
            if soc is not None:
                counts.cycles += 1
                packets.append((soc, 0, soc_frame(soc, int(round(soc / cycle_time)) * round(cycle_time * 1e6)), "SoC"))
            tpdo1: dict[int, tuple[float, bytes]] = {}
            emcy: list[tuple[float, int, bytes]] = []
            asynchronous: list[tuple[float, bytes, str]] = []  # SDO / NMT ASnds (fieldbus.asynchronous)
            invite = 0  # the node whose SDO answer the SoA invites
            last_pres = None
            for t, arbitration_id, error, data in items:
                base, node = arbitration_id & ~0x7F, arbitration_id & 0x7F
                if error:
                    counts.left_out_error_frames += 1
                    continue
                if base == 0x200:
                    packets.append((t, 1, preq_frame(node, data), "PReq"))
                elif base == 0x180:
                    tpdo1[node] = (t, data)
                elif base == 0x280 and node in tpdo1:
                    t1, first = tpdo1.pop(node)
                    payload = first + data
                    packets.append((t1, 1, pres_frame(node, payload), "PRes"))
                    end = t1 + wire_time(config.timing, 10 + len(payload)) + layout.propagation[min(
                        node, len(layout.propagation) - 1)]
                    last_pres = end if last_pres is None else max(last_pres, end)
                elif base == 0x080:
                    emcy.append((t, node, data))
                elif arbitration_id == 0x000:
                    asynchronous.append((t, nmt_command_frame(data), "ASnd"))
                elif base == 0x600:
                    asynchronous.append((t, sdo_frame(MN_NODE_ID, node, data), "ASnd"))
                elif base == 0x580:
                    asynchronous.append((t, sdo_frame(node, MN_NODE_ID, data), "ASnd"))
                    invite = node
            if soc is not None:
                soa_time = (last_pres if last_pres is not None else soc + layout.nominal_end_of_isochronous) \
                    + layout.mn_turnaround
                if emcy:
                    service, target = SOA_STATUS_REQUEST, emcy[0][1]
                elif invite:
                    service, target = SOA_UNSPECIFIED_INVITE, invite
                else:
                    service, target = SOA_NO_SERVICE, 0
                packets.append((soa_time, 2, soa_frame(service, target), "SoA"))
            for t, frame, kind in asynchronous:
                packets.append((max(t, soa_time if soc is not None else t), 3, frame, kind))
            for t, node, data in emcy:
                packets.append((max(t, soa_time if soc is not None else t), 3,
                                status_response_frame(node, t, data), "ASnd"))
            counts.left_out_error_frames += len(tpdo1)  # a TPDO1 whose TPDO2 was corrupted: no PRes
            for t, _, frame, kind in sorted(packets, key=lambda p: (p[0], p[1])):
                writer.write(int(round(t * 1e9)), frame)
                counts.add(kind)
    finally:
        writer.close()
    return counts


def socketcan_frame(arbitration_id: int, error: bool, data: bytes) -> bytes:
    """One LINKTYPE_CAN_SOCKETCAN record: CAN id (network byte order), length, flags, 2 reserved, data."""
    if error:
        payload = bytes((0, 0, 0, CAN_ERR_PROT_LOC_CRC_SEQ, 0, 0, 0, 0))
        return struct.pack(">IBBBB", CAN_ERR_FLAG | CAN_ERR_PROT, 8, 0, 0, 0) + payload
    if len(data) > 8:
        return struct.pack(">IBBBB", arbitration_id, len(data), CANFD_FDF, 0, 0) + data.ljust(64, b"\0")
    return struct.pack(">IBBBB", arbitration_id, len(data), 0, 0, 0) + data.ljust(8, b"\0")


_CAN_KINDS = {0x200: "RPDO1", 0x180: "TPDO1", 0x280: "TPDO2", 0x080: "EMCY", 0x000: "NMT", 0x600: "SDO request",
              0x580: "SDO answer"}


def write_can(log_path: str | Path, out: str | Path) -> CaptureCounts:
    """Write the CAN log ``log_path`` as a SocketCAN capture ``out`` (pcapng); see the module docstring."""
    from fieldbus.canlog import read_frames

    log = read_frames(log_path)
    stamps = log.timestamps
    counts = CaptureCounts()
    writer = _Writer(Path(out), LINKTYPE_CAN_SOCKETCAN, "can", "rx130l-cosim CAN log (CANopen telegrams)")
    try:
        frames = log.frames
        width = frames["data"].shape[1] if frames.size else 0
        blob = np.ascontiguousarray(frames["data"]).tobytes()
        times = stamps.tolist()
        for k, (arbitration_id, error, length) in enumerate(zip(frames["id"].tolist(), frames["error"].tolist(),
                                                               frames["length"].tolist())):
            writer.write(int(round(times[k] * 1e9)),
                         socketcan_frame(arbitration_id, bool(error), blob[k * width:k * width + length]))
            counts.add("error" if error else "SYNC" if arbitration_id == 0x080 else _CAN_KINDS.get(
                arbitration_id & ~0x7F, f"0x{arbitration_id:03X}"))
            counts.cycles += int(arbitration_id == 0x080 and not error)
    finally:
        writer.close()
    return counts


__all__ = ["CaptureCounts", "ETHERTYPE_POWERLINK", "LINKTYPE_CAN_SOCKETCAN", "MN_NODE_ID", "socketcan_frame",
           "write_can", "write_powerlink"]
