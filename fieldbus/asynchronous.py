"""The asynchronous phase of the POWERLINK cycle: SDO and NMT after the SoA, one frame per cycle.

A POWERLINK cycle is ``SoC | PReq/PRes x N | SoA | async | idle`` (``fieldbus.timing``). The
isochronous part carries the PDOs (the set-points and actual values) and its timing does not
depend on anything here. After the SoA exactly one asynchronous frame (an ASnd, up to
``timing.async_frame_bytes``, reserved in the cycle budget whether used or not) may go on the
wire, sent by the node the SoA invites: the MN itself or one CN. This module fills that slot:

* **SDO** (CiA 301 expedited and segmented upload/download, the 8-byte CANopen SDO frames on
  COB-ID 0x600 + node and 0x580 + node): the MN's SDO client sends a request in the slot of
  cycle k; the SoA of cycle k + 1 invites the addressed node, whose :class:`~fieldbus.sdo.SdoServer`
  (inside its :class:`~fieldbus.canopen_node.CanopenNode`) handles the request then and sends its
  answer in that slot. A written value takes effect (``on_write``) from that cycle, k + 1. A
  segmented transfer takes two cycles per segment. Requests queue; one transfer is in flight.
* **NMT** (COB-ID 0x000, command + node id, 0 = all): sent by the MN in the slot and taken by the
  nodes at once. A node in NMT state pre-operational or stopped takes no PDO: its drive keeps the
  set-points it applied last (``fresh`` false); entering *stopped* is also a CiA 402 "abort
  connection" event (object 0x6007, ``[fieldbus.reaction] abort_connection_option``): fault code
  0x8100 (or the quick-stop controlword 0x0002) goes to the drive for as long as the node is
  stopped. *start* makes it take PDOs again (a drive in Fault needs the controller's fault reset).
  Reset node / reset communication restore the defaults and end with a boot-up message (0x700 +
  node); the node then is pre-operational until the next start.
* **EMCY**: the drives' and the nodes' EMCY frames (``fieldbus.nodes``) are sent in the slot of
  the cycle the error appears in; an SDO or NMT frame due in that cycle waits for the next.

The nodes are operational from cycle 0 (the MN booted and started them before the run; those
boot-up and NMT frames are not in the log). No CANopen heartbeat is sent: on POWERLINK a node's
NMT state travels in its PRes. The SDO and NMT frames go from the MN to the nodes in this
process and into the CAN log at their slot times (the MN's frame ``ASYNC_OFFSETS['mn']`` after
the SoC of its cycle, a node's answer ``ASYNC_OFFSETS['cn']``), so ``cosim export-pcap`` shows
them as SDO/NMT in the CAN capture and as ASnd after the SoA in the POWERLINK capture.

Requests come from a scenario (``[[fieldbus.asynchronous]]``, :func:`parse_requests`) or from a
controller through :meth:`AsynchronousPhase.submit`; every transfer's outcome is in
:attr:`AsynchronousPhase.results` and its counts in :meth:`AsynchronousPhase.summary`.

Cost when idle: :meth:`AsynchronousPhase.due` is one comparison per cycle.
"""
from __future__ import annotations

import math
import struct
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import can

from fieldbus.canopen_node import NMT_ID, CanopenNode
from fieldbus.object_dictionary import DATA_TYPES, Entry, ObjectDictionary
from fieldbus.sdo import SDO_RX_BASE, SDO_TX_BASE, UNKNOWN_OBJECT_ABORTS, encode_value
from fieldbus.telegrams import FastMessage

#: NMT commands by the name a scenario gives (CiA 301 command specifiers, fieldbus.canopen_node)
NMT_BY_NAME = {"start": 0x01, "stop": 0x02, "pre-operational": 0x80, "reset-node": 0x81,
               "reset-communication": 0x82}
SERVICES = ("read", "write", "raw", "nmt")
#: CiA 402 abort connection: fault code 0x8100 / quick-stop controlword (as fieldbus.nodes)
ABORT_CONNECTION_FAULT = 0x8100
QUICK_STOP_CONTROLWORD = 0x0002
#: the held set-point fields of a node that takes no PDO
_HELD = ("controlword", "position", "torque_offset", "modes_of_operation", "target_velocity", "velocity_offset",
         "target_torque")


@dataclass(frozen=True)
class AsyncRequest:
    """One SDO or NMT request of the MN. ``service``: "read" (SDO upload), "write" (SDO
    download of ``value`` in the object's bus unit), "raw" (the 8-or-other ``data`` bytes as the
    SDO request: for testing a server's answer to a malformed request) or "nmt" (``command``,
    one of :data:`NMT_BY_NAME`; node 0 = every node). ``time_s``: the earliest simulated time
    at which the MN sends it (the first slot at or after it)."""

    time_s: float
    node: int
    service: str
    index: int = 0
    subindex: int = 0
    value: Any = None
    data: bytes = b""
    command: str = ""
    origin: str = "scenario"


@dataclass
class AsyncResult:
    """What became of one request: ``answer`` is the value read, "ok" (write confirmed, NMT
    sent), ``abort`` the CiA 301 abort code (then ``answer`` is None), or ``answer`` "no answer"
    (a node that is not on the bus or in NMT state stopped)."""

    request: AsyncRequest
    sent_cycle: int
    answered_cycle: int | None = None
    answer: Any = None
    abort: int | None = None

    def as_dict(self) -> dict[str, Any]:
        r = self.request
        out = {"time_s": r.time_s, "node": r.node, "service": r.service, "origin": r.origin,
               "sent_cycle": self.sent_cycle, "answered_cycle": self.answered_cycle}
        if r.service == "nmt":
            out["command"] = r.command
        elif r.service == "raw":
            out["data"] = r.data.hex()
        else:
            out.update(index=f"0x{r.index:04X}", subindex=r.subindex)
            if r.service == "write":
                out["value"] = r.value
        out["answer"] = self.answer
        if self.abort is not None:
            out["abort"] = f"0x{self.abort:08X}"
        return out


# ---------------------------------------------------------------------------- scenario keys
def parse_requests(value: object, nodes: int, fail: Callable[[str, object, str], None]) -> tuple[AsyncRequest, ...]:
    """The ``[[fieldbus.asynchronous]]`` list as requests, sorted by time (stable). ``fail(key,
    given, expected)`` raises the configuration error naming the key. Each table: ``time_s``
    (>= 0), ``node`` (1..127; 0..127 for nmt: a node not on the bus is allowed, it does not
    answer), and one of ``sdo = "read" | "write" | "raw"`` (with ``index``, ``subindex`` (default
    0), ``value`` for write: an integer in the object's bus unit or a string; ``data`` for raw: a
    list of 0..8 bytes) or ``nmt = "start" | "stop" | "pre-operational" | "reset-node" |
    "reset-communication"``."""
    if not isinstance(value, (list, tuple)):
        fail("asynchronous", value, "a list of tables [[fieldbus.asynchronous]]")
    out = []
    for i, item in enumerate(value):  # type: ignore[union-attr]
        key = f"asynchronous[{i}]"
        if not isinstance(item, Mapping):
            fail(key, item, "a table with time_s, node and sdo or nmt")
        allowed = {"time_s", "node", "sdo", "nmt", "index", "subindex", "value", "data"}
        for name in item:
            if name not in allowed:
                fail(f"{key}.{name}", item[name], "one of the keys " + ", ".join(sorted(allowed)))
        t = item.get("time_s")
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or t < 0:
            fail(f"{key}.time_s", t, "a time >= 0 in seconds")
        if ("sdo" in item) == ("nmt" in item):
            fail(key, dict(item), "exactly one of sdo = \"read\"|\"write\"|\"raw\" or nmt = \"" +
                 "\"|\"".join(NMT_BY_NAME) + "\"")
        node = item.get("node")
        low = 0 if "nmt" in item else 1
        if isinstance(node, bool) or not isinstance(node, int) or not low <= node <= 127:
            fail(f"{key}.node", node, f"a node id {low}..127 (the bus has nodes 1..{nodes})")
        if "nmt" in item:
            command = item["nmt"]
            if command not in NMT_BY_NAME:
                fail(f"{key}.nmt", command, "one of " + ", ".join(NMT_BY_NAME))
            for name in ("index", "subindex", "value", "data"):
                if name in item:
                    fail(f"{key}.{name}", item[name], "no such key with nmt")
            out.append(AsyncRequest(float(t), node, "nmt", command=command))
            continue
        service = item["sdo"]
        if service not in ("read", "write", "raw"):
            fail(f"{key}.sdo", service, "one of read, write, raw")
        if service == "raw":
            data = item.get("data")
            if not isinstance(data, list) or len(data) > 8 or any(
                    isinstance(b, bool) or not isinstance(b, int) or not 0 <= b <= 255 for b in data):
                fail(f"{key}.data", data, "a list of 0..8 bytes (integers 0..255)")
            for name in ("index", "subindex", "value"):
                if name in item:
                    fail(f"{key}.{name}", item[name], "no such key with sdo = \"raw\"")
            out.append(AsyncRequest(float(t), node, "raw", data=bytes(data)))
            continue
        index, sub = item.get("index"), item.get("subindex", 0)
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index <= 0xFFFF:
            fail(f"{key}.index", index, "an object index 0x0000..0xFFFF")
        if isinstance(sub, bool) or not isinstance(sub, int) or not 0 <= sub <= 0xFF:
            fail(f"{key}.subindex", sub, "a sub-index 0..255")
        if "data" in item:
            fail(f"{key}.data", item["data"], "no such key with sdo = \"%s\"" % service)
        if service == "write":
            v = item.get("value")
            if isinstance(v, bool) or not isinstance(v, (int, str)):
                fail(f"{key}.value", v, "an integer in the object's bus unit (or a string)")
        elif "value" in item:
            fail(f"{key}.value", item["value"], "no value with sdo = \"read\"")
        out.append(AsyncRequest(float(t), node, service, index, sub, item.get("value")))
    return tuple(sorted(out, key=lambda r: r.time_s))


# ---------------------------------------------------------------------------- the SDO client
class _Transfer:
    """The MN's SDO client for one request: the frames it sends, the answers it takes."""

    def __init__(self, request: AsyncRequest, od: ObjectDictionary | None) -> None:
        self.request = request
        self.done = False
        self.answer: Any = None
        self.abort: int | None = None
        self._toggle = 0
        self._upload = bytearray()
        self._download: bytes | None = None  # the rest of a segmented download
        self._entry: Entry | None = None
        if od is not None:
            try:
                self._entry = od.entry(request.index, request.subindex)
            except KeyError:
                self._entry = None

    def first(self) -> bytes:
        r = self.request
        if r.service == "raw":
            return r.data
        head = struct.pack("<HB", r.index, r.subindex)
        if r.service == "read":
            return b"\x40" + head + bytes(4)
        data = self._value_bytes()
        if len(data) <= 4:
            return bytes((0x23 | ((4 - len(data)) << 2),)) + head + data.ljust(4, b"\0")
        self._download = data
        return b"\x21" + head + struct.pack("<I", len(data))

    def _value_bytes(self) -> bytes:
        value, entry = self.request.value, self._entry
        if entry is not None and (entry.data_type == "VISIBLE_STRING" or DATA_TYPES[entry.data_type][2]):
            try:
                return encode_value(entry, value)
            except (struct.error, TypeError, ValueError, UnicodeEncodeError):
                pass  # a value the type cannot carry: sent as 4 bytes, the server judges it
        if isinstance(value, str):
            return value.encode("ascii", "replace")
        return struct.pack("<q", int(value))[:4] if -(1 << 31) <= value < (1 << 32) else struct.pack("<q", value)

    def take(self, answer: bytes) -> bytes | None:
        """The next request after ``answer`` (None: the transfer is done)."""
        r = self.request
        if len(answer) < 8:
            self.done, self.answer = True, "malformed answer"
            return None
        scs = answer[0] >> 5
        if answer[0] == 0x80:
            self.done, self.abort = True, struct.unpack_from("<I", answer, 4)[0]
            return None
        if r.service == "raw":
            self.done, self.answer = True, answer.hex()
            return None
        if r.service == "read":
            if scs == 2:  # initiate upload response
                if answer[0] & 0x02:  # expedited
                    n = 4 - ((answer[0] >> 2) & 0x03) if answer[0] & 0x01 else 4
                    self._finish_upload(answer[4:4 + n])
                    return None
                return bytes((0x60 | (self._toggle << 4),)) + bytes(7)
            if scs == 0:  # upload segment
                n = 7 - ((answer[0] >> 1) & 0x07)
                self._upload += answer[1:1 + n]
                if answer[0] & 0x01:
                    self._finish_upload(bytes(self._upload))
                    return None
                self._toggle ^= 1
                return bytes((0x60 | (self._toggle << 4),)) + bytes(7)
        else:
            if scs == 3 and self._download is not None:  # initiate download response: the first segment
                return self._segment()
            if scs == 1 and self._download:  # segment confirmed, more to send
                self._toggle ^= 1
                return self._segment()
            if scs in (3, 1):
                self.done, self.answer = True, "ok"
                return None
        self.done, self.answer = True, f"unexpected answer {answer.hex()}"
        return None

    def _segment(self) -> bytes:
        data = self._download or b""
        chunk, self._download = data[:7], data[7:]
        last = int(not self._download)
        return bytes(((self._toggle << 4) | ((7 - len(chunk)) << 1) | last,)) + chunk.ljust(7, b"\0")

    def _finish_upload(self, data: bytes) -> None:
        self.done = True
        entry = self._entry
        if entry is not None and entry.data_type == "VISIBLE_STRING":
            self.answer = data.decode("ascii", "replace")
        elif entry is not None and DATA_TYPES[entry.data_type][2] and len(data) == struct.calcsize(
                "<" + DATA_TYPES[entry.data_type][2]):
            self.answer = struct.unpack("<" + DATA_TYPES[entry.data_type][2], data)[0]
        else:
            self.answer = int.from_bytes(data, "little")


# ---------------------------------------------------------------------------- the two halves
#: what became of a slot (:meth:`AsyncNodes.slot`): the MN's frame went out ("taken"), a node
#: answered ("answer", with its 8 bytes), the addressed node did not ("silent"), an EMCY had the slot
TAKEN, ANSWER, SILENT, EMCY = "taken", "answer", "silent", "emcy"


@dataclass
class _Counts:
    requests: int = 0
    answers: int = 0
    no_answer: int = 0
    aborts: dict[int, int] = field(default_factory=dict)
    nmt_commands: int = 0
    nmt_to_missing_node: int = 0
    frames: int = 0
    slots_taken_by_emcy: int = 0


class AsyncClient:
    """The managing node's half: the scripted and submitted requests, its SDO client, the
    results and counts. Per slot: :meth:`offer` (the frame it would send) before the slot,
    :meth:`outcome` after it (what happened, from :meth:`AsyncNodes.slot`), which returns the
    frames the slot carried (for the CAN log)."""

    def __init__(self, requests: Sequence[AsyncRequest], node_ids: Sequence[int], offsets: tuple[float, float],
                 t0: float, cycle_time: float, ods: Sequence[ObjectDictionary] = ()) -> None:
        self.node_ids = set(node_ids)
        self.ods = {od.node: od for od in ods}
        self._mn_offset, self._cn_offset = offsets
        self._t0, self._cycle_time = t0, cycle_time
        self._script = deque(requests)
        self._queue: deque[tuple[AsyncRequest, AsyncResult | None]] = deque()
        self._transfer: _Transfer | None = None
        self._result: AsyncResult | None = None
        self._frame: tuple[int, bytes] | None = None  # the frame offered and not yet sent
        # the request the offered frame starts (None: a segment) and its result if made at submit
        self._offered: tuple[AsyncRequest, AsyncResult | None] | None = None
        self.now_s = t0  # the time of the last slot
        self.on_submit: Callable[[], None] | None = None  # told when a request is queued
        self.awaiting = False  # a request went out: the node answers in the next slot
        self.results: list[AsyncResult] = []
        self.counts = _Counts()
        self.next_cycle: float = self._idle_next()

    def _idle_next(self) -> float:
        if self._queue or self._transfer is not None or self._frame is not None or self.awaiting:
            return 0
        if self._script:
            return max(0, math.ceil((self._script[0].time_s - self._t0) / self._cycle_time - 1e-9))
        return math.inf

    def submit(self, request: AsyncRequest) -> AsyncResult:
        """Queue a request (a controller's): offered in the first slot from now on that is free.
        Returns its result, filled in when it is sent (``sent_cycle``) and answered
        (``answered_cycle``, ``answer``, ``abort``)."""
        result = AsyncResult(request, -1)
        self._queue.append((request, result))
        self.next_cycle = 0
        if self.on_submit is not None:
            self.on_submit()
        return result

    def offer(self, cycle: int) -> tuple[int, bytes] | None:
        """The frame (COB-ID, data) the MN sends in the slot of ``cycle`` if the slot is free
        for it; None when it has none or a node's answer is due in it."""
        t = self._t0 + cycle * self._cycle_time
        self.now_s = t
        while self._script and self._script[0].time_s <= t + 1e-12:
            self._queue.append((self._script.popleft(), None))
        if self.awaiting:
            return None
        if self._frame is None and self._queue:
            request, result = self._queue.popleft()
            if request.service == "nmt":
                self._frame = (NMT_ID, bytes((NMT_BY_NAME[request.command], request.node)))
            else:
                self._transfer = _Transfer(request, self.ods.get(request.node))
                self._frame = (SDO_RX_BASE + request.node, self._transfer.first())
            self._offered = (request, result)
        return self._frame

    def outcome(self, cycle: int, kind: str | None, data: bytes | None = None) -> list[can.Message]:
        """Take what the slot of ``cycle`` carried; returns its frames (MN frame or answer)."""
        t = self._t0 + cycle * self._cycle_time
        self.now_s = t
        out: list[can.Message] = []
        if kind == EMCY:
            self.counts.slots_taken_by_emcy += 1
        elif kind == TAKEN and self._frame is not None:
            cob, payload = self._frame
            out.append(FastMessage(t + self._mn_offset, cob, bytearray(payload)))
            self._frame = None
            offered, self._offered = self._offered, None
            if offered is not None:
                request, result = offered
                self.counts.requests += 1
                if result is None:
                    result = AsyncResult(request, cycle)
                result.sent_cycle = cycle
                self.results.append(result)
                if request.service == "nmt":
                    self.counts.nmt_commands += 1
                    missing = request.node != 0 and request.node not in self.node_ids
                    self.counts.nmt_to_missing_node += missing  # no node reacts (CiA 301)
                    result.answer, result.answered_cycle = ("no node" if missing else "ok"), cycle
                else:
                    self._result = result
            if cob != NMT_ID:
                self.awaiting = True
        elif kind in (ANSWER, SILENT) and self.awaiting and self._transfer is not None:
            self.awaiting = False
            transfer, result = self._transfer, self._result
            assert result is not None
            if kind == SILENT:
                self.counts.no_answer += 1
                result.answer, result.answered_cycle = "no answer", cycle
                self._transfer = self._result = None
            else:
                answer = bytes(data or b"")
                out.append(FastMessage(t + self._cn_offset, SDO_TX_BASE + transfer.request.node, bytearray(answer)))
                self.counts.answers += 1
                following = transfer.take(answer)
                if transfer.done:
                    result.answered_cycle, result.answer, result.abort = cycle, transfer.answer, transfer.abort
                    if transfer.abort is not None:
                        self.counts.aborts[transfer.abort] = self.counts.aborts.get(transfer.abort, 0) + 1
                    self._transfer = self._result = None
                elif following is not None:
                    self._frame = (SDO_RX_BASE + transfer.request.node, following)
        self.counts.frames += len(out)
        self.next_cycle = cycle + 1 if (self._queue or self._transfer is not None or self._frame is not None
                                        or self.awaiting) else self._idle_next()
        return out

    def summary(self) -> dict[str, Any]:
        c = self.counts
        unknown = sum(v for k, v in c.aborts.items() if k in UNKNOWN_OBJECT_ABORTS)
        return {"requests": c.requests, "answers": c.answers, "no_answer": c.no_answer,
                "aborts": {f"0x{k:08X}": v for k, v in sorted(c.aborts.items())},
                "nmt_commands": c.nmt_commands, "frames": c.frames, "slots_taken_by_emcy": c.slots_taken_by_emcy,
                "bad_input": {"unknown_object": unknown, "nmt_to_missing_node": c.nmt_to_missing_node},
                "results": [r.as_dict() for r in self.results]}


class AsyncNodes:
    """The controlled nodes' half: one :class:`CanopenNode` per drive (NMT, SDO server, EMCY
    history), the set-points held while a node takes no PDO. :meth:`slot` decides each slot.

    Args:
        ods: the nodes' object dictionaries (node ids 1..N).
        abort_connection_option: "fault" or "quick_stop" (what NMT stop presents to the drive).
        on_write: ``on_write(node, entry, value)`` for every value an SDO download or a reset
            changes (bus unit), in the slot the answer is sent; may raise ``SdoAbort``.
        scaling: a :class:`fieldbus.scaling.JointScaling` (actual values into the dictionary
            before an SDO request is handled), or None.
        invalidate: called after the held set-points were written into the applied arrays (the
            bus's ``ControlledNodes.invalidate_applied``: its next cycle writes every field).
    """

    def __init__(self, ods: Sequence[ObjectDictionary], t0: float = 0.0, abort_connection_option: str = "fault",
                 on_write: Callable[[int, Entry, Any], None] | None = None, scaling: Any = None,
                 invalidate: Callable[[], None] | None = None) -> None:
        self.on_write = on_write
        self.invalidate = invalidate
        self.nodes: dict[int, CanopenNode] = {}
        for od in ods:
            node = CanopenNode(od.node, od, on_write=self._writer(od.node))
            node.boot(t0)
            node._enter("operational")  # started by the MN before cycle 0 (module docstring)
            self.nodes[od.node] = node
        self._quick_stop = abort_connection_option == "quick_stop"
        self._held: dict[int, dict[str, Any]] = {}  # node -> set-points it holds (not operational)
        self._pending: tuple[int, bytes] | None = None  # the SDO request a node answers in the next slot
        self.scaling = scaling

    def _writer(self, node_id: int) -> Callable[[Entry, Any], None] | None:
        if self.on_write is None:
            return None

        def write(entry: Entry, value: Any) -> None:
            self.on_write(node_id, entry, value)  # type: ignore[misc]
        return write

    @property
    def owes_answer(self) -> bool:
        """An SDO request went out: its node answers in the next slot."""
        return self._pending is not None

    @property
    def busy(self) -> bool:
        """An SDO request waits for its answer, or a node holds its set-points."""
        return self._pending is not None or bool(self._held)

    def slot(self, cycle: int, t: float, applied: Any, actuals: Any, offer: tuple[int, bytes] | None,
             emcy_sent: bool = False) -> tuple[str, bytes | None] | None:
        """The slot of ``cycle`` (SoC at ``t``), after its isochronous part: the set-points of
        nodes that take no PDO are held (in ``applied``), then the slot goes to an EMCY sent in
        it, else to the answer of the pending SDO request, else to the MN's ``offer``. Returns
        (kind, answer bytes) or None (nothing was due)."""
        if self._held:
            self._hold(applied)
        pending = self._pending
        if emcy_sent:
            return (EMCY, None) if (offer is not None or pending is not None) else None
        if pending is not None:
            self._pending = None
            cob, data = pending
            node = self.nodes.get(cob - SDO_RX_BASE)
            if node is None:
                return SILENT, None
            if actuals is not None and self.scaling is not None:
                self._latch(node.node_id, actuals)
            request = FastMessage(t, cob, bytearray(data))
            answers = node.receive(request, t)
            return (ANSWER, bytes(answers[0].data)) if answers else (SILENT, None)
        if offer is None:
            return None
        cob, data = offer
        if cob == NMT_ID:
            msg = FastMessage(t, NMT_ID, bytearray(data))
            for node_id, node in self.nodes.items():
                before = node.nmt_state
                node.receive(msg, t)  # a reset's boot-up message stays off POWERLINK: the PRes carries the state
                self._state_changed(node_id, before, node.nmt_state, applied)
        else:
            self._pending = offer
        return TAKEN, None

    def _latch(self, node_id: int, actuals: Any) -> None:
        """The drive's actual values at this SoC into its dictionary (what an upload of
        0x6041, 0x6064, 0x606C, 0x6077, 0x603F reads)."""
        values, i, s = self.nodes[node_id].sdo.values, node_id - 1, self.scaling
        if i >= len(actuals.position):
            return
        values[(0x6041, 0)] = int(actuals.statusword[i]) & 0xFFFF
        values[(0x6064, 0)] = s.position_count(i, float(actuals.position[i]))
        values[(0x606C, 0)] = s.velocity_count(i, float(actuals.velocity[i]))
        values[(0x6077, 0)] = s.torque_unit(i, float(actuals.torque[i]))
        values[(0x603F, 0)] = int(actuals.error_code[i]) & 0xFFFF

    def _state_changed(self, node_id: int, before: str, after: str, applied: Any) -> None:
        if after == "operational":
            self._held.pop(node_id, None)
        elif before == "operational" or node_id not in self._held:
            i = node_id - 1
            self._held[node_id] = {name: getattr(applied, name)[i] for name in _HELD
                                   if getattr(applied, name, None) is not None}

    def _hold(self, applied: Any) -> None:
        for node_id, held in self._held.items():
            i = node_id - 1
            for name, value in held.items():
                getattr(applied, name)[i] = value
            applied.fresh[i] = False
            if self.nodes[node_id].nmt_state == "stopped":  # CiA 402 0x6007: abort connection
                if self._quick_stop:
                    applied.controlword[i] = QUICK_STOP_CONTROLWORD
                elif not applied.fault_code[i]:
                    applied.fault_code[i] = ABORT_CONNECTION_FAULT
        if self.invalidate is not None:
            self.invalidate()

    def note_emcy(self, frames: Sequence[Any]) -> None:
        """EMCY frames the nodes sent (fieldbus.nodes): into each node's error register 0x1001
        and error history 0x1003 (what an SDO upload of them reads)."""
        for msg in frames:
            node = self.nodes.get(msg.arbitration_id - 0x080)
            if node is not None and len(msg.data) >= 3:
                node.emcy(msg.data[0] | (msg.data[1] << 8), msg.data[2], msg.timestamp)

    def summary(self) -> dict[str, Any]:
        return {"malformed_sdo": sum(n.sdo.malformed for n in self.nodes.values()),
                "nmt_state": {str(k): n.nmt_state for k, n in self.nodes.items()}}


class AsyncPort:
    """What a controller gets as ``info.asynchronous`` (controller/contract.py): it queues SDO
    and NMT requests for the asynchronous slot, and each call returns the request's
    :class:`AsyncResult`, filled in when the request went out (``sent_cycle``) and when its
    answer came back (``answered_cycle``; ``answer``, or ``abort`` the CiA 301 abort code): at
    the earliest in the cycle after the request went out, which is the cycle after the call.
    Values are in the object's bus unit (fieldbus/object_dictionary.toml)."""

    def __init__(self, client: AsyncClient) -> None:
        self._client = client

    def _submit(self, node: int, service: str, **kwargs: Any) -> AsyncResult:
        return self._client.submit(AsyncRequest(self._client.now_s, node, service, origin="controller", **kwargs))

    def sdo_read(self, node: int, index: int, subindex: int = 0) -> AsyncResult:
        """An SDO upload of ``index``/``subindex`` from ``node``."""
        return self._submit(node, "read", index=index, subindex=subindex)

    def sdo_write(self, node: int, index: int, subindex: int, value: int | str) -> AsyncResult:
        """An SDO download of ``value`` (bus unit) to ``index``/``subindex`` of ``node``."""
        return self._submit(node, "write", index=index, subindex=subindex, value=value)

    def nmt(self, node: int, command: str) -> AsyncResult:
        """The NMT ``command`` (one of :data:`NMT_BY_NAME`) to ``node`` (0: every node)."""
        if command not in NMT_BY_NAME:
            raise ValueError(f"nmt command = {command!r}: expected one of {', '.join(NMT_BY_NAME)}")
        return self._submit(node, "nmt", command=command)

    @property
    def results(self) -> list[AsyncResult]:
        """Every request sent so far (the scenario's too), oldest first."""
        return self._client.results


def merged_summary(client: dict[str, Any], nodes: dict[str, Any] | None) -> dict[str, Any]:
    """One summary of the two halves (summary.json ``fieldbus.asynchronous``)."""
    out = dict(client)
    out["bad_input"] = {"malformed_sdo": (nodes or {}).get("malformed_sdo"), **client["bad_input"]}
    out["nmt_state"] = (nodes or {}).get("nmt_state")
    results = out.pop("results")
    out["results"] = results
    return out


class AsynchronousPhase:
    """Both halves in one process (the in-process and paced cell): :meth:`run` is one slot."""

    def __init__(self, client: AsyncClient, nodes: AsyncNodes, t0: float, cycle_time: float) -> None:
        self.client, self.nodes = client, nodes
        self._t0, self._cycle_time = t0, cycle_time

    @property
    def next_cycle(self) -> float:
        return 0 if self.nodes.busy else self.client.next_cycle

    def run(self, cycle: int, applied: Any, actuals: Any = None, emcy_sent: bool = False) -> list[can.Message]:
        """The slot of ``cycle``; returns the frames it carried (for the CAN log)."""
        client = self.client
        offer = client.offer(cycle) if cycle >= client.next_cycle else None
        outcome = self.nodes.slot(cycle, self._t0 + cycle * self._cycle_time, applied, actuals, offer, emcy_sent)
        if outcome is None:
            return []
        return client.outcome(cycle, *outcome)

    def submit(self, request: AsyncRequest) -> AsyncResult:
        return self.client.submit(request)

    @property
    def results(self) -> list[AsyncResult]:
        return self.client.results

    def note_emcy(self, frames: Sequence[Any]) -> None:
        self.nodes.note_emcy(frames)

    def summary(self) -> dict[str, Any]:
        return merged_summary(self.client.summary(), self.nodes.summary())


def slot_offsets(layout: Any, node: int = 0) -> tuple[float, float]:
    """(MN frame, CN frame) start after the SoC, s, from the cycle layout (fieldbus.timing): the
    SoA leaves ``mn_turnaround`` after the last PRes has arrived; the MN's own ASnd follows it
    after another turnaround, an invited CN's ASnd ``cn_response`` after the SoA has arrived
    (the instant the EMCYs of fieldbus.endpoints use)."""
    soa_end = layout.nominal_end_of_isochronous + layout.mn_turnaround + layout.wire_soa
    return soa_end + layout.mn_turnaround, soa_end + layout.cn_response


__all__ = ["ANSWER", "AsyncClient", "AsyncPort", "AsyncNodes", "AsyncRequest", "AsyncResult", "AsynchronousPhase", "EMCY",
           "NMT_BY_NAME", "SERVICES", "SILENT", "TAKEN", "merged_summary", "parse_requests", "slot_offsets"]
