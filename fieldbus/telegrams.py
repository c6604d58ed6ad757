"""CANopen-style CiA 402 telegrams: identifiers, byte layouts, a validating decoder.

Identifiers follow the CANopen predefined connection set, so captures decode in
ordinary CAN tools:

=========  =============  =====================================================  =====
frame      COB-ID         payload (little endian)                                bytes
=========  =============  =====================================================  =====
SYNC       0x080          SYNC counter UINT8 1..overflow (CiA 301 0x1019)          1
RPDO1      0x200 + node   controlword 0x6040 UINT16, target position 0x607A      20
           (CAN FD)       INT32 [counts], torque offset 0x60B2 INT16 [0.1 % of    (8)
                          rated torque], modes of operation 0x6060 INT8,
                          reserved UINT8 (0), target torque 0x6071 INT16
                          [0.1 %], target velocity 0x60FF INT32 [counts/s],
                          velocity offset 0x60B1 INT32 [counts/s]
TPDO1      0x180 + node   statusword 0x6041 UINT16, position actual 0x6064        8
                          INT32 [counts], torque actual 0x6077 INT16 [0.1 %]
TPDO2      0x280 + node   velocity actual 0x606C INT32 [counts/s], error code     7
                          0x603F UINT16, modes of operation display 0x6061 INT8
EMCY       0x080 + node   error code UINT16, error register 0x1001 UINT8,         8
                          5 bytes manufacturer specific (here: the counter that
                          tripped, its value, its threshold)
=========  =============  =====================================================  =====

POWERLINK mapping: SYNC = SoC, RPDO1 = the PDO payload of the PReq to the node,
TPDO1 + TPDO2 = the PDO payload of the node's PRes (one Ethernet frame, two CAN
telegrams), EMCY = an asynchronous frame after the SoA.

The RPDO1 carries every set-point of the three cyclic synchronous modes (position 8,
velocity 9, torque 10) in one 20-byte CAN FD frame: a PReq is one POWERLINK frame
whatever its mapping, and 10 + 20 bytes still fit the padded minimum Ethernet frame,
so the cycle timing is that of the 8-byte telegram. Its first 8 bytes are exactly the
classic CSP telegram (controlword, target position, torque offset); the drive side also
accepts that classic 8-byte RPDO1 from a controller on classic CAN, read as mode 8 with
no velocity offset (target velocity and target torque 0).
"""
from __future__ import annotations

import struct
from typing import NamedTuple

import can

from fieldbus.errors import FrameDecodeError
from fieldbus.object_dictionary import pdo_layout

SYNC_ID = 0x080
EMCY_BASE = 0x080
TPDO1_BASE = 0x180
RPDO1_BASE = 0x200
TPDO2_BASE = 0x280
MAX_NODE_ID = 127

# controlword, target position, torque offset, modes of operation, reserved, target torque,
# target velocity, velocity offset
# the PDO layouts are the mappings of the drives' object dictionary (fieldbus/object_dictionary.toml)
RPDO1_SIGNED = struct.Struct(pdo_layout("RPDO1"))  # "<HihbBhii"
RPDO1_CLASSIC = struct.Struct(RPDO1_SIGNED.format[:4])  # controlword, target position, torque offset (classic CAN, CSP only)
TPDO1 = struct.Struct(pdo_layout("TPDO1"))  # "<Hih": statusword, position actual, torque actual
TPDO2 = struct.Struct(pdo_layout("TPDO2"))  # "<iHb": velocity actual, error code, modes of operation display
EMCY = struct.Struct("<HBBHH")  # error code, error register, counter id, counter value, threshold

PREQ_PAYLOAD_BYTES = RPDO1_SIGNED.size

# Set-point look-ahead: an RPDO1 longer than 20 bytes carries, after the 20 bytes above,
# byte 9 (the reserved byte) = k look-ahead entries, then k entries of 10 bytes, one per
# following cycle: the active mode's set-point INT32 (target position 0x607A [counts] in
# mode 8, target velocity 0x60FF [counts/s] in mode 9, target torque 0x6071 [0.1 %] in
# mode 10), torque offset 0x60B2 INT16 [0.1 %], velocity offset 0x60B1 INT32 [counts/s];
# zero padding up to the next CAN FD data length (32, 48 or 64 bytes).
RPDO1_LOOKAHEAD_ENTRY = struct.Struct("<ihi")
RPDO1_MAX_BYTES = 64  # the longest CAN FD data field
MAX_LOOKAHEAD = (RPDO1_MAX_BYTES - RPDO1_SIGNED.size) // RPDO1_LOOKAHEAD_ENTRY.size
CAN_FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
RPDO1_LOOKAHEAD_LENGTHS = (32, 48, 64)  # the CAN FD lengths that hold 1..MAX_LOOKAHEAD entries

# Set-point buffer (``[fieldbus] setpoint_buffer``, after CiA 402 object 0x60C4): a 64-byte
# RPDO1 carries at bytes 60-61 the entry skip s (UINT16): its entry j is for the cycle
# s + j after the one of its own set-point (s = 0, the zero padding of the plain look-ahead:
# the entries follow the own set-point). A TPDO2 of 8 bytes carries at byte 7 how many
# set-points the drive holds for the cycles after the current one (0x60C4 sub 2, UINT8).
RPDO1_BUFFER_SKIP = struct.Struct("<H")
RPDO1_BUFFER_SKIP_OFFSET = RPDO1_MAX_BYTES - 4  # bytes 60-61, after 4 entries (20 + 4 * 10 = 60)
TPDO2_BUFFERED = struct.Struct(pdo_layout("TPDO2", setpoint_buffer=True))  # "<iHbB": TPDO2 + set-points held ahead (0x60C4 sub 2, UINT8)
#: the deepest set-point buffer the telegrams can report (byte 7 of the TPDO2 is a UINT8
#: holding buffer + dead time; 5 kept free for dead times of up to 5 cycles)
MAX_SETPOINT_BUFFER = 250


def rpdo1_length(lookahead: int) -> int:
    """Data bytes of an RPDO1 carrying ``lookahead`` entries (20 without any): 20 + 10 k
    rounded up to a CAN FD data length."""
    need = RPDO1_SIGNED.size + lookahead * RPDO1_LOOKAHEAD_ENTRY.size
    return next(size for size in CAN_FD_LENGTHS if size >= need)
PRES_PAYLOAD_BYTES = TPDO1.size + TPDO2.size

# CANopen emergency error code for communication faults (CiA 301: 0x81xx communication)
EMCY_COMMUNICATION = 0x8100
EMCY_ERROR_REGISTER_COMMUNICATION = 0x10  # bit 4 of 0x1001: communication error

INT16_MIN, INT16_MAX = -(1 << 15), (1 << 15) - 1
INT32_MIN, INT32_MAX = -(1 << 31), (1 << 31) - 1


#: modes of operation (0x6060) the telegrams carry set-points for: cyclic synchronous
#: position, velocity, torque
MODES_OF_OPERATION = (8, 9, 10)
#: what the 8-byte classic RPDO1 stands for in the fields it lacks
CLASSIC_RPDO1_DEFAULTS = (8, 0, 0, 0, 0)  # mode, reserved, target torque, target velocity, velocity offset


class RxPdo1(NamedTuple):
    """Decoded RPDO1 (MN -> drive) in telegram units (a classic 8-byte RPDO1 decodes with
    mode 8 and zero target torque, target velocity and velocity offset)."""

    node: int
    controlword: int
    target_position: int
    torque_offset: int
    modes_of_operation: int = 8
    target_torque: int = 0
    target_velocity: int = 0
    velocity_offset: int = 0
    lookahead: tuple = ()  # (set-point of the active mode, torque offset, velocity offset) per following cycle
    lookahead_skip: int = 0  # entry j is for the cycle lookahead_skip + j after the own set-point's (64 bytes)


class TxPdo1(NamedTuple):
    """Decoded TPDO1 (drive -> MN) in telegram units."""

    node: int
    statusword: int
    position_actual: int
    torque_actual: int


class TxPdo2(NamedTuple):
    """Decoded TPDO2 (drive -> MN) in telegram units."""

    node: int
    velocity_actual: int
    error_code: int
    modes_of_operation_display: int = 8
    setpoints_held: int = -1  # 8-byte TPDO2: set-points the drive holds ahead (0x60C4 sub 2); -1: not sent


class Sync(NamedTuple):
    """Decoded SYNC (SoC); counter 0 means the frame carried no counter."""

    counter: int


class Emergency(NamedTuple):
    """Decoded EMCY frame."""

    node: int
    error_code: int
    error_register: int
    counter_id: int
    counter_value: int
    threshold: int


Telegram = RxPdo1 | TxPdo1 | TxPdo2 | Sync | Emergency


def classify(arbitration_id: int) -> tuple[str, int]:
    """(kind, node) of a COB-ID; kind is 'sync', 'emcy', 'rpdo1', 'tpdo1', 'tpdo2' or
    'unknown' (node 0 for SYNC and unknown ids)."""
    if arbitration_id == SYNC_ID:
        return "sync", 0
    base, node = arbitration_id & ~0x7F, arbitration_id & 0x7F
    if node == 0 or arbitration_id > 0x7FF:
        return "unknown", 0
    kind = {EMCY_BASE: "emcy", TPDO1_BASE: "tpdo1", RPDO1_BASE: "rpdo1", TPDO2_BASE: "tpdo2"}.get(base)
    return (kind, node) if kind else ("unknown", 0)


_LENGTHS = {"sync": (0, 1), "emcy": (EMCY.size,),
            "rpdo1": (RPDO1_SIGNED.size, RPDO1_CLASSIC.size) + RPDO1_LOOKAHEAD_LENGTHS,
            "tpdo1": (TPDO1.size,), "tpdo2": (TPDO2.size, TPDO2_BUFFERED.size)}


def check_frame(msg: can.Message, kind: str, node: int) -> None:
    """Raise :class:`FrameDecodeError` if ``msg`` cannot be a valid ``kind`` telegram."""
    if kind == "unknown":
        raise FrameDecodeError("unknown_id", msg.arbitration_id, 0,
                               "not a SYNC, EMCY, RPDO1, TPDO1 or TPDO2 identifier")
    if msg.is_error_frame:
        raise FrameDecodeError("error_frame", msg.arbitration_id, node,
                               "frame failed its checksum (corrupted on the wire)")
    if msg.is_remote_frame:
        raise FrameDecodeError("remote_frame", msg.arbitration_id, node, "remote frames carry no data")
    if msg.is_extended_id:
        raise FrameDecodeError("unknown_id", msg.arbitration_id, node,
                               "29-bit identifier; CANopen uses 11-bit identifiers")
    length = len(msg.data)
    allowed = _LENGTHS[kind]
    if length not in allowed:
        reason = "short_frame" if length < min(allowed) else "long_frame"
        raise FrameDecodeError(reason, msg.arbitration_id, node,
                               f"{length} data bytes, {kind.upper()} needs {' or '.join(map(str, allowed))}")
    if kind == "rpdo1" and length > RPDO1_SIGNED.size:
        entries = msg.data[9]
        if RPDO1_SIGNED.size + entries * RPDO1_LOOKAHEAD_ENTRY.size > length:
            raise FrameDecodeError("bad_lookahead", msg.arbitration_id, node,
                                   f"{entries} look-ahead entries (byte 9) do not fit {length} data bytes")


def decode(msg: can.Message) -> Telegram:
    """Decode any telegram of this network; raises :class:`FrameDecodeError` (a
    ``ValueError``) for unknown ids, wrong lengths, error or remote frames."""
    kind, node = classify(msg.arbitration_id)
    check_frame(msg, kind, node)
    data = msg.data
    if kind == "rpdo1":
        if len(data) == RPDO1_CLASSIC.size:
            return RxPdo1(node, *RPDO1_CLASSIC.unpack(data))
        cw, pos, tq, mode, _, target_torque, target_velocity, velocity_offset = RPDO1_SIGNED.unpack_from(data)
        ahead, skip = (), 0
        if len(data) > RPDO1_SIGNED.size:
            ahead = tuple(RPDO1_LOOKAHEAD_ENTRY.unpack_from(data, RPDO1_SIGNED.size + j * RPDO1_LOOKAHEAD_ENTRY.size)
                          for j in range(data[9]))
            if len(data) == RPDO1_MAX_BYTES:
                skip = RPDO1_BUFFER_SKIP.unpack_from(data, RPDO1_BUFFER_SKIP_OFFSET)[0]
        return RxPdo1(node, cw, pos, tq, mode, target_torque, target_velocity, velocity_offset, ahead, skip)
    if kind == "tpdo1":
        return TxPdo1(node, *TPDO1.unpack(data))
    if kind == "tpdo2":
        return TxPdo2(node, *(TPDO2.unpack(data) if len(data) == TPDO2.size else TPDO2_BUFFERED.unpack(data)))
    if kind == "sync":
        return Sync(data[0] if data else 0)
    return Emergency(node, *EMCY.unpack(data))


def _checked(value: int, low: int, high: int, name: str) -> int:
    if not low <= value <= high:
        raise ValueError(f"{name} = {value}: expected an integer in [{low}, {high}]")
    return value


def check_mode_of_operation(mode: int, name: str = "modes_of_operation") -> int:
    """``mode`` if the telegrams carry set-points for it (8, 9, 10); ValueError naming ``name`` otherwise."""
    if isinstance(mode, bool) or mode not in MODES_OF_OPERATION:
        raise ValueError(f"{name} = {mode!r}: expected 8 (cyclic synchronous position), 9 (cyclic synchronous "
                         "velocity) or 10 (cyclic synchronous torque)")
    return int(mode)


def encode_rpdo1(controlword: int, target_position: int, torque_offset: int, modes_of_operation: int = 8,
                 target_torque: int = 0, target_velocity: int = 0, velocity_offset: int = 0,
                 lookahead: tuple | list = (), lookahead_skip: int = 0) -> bytes:
    """RPDO1 payload (20 bytes, or with ``lookahead`` = up to 4 tuples (set-point of the active
    mode, torque offset, velocity offset) for the following cycles: 32, 48 or 64 bytes; with
    ``lookahead_skip`` s > 0 (a set-point buffer) always 64 bytes, entry j for the cycle s + j
    after the own set-point's); raises ValueError naming the field if a value is out of range."""
    if len(lookahead) > MAX_LOOKAHEAD:
        raise ValueError(f"lookahead: {len(lookahead)} entries, expected at most {MAX_LOOKAHEAD}")
    base = _encode_base(controlword, target_position, torque_offset, modes_of_operation, target_torque,
                        target_velocity, velocity_offset)
    if not lookahead:
        return base
    data = bytearray(base)
    data[9] = len(lookahead)
    target_range = (INT16_MIN, INT16_MAX) if modes_of_operation == 10 else (INT32_MIN, INT32_MAX)
    for j, (target, offset, velocity) in enumerate(lookahead):
        data += RPDO1_LOOKAHEAD_ENTRY.pack(_checked(target, *target_range, f"lookahead[{j}] set-point"),
                                           _checked(offset, INT16_MIN, INT16_MAX, f"lookahead[{j}] torque offset"),
                                           _checked(velocity, INT32_MIN, INT32_MAX, f"lookahead[{j}] velocity offset"))
    if lookahead_skip:
        data = data.ljust(RPDO1_MAX_BYTES, b"\0")
        RPDO1_BUFFER_SKIP.pack_into(data, RPDO1_BUFFER_SKIP_OFFSET, _checked(lookahead_skip, 0, 0xFFFF, "lookahead_skip"))
    return bytes(data.ljust(rpdo1_length(len(lookahead)), b"\0"))


def _encode_base(controlword: int, target_position: int, torque_offset: int, modes_of_operation: int,
                 target_torque: int, target_velocity: int, velocity_offset: int) -> bytes:
    return RPDO1_SIGNED.pack(_checked(controlword, 0, 0xFFFF, "controlword"),
                             _checked(target_position, INT32_MIN, INT32_MAX, "target_position"),
                             _checked(torque_offset, INT16_MIN, INT16_MAX, "torque_offset"),
                             check_mode_of_operation(modes_of_operation), 0,
                             _checked(target_torque, INT16_MIN, INT16_MAX, "target_torque"),
                             _checked(target_velocity, INT32_MIN, INT32_MAX, "target_velocity"),
                             _checked(velocity_offset, INT32_MIN, INT32_MAX, "velocity_offset"))


def encode_tpdo1(statusword: int, position_actual: int, torque_actual: int) -> bytes:
    """TPDO1 payload; raises ValueError naming the field if a value is out of range."""
    return TPDO1.pack(_checked(statusword, 0, 0xFFFF, "statusword"),
                      _checked(position_actual, INT32_MIN, INT32_MAX, "position_actual"),
                      _checked(torque_actual, INT16_MIN, INT16_MAX, "torque_actual"))


def encode_tpdo2(velocity_actual: int, error_code: int, modes_of_operation_display: int = 8,
                 setpoints_held: int | None = None) -> bytes:
    """TPDO2 payload (8 bytes with ``setpoints_held``, the set-point buffer's fill: 0x60C4 sub 2);
    raises ValueError naming the field if a value is out of range."""
    if setpoints_held is not None:
        return encode_tpdo2(velocity_actual, error_code, modes_of_operation_display) + bytes(
            [_checked(setpoints_held, 0, 255, "setpoints_held")])
    return TPDO2.pack(_checked(velocity_actual, INT32_MIN, INT32_MAX, "velocity_actual"),
                      _checked(error_code, 0, 0xFFFF, "error_code"),
                      _checked(modes_of_operation_display, -128, 127, "modes_of_operation_display"))


class FastMessage(can.Message):
    """A :class:`can.Message` with a lean positional constructor for the hot loop:
    standard 11-bit id, data frame, received (``is_rx``), no channel; a CAN FD frame
    (``is_fd``) when it carries more than 8 bytes."""

    __slots__ = ()

    def __init__(self, timestamp: float, arbitration_id: int, data: bytearray,
                 is_error_frame: bool = False) -> None:  # pylint: disable=super-init-not-called
        self.timestamp = timestamp
        self.arbitration_id = arbitration_id
        self.is_extended_id = False
        self.is_remote_frame = False
        self.is_error_frame = is_error_frame
        self.channel = None
        self.is_fd = len(data) > 8
        self.is_rx = True
        self.bitrate_switch = False
        self.error_state_indicator = False
        self.data = data
        self.dlc = len(data)
