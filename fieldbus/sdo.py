"""A CiA 301 SDO server for one drive node, answering from its object dictionary.

:class:`SdoServer` turns an SDO request (the 8 data bytes a client sends on COB-ID 0x600 + node)
into the response the node sends on 0x580 + node, reading and writing the values of the node's
:class:`~fieldbus.object_dictionary.ObjectDictionary` (its defaults to start with):

* expedited download (initiate download with e = 1: 1 to 4 data bytes), confirmed with 0x60;
* segmented download (initiate with e = 0 and the size, then 7-byte segments with the toggle
  bit, each confirmed), checked and applied when the last segment (c = 1) has arrived;
* upload, expedited for values of up to 4 bytes and segmented (initiate with the size, then
  7-byte segments with the toggle bit) for longer ones (the device name 0x1008);
* an abort (command 0x80) with the CiA 301 abort code for what it cannot do:

==========  ==========================================================================
0x05030000  toggle bit not alternated (segmented upload)
0x05040001  command specifier not valid or unknown (also a request that is not 8 bytes long,
            a segment without an initiated transfer, block transfers)
0x06010001  attempt to read a write-only object
0x06010002  attempt to write a read-only object
0x06020000  object does not exist in the object dictionary
0x06040041  object cannot be mapped to the PDO (raised by ``on_write``, fieldbus/canopen_node.py)
0x06040042  number and length of the objects to be mapped would exceed the PDO length (idem)
0x06040043  general parameter incompatibility (idem: a mapping the bus's fixed telegrams do not carry)
0x06070010  data type does not match, length of service parameter does not match
0x06090011  sub-index does not exist
0x06090030  invalid value for parameter (outside the data type's range)
0x06090031  value of parameter written too high (above the object's high limit)
0x06090032  value of parameter written too low (below the object's low limit)
0x08000022  data cannot be transferred because of the present device state (PDO
            communication or mapping parameters written in NMT state operational)
==========  ==========================================================================

In NMT state stopped the server does not answer (CiA 301: SDO is not available there); a
client's abort is taken without an answer. ``on_write(entry, value)``, if given, is called for
every accepted download (what applies a new limit or gain to the drive); it may raise
:class:`SdoAbort` to refuse the value. Counters: ``requests``, ``transfers`` (completed
uploads and downloads), ``malformed`` (not 8 bytes, an unknown command specifier, a segment
without a transfer), ``aborts`` (by code).

This is the server alone: it answers the requests handed to it (``tests/fieldbus/test_sdo.py``
drives it with the ``canopen`` library's SDO client over a python-can bus).
:class:`fieldbus.canopen_node.CanopenNode` puts it on the bus with the node's NMT state machine.
"""
from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

from fieldbus.object_dictionary import DATA_TYPES, Entry, ObjectDictionary

SDO_RX_BASE = 0x600  # client -> server (request)
SDO_TX_BASE = 0x580  # server -> client (response)

TOGGLE_NOT_ALTERNATED = 0x05030000
COMMAND_UNKNOWN = 0x05040001
READ_WRITE_ONLY = 0x06010001
WRITE_READ_ONLY = 0x06010002
NO_OBJECT = 0x06020000
LENGTH_MISMATCH = 0x06070010
NO_SUBINDEX = 0x06090011
#: the abort codes of a request naming an object or subindex the dictionary does not hold
UNKNOWN_OBJECT_ABORTS = (NO_OBJECT, NO_SUBINDEX)
INVALID_VALUE = 0x06090030
VALUE_TOO_HIGH = 0x06090031
VALUE_TOO_LOW = 0x06090032
WRONG_STATE = 0x08000022
NOT_MAPPABLE = 0x06040041
MAPPING_TOO_LONG = 0x06040042
PARAMETER_INCOMPATIBLE = 0x06040043

NMT_STATES = ("pre-operational", "operational", "stopped")


class SdoAbort(Exception):
    """An SDO transfer the server aborts with ``code``."""

    def __init__(self, code: int, index: int, subindex: int) -> None:
        super().__init__(f"SDO abort 0x{code:08X} for 0x{index:04X} sub {subindex}")
        self.code, self.index, self.subindex = code, index, subindex


def _codec(entry: Entry) -> str | None:
    return DATA_TYPES[entry.data_type][2]


def encode_value(entry: Entry, value: Any) -> bytes:
    """The value's bytes on the bus (little endian; a string as its ASCII bytes)."""
    if entry.data_type == "VISIBLE_STRING":
        return str(value).encode("ascii")
    return struct.pack("<" + _codec(entry), value)


class SdoServer:
    """The SDO server of one node (see the module docstring). ``values`` holds every entry's
    current value, starting from the dictionary's defaults."""

    def __init__(self, od: ObjectDictionary, *, state: str = "pre-operational",
                 on_write: Callable[[Entry, Any], None] | None = None) -> None:
        self.od = od
        self.node = od.node
        self.state = state
        self.on_write = on_write
        self.values: dict[tuple[int, int], Any] = {(e.index, e.subindex): e.default for e in od.entries()}
        self.aborts: dict[int, int] = {}  # abort code -> how many were sent
        self.requests = 0
        self.transfers = 0
        self.malformed = 0
        self._upload: tuple[int, int, bytes, int] | None = None  # index, sub, remaining bytes, next toggle
        # segmented download: entry, size indicated (or None), bytes so far, next toggle
        self._download_state: tuple[Entry, int | None, bytearray, int] | None = None

    @property
    def state(self) -> str:
        return self._state

    @state.setter
    def state(self, value: str) -> None:
        if value not in NMT_STATES:
            raise ValueError(f"state = {value!r}: expected one of {NMT_STATES}")
        self._state = value

    # ------------------------------------------------------------------ the protocol
    def handle(self, request: bytes) -> bytes | None:
        """The response (8 bytes) to the request ``request``, or None (no answer)."""
        if self.state == "stopped":
            return None
        self.requests += 1
        if len(request) != 8:
            self.malformed += 1
            return self._abort(COMMAND_UNKNOWN, 0, 0)
        command = request[0]
        index, subindex = struct.unpack_from("<HB", request, 1)
        ccs = command >> 5
        try:
            if ccs == 4:  # abort transfer from the client
                self._upload = self._download_state = None
                return None
            if ccs == 1:
                return self._download(command, index, subindex, request[4:8])
            if ccs == 0:
                return self._download_segment(command, request[1:8])
            if ccs == 2:
                return self._initiate_upload(index, subindex)
            if ccs == 3:
                return self._upload_segment(command)
            if ccs > 4:
                self.malformed += ccs != 5 and ccs != 6  # 5, 6: block transfers, which this server does not take
            raise SdoAbort(COMMAND_UNKNOWN, index, subindex)
        except SdoAbort as abort:
            self._upload = self._download_state = None
            return self._abort(abort.code, abort.index, abort.subindex)

    def _abort(self, code: int, index: int, subindex: int) -> bytes:
        self.aborts[code] = self.aborts.get(code, 0) + 1
        return struct.pack("<BHBI", 0x80, index, subindex, code)

    def entry(self, index: int, subindex: int) -> Entry:
        obj = self.od.objects.get(index)
        if obj is None:
            raise SdoAbort(NO_OBJECT, index, subindex)
        for e in obj.entries:
            if e.subindex == subindex:
                return e
        raise SdoAbort(NO_SUBINDEX, index, subindex)

    def _download(self, command: int, index: int, subindex: int, data: bytes) -> bytes:
        self._upload = self._download_state = None
        entry = self.entry(index, subindex)
        expedited, size_indicated = bool(command & 0x02), bool(command & 0x01)
        if entry.access not in ("rw", "wo"):
            raise SdoAbort(WRITE_READ_ONLY, index, subindex)
        if 0x1400 <= index <= 0x1BFF and self.state == "operational":
            raise SdoAbort(WRONG_STATE, index, subindex)
        length = (entry.bits or 0) // 8
        if not expedited:
            size = struct.unpack_from("<I", data)[0] if size_indicated else None
            if size is not None and entry.bits is not None and size != length:
                raise SdoAbort(LENGTH_MISMATCH, index, subindex)
            self._download_state = (entry, size, bytearray(), 0)
            return struct.pack("<BHB4x", 0x60, index, subindex)
        if size_indicated and 4 - ((command >> 2) & 0x03) != length:
            raise SdoAbort(LENGTH_MISMATCH, index, subindex)
        self._store(entry, struct.unpack_from("<" + _codec(entry), data)[0])
        return struct.pack("<BHB4x", 0x60, index, subindex)

    def _download_segment(self, command: int, data: bytes) -> bytes:
        if self._download_state is None:
            self.malformed += 1
            raise SdoAbort(COMMAND_UNKNOWN, 0, 0)
        entry, size, received, toggle = self._download_state
        if (command >> 4) & 0x01 != toggle:
            raise SdoAbort(TOGGLE_NOT_ALTERNATED, entry.index, entry.subindex)
        received += data[:7 - ((command >> 1) & 0x07)]
        answer = bytes(((0x20 | (toggle << 4)),)) + bytes(7)
        if not command & 0x01:
            self._download_state = (entry, size, received, toggle ^ 1)
            return answer
        self._download_state = None
        if (size is not None and len(received) != size) or (entry.bits is not None
                                                             and len(received) != entry.bits // 8):
            raise SdoAbort(LENGTH_MISMATCH, entry.index, entry.subindex)
        if entry.data_type == "VISIBLE_STRING":
            try:
                value: Any = bytes(received).decode("ascii")
            except UnicodeDecodeError:
                raise SdoAbort(INVALID_VALUE, entry.index, entry.subindex) from None
        else:
            value = struct.unpack("<" + _codec(entry), received)[0]
        self._store(entry, value)
        return answer

    def _store(self, entry: Entry, value: Any) -> None:
        """Check ``value`` against the entry's limits, hand it to ``on_write``, keep it."""
        index, subindex = entry.index, entry.subindex
        if entry.low is not None and value < entry.low:
            raise SdoAbort(VALUE_TOO_LOW, index, subindex)
        if entry.high is not None and value > entry.high:
            raise SdoAbort(VALUE_TOO_HIGH, index, subindex)
        if entry.data_type != "VISIBLE_STRING" and not entry.in_range(value):
            raise SdoAbort(INVALID_VALUE, index, subindex)
        if self.on_write is not None:
            self.on_write(entry, value)
        self.values[(index, subindex)] = value
        self.transfers += 1

    def _initiate_upload(self, index: int, subindex: int) -> bytes:
        self._upload = self._download_state = None
        entry = self.entry(index, subindex)
        if entry.access == "wo":
            raise SdoAbort(READ_WRITE_ONLY, index, subindex)
        data = encode_value(entry, self.values[(index, subindex)])
        if len(data) <= 4:
            command = 0x43 | ((4 - len(data)) << 2)
            self.transfers += 1
            return struct.pack("<BHB", command, index, subindex) + data.ljust(4, b"\0")
        self._upload = (index, subindex, data, 0)
        return struct.pack("<BHBI", 0x41, index, subindex, len(data))

    def _upload_segment(self, command: int) -> bytes:
        if self._upload is None:
            self.malformed += 1
            raise SdoAbort(COMMAND_UNKNOWN, 0, 0)
        index, subindex, data, toggle = self._upload
        if (command >> 4) & 0x01 != toggle:
            raise SdoAbort(TOGGLE_NOT_ALTERNATED, index, subindex)
        chunk, rest = data[:7], data[7:]
        last = not rest
        self._upload = None if last else (index, subindex, rest, toggle ^ 1)
        self.transfers += last
        return bytes(((toggle << 4) | ((7 - len(chunk)) << 1) | int(last),)) + chunk.ljust(7, b"\0")


__all__ = ["MAPPING_TOO_LONG", "NOT_MAPPABLE", "PARAMETER_INCOMPATIBLE", "SDO_RX_BASE", "SDO_TX_BASE", "SdoAbort",
           "SdoServer", "encode_value"]
