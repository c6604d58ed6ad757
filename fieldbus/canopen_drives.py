"""Six CiA 402 drives as CANopen devices on a python-can bus, frame by frame, SYNC-driven.

:class:`CanopenDrives` is the drive side of a CANopen network whose master is someone else's
program (a PLC's CANopen master on a USB-CAN adapter, the ``canopen`` Python library): one
:class:`fieldbus.canopen_node.CanopenNode` per drive answers NMT, SDO and sends boot-up, heartbeat
and EMCY; on top of it this module runs the PDOs the way CiA 301 defines them for synchronous
transmission:

* An RPDO (COB-ID and mapping from 0x1400+/0x1600+ as the master wrote them over SDO) is taken
  in NMT state operational only; its mapped values are held in a receive buffer and copied into
  the object dictionary at the next SYNC (transmission types 0..240), or at once (254/255).
* At each SYNC (COB-ID 0x080): the buffers of the RPDOs received since the previous SYNC go into
  the dictionary; the drive's set-points for the next cycle are read from it (controlword 0x6040,
  target position 0x607A, torque offset 0x60B2, modes of operation 0x6060, target torque 0x6071,
  target velocity 0x60FF, velocity offset 0x60B1 - whatever wrote them: an RPDO or an SDO
  download); the drive's actual values at the SYNC go into the dictionary (0x6041, 0x6064,
  0x606C, 0x6077, 0x603F, 0x6061) and every valid synchronous TPDO (0x1800+/0x1A00+) whose
  transmission type divides the SYNC count is sent.
* Counted per node (:attr:`counters`): RPDOs taken, a SYNC interval in which an operational
  node got no RPDO (``rpdo_missing``: the drive keeps its last set-point), more than one RPDO of
  the same number in one interval (``rpdo_overwritten``: the older is lost), RPDOs shorter than
  their mapping (``rpdo_short``: dropped, CiA 301's EMCY 0x8210), RPDOs in a state other than
  operational (``rpdo_ignored``), TPDOs sent, mappings that do not make a PDO
  (``pdo_mapping_invalid``: that PDO is neither taken nor sent); the node's own counters (SDO
  aborts by code, malformed requests, NMT commands, NMT commands for a node that does not exist
  on this bus) come from :class:`CanopenNode`.

Units on the bus are the dictionary's (counts, counts/s, 0.1 % of rated torque); the drive side
works in rad, rad/s and N m through :class:`fieldbus.scaling.JointScaling` (the same conversion
as the POWERLINK telegrams).
"""
from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import can
import numpy as np

from fieldbus.canopen_node import CanopenNode
from fieldbus.object_dictionary import DATA_TYPES, Entry, ObjectDictionary
from fieldbus.process_data import AppliedSetpoints, DriveActuals
from fieldbus.scaling import JointScaling
from fieldbus.sdo import MAPPING_TOO_LONG, SdoAbort

SYNC_ID = 0x080
NMT_ID = 0x000
#: COB-ID bit 31: the PDO does not exist / is not valid (CiA 301 0x1400/0x1800 sub 1)
COB_INVALID = 1 << 31
#: the largest PDO payload, bytes (CAN FD; a classic CAN PDO has 8)
MAX_PDO_BYTES = 64
#: CiA 301 EMCY error code: PDO not processed due to length error
EMCY_PDO_LENGTH = 0x8210

#: struct codes of the data types a dummy mapping entry (index 0x0001..0x0007) names
_DUMMY_CODES = {0x0001: "?", 0x0002: "b", 0x0003: "h", 0x0004: "i", 0x0005: "B", 0x0006: "H", 0x0007: "I"}
_CODE_BY_TYPE_INDEX = {index: code for index, _bits, code in DATA_TYPES.values() if code}

#: the drive's process data in the dictionary
CONTROLWORD, TARGET_POSITION, TORQUE_OFFSET, MODES = 0x6040, 0x607A, 0x60B2, 0x6060
TARGET_TORQUE, TARGET_VELOCITY, VELOCITY_OFFSET = 0x6071, 0x60FF, 0x60B1
STATUSWORD, POSITION_ACTUAL, VELOCITY_ACTUAL, TORQUE_ACTUAL = 0x6041, 0x6064, 0x606C, 0x6077
ERROR_CODE, MODES_DISPLAY = 0x603F, 0x6061


@dataclass(frozen=True)
class PdoMap:
    """One PDO as its communication and mapping objects describe it now."""

    number: int
    cob_id: int
    transmission_type: int
    layout: struct.Struct | None  # None: mapped nothing
    targets: tuple[tuple[int, int] | None, ...]  # (index, sub) per field; None for a dummy entry

    @property
    def synchronous(self) -> bool:
        return self.transmission_type <= 240


def pdo_maps(values: dict[tuple[int, int], Any], od: ObjectDictionary, receive: bool) -> tuple[list[PdoMap], int]:
    """The valid PDOs of one direction from the dictionary's current values, and how many PDO
    definitions were invalid (a mapping entry naming no mappable object, a length that differs
    from the object's data type, more than :data:`MAX_PDO_BYTES`)."""
    com_base, map_base = (0x1400, 0x1600) if receive else (0x1800, 0x1A00)
    maps: list[PdoMap] = []
    invalid = 0
    for n in range(512):
        com, mapping = com_base + n, map_base + n
        if com not in od.objects or mapping not in od.objects:
            continue
        cob = int(values.get((com, 1), COB_INVALID))
        if cob & COB_INVALID:
            continue
        count = int(values.get((mapping, 0), 0))
        codes, targets, bits, ok = ["<"], [], 0, True
        for k in range(1, count + 1):
            raw = int(values.get((mapping, k), 0))
            index, sub, length = raw >> 16, (raw >> 8) & 0xFF, raw & 0xFF
            if index in _DUMMY_CODES:
                code = _DUMMY_CODES[index]
                targets.append(None)
            else:
                try:
                    entry = od.entry(index, sub)
                except KeyError:
                    ok = False
                    break
                code = _CODE_BY_TYPE_INDEX.get(entry.data_type_index)
                if not entry.pdo or code is None or entry.bits != length:
                    ok = False
                    break
                targets.append((index, sub))
            if struct.calcsize("<" + code) * 8 != length:
                ok = False
                break
            codes.append(code)
            bits += length
        if not ok or bits > MAX_PDO_BYTES * 8:
            invalid += 1
            continue
        layout = struct.Struct("".join(codes)) if count else None
        maps.append(PdoMap(n + 1, cob & 0x1FFFFFFF, int(values.get((com, 2), 255)), layout, tuple(targets)))
    return maps, invalid


class _Drive:
    """One node: its CanopenNode, its PDO maps and receive buffers."""

    def __init__(self, node: Any, od: ObjectDictionary) -> None:
        self.node = node
        self.od = od
        self.values: dict[tuple[int, int], Any] = node_values(node)
        self.dirty = True
        self.rpdos: dict[int, PdoMap] = {}
        self.tpdos: list[PdoMap] = []
        self.pending: dict[int, tuple] = {}  # RPDO number -> values received since the last SYNC
        self.invalid = 0
        self.counts = {"rpdo_taken": 0, "rpdo_missing": 0, "rpdo_overwritten": 0, "rpdo_short": 0,
                       "rpdo_ignored": 0, "tpdo_sent": 0, "pdo_mapping_invalid": 0}
        self.got_rpdo = False  # an RPDO was taken since the node last entered operational

    def refresh(self) -> bool:
        """Rebuild the PDO maps after a write to them; True when they changed."""
        if self.dirty:
            rpdos, bad_r = pdo_maps(self.values, self.od, True)
            self.tpdos, bad_t = pdo_maps(self.values, self.od, False)
            self.rpdos = {p.cob_id: p for p in rpdos}
            self.counts["pdo_mapping_invalid"] = bad_r + bad_t
            self.dirty = False
            return True
        return False


def node_values(node: Any) -> dict[tuple[int, int], Any]:
    """The live value table of a :class:`CanopenNode` ((index, sub) -> value, shared with its SDO server)."""
    for path in (("values",), ("sdo", "values"), ("server", "values"), ("_sdo", "values")):
        obj = node
        for name in path:
            obj = getattr(obj, name, None)
        if isinstance(obj, dict):
            return obj
    raise TypeError(f"{type(node).__name__}: no value table (values / sdo.values)")


class FreeMappingNode(CanopenNode):
    """A :class:`CanopenNode` whose PDOs a CANopen master maps as it likes (any PDO-mappable
    objects of the right length, up to :data:`MAX_PDO_BYTES`; CiA 301 abort 0x06040041 /
    0x06040042 otherwise): on a bus carried frame by frame the PDOs are packed from the mapping
    itself, not from the POWERLINK cycle's fixed telegram layout."""

    def _check_mapping(self, entry: Entry, value: int) -> None:
        index, sub = entry.index, entry.subindex
        if sub != 0:
            self._mapped_bits(index, sub, value)
            return
        mapped = [self.sdo.values.get((index, k)) for k in range(1, value + 1)]
        if any(m is None for m in mapped):
            raise SdoAbort(MAPPING_TOO_LONG, index, sub)
        if sum(self._mapped_bits(index, k, m) for k, m in enumerate(mapped, start=1)) > MAX_PDO_BYTES * 8:
            raise SdoAbort(MAPPING_TOO_LONG, index, sub)


class CanopenDrives:
    """The drive side of the network (see the module docstring): ``nodes[i]`` is the
    CanopenNode of drive ``i + 1``, ``ods[i]`` its object dictionary."""

    def __init__(self, nodes: Sequence[Any], ods: Sequence[ObjectDictionary], scaling: JointScaling) -> None:
        self.drives = [_Drive(node, od) for node, od in zip(nodes, ods)]
        self.by_id = {d.node.node_id if hasattr(d.node, "node_id") else d.od.node: d for d in self.drives}
        self.scaling = scaling
        self.syncs = 0
        self.sync_counter_errors = 0  # a SYNC whose counter byte did not follow the previous one
        self._last_counter: int | None = None
        self.rpdo_foreign = 0  # a PDO-range frame no node takes (another node id, an unmapped COB-ID)
        self.nmt_to_missing_node = 0  # NMT commands addressed to a node id that is not on this bus
        self._own_static = {base + n for n in self.by_id for base in (0x080, 0x580, 0x700)}
        self._own: set[int] = set(self._own_static)

    # ---------------------------------------------------------------- set-up
    def mark_dirty(self, node_id: int, index: int) -> None:
        """A PDO communication or mapping object of ``node_id`` was written: maps are rebuilt."""
        if 0x1400 <= index <= 0x1BFF and node_id in self.by_id:
            self.by_id[node_id].dirty = True

    def _refresh(self) -> None:
        if any([d.refresh() for d in self.drives]):
            self._own = self._own_static | {p.cob_id for d in self.drives for p in d.tpdos}

    def boot(self, time_s: float) -> list[can.Message]:
        out: list[can.Message] = []
        for d in self.drives:
            out += d.node.boot(time_s)
        return out

    def tick(self, time_s: float) -> list[can.Message]:
        out: list[can.Message] = []
        for d in self.drives:
            out += d.node.tick(time_s)
        return out

    # ---------------------------------------------------------------- frames
    def receive(self, msg: can.Message, time_s: float) -> list[can.Message]:
        """Every frame that is not a SYNC: NMT and SDO to the nodes, RPDOs into the receive
        buffers; returns the answers to send."""
        cob = msg.arbitration_id
        if cob in self._own:  # what the nodes themselves send (a bus that echoes, e.g. udp_multicast)
            return []
        if 0x180 <= cob < 0x580 and not msg.is_remote_frame:
            self._refresh()
            for d in self.drives:
                pdo = d.rpdos.get(cob)
                if pdo is not None:
                    self._take_rpdo(d, pdo, msg, time_s)
                    return []
            self.rpdo_foreign += 1
            return []
        out: list[can.Message] = []
        if cob == NMT_ID and len(msg.data) == 2 and msg.data[1] != 0 and msg.data[1] not in self.by_id:
            self.nmt_to_missing_node += 1  # no node answers (CiA 301: no reaction); counted once per bus
        if cob == NMT_ID or 0x600 <= cob < 0x680:
            before = [d.node.nmt_state for d in self.drives]
            for d in self.drives:
                out += d.node.receive(msg, time_s)
            for d, state in zip(self.drives, before):
                if d.node.nmt_state != state:
                    d.got_rpdo = False
                    d.pending.clear()
                    d.dirty = True
        return out

    def _take_rpdo(self, d: _Drive, pdo: PdoMap, msg: can.Message, time_s: float) -> None:
        if d.node.nmt_state != "operational":
            d.counts["rpdo_ignored"] += 1
            return
        if pdo.layout is None:
            return
        if len(msg.data) < pdo.layout.size:
            d.counts["rpdo_short"] += 1
            return
        decoded = pdo.layout.unpack_from(bytes(msg.data))
        if pdo.synchronous:
            if pdo.number in d.pending:
                d.counts["rpdo_overwritten"] += 1
            d.pending[pdo.number] = (pdo, decoded)
        else:
            self._store(d, pdo, decoded)
        d.counts["rpdo_taken"] += 1
        d.got_rpdo = True

    @staticmethod
    def _store(d: _Drive, pdo: PdoMap, decoded: tuple) -> None:
        values = d.values
        for target, value in zip(pdo.targets, decoded):
            if target is not None:
                values[target] = value

    # ---------------------------------------------------------------- the SYNC
    def sync(self, msg: can.Message, actuals: DriveActuals, applied: AppliedSetpoints,
             time_s: float) -> list[can.Message]:
        """A SYNC: RPDO buffers into the dictionaries, the dictionaries' set-points into
        ``applied`` (rad, N m; ``fresh`` where an RPDO came in the interval), ``actuals`` (the
        drives' values at the SYNC) into the dictionaries; returns the TPDOs to send."""
        self.syncs += 1
        if msg.data:
            counter = msg.data[0]
            if self._last_counter is not None and counter != self._last_counter + 1 and counter != 1:
                self.sync_counter_errors += 1
            self._last_counter = counter
        scaling = self.scaling
        out: list[can.Message] = []
        self._refresh()
        for i, d in enumerate(self.drives):
            values = d.values
            operational = d.node.nmt_state == "operational"
            fresh = bool(d.pending)
            for pdo, decoded in d.pending.values():
                self._store(d, pdo, decoded)
            d.pending.clear()
            if operational and d.got_rpdo and not fresh:
                d.counts["rpdo_missing"] += 1
            applied.controlword[i] = values[(CONTROLWORD, 0)]
            applied.position[i] = values[(TARGET_POSITION, 0)] * scaling.rad_per_count[i]
            applied.torque_offset[i] = values[(TORQUE_OFFSET, 0)] * scaling.newton_metre_per_unit[i]
            applied.fresh[i] = fresh
            if applied.modes_of_operation is not None:
                applied.modes_of_operation[i] = values[(MODES, 0)]
            if applied.target_torque is not None:
                applied.target_torque[i] = values[(TARGET_TORQUE, 0)] * scaling.newton_metre_per_unit[i]
            if applied.target_velocity is not None:
                applied.target_velocity[i] = values[(TARGET_VELOCITY, 0)] * scaling.rad_per_count[i]
            if applied.velocity_offset is not None:
                applied.velocity_offset[i] = values[(VELOCITY_OFFSET, 0)] * scaling.rad_per_count[i]
            self.latch(i, actuals)
            if not operational:
                continue
            for pdo in d.tpdos:
                if not pdo.synchronous or pdo.layout is None:
                    continue
                if pdo.transmission_type > 1 and self.syncs % pdo.transmission_type:
                    continue
                data = pdo.layout.pack(*(0 if t is None else values[t] for t in pdo.targets))
                out.append(can.Message(arbitration_id=pdo.cob_id, data=data, is_extended_id=False,
                                       is_fd=len(data) > 8, timestamp=time_s))
                d.counts["tpdo_sent"] += 1
        return out

    def latch(self, i: int, actuals: DriveActuals) -> None:
        """Drive ``i``'s actual values into its dictionary (what SDO uploads and TPDOs read)."""
        values = self.drives[i].values
        scaling = self.scaling
        values[(STATUSWORD, 0)] = int(actuals.statusword[i]) & 0xFFFF
        values[(POSITION_ACTUAL, 0)] = scaling.position_count(i, float(actuals.position[i]))
        values[(VELOCITY_ACTUAL, 0)] = scaling.velocity_count(i, float(actuals.velocity[i]))
        values[(TORQUE_ACTUAL, 0)] = scaling.torque_unit(i, float(actuals.torque[i]))
        values[(ERROR_CODE, 0)] = int(actuals.error_code[i]) & 0xFFFF
        if actuals.modes_of_operation_display is not None:
            values[(MODES_DISPLAY, 0)] = int(actuals.modes_of_operation_display[i])

    # ---------------------------------------------------------------- figures
    @property
    def counters(self) -> dict[str, Any]:
        """Per node (``"1"`` ..) the PDO counters and the node's own (NMT, SDO)."""
        out: dict[str, Any] = {}
        self._refresh()
        for d in self.drives:
            node_counts = dict(getattr(d.node, "counters", {}) or {})
            out[str(d.od.node)] = {**d.counts, **node_counts, "nmt_state": d.node.nmt_state}
        return out

    def totals(self) -> dict[str, int]:
        """The integer counters summed over the nodes (SDO aborts by code summed too)."""
        total: dict[str, Any] = {}
        for row in self.counters.values():
            for key, value in row.items():
                if isinstance(value, bool) or key == "nmt_state":
                    continue
                if isinstance(value, int):
                    total[key] = total.get(key, 0) + value
                elif isinstance(value, dict):
                    sub = total.setdefault(key, {})
                    for k, v in value.items():
                        sub[str(k)] = sub.get(str(k), 0) + int(v)
        return total


def applied_setpoints(n: int) -> AppliedSetpoints:
    """A zeroed AppliedSetpoints of ``n`` drives with every optional field (for a caller without the cell's views)."""
    z = np.zeros
    return AppliedSetpoints(controlword=z(n, dtype=np.int64), position=z(n), torque_offset=z(n), fresh=z(n, dtype=bool),
                            comm_fault=z(n, dtype=bool), fault_code=z(n, dtype=np.int64),
                            modes_of_operation=np.full(n, 8, dtype=np.int64), target_velocity=z(n),
                            velocity_offset=z(n), target_torque=z(n))


__all__ = ["CanopenDrives", "EMCY_PDO_LENGTH", "FreeMappingNode", "MAX_PDO_BYTES", "PdoMap", "applied_setpoints", "node_values",
           "pdo_maps"]

