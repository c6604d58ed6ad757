"""The managing node (controller side) and the controlled nodes (drive side).

Both are reactive: they build the frames they send and digest the frames they
receive through ``receive(msg)``, which never raises; a frame that cannot be decoded
is counted, recorded as an event and logged. Threshold counters live on both sides.

Synchronous semantics (one cycle k, SoC at t_k):

* At the SoC (the CN's cycle timer, nominally t_k) each controlled node latches its drive's actual values (sent in this
  cycle's PRes) and applies the set-point that arrived in the PReq of cycle
  k - dead_time_cycles (held, or extrapolated for one cycle and then held, if it never arrived).
* The PReq of cycle k carries the set-point the controller computed after cycle
  k - 1; it takes effect at the SoC of cycle k + dead_time_cycles.

Fault reactions:

* Controlled node n, threshold reached (loss of SoC/PReq, CRC, SoC jitter): it latches
  ``comm_fault[n]``, sends an EMCY frame in the asynchronous slot and, from the next
  SoC, with abort option 'fault' (CiA 402 0x6007 = 1, default) presents fault code
  0x8100 to its drive (``applied.fault_code``: the drive runs its fault reaction);
  with option 'quick_stop' (0x6007 = 3) it presents controlword 0x0002 instead of the
  received one. The latch clears when a received controlword
  with a rising fault-reset bit is applied while no counter of the node is at its
  threshold; that controlword then passes to the drive.
* Managing node, threshold reached for node n (loss of PRes, late PRes, CRC): it
  latches ``node_fault[n]`` for the controller, which must stop commanding motion;
  cleared by the controller sending a fault reset (rising bit 7) to node n once the
  node's counters are below threshold.
"""
from __future__ import annotations

import struct
from collections import deque
from collections.abc import Callable
from functools import partial
from itertools import islice
from math import floor
from operator import mul
from typing import TYPE_CHECKING

import can
import numpy as np

from fieldbus.cia402 import CW_FAULT_RESET, Command
from fieldbus.codec import load_codec
from fieldbus.events import CounterBank, EventLog, FieldbusEvent, ThresholdCounter
from fieldbus.process_data import AppliedSetpoints, DriveActuals, ObservedActuals
from fieldbus.telegrams import (
    CLASSIC_RPDO1_DEFAULTS, EMCY, EMCY_BASE, EMCY_COMMUNICATION, EMCY_ERROR_REGISTER_COMMUNICATION,
    MODES_OF_OPERATION, RPDO1_BASE, RPDO1_BUFFER_SKIP, RPDO1_BUFFER_SKIP_OFFSET, RPDO1_CLASSIC, RPDO1_LOOKAHEAD_ENTRY,
    RPDO1_LOOKAHEAD_LENGTHS, RPDO1_MAX_BYTES, RPDO1_SIGNED, SYNC_ID, TPDO1, TPDO1_BASE, TPDO2, TPDO2_BUFFERED,
    TPDO2_BASE, FastMessage, check_frame, check_mode_of_operation, classify, rpdo1_length,
)

if TYPE_CHECKING:
    from fieldbus.config import FieldbusConfig
    from fieldbus.process_data import Setpoints
    from fieldbus.scaling import JointScaling
    from fieldbus.timing import CycleLayout

_ERROR_CODE_CHANGED = 4  # codec.latch_pres: packed, and a drive's error code changed since the last cycle
DRIVE_ERROR_TEXT = {0x0000: "error reset", 0x2310: "continuous over current: I2t derating",
                    0x8400: "velocity speed controller: max motor speed exceeded",
                    0x8611: "following error", 0x8612: "reference limit: software position limit"}
"""Meaning of the CiA 402 error codes the drives' protection raises (docs/explanation/fmus.md "Protection")."""


def _drive_error_register(code: int) -> int:
    """Error register 0x1001 of a drive error's EMCY: 0 for the reset, else generic (bit 0) plus
    current (bit 1) for 0x2xxx, device-profile specific (bit 5) for 0x8xxx."""
    if not code:
        return 0
    return 0x01 | (0x02 if code >> 12 == 0x2 else 0x20 if code >> 12 == 0x8 else 0)


_TPDO1_LEN = TPDO1.size
_TPDO2_LEN = TPDO2.size
_RPDO1_LEN = RPDO1_SIGNED.size
_RPDO1_CLASSIC_LEN = RPDO1_CLASSIC.size
_UNPACK_RPDO1_CLASSIC = RPDO1_CLASSIC.unpack
_PACK_RPDO1_INTO = RPDO1_SIGNED.pack_into
_PACK_TPDO1_INTO = TPDO1.pack_into
_PACK_TPDO2_INTO = TPDO2.pack_into
_UNPACK_RPDO1 = RPDO1_SIGNED.unpack
_UNPACK_TPDO1 = TPDO1.unpack
_UNPACK_TPDO2 = TPDO2.unpack
_TPDO2_BUFFERED_LEN = TPDO2_BUFFERED.size
_UNPACK_TPDO2_BUFFERED = TPDO2_BUFFERED.unpack
_PACK_SKIP = RPDO1_BUFFER_SKIP.pack_into
_UNPACK_SKIP = RPDO1_BUFFER_SKIP.unpack_from

def _lookahead_entry(raw: bytes) -> bytes:
    """The 10-byte look-ahead entry of a packed 20-byte RPDO1: the set-point of its mode
    (target position / velocity INT32, target torque INT16 widened), torque offset,
    velocity offset (docs/reference/fieldbus.md, Telegrams)."""
    mode = raw[8]
    if mode == 9:
        target = raw[12:16]
    elif mode == 10:
        target = _I32.pack(_I16.unpack_from(raw, 10)[0])
    else:
        target = raw[2:6]
    return target + raw[6:8] + raw[16:20]


def _entry_setpoint(due: tuple[int, ...], data: bytes, j: int) -> tuple[int, ...]:
    """The pipe tuple (cw, pos, tq, mode, 0, tt, tv, vo) of look-ahead entry ``j`` (1..k) of an
    RPDO1 whose own set-point is ``due``: controlword and mode are the PReq's, the entry's
    value is the set-point of that mode (docs/reference/fieldbus.md, Telegrams)."""
    cw, pos, _, mode, _, tt, tv, _ = due
    target, offset, velocity = _UNPACK_ENTRY(data, 20 + _ENTRY_LEN * (j - 1))
    if mode == 9:
        return (cw, pos, offset, mode, 0, tt, target, velocity)
    if mode == 10:
        return (cw, pos, offset, mode, 0, target, tv, velocity)
    return (cw, target, offset, mode, 0, tt, tv, velocity)


def _interpolated(old: bytes, new: bytes, gap: int, keep: int) -> list[bytes]:
    """The last (at most ``keep``) of the ``gap - 1`` packed RPDO1s between ``old`` and ``new``
    (``gap`` cycles apart, both exclusive), their set-points (target position, torque offset,
    target torque, target velocity, velocity offset) interpolated linearly and rounded;
    controlword and mode those of ``new``."""
    a, b = _RPDO1_FIELDS.unpack(old), _RPDO1_FIELDS.unpack(new)
    out = []
    for i in range(max(1, gap - keep), gap):
        s = i / gap
        values = [round(x + (y - x) * s) for x, y in zip(a, b)]
        data = bytearray(new)
        _RPDO1_FIELDS.pack_into(data, 0, *values)
        data[:2] = new[:2]
        data[8:10] = new[8:10]
        out.append(bytes(data))
    return out


# the RPDO1's 16-bit words and integers as one struct (controlword and mode/reserved kept apart)
_RPDO1_FIELDS = struct.Struct("<2xih2xhii")
_I16 = struct.Struct("<h")
_I32 = struct.Struct("<i")
_UNPACK_ENTRY = RPDO1_LOOKAHEAD_ENTRY.unpack_from
_ENTRY_LEN = RPDO1_LOOKAHEAD_ENTRY.size

COUNTER_IDS = {"cn_loss_of_soc": 1, "cn_loss_of_preq": 2, "cn_crc_error": 3, "cn_soc_jitter": 4}


def _array_writer(array: np.ndarray) -> Callable[..., None]:
    """f(*values) that overwrites the whole 1-D ``array`` in place (struct.pack_into its
    buffer: about twice as fast as ``array[:] = values`` for six entries)."""
    code = {"float64": "d", "int64": "q", "bool": "?"}[array.dtype.name]
    return partial(struct.Struct(f"@{array.size}{code}").pack_into, memoryview(array).cast("B"), 0)


def _doubles(values: list[float]) -> bytes:
    """Native float64 packing of constants for the compiled codec."""
    return struct.pack(f"@{len(values)}d", *values)


def _decode_error(log: EventLog, side: str, msg: can.Message, cycle: int, time_s: float) -> tuple[str, int]:
    """Classify an undecodable frame, record it; returns (reason, node)."""
    kind, node = classify(msg.arbitration_id)
    try:
        check_frame(msg, kind, node)
        reason, detail = "unexpected_id", f"{kind.upper()} 0x{msg.arbitration_id:03X} is not for the {side.upper()}"
    except ValueError as error:
        reason = getattr(error, "reason", "invalid")
        detail = str(error)
    log.add(FieldbusEvent(time_s, cycle, side, node, reason, "decode_error", -1, -1, -1, detail))
    return reason, node


def _init_common(node: "ManagingNode | ControlledNodes", config: "FieldbusConfig", scaling: "JointScaling",
                 layout: "CycleLayout", log: EventLog) -> None:
    """Set what the managing node and the controlled nodes share: configuration, cycle
    clock, the per-joint scaling constants (plain lists for the Python code, packed
    float64 for the compiled codec), the threshold counters, the frame tallies.

    A function rather than a base class: each of these objects has more attributes
    than CPython 3.11 keeps in a shared-key dict, so its method calls are not
    specialised and an extra class in the MRO makes them dearer (an empty base class
    alone cost 1 % more instructions per cycle on the Python path, callgrind)."""
    node.nodes = config.nodes
    node.config = config
    node.scaling = scaling
    node.layout = layout
    node.log = log
    node.cycle = -1
    node._t0 = config.start_time_s
    node._cycle_time = config.cycle_time_s
    node._sync_overflow = config.scaling.sync_counter_overflow
    node._cpr = scaling.counts_per_rad.tolist()
    node._upn = scaling.units_per_newton_metre.tolist()
    node._rpc = scaling.rad_per_count.tolist()
    node._npu = scaling.newton_metre_per_unit.tolist()
    # the compiled codec (fieldbus/codec.c) and its packed constants; None: Python only
    node._codec = load_codec()
    node._packed = {name: _doubles(values) for name, values in
                    (("cpr", node._cpr), ("upn", node._upn), ("rpc", node._rpc), ("npu", node._npu))}
    node.counters = CounterBank(log, node._on_threshold)
    node.frames_received = 0
    node.decode_errors = 0


def _counters_per_node(node: "ManagingNode | ControlledNodes", kind: str, threshold: int) -> list[ThresholdCounter]:
    """One threshold counter of ``kind`` per node of ``node.side`` (index = node id - 1),
    counting with the configured increment and decrement."""
    th = node.config.thresholds
    new = node.counters.new
    return [new(node.side, i + 1, kind, threshold, th.increment, th.decrement) for i in range(node.nodes)]


class ManagingNode:
    """Controller-side POWERLINK MN: builds the SoC (SYNC) and PReqs (RPDO1), collects
    the PRes frames (TPDO1 + TPDO2) into :class:`ObservedActuals`.

    Per cycle: :meth:`start_cycle`, :meth:`frames`, :meth:`receive` for every frame
    that arrived, :meth:`end_cycle` (returns the observed actual values)."""

    side = "mn"

    def __init__(self, config: "FieldbusConfig", scaling: "JointScaling",
                 layout: "CycleLayout", log: EventLog) -> None:
        _init_common(self, config, scaling, layout, log)
        n = self.nodes
        self.observed = ObservedActuals.zeros(n)
        self._write_position = _array_writer(self.observed.position)
        self._write_velocity = _array_writer(self.observed.velocity)
        self._write_torque = _array_writer(self.observed.torque)
        # a PRes counts as in time if it reaches the MN within pres_timeout after the PReq
        self._pres_wait = [layout.wire_preq + layout.pres_timeout - layout.propagation[i + 1] for i in range(n)]
        self._packed["wait"] = _doubles(self._pres_wait)
        # per node (index = node - 1), raw telegram values of the last valid PRes
        self._sw = [0] * n
        self._pos = [0] * n
        self._tq = [0] * n
        self._vel = [0] * n
        self._err = [0] * n
        self._mode = [8] * n  # modes of operation display (0x6061)
        self._csp = [8] * n  # defaults of frames() for the optional set-points
        self._zeros = [0.0] * n
        self._extra_si: tuple = ()  # (target torque, target velocity, velocity offset) last quantised, SI
        self._extra_counts: tuple = ()
        self._last_sw: list[int] = [0] * n
        self._last_err: list[int] = [0] * n
        self._last_mode: list[int] = [8] * n
        self._got1 = [False] * n
        self._got2 = [False] * n
        self._late = [False] * n
        self._crc = [False] * n
        self._all_fresh = False
        self._latest = [0.0] * n  # latest PRes send time the MN accepts (PRes timeout), per node
        self._last_cw = [0] * n
        self.node_fault = [False] * n
        self._tpdo1_index = {TPDO1_BASE + i + 1: i for i in range(n)}
        self._tpdo2_index = {TPDO2_BASE + i + 1: i for i in range(n)}
        # the MN's frames are allocated once and refilled every cycle (allocation-light)
        self._sync_msg = FastMessage(0.0, SYNC_ID, bytearray(1))
        self._preq_msgs = [FastMessage(0.0, RPDO1_BASE + i + 1, bytearray(_RPDO1_LEN)) for i in range(n)]
        self._frames = [self._sync_msg] + self._preq_msgs
        # set-point look-ahead: the controller's outputs go out setpoint_lookahead cycles late
        # as the PReq's set-point due next, each first in that many PReqs before as a
        # look-ahead entry (the controller computes them that much earlier: its lead_cycles)
        self._k = k = config.setpoint_lookahead
        # set-point buffer (setpoint_buffer = D > 0): the ring holds D + 1 planned set-points and
        # each PReq's k entries start at the first cycle the drive reported missing in its PRes
        self._depth = depth = config.setpoint_buffer or k
        self._buffered = config.setpoint_buffer > 0
        self._dead = config.dead_time_cycles
        self.buffer_missing_from: list[int | None] = [None] * n  # per node: first SoC cycle the drive lacks
        if k:
            self._ring = [deque(maxlen=depth + 1) for _ in range(n)]
            self._entries = [deque(maxlen=depth + 1) for _ in range(n)]  # the ring's look-ahead entries, packed
            length = RPDO1_MAX_BYTES if self._buffered else rpdo1_length(k)
            self._la_msgs = [FastMessage(0.0, RPDO1_BASE + i + 1, bytearray(length)) for i in range(n)]
            self._frames_sent = [self._sync_msg] + self._la_msgs
            self._la_cycle = -1  # cycle of the last PReqs sent
        th = config.thresholds
        self._c_loss = _counters_per_node(self, "loss_of_pres", th.mn_loss_of_pres)
        self._c_late = _counters_per_node(self, "late_pres", th.mn_late_pres)
        self._c_crc = _counters_per_node(self, "crc_error", th.mn_crc_error)
        self.emcy_received: list[FieldbusEvent] = []

    # ------------------------------------------------------------------ sending
    def start_cycle(self, cycle: int) -> None:
        """Begin ``cycle``: forget last cycle's reception flags."""
        self.cycle = cycle
        n = self.nodes
        self._got1 = [False] * n
        self._got2 = [False] * n
        self._late = [False] * n
        self._crc = [False] * n

    def encode(self, cycle: int, times: list, setpoints: "Setpoints", build: bool = True) -> list[FastMessage] | None:
        """:meth:`frames` for ``setpoints`` (arrays) through the compiled codec; None when
        the codec is unavailable or declines (a node fault latched, a value outside the
        telegram range or not finite, unusual arrays): then call :meth:`frames`."""
        codec = self._codec
        if codec is None or True in self.node_fault:
            return None
        packed = self._packed
        if codec.pack_preq(self._preq_msgs, times, setpoints.controlword, setpoints.position,
                           setpoints.torque_offset, setpoints.modes_of_operation, setpoints.target_torque,
                           setpoints.target_velocity, setpoints.velocity_offset, packed["cpr"], packed["upn"],
                           packed["wait"], self._latest, self._last_cw):
            return None
        sync = self._sync_msg
        sync.timestamp = times[0]
        sync.data[0] = (cycle % self._sync_overflow) + 1
        if not self._k:
            return self._frames
        return self._lookahead_frames(cycle) if build else self._lookahead_frames(cycle, False)

    def _lookahead_frames(self, cycle: int, build: bool = True) -> list[FastMessage]:
        """The PReqs of ``cycle`` with the set-point look-ahead, from this cycle's packed
        20-byte RPDO1s (the controller's newest output, for the SoC of cycle + d + k): per
        node a ring of the planned set-points for the SoCs of cycles cycle + d .. cycle + d + k;
        the first is the set-point due next, the others the k look-ahead entries.

        With a set-point buffer of depth D (``setpoint_buffer``) the ring holds cycle + d ..
        cycle + d + D and the k entries start at the first cycle the drive reported missing
        (its PRes, :attr:`buffer_missing_from`), at most at the newest k: in steady state the
        newest with k - 1 repeated, after lost PReqs a refill of k per cycle; bytes 60-61 carry
        where they start. ``build`` False: only take the output into the ring (a controller
        catching up on cycles it did not run; nothing is sent).

        A new controlword or mode of operation replaces the node's ring with the new output
        (the controller changed its plan: enabling, a quick stop, a fault reset go out at
        once). A controller that skipped cycles (it fell behind and jumped to the cell's
        cycle) left no set-points for the cycles in between: they are interpolated linearly
        between its last output and the new one, in telegram units."""
        k, depth = self._k, self._depth
        gap = cycle - self._la_cycle
        self._la_cycle = cycle
        entry = _lookahead_entry
        buffered = self._buffered
        base = cycle + self._dead  # the SoC cycle of ring[0], the set-point due next
        for staged, ring, entries, msg, missing in zip(self._preq_msgs, self._ring, self._entries, self._la_msgs,
                                                       self.buffer_missing_from):
            raw = bytes(staged.data)
            if not ring or gap < 1 or raw[:2] != ring[-1][:2] or raw[8] != ring[-1][8]:
                ring.clear()
                ring.extend((raw,) * (depth + 1))
                entries.clear()
                entries.extend((entry(raw),) * (depth + 1))
            else:
                if gap > 1:
                    for between in _interpolated(ring[-1], raw, gap, depth):
                        ring.append(between)
                        entries.append(entry(between))
                ring.append(raw)
                entries.append(entry(raw))
            if not build:
                continue
            data = msg.data
            data[:20] = ring[0]
            data[9] = k
            if buffered:
                first = depth + 1 - k  # the newest k
                if missing is not None and missing - base < first:
                    first = max(missing - base, 1)
                data[20:20 + 10 * k] = b"".join(islice(entries, first, first + k))
                _PACK_SKIP(data, RPDO1_BUFFER_SKIP_OFFSET, first - 1)
            else:
                entries.rotate(-1)  # the k newest, then the oldest (the set-point due next)
                data[20:20 + 10 * k] = b"".join(entries)[:10 * k]
                entries.rotate(1)
            msg.timestamp = staged.timestamp
        return self._frames_sent

    def frames(self, cycle: int, times: list, controlword: list, position: list, torque_offset: list,
               modes: list | None = None, target_torque: list | None = None, target_velocity: list | None = None,
               velocity_offset: list | None = None, build: bool = True) -> list[FastMessage]:
        """SYNC and one RPDO1 per node for ``cycle``: ``times`` = [soc, preq_1..N, ...]
        send times (s); set-points per node as plain lists in SI units (quantised
        here; modes of operation 8, 9 or 10, default 8, others raise ValueError; the
        velocity and torque set-points default to 0). Arms the PRes timeouts and notes
        fault-reset edges.

        The returned list and its messages are reused next cycle (receivers that keep
        a frame beyond the cycle must copy it)."""
        sync = self._sync_msg
        sync.timestamp = times[0]
        sync.data[0] = (cycle % self._sync_overflow) + 1
        n = self.nodes
        zeros = self._zeros
        modes = modes if modes is not None else self._csp
        target_torque = target_torque if target_torque is not None else zeros
        target_velocity = target_velocity if target_velocity is not None else zeros
        velocity_offset = velocity_offset if velocity_offset is not None else zeros
        cpr, upn = self._cpr, self._upn
        try:
            counts = [floor(q * c + 0.5) for q, c in zip(position, cpr)]
            units = [floor(t * u + 0.5) for t, u in zip(torque_offset, upn)]
            extra = (target_torque, target_velocity, velocity_offset)
            if extra != self._extra_si:  # mostly constant (0 in CSP): quantised again only when changed
                self._extra_counts = ([floor(t * u + 0.5) for t, u in zip(target_torque, upn)],
                                      [floor(v * c + 0.5) for v, c in zip(target_velocity, cpr)],
                                      [floor(v * c + 0.5) for v, c in zip(velocity_offset, cpr)])
                self._extra_si = tuple(list(x) for x in extra)
            tt_units, tv_counts, vo_counts = self._extra_counts
        except (ValueError, OverflowError) as error:
            raise ValueError(f"setpoints: position = {position}, torque_offset = {torque_offset}, target_torque = "
                             f"{target_torque}, target_velocity = {target_velocity}, velocity_offset = "
                             f"{velocity_offset}: expected finite numbers ({error})") from error
        msgs, latest, last_cw, wait = self._preq_msgs, self._latest, self._last_cw, self._pres_wait
        node_fault = self.node_fault
        for i in range(n):
            ts = times[i + 1]
            latest[i] = ts + wait[i]
            cw = controlword[i]
            mode = modes[i]
            if mode not in MODES_OF_OPERATION:
                check_mode_of_operation(mode, f"setpoints.modes_of_operation[{i}]")
            if cw & CW_FAULT_RESET and not last_cw[i] & CW_FAULT_RESET and node_fault[i]:
                self._clear_fault(i, ts)
            msg = msgs[i]
            msg.timestamp = ts
            try:
                _PACK_RPDO1_INTO(msg.data, 0, cw, counts[i], units[i], mode, 0, tt_units[i], tv_counts[i],
                                 vo_counts[i])
            except struct.error:  # out of the telegram range: saturate, or name the bad controlword
                self._pack_saturated(msg, i, cw, position[i], torque_offset[i], mode, target_torque[i],
                                     target_velocity[i], velocity_offset[i])
        self._last_cw = controlword
        if not self._k:
            return self._frames
        return self._lookahead_frames(cycle) if build else self._lookahead_frames(cycle, False)

    def _pack_saturated(self, msg: FastMessage, i: int, cw: int, position: float, torque: float, mode: int,
                        target_torque: float, target_velocity: float, velocity_offset: float) -> None:
        if not isinstance(cw, int) or not 0 <= cw <= 0xFFFF:
            raise ValueError(f"setpoints.controlword[{i}] = {cw!r}: expected an integer in [0, 0xFFFF]")
        s = self.scaling
        _PACK_RPDO1_INTO(msg.data, 0, cw, s.position_count(i, position), s.torque_unit(i, torque), mode, 0,
                         s.torque_unit(i, target_torque), s.velocity_count(i, target_velocity),
                         s.velocity_count(i, velocity_offset))

    # ------------------------------------------------------------------ receiving
    def receive(self, msg: can.Message) -> None:
        """Digest one received frame; never raises (bad frames are counted and recorded)."""
        self.receive_all((msg,))

    def receive_all(self, msgs: list | tuple) -> None:
        """Digest received frames in order; never raises."""
        self.frames_received += len(msgs)
        codec = self._codec
        if codec is None:
            self._receive_frames(msgs)
            return
        count, k = len(msgs), 0
        while k < count:  # the codec digests the PDOs; any other frame goes through Python, in order
            k = codec.receive_pres(msgs, k, self._latest, self._sw, self._pos, self._tq, self._vel, self._err,
                                   self._mode, self._got1, self._got2, self._late)
            if k < count:
                self._receive_frames(msgs[k:k + 1])
                k += 1

    def _receive_frames(self, msgs: list | tuple) -> None:
        tpdo1, tpdo2, latest = self._tpdo1_index, self._tpdo2_index, self._latest
        sw, pos, tq, vel, err, mode = self._sw, self._pos, self._tq, self._vel, self._err, self._mode
        got1, got2, late = self._got1, self._got2, self._late
        for msg in msgs:
            if not (msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id):
                arb = msg.arbitration_id
                i = tpdo1.get(arb)
                if i is not None:
                    data = msg.data
                    if len(data) == _TPDO1_LEN:
                        if msg.timestamp > latest[i]:
                            late[i] = True
                        else:
                            sw[i], pos[i], tq[i] = _UNPACK_TPDO1(data)
                            got1[i] = True
                        continue
                else:
                    i = tpdo2.get(arb)
                    if i is not None:
                        data = msg.data
                        if len(data) == _TPDO2_LEN:
                            if msg.timestamp > latest[i]:
                                late[i] = True
                            else:
                                vel[i], err[i], mode[i] = _UNPACK_TPDO2(data)
                                got2[i] = True
                            continue
                        if len(data) == _TPDO2_BUFFERED_LEN:  # with the set-points the drive holds ahead
                            if msg.timestamp > latest[i]:
                                late[i] = True
                            else:
                                vel[i], err[i], mode[i], held = _UNPACK_TPDO2_BUFFERED(data)
                                got2[i] = True
                                # it holds the SoCs of cycle + 1 .. cycle + held
                                self.buffer_missing_from[i] = self.cycle + 1 + held
                            continue
            self._other_frame(msg)

    def _other_frame(self, msg: can.Message) -> None:
        """An EMCY frame, or a frame that cannot be decoded."""
        data = msg.data
        if (msg.arbitration_id & ~0x7F == EMCY_BASE and 0 < msg.arbitration_id & 0x7F <= self.nodes
                and len(data) == EMCY.size and not (msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id)):
            code, register, counter_id, value, threshold = EMCY.unpack(data)
            event = FieldbusEvent(msg.timestamp, self.cycle, "mn", msg.arbitration_id & 0x7F, "emcy",
                                  "emcy_received", value, -1, threshold,
                                  f"EMCY 0x{code:04X} register 0x{register:02X} counter id {counter_id}")
            self.emcy_received.append(event)
            self.log.add(event)
            return
        self._bad_frame(msg)

    def _bad_frame(self, msg: can.Message) -> None:
        self.decode_errors += 1
        reason, node = _decode_error(self.log, "mn", msg, self.cycle, msg.timestamp)
        if node and node <= self.nodes and reason != "unexpected_id" and \
                msg.arbitration_id & ~0x7F in (TPDO1_BASE, TPDO2_BASE):
            i = node - 1
            if not self._crc[i]:
                self._crc[i] = True
                self._c_crc[i].error(self.cycle, msg.timestamp, f"PRes {reason}")

    # ------------------------------------------------------------------ end of cycle
    def end_cycle(self, cycle: int) -> ObservedActuals:
        """Judge this cycle's PRes frames, update counters, publish ObservedActuals."""
        obs = self.observed
        got1, got2 = self._got1, self._got2
        all_fresh = all(got1) and all(got2)
        if all_fresh:
            if not self._all_fresh:
                obs.fresh[:] = True
        else:
            t = self._t0 + cycle * self._cycle_time
            fresh = [a and b for a, b in zip(got1, got2)]
            obs.fresh[:] = fresh
            for i, ok in enumerate(fresh):
                if not ok:
                    if self._late[i]:
                        self._c_late[i].error(cycle, t, "PRes arrived after the PRes timeout")
                    else:
                        self._c_loss[i].error(cycle, t, "no valid PRes" + (" (CRC error)" if self._crc[i] else ""))
        self._all_fresh = all_fresh
        if self.counters.busy:
            self.counters.end_cycle(cycle, self._t0 + cycle * self._cycle_time)
        if self._sw != self._last_sw:
            obs.statusword[:] = self._sw
            self._last_sw = list(self._sw)
        if self._err != self._last_err:
            obs.error_code[:] = self._err
            self._last_err = list(self._err)
        if self._mode != self._last_mode:
            obs.modes_of_operation_display[:] = self._mode
            self._last_mode = list(self._mode)
        codec = self._codec
        if codec is not None:
            packed = self._packed
            if not (codec.scale_into(self._pos, packed["rpc"], obs.position)
                    or codec.scale_into(self._vel, packed["rpc"], obs.velocity)
                    or codec.scale_into(self._tq, packed["npu"], obs.torque)):
                return obs
        rpc = self._rpc
        self._write_position(*map(mul, self._pos, rpc))
        self._write_velocity(*map(mul, self._vel, rpc))
        self._write_torque(*map(mul, self._tq, self._npu))
        return obs

    # ------------------------------------------------------------------ faults
    def _on_threshold(self, counter: ThresholdCounter, cycle: int, time_s: float) -> None:
        i = counter.node - 1
        if not self.node_fault[i]:
            self.node_fault[i] = True
            self.observed.node_fault[i] = True
            self.log.add(FieldbusEvent(time_s, cycle, "mn", counter.node, counter.kind, "fault_reaction",
                                       counter.value, counter.cumulative, counter.threshold,
                                       "MN reports the node faulted: controller must stop commanding motion"))

    def _clear_fault(self, i: int, time_s: float) -> None:
        node = i + 1
        if self.counters.node_tripped(node):
            return
        self.node_fault[i] = False
        self.observed.node_fault[i] = False
        self.log.add(FieldbusEvent(time_s, self.cycle, "mn", node, "node_fault", "fault_cleared",
                                   -1, -1, -1, "fault reset sent with all counters below threshold"))


class ControlledNodes:
    """The drive-side POWERLINK CNs (node ids 1..N) sharing one bus connection.

    Per cycle: :meth:`start_cycle` (the SoC: latch actuals, apply due set-points),
    :meth:`receive` for every frame that arrived, :meth:`responses` (the PRes frames of
    the nodes whose PReq arrived), :meth:`end_cycle` (judge SoC and PReqs, counters),
    :meth:`emergency_messages` (EMCY of nodes that tripped, for the async slot)."""

    side = "cn"

    def __init__(self, config: "FieldbusConfig", scaling: "JointScaling",
                 layout: "CycleLayout", log: EventLog) -> None:
        _init_common(self, config, scaling, layout, log)
        n = self.nodes
        self.applied = AppliedSetpoints.zeros(n)
        self._bind_writers(self.applied)
        self._d = config.dead_time_cycles
        self._hold = config.reaction.missing_setpoint == "hold"
        self._quick_stop = config.reaction.abort_connection_option == "quick_stop"
        self._jitter_range = config.timing.cn_soc_jitter_range_s
        self._arrival = [layout.wire_preq + layout.propagation[i + 1] for i in range(n)]
        self._packed["arrival"] = _doubles(self._arrival)
        # per node, per dead-time slot: the received RPDO1 (cw, pos, tq, mode, reserved, tt, tv, vo) or None
        self._pipe: list[list[tuple[int, ...] | None]] = [[None] * self._d for _ in range(n)]
        self._preq_ok = [False] * n
        self._preq_late = [False] * n
        self._crc = [False] * n
        self._sync_seen = False
        self._sync_ts = 0.0
        self._next_soc = 0.0
        # set-point look-ahead buffer, per node: (cycle whose SoC applies the newest PReq's own
        # set-point, that set-point as a pipe tuple, the PReq's data with its entries) or None
        self._ahead: list[tuple[int, tuple[int, ...], bytes] | None] = [None] * n
        self._ahead_any = False
        self._ahead_new = [False] * n  # the buffer was refilled by this cycle's PReq
        self.cycles_covered = [0] * n  # cycles whose set-point came from the buffer (PReq lost or late)
        self.cycles_without_setpoint = [0] * n  # cycles with neither a PReq's nor a buffered set-point
        # set-point buffer (setpoint_buffer = D > 0, CiA 402 0x60C4): per node a FIFO of the set-points
        # for consecutive SoCs from _fifo_head on, at most D + dead time (0x60C4 sub 1), refilled by
        # the look-ahead entries of every PReq where it ends; None: the newest PReq's look-ahead only
        self._fifo_cap = config.setpoint_buffer + self._d if config.setpoint_buffer else 0
        self._fifo: list[deque] | None = [deque() for _ in range(n)] if self._fifo_cap else None
        self._fifo_head = [0] * n
        self._tpdo2_held_msgs = [FastMessage(0.0, TPDO2_BASE + i + 1, bytearray(_TPDO2_BUFFERED_LEN))
                                 for i in range(n)]
        self.covered_now: list[int] = []  # nodes (index) covered from the buffer at this cycle's SoC
        # latched actuals (telegram units), index = node - 1
        self._a_sw = [0] * n
        self._a_pos = [0] * n
        self._a_si: tuple[list, list, list] = ([0.0] * n, [0.0] * n, [0.0] * n)
        self._a_tq = [0] * n
        self._a_vel = [0] * n
        self._a_err = [0] * n
        self._a_mode = [8] * n
        # applied set-points (telegram units), index = node - 1
        self._cw = [0] * n
        self._pos: list[int | None] = [None] * n
        self._prev_pos: list[int | None] = [None] * n
        self._tq = [0] * n
        self._mode = [8] * n
        self._tt = [0] * n
        self._tv = [0] * n
        self._vo = [0] * n
        self._last_app_mode: list[int] | None = None  # last written to the applied arrays (None: write)
        self._last_app_tv: list[int] | None = None
        self._last_app_vo: list[int] | None = None
        self._last_app_tt: list[int] | None = None
        self._fresh = [False] * n
        self._last_app_cw: list[int] | None = None
        self._all_fresh = False
        self.comm_fault = [False] * n
        self._any_fault = False
        self._fault_shown = False  # applied arrays still show a fault that was cleared
        self._emcy_due: list[ThresholdCounter | tuple[int, int]] = []  # tripped counters, (node, drive error)
        self.last_emcy_cycle = -1  # the last cycle whose asynchronous slot carried EMCYs
        #: called with the EMCY frames of a cycle (fieldbus.asynchronous: error register and history)
        self.on_emcy: Callable[[list], None] | None = None
        self._errors_seen = [0] * n  # each drive's error code 0x603F at the last SoC
        self._errors_announced = [False] * n  # an EMCY announced the node's present drive error
        self._ids: dict[int, int] = {RPDO1_BASE + i + 1: i for i in range(n)}
        self._tpdo1_ids = [TPDO1_BASE + i + 1 for i in range(n)]
        self._tpdo2_ids = [TPDO2_BASE + i + 1 for i in range(n)]
        self._tpdo1_msgs = [FastMessage(0.0, i, bytearray(_TPDO1_LEN)) for i in self._tpdo1_ids]
        self._tpdo2_msgs = [FastMessage(0.0, i, bytearray(_TPDO2_LEN)) for i in self._tpdo2_ids]
        self._traffic = set(self._tpdo1_ids) | set(self._tpdo2_ids) | {EMCY_BASE + i + 1 for i in range(n)}
        self._prepacked = False  # this cycle's PRes payloads were packed at the SoC by the codec
        th = config.thresholds
        self._c_soc = _counters_per_node(self, "loss_of_soc", th.cn_loss_of_soc)
        self._c_preq = _counters_per_node(self, "loss_of_preq", th.cn_loss_of_preq)
        self._c_crc = _counters_per_node(self, "crc_error", th.cn_crc_error)
        self._c_jit = _counters_per_node(self, "soc_jitter", th.cn_soc_jitter)

    def bind_applied(self, applied: AppliedSetpoints) -> None:
        """Write what the drives apply into ``applied``'s arrays from now on (e.g. views of a
        co-simulation master's variables, so nothing is copied per cycle): (N,) each,
        float64 C-contiguous writable ``position`` and ``torque_offset``, integer
        ``controlword`` and ``fault_code``, bool ``fresh`` and ``comm_fault``. Their values
        are set to the current ones; ValueError naming the array otherwise."""
        n = self.nodes
        kinds = {"position": "f", "torque_offset": "f", "controlword": "iu", "fault_code": "iu", "fresh": "b",
                 "comm_fault": "b", "modes_of_operation": "iu", "target_velocity": "f", "velocity_offset": "f",
                 "target_torque": "f"}
        for name, kind in kinds.items():
            array = getattr(applied, name)
            if not (isinstance(array, np.ndarray) and array.shape == (n,) and array.dtype.kind in kind
                    and array.flags.writeable and (kind != "f" or (array.dtype == np.float64
                                                                    and array.flags.c_contiguous))):
                raise ValueError(f"bind_applied: applied.{name} must be a writable ({n},) "
                                 f"{'C-contiguous float64' if kind == 'f' else 'integer' if kind == 'iu' else 'bool'} "
                                 f"array, got {getattr(array, 'dtype', type(array).__name__)} "
                                 f"{getattr(array, 'shape', '')}")
        old = self.applied
        for name in kinds:
            getattr(applied, name)[:] = getattr(old, name)
        self.applied = applied
        self._bind_writers(applied)
        self._last_app_mode = self._last_app_tv = self._last_app_vo = self._last_app_tt = None

    def _bind_writers(self, applied: AppliedSetpoints) -> None:
        self._write_position = _array_writer(applied.position)
        self._write_torque = _array_writer(applied.torque_offset)
        self._write_tv = _array_writer(applied.target_velocity)
        self._write_vo = _array_writer(applied.velocity_offset)
        self._write_tt = _array_writer(applied.target_torque)

    # ------------------------------------------------------------------ SoC
    def start_cycle(self, cycle: int, actuals: DriveActuals) -> AppliedSetpoints:
        """SoC of ``cycle``: latch ``actuals`` (quantised), apply the set-points due now.

        The CN's own cycle timer marks the SoC; whether the SoC frame itself arrived (in
        time) is judged in :meth:`end_cycle`."""
        self.cycle = cycle
        n = self.nodes
        t = self._t0 + cycle * self._cycle_time
        self._next_soc = t + self._cycle_time
        codec, packed = self._codec, self._packed
        # latch actual values (quantised as they enter the PRes; range-checked when packed)
        latched = -1 if codec is None else codec.latch_pres(
            actuals.statusword, actuals.position, actuals.velocity, actuals.torque, actuals.error_code,
            actuals.modes_of_operation_display, packed["cpr"], packed["upn"], self._tpdo1_msgs, self._tpdo2_msgs,
            self._a_pos)
        self._prepacked = latched == 0 or latched == _ERROR_CODE_CHANGED
        if self._prepacked:
            a_pos = self._a_pos
            if latched == _ERROR_CODE_CHANGED:
                self._drive_errors(actuals.error_code.tolist())
        else:
            self._a_sw = actuals.statusword.tolist()
            self._a_err = actuals.error_code.tolist()
            if self._a_err != self._errors_seen:
                self._drive_errors(self._a_err)
            self._a_mode = actuals.modes_of_operation_display.tolist()
            pos, vel, tq = actuals.position.tolist(), actuals.velocity.tolist(), actuals.torque.tolist()
            cpr = self._cpr
            try:
                self._a_pos = a_pos = [floor(q * c + 0.5) for q, c in zip(pos, cpr)]
                self._a_vel = [floor(v * c + 0.5) for v, c in zip(vel, cpr)]
                self._a_tq = [floor(t * u + 0.5) for t, u in zip(tq, self._upn)]
            except (ValueError, OverflowError) as error:
                raise ValueError(f"actuals: position = {pos}, velocity = {vel}, torque = {tq}: "
                                 f"expected finite numbers ({error})") from error
            self._a_si = (pos, vel, tq)
        # apply the set-points due at this SoC
        slot = cycle % self._d
        covered = self._cover_from_buffer(cycle, slot) if self._ahead_any else None
        if covered is None and self.covered_now:
            self.covered_now = []
        cws, poss, prev, tqs, fresh = self._cw, self._pos, self._prev_pos, self._tq, self._fresh
        modes, tts, tvs, vos = self._mode, self._tt, self._tv, self._vo
        done = -1
        if codec is not None and not self._any_fault:
            done = codec.apply_due(self._pipe, slot, cws, poss, prev, tqs, modes, tts, tvs, vos, fresh, a_pos,
                                   self._hold)
        all_fresh = bool(done) if done >= 0 else True
        for i in range(n if done < 0 else 0):  # (nothing left when the codec applied them)
            pipe = self._pipe[i]
            due = pipe[slot]
            if due is not None:
                pipe[slot] = None
                cw = due[0]
                if self._any_fault and self.comm_fault[i] and cw & CW_FAULT_RESET and not cws[i] & CW_FAULT_RESET:
                    self._clear_fault(i, cycle, t)
                cws[i] = cw
                prev[i] = poss[i]
                poss[i] = due[1]
                tqs[i] = due[2]
                modes[i] = due[3]
                tts[i] = due[5]
                tvs[i] = due[6]
                vos[i] = due[7]
                fresh[i] = True
            else:
                all_fresh = False
                fresh[i] = False
                last = poss[i]
                if last is None:
                    poss[i] = a_pos[i]  # nothing received yet: hold where the drive is
                elif not self._hold and prev[i] is not None:
                    # one cycle extrapolated, then held (prev = poss: the next step is zero); a
                    # drive does not run on blind along a straight line
                    poss[i] = prev[i] = last + (last - prev[i])
        if covered:
            for i in covered:  # applied exactly as planned, but no PReq arrived for it
                fresh[i] = False
            all_fresh = False
        if not all_fresh:
            without = self.cycles_without_setpoint
            for i in range(n):
                if not fresh[i] and not (covered and i in covered):
                    without[i] += 1
        app = self.applied
        if self._any_fault or self._fault_shown:
            forced = list(cws)
            codes = [0] * n
            for i in range(n):
                if self.comm_fault[i]:
                    if self._quick_stop:
                        forced[i] = int(Command.QUICK_STOP)
                    else:
                        codes[i] = EMCY_COMMUNICATION
            app.controlword[:] = forced
            app.comm_fault[:] = self.comm_fault
            app.fault_code[:] = codes
            self._last_app_cw = None
            self._fault_shown = self._any_fault
        elif cws != self._last_app_cw:
            app.controlword[:] = cws
            self._last_app_cw = list(cws)
        if modes != self._last_app_mode:
            app.modes_of_operation[:] = modes
            self._last_app_mode = list(modes)
        if codec is None or codec.scale_into(poss, packed["rpc"], app.position) \
                or codec.scale_into(tqs, packed["npu"], app.torque_offset):
            self._write_position(*map(mul, poss, self._rpc))
            self._write_torque(*map(mul, tqs, self._npu))
        if tvs != self._last_app_tv or vos != self._last_app_vo or tts != self._last_app_tt:
            # the velocity and torque set-points of modes 9/10 and the velocity offset: often constant (0 in CSP)
            if codec is None or codec.scale_into(tvs, packed["rpc"], app.target_velocity) \
                    or codec.scale_into(vos, packed["rpc"], app.velocity_offset) \
                    or codec.scale_into(tts, packed["npu"], app.target_torque):
                self._write_tv(*map(mul, tvs, self._rpc))
                self._write_vo(*map(mul, vos, self._rpc))
                self._write_tt(*map(mul, tts, self._npu))
            self._last_app_tv, self._last_app_vo, self._last_app_tt = list(tvs), list(vos), list(tts)
        if not (all_fresh and self._all_fresh):
            app.fresh[:] = fresh
        self._all_fresh = all_fresh
        return app

    def _cover_from_buffer(self, cycle: int, slot: int) -> list[int]:
        """Put the buffered look-ahead set-point for ``cycle`` where a node's due set-point is
        missing (its PReq was lost or late); returns the nodes covered. A node whose buffer
        has nothing for this cycle stays missing: ``missing_setpoint`` applies."""
        covered = []
        if self._fifo is not None:  # the set-point buffer: its head is due now (consumed either way)
            for i, fifo in enumerate(self._fifo):
                if not fifo:
                    continue
                head = self._fifo_head[i]
                while fifo and head < cycle:
                    fifo.popleft()
                    head += 1
                if fifo and head == cycle:
                    held = fifo.popleft()
                    head += 1
                    if self._pipe[i][slot] is None:
                        self._pipe[i][slot] = held
                        self.cycles_covered[i] += 1
                        covered.append(i)
                self._fifo_head[i] = head
            self.covered_now = covered
            return covered
        for i, ahead in enumerate(self._ahead):
            if ahead is not None and self._pipe[i][slot] is None:
                base, due, data = ahead
                j = cycle - base
                if 1 <= j <= data[9]:
                    self._pipe[i][slot] = _entry_setpoint(due, data, j)
                    self.cycles_covered[i] += 1
                    covered.append(i)
        self.covered_now = covered
        return covered

    # ------------------------------------------------------------------ receiving
    def receive(self, msg: can.Message) -> None:
        """Digest one received frame; never raises (bad frames are counted and recorded)."""
        self.receive_all((msg,))

    def receive_all(self, msgs: list | tuple) -> None:
        """Digest received frames in order; never raises."""
        self.frames_received += len(msgs)
        codec = self._codec
        if codec is None:
            self._receive_frames(msgs)
            return
        count, k, cycle = len(msgs), 0, self.cycle
        slot, counter = cycle % self._d, cycle % self._sync_overflow + 1
        while k < count:  # the codec digests the SoC and the PReqs; any other frame goes through Python, in order
            k = codec.receive_preq(msgs, k, self._pipe, slot, self._packed["arrival"], self._next_soc,
                                   self._preq_ok, self._preq_late, self, counter)
            if k < count:
                self._receive_frames(msgs[k:k + 1])
                k += 1

    def _receive_frames(self, msgs: list | tuple) -> None:
        ids, arrival, next_soc = self._ids, self._arrival, self._next_soc
        pipe, ok, late = self._pipe, self._preq_ok, self._preq_late
        slot = self.cycle % self._d
        for msg in msgs:
            i = ids.get(msg.arbitration_id)
            size = len(msg.data)
            if i is None or msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id \
                    or (size != _RPDO1_LEN and size != _RPDO1_CLASSIC_LEN and size not in RPDO1_LOOKAHEAD_LENGTHS):
                self._other_frame(msg)
            elif msg.timestamp + arrival[i] > next_soc:
                late[i] = True
            elif size > _RPDO1_LEN:  # with a set-point look-ahead
                data = msg.data
                entries = data[9]
                if _RPDO1_LEN + _ENTRY_LEN * entries > size:
                    self._bad_frame(msg)
                    continue
                pipe[i][slot] = due = _UNPACK_RPDO1(data[:_RPDO1_LEN])
                ok[i] = True
                if entries:  # kept as received; an entry is decoded only when a cycle needs it
                    if self._fifo is not None:
                        self._buffer_take(i, due, data, entries, size)
                    else:
                        self._ahead[i] = (self.cycle + self._d, due, bytes(data))
                    self._ahead_new[i] = True
                    self._ahead_any = True

            else:
                pipe[i][slot] = (_UNPACK_RPDO1(msg.data) if size == _RPDO1_LEN
                                 else _UNPACK_RPDO1_CLASSIC(msg.data) + CLASSIC_RPDO1_DEFAULTS)
                ok[i] = True

    def _buffer_take(self, i: int, due: tuple[int, ...], data: bytearray, entries: int, size: int) -> None:
        """Node ``i``'s set-point buffer after a PReq with look-ahead ``entries``: its own
        set-point ``due`` (for the SoC of cycle + d) and its entries (cycle + d + s + j, s from
        bytes 60-61 of a 64-byte RPDO1) where they continue the FIFO without a gap, up to its
        maximum size; a new controlword or mode of operation clears it first (the controller
        changed its plan), as does a gap before the own set-point."""
        fifo = self._fifo[i]
        own = self.cycle + self._d
        if fifo and (fifo[-1][0] != due[0] or fifo[-1][3] != due[3]):
            fifo.clear()
        head = self._fifo_head[i]
        end = head + len(fifo)
        if not fifo or own < head or own > end:
            fifo.clear()
            fifo.append(due)
            head, end = own, own + 1
        elif own == end:
            fifo.append(due)
            end += 1
        else:
            fifo[own - head] = due
        skip = _UNPACK_SKIP(data, RPDO1_BUFFER_SKIP_OFFSET)[0] if size == RPDO1_MAX_BYTES else 0
        cap = self._fifo_cap
        first = max(end - own - skip, 1)  # the first entry not yet held
        if first <= entries and own + skip + first == end:
            data = bytes(data)
            for j in range(first, entries + 1):
                if len(fifo) >= cap:
                    break
                fifo.append(_entry_setpoint(due, data, j))
        self._fifo_head[i] = head

    def buffer_held(self, i: int) -> int:
        """Node ``i``'s set-points held beyond the current SoC without a gap (0x60C4 sub 2 as its
        PRes reports it): the buffer holds the SoCs up to cycle + this value."""
        fifo = self._fifo[i] if self._fifo is not None else None
        if not fifo:
            return 0
        return min(max(self._fifo_head[i] + len(fifo) - 1 - self.cycle, 0), 255)

    def _other_frame(self, msg: can.Message) -> None:
        """The SYNC, other nodes' traffic, or a frame that cannot be decoded."""
        arb = msg.arbitration_id
        data = msg.data
        bad = msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id
        if arb == SYNC_ID and len(data) <= 1 and not bad:
            expected = self.cycle % self._sync_overflow + 1
            if data and data[0] != expected:
                self.decode_errors += 1
                self.log.add(FieldbusEvent(msg.timestamp, self.cycle, "cn", 0, "sync_counter", "decode_error",
                                           -1, -1, -1, f"SYNC counter {data[0]}, expected {expected}"))
                return
            self._sync_seen = True
            self._sync_ts = msg.timestamp
            return
        if arb in self._traffic and len(data) in (_TPDO1_LEN, _TPDO2_LEN, EMCY.size) and not bad:
            return  # other nodes' PRes / EMCY on the shared medium
        self._bad_frame(msg)

    def _bad_frame(self, msg: can.Message) -> None:
        self.decode_errors += 1
        reason, node = _decode_error(self.log, "cn", msg, self.cycle, msg.timestamp)
        if reason == "unexpected_id":
            return
        if msg.arbitration_id == SYNC_ID:
            targets = range(self.nodes)  # the multicast SoC was bad at every CN
        elif node and node <= self.nodes and msg.arbitration_id & ~0x7F == RPDO1_BASE:
            targets = range(node - 1, node)
        else:
            return
        for i in targets:
            if not self._crc[i]:
                self._crc[i] = True
                self._c_crc[i].error(self.cycle, msg.timestamp, reason)

    # ------------------------------------------------------------------ sending
    def responses(self, times: list, answer_all: bool = False) -> list[FastMessage]:
        """PRes frames (TPDO1, TPDO2 per node) with the values latched at the SoC, for
        every node whose PReq arrived (a PReq too late to apply is answered too, as a
        POWERLINK CN answers every PReq) and whose entry in ``times`` (= [soc,
        preq_1..N, pres_1..N] send times) is not None. The messages are reused next
        cycle (receivers that keep a frame beyond the cycle must copy it). ``answer_all``:
        every node answers, polled or not (the paced cell side of a hardware-in-the-loop
        run, whose PRes frames pace the controller)."""
        ok, late = self._preq_ok, self._preq_late
        if answer_all:
            ok = [True] * self.nodes
        if self._prepacked:  # payloads packed at the SoC by the codec
            out = self._codec.pres_frames(self._tpdo1_msgs, self._tpdo2_msgs, times, ok, late)
            return self._with_buffer_held(out) if self._fifo is not None else out
        n = self.nodes
        out: list[FastMessage] = []
        append = out.append
        a_sw, a_pos, a_tq, a_vel, a_err, a_mode = (self._a_sw, self._a_pos, self._a_tq, self._a_vel, self._a_err,
                                                   self._a_mode)
        msgs1, msgs2 = self._tpdo1_msgs, self._tpdo2_msgs
        for i in range(n):
            ts = times[n + 1 + i]
            if (ok[i] or late[i]) and ts is not None:
                m1 = msgs1[i]
                m1.timestamp = ts
                m2 = msgs2[i]
                m2.timestamp = ts
                try:
                    _PACK_TPDO1_INTO(m1.data, 0, a_sw[i], a_pos[i], a_tq[i])
                    _PACK_TPDO2_INTO(m2.data, 0, a_vel[i], a_err[i], a_mode[i])
                except struct.error:  # out of the telegram range: saturate, or name the bad word
                    self._pack_saturated(m1, m2, i)
                append(m1)
                append(m2)
        return self._with_buffer_held(out) if self._fifo is not None else out

    def _with_buffer_held(self, out: list) -> list:
        """``out`` with each TPDO2 as the 8-byte TPDO2 whose byte 7 reports the node's
        set-points held ahead (:meth:`buffer_held`)."""
        held_msgs = self._tpdo2_held_msgs
        for index, m in enumerate(out):
            i = m.arbitration_id - TPDO2_BASE - 1
            if 0 <= i < self.nodes:
                held = held_msgs[i]
                data = held.data
                data[:7] = m.data
                data[7] = self.buffer_held(i)
                held.timestamp = m.timestamp
                out[index] = held
        return out

    def _pack_saturated(self, m1: FastMessage, m2: FastMessage, i: int) -> None:
        for name, word in (("statusword", self._a_sw[i]), ("error_code", self._a_err[i])):
            if not isinstance(word, int) or not 0 <= word <= 0xFFFF:
                raise ValueError(f"actuals.{name}[{i}] = {word!r}: expected an integer in [0, 0xFFFF]")
        mode = self._a_mode[i]
        if not isinstance(mode, int) or not -128 <= mode <= 127:
            raise ValueError(f"actuals.modes_of_operation_display[{i}] = {mode!r}: expected an integer in "
                             "[-128, 127] (CiA 402 0x6061, INT8)")
        s = self.scaling
        pos, vel, tq = self._a_si
        self._a_pos[i] = s.position_count(i, pos[i])
        self._a_vel[i] = s.velocity_count(i, vel[i])
        self._a_tq[i] = s.torque_unit(i, tq[i])
        _PACK_TPDO1_INTO(m1.data, 0, self._a_sw[i], self._a_pos[i], self._a_tq[i])
        _PACK_TPDO2_INTO(m2.data, 0, self._a_vel[i], self._a_err[i], mode)

    def preq_received(self, node: int) -> bool:
        """True when a valid, timely PReq for ``node`` (1-based) arrived in this cycle."""
        return self._preq_ok[node - 1]

    # ------------------------------------------------------------------ end of cycle
    def end_cycle(self, cycle: int, judge: bool = True) -> None:
        """Judge the SoC and the PReqs of ``cycle``, decrement counters. ``judge`` False: the
        nodes are not operational on the bus (a paced cell before its controller's first
        frames, or whose every node has already reacted to a lost controller): nothing is
        counted as lost, counters only decrement."""
        n = self.nodes
        t = self._t0 + cycle * self._cycle_time
        if self._ahead_any:  # a PReq without look-ahead empties the node's buffer
            ok, new = self._preq_ok, self._ahead_new
            fifo = self._fifo
            for i in range(n):
                if ok[i] and not new[i]:
                    self._ahead[i] = None
                    if fifo is not None:
                        fifo[i].clear()
            self._ahead_new = [False] * n
            self._ahead_any = any(fifo) if fifo is not None else any(a is not None for a in self._ahead)
        if not judge:
            self._sync_seen = False
            self._preq_ok = [False] * n
            self._preq_late = [False] * n
            self._crc = [False] * n
            if self.counters.busy:
                self.counters.end_cycle(cycle, t)
            return
        if not self._sync_seen:
            for i in range(n):
                self._c_soc[i].error(cycle, t, "no valid SoC")
        elif abs(self._sync_ts - t) > self._jitter_range:
            for i in range(n):
                self._c_jit[i].error(cycle, t, f"SoC {(self._sync_ts - t) * 1e6:.2f} us off its time")
        self._sync_seen = False
        ok = self._preq_ok
        if not all(ok):
            for i in range(n):
                if not ok[i]:
                    detail = "PReq arrived after the next SoC" if self._preq_late[i] else "no valid PReq"
                    self._c_preq[i].error(cycle, t, detail)
        self._preq_ok = [False] * n
        self._preq_late = [False] * n
        self._crc = [False] * n
        if self.counters.busy:
            self.counters.end_cycle(cycle, t)

    def invalidate_applied(self) -> None:
        """Someone else wrote into the applied arrays after this cycle's :meth:`start_cycle`
        (fieldbus.asynchronous: a node that takes no PDO holds its set-points): the next
        start_cycle writes every field again instead of only those that changed."""
        self._last_app_cw = self._last_app_mode = self._last_app_tv = self._last_app_vo = self._last_app_tt = None
        self._all_fresh = False
        self._fault_shown = True

    def emergency_messages(self, timestamp: float) -> list[FastMessage]:
        """EMCY frames due in this cycle's asynchronous slot: one per tripped counter (0x8100),
        one per drive whose error code 0x603F changed at this cycle's SoC (:meth:`_drive_errors`)."""
        if not self._emcy_due:
            return []
        out = []
        for due in self._emcy_due:
            if isinstance(due, tuple):
                node, code = due
                data = bytearray(EMCY.pack(code, _drive_error_register(code), 0, 0, 0))
                out.append(FastMessage(timestamp, EMCY_BASE + node, data))
                self.log.add(FieldbusEvent(timestamp, self.cycle, "cn", node, "drive_error", "emcy_sent", code, -1, -1,
                                           f"EMCY 0x{code:04X} ({DRIVE_ERROR_TEXT.get(code, 'drive error')})"))
                continue
            counter = due
            data = bytearray(EMCY.pack(EMCY_COMMUNICATION, EMCY_ERROR_REGISTER_COMMUNICATION,
                                       COUNTER_IDS.get(f"cn_{counter.kind}", 0),
                                       min(counter.value, 0xFFFF), counter.threshold))
            out.append(FastMessage(timestamp, EMCY_BASE + counter.node, data))
            self.log.add(FieldbusEvent(timestamp, self.cycle, "cn", counter.node, counter.kind, "emcy_sent",
                                       counter.value, counter.cumulative, counter.threshold,
                                       f"EMCY 0x{EMCY_COMMUNICATION:04X}"))
        self._emcy_due = []
        self.last_emcy_cycle = self.cycle
        if self.on_emcy is not None:
            self.on_emcy(out)
        return out

    def _drive_errors(self, codes: list[int]) -> None:
        """The drives' error codes (0x603F) latched at this SoC differ from the last ones: a node
        whose drive shows a new error (a protection fault or warning, docs/explanation/fmus.md "Protection")
        sends its EMCY with that code in this cycle's asynchronous slot, and EMCY 0x0000 (error
        reset) when that error is gone. Codes the node presented to its drive itself (its
        communication fault reaction, already announced by its own EMCY 0x8100) are not repeated."""
        seen, announced = self._errors_seen, self._errors_announced
        for i, code in enumerate(codes):
            if code == seen[i]:
                continue
            if code and code != EMCY_COMMUNICATION and not self.comm_fault[i]:
                self._emcy_due.append((i + 1, code))
                announced[i] = True
            elif not code and announced[i]:
                self._emcy_due.append((i + 1, 0))
                announced[i] = False
            else:
                announced[i] = False
        self._errors_seen = list(codes)

    # ------------------------------------------------------------------ faults
    def _on_threshold(self, counter: ThresholdCounter, cycle: int, time_s: float) -> None:
        i = counter.node - 1
        self._emcy_due.append(counter)
        if not self.comm_fault[i]:
            self.comm_fault[i] = True
            self._any_fault = True
            what = ("drive gets quick stop controlword 0x0002 from the next SoC (abort option 'quick_stop')"
                    if self._quick_stop else
                    f"drive gets fault code 0x{EMCY_COMMUNICATION:04X} from the next SoC (abort option 'fault')")
            self.log.add(FieldbusEvent(time_s, cycle, "cn", counter.node, counter.kind, "fault_reaction",
                                       counter.value, counter.cumulative, counter.threshold, what))

    def _clear_fault(self, i: int, cycle: int, time_s: float) -> None:
        node = i + 1
        if self.counters.node_tripped(node):
            return
        self.comm_fault[i] = False
        self._any_fault = any(self.comm_fault)
        self.log.add(FieldbusEvent(time_s, cycle, "cn", node, "comm_fault", "fault_cleared",
                                   -1, -1, -1, "fault reset applied with all counters below threshold"))
