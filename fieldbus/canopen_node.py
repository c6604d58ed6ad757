"""The CiA 301 side of one drive node: NMT state machine, boot-up, heartbeat, SDO, EMCY.

A :class:`CanopenNode` is reactive, like the POWERLINK nodes of ``fieldbus/nodes.py``: it is
handed every frame it may care about (:meth:`CanopenNode.receive`) and the time
(:meth:`CanopenNode.tick`), and returns the frames it sends. It never raises on what arrives
from the bus: a frame it cannot take is answered as CiA 301 says (an SDO abort) or ignored,
and counted.

NMT state machine (CiA 301 §7.3.2)::

    power on / reset --> initialising --(boot-up 0x700+id, data 00)--> pre-operational
    pre-operational  --start (0x01)-->            operational
    operational      --enter pre-operational (0x80)--> pre-operational
    any state        --stop (0x02)-->             stopped
    any state        --reset node (0x81) / reset communication (0x82)--> initialising --> ...

NMT commands arrive on COB-ID 0x000 with two bytes (command specifier, node id; node id 0
addresses every node). Reset node restores every object to its default (the drive's limits
and gains too: ``on_write`` is called for each one that changes back), reset communication
the communication area 0x1000-0x1FFF only; both end with a new boot-up message.

What each state allows (CiA 301 table 84):

===============  ==========  ===========  =========  ===============
state            NMT         SDO          EMCY       PDO
===============  ==========  ===========  =========  ===============
pre-operational  yes         yes          yes        no
operational      yes         yes          yes        yes (``pdo_active``)
stopped          yes         no answer    no         no
===============  ==========  ===========  =========  ===============

The heartbeat (0x700 + id, one byte: 0x04 stopped, 0x05 operational, 0x7F pre-operational) is
produced every ``0x1017`` ms (0: none) in every state after the boot-up. :attr:`next_tick_s`
is the time the next one is due (``inf`` when none is), so a caller can skip :meth:`tick`
with one comparison per cycle.

SDO requests (0x600 + id) go to :class:`fieldbus.sdo.SdoServer` (expedited and segmented,
upload and download) and its answer leaves on 0x580 + id. On top of the server's checks the
node refuses PDO mappings it cannot carry: writing sub-index 0 (the number of mapped objects)
of an RPDO/TPDO mapping (0x1600-0x17FF, 0x1A00-0x1BFF) is answered with

* 0x06040041 when a mapped entry names no PDO-mappable object or the wrong length,
* 0x06040042 when the number of mapped objects exceeds the mapping's entries or the mapped
  bits exceed the PDO's frame (the payload the POWERLINK PReq/PRes
  reserves for it, the dictionary's mapping length: 8 bytes for TPDO1 ...),
* 0x06040043 when the mapping differs from the telegram layout the bus packs
  (``fieldbus/telegrams.py``; the cyclic telegrams are fixed).

Writing the producer heartbeat time (0x1017) restarts the heartbeat from the write.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import can

from fieldbus.object_dictionary import DATA_TYPES, Entry, ObjectDictionary
from fieldbus.sdo import (MAPPING_TOO_LONG, NOT_MAPPABLE, PARAMETER_INCOMPATIBLE, SDO_RX_BASE, SDO_TX_BASE, SdoAbort,
                          SdoServer)

NMT_ID = 0x000
EMCY_BASE = 0x080
HEARTBEAT_BASE = 0x700

NMT_START = 0x01
NMT_STOP = 0x02
NMT_ENTER_PRE_OPERATIONAL = 0x80
NMT_RESET_NODE = 0x81
NMT_RESET_COMMUNICATION = 0x82
NMT_COMMANDS = {NMT_START: "start", NMT_STOP: "stop", NMT_ENTER_PRE_OPERATIONAL: "enter pre-operational",
                NMT_RESET_NODE: "reset node", NMT_RESET_COMMUNICATION: "reset communication"}
"""CiA 301 NMT command specifiers and their names."""

#: the heartbeat / boot-up state byte of each NMT state (CiA 301 table 82)
HEARTBEAT_STATE = {"initialising": 0x00, "stopped": 0x04, "operational": 0x05, "pre-operational": 0x7F}
STATES = tuple(HEARTBEAT_STATE)


def _is_mapping(index: int) -> bool:
    return 0x1600 <= index <= 0x17FF or 0x1A00 <= index <= 0x1BFF


class CanopenNode:
    """The CiA 301 side of one node (see the module docstring).

    Args:
        node_id: 1..127, the node's id (the dictionary's node).
        od: its object dictionary; the values start from its defaults.
        on_write: called as ``on_write(entry, value)`` (value in the bus unit of the entry) for
            every accepted SDO download and every value a reset restores; raise
            :class:`fieldbus.sdo.SdoAbort` to refuse it.
    """

    def __init__(self, node_id: int, od: ObjectDictionary, *,
                 on_write: Callable[[Entry, Any], None] | None = None) -> None:
        if isinstance(node_id, bool) or not isinstance(node_id, int) or not 1 <= node_id <= 127:
            raise ValueError(f"node_id = {node_id!r}: expected a node id 1..127")
        if od.node != node_id:
            raise ValueError(f"node_id = {node_id}: the object dictionary is node {od.node}'s")
        self.node_id = node_id
        self.od = od
        self.on_write = on_write
        self.sdo = SdoServer(od, on_write=self._written)
        self._state = "initialising"
        self._now = 0.0
        self.next_tick_s = math.inf
        self._heartbeat_s = 0.0
        # the mapping each PDO's frame carries: mapping index -> (mapping values, frame bits)
        self._fixed = {p.mapping_index: (tuple(f.mapping_value for f in p.fields), sum(f.bits for f in p.fields))
                       for p in od.pdos}
        self.nmt_commands = 0
        self.nmt_ignored = 0
        self.heartbeats = 0
        self.boot_ups = 0
        self.emcys = 0

    # ------------------------------------------------------------------ state
    @property
    def nmt_state(self) -> str:
        """"initialising" | "pre-operational" | "operational" | "stopped"."""
        return self._state

    @property
    def pdo_active(self) -> bool:
        """Whether the node exchanges PDOs: only in NMT state operational."""
        return self._state == "operational"

    def _enter(self, state: str) -> None:
        self._state = state
        if state != "initialising":
            self.sdo.state = state

    @property
    def counters(self) -> dict[str, Any]:
        """JSON-ready counters: SDO requests, completed transfers, aborts by code (hex text),
        malformed requests, NMT commands taken and ignored, heartbeats, boot-ups, EMCYs."""
        return {"sdo_requests": self.sdo.requests, "sdo_transfers": self.sdo.transfers,
                "sdo_aborts": {f"0x{code:08X}": n for code, n in sorted(self.sdo.aborts.items())},
                "malformed": self.sdo.malformed, "nmt_commands": self.nmt_commands, "nmt_ignored": self.nmt_ignored,
                "heartbeats": self.heartbeats, "boot_ups": self.boot_ups, "emcy": self.emcys}

    # ------------------------------------------------------------------ frames out
    def _frame(self, cob_id: int, data: bytes, time_s: float) -> can.Message:
        return can.Message(timestamp=time_s, arbitration_id=cob_id, data=data, is_extended_id=False)

    def boot(self, time_s: float) -> list[can.Message]:
        """Finish the initialisation: the boot-up message (0x700 + id, data 00), then
        pre-operational; the heartbeat (if 0x1017 > 0) runs from here."""
        self._now = time_s
        self._enter("pre-operational")
        self.boot_ups += 1
        self._restart_heartbeat(time_s)
        return [self._frame(HEARTBEAT_BASE + self.node_id, b"\x00", time_s)]

    def _restart_heartbeat(self, time_s: float) -> None:
        period_ms = self.sdo.values.get((0x1017, 0), 0)
        self._heartbeat_s = period_ms * 1e-3
        self.next_tick_s = time_s + self._heartbeat_s if period_ms > 0 and self._state != "initialising" else math.inf

    def tick(self, time_s: float) -> list[can.Message]:
        """The heartbeat if one is due at ``time_s`` (at most one per call), else []."""
        if time_s < self.next_tick_s:
            return []
        self.next_tick_s += self._heartbeat_s
        if self.next_tick_s <= time_s:  # called late: the next one a period from now
            self.next_tick_s = time_s + self._heartbeat_s
        self.heartbeats += 1
        return [self._frame(HEARTBEAT_BASE + self.node_id, bytes((HEARTBEAT_STATE[self._state],)), time_s)]

    def emcy(self, error_code: int, error_register: int, time_s: float) -> can.Message:
        """The EMCY frame (0x080 + id: error code, error register 0x1001, 5 bytes 0) of a new
        error; updates 0x1001 and the error history 0x1003 (newest first; code 0 = error reset
        clears the register, not the history). A node in NMT state stopped must not send it:
        the caller checks :attr:`nmt_state`."""
        values = self.sdo.values
        values[(0x1001, 0)] = error_register & 0xFF
        if error_code:
            subs = sorted(e.subindex for e in self.od.objects[0x1003].entries if e.subindex) \
                if 0x1003 in self.od.objects else []
            for k in reversed(subs[1:]):
                values[(0x1003, k)] = values[(0x1003, k - 1)]
            if subs:
                values[(0x1003, subs[0])] = error_code & 0xFFFF
                values[(0x1003, 0)] = min(values.get((0x1003, 0), 0) + 1, len(subs))
        self.emcys += 1
        return self._frame(EMCY_BASE + self.node_id,
                           bytes((error_code & 0xFF, (error_code >> 8) & 0xFF, error_register & 0xFF, 0, 0, 0, 0, 0)),
                           time_s)

    # ------------------------------------------------------------------ frames in
    def receive(self, msg: can.Message, time_s: float) -> list[can.Message]:
        """The node's answer to ``msg`` (NMT command or SDO request for it); [] for any other
        frame, a frame for another node, and everything before :meth:`boot`."""
        cob_id = msg.arbitration_id
        if self._state == "initialising" or msg.is_remote_frame or msg.is_error_frame:
            return []
        self._now = time_s
        if cob_id == NMT_ID:
            return self._nmt(bytes(msg.data), time_s)
        if cob_id == SDO_RX_BASE + self.node_id:
            answer = self.sdo.handle(bytes(msg.data))
            return [] if answer is None else [self._frame(SDO_TX_BASE + self.node_id, answer, time_s)]
        return []

    def _nmt(self, data: bytes, time_s: float) -> list[can.Message]:
        if len(data) != 2 or data[0] not in NMT_COMMANDS:
            if len(data) == 2 and data[1] not in (0, self.node_id):
                return []  # for another node: not ours to judge
            self.nmt_ignored += 1
            return []
        command, target = data
        if target not in (0, self.node_id):
            return []
        self.nmt_commands += 1
        if command == NMT_START:
            self._enter("operational")
        elif command == NMT_STOP:
            self._enter("stopped")
        elif command == NMT_ENTER_PRE_OPERATIONAL:
            self._enter("pre-operational")
        else:
            self._reset(communication_only=command == NMT_RESET_COMMUNICATION)
            self._state = "initialising"
            return self.boot(time_s)
        return []

    def _reset(self, communication_only: bool) -> None:
        """Every object (or the communication area) back to its default."""
        values = self.sdo.values
        for entry in self.od.entries():
            if communication_only and not 0x1000 <= entry.index <= 0x1FFF:
                continue
            key = (entry.index, entry.subindex)
            if values.get(key) != entry.default:
                if self.on_write is not None and entry.writable and not communication_only:
                    self.on_write(entry, entry.default)
                values[key] = entry.default
        self.sdo._upload = self.sdo._download_state = None

    # ------------------------------------------------------------------ checks of written values
    def _written(self, entry: Entry, value: Any) -> None:
        index = entry.index
        if _is_mapping(index):
            self._check_mapping(entry, value)
        if self.on_write is not None:
            self.on_write(entry, value)
        if index == 0x1017 and entry.subindex == 0:
            self.sdo.values[(0x1017, 0)] = value
            self._restart_heartbeat(self._now)

    def _check_mapping(self, entry: Entry, value: int) -> None:
        index, sub = entry.index, entry.subindex
        if sub != 0:  # one mapped object: an existing PDO-mappable entry of that length
            self._mapped_bits(index, sub, value)
            return
        values = self.sdo.values
        mapped = [values.get((index, k)) for k in range(1, value + 1)]
        if any(m is None for m in mapped):  # more objects than the mapping has entries
            raise SdoAbort(MAPPING_TOO_LONG, index, sub)
        fixed, frame_bits = self._fixed.get(index, ((), 0))
        bits = sum(self._mapped_bits(index, k, m) for k, m in enumerate(mapped, start=1))
        if bits > frame_bits:
            raise SdoAbort(MAPPING_TOO_LONG, index, sub)
        if value and tuple(mapped) != fixed:
            raise SdoAbort(PARAMETER_INCOMPATIBLE, index, sub)

    def _mapped_bits(self, index: int, sub: int, mapping: int) -> int:
        target, target_sub, bits = mapping >> 16, (mapping >> 8) & 0xFF, mapping & 0xFF
        if target < 0x1000:  # a dummy entry: the data type's index
            dummy = next((b for (i, b, _c) in DATA_TYPES.values() if i == target), None)
            if dummy is None or target_sub != 0 or bits != dummy:
                raise SdoAbort(NOT_MAPPABLE, index, sub)
            return bits
        try:
            mapped = self.od.entry(target, target_sub)
        except KeyError:
            raise SdoAbort(NOT_MAPPABLE, index, sub) from None
        if not mapped.pdo or mapped.bits != bits:
            raise SdoAbort(NOT_MAPPABLE, index, sub)
        return bits


__all__ = ["EMCY_BASE", "HEARTBEAT_BASE", "HEARTBEAT_STATE", "NMT_COMMANDS", "NMT_ENTER_PRE_OPERATIONAL", "NMT_ID",
           "NMT_RESET_COMMUNICATION", "NMT_RESET_NODE", "NMT_START", "NMT_STOP", "STATES", "CanopenNode"]
