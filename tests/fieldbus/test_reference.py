"""The generated wire-format reference (fieldbus/reference.py, shown on docs/reference/fieldbus.md)
says what the bus really sends: bytes read at the documented offsets give back what was encoded."""
from __future__ import annotations

import struct

import can
import pytest

from fieldbus import reference, telegrams, udpcycle
from fmus.servo_drive.object_dictionary import drive_object_dictionary


def _fields(rows, data: bytes) -> dict[str, bytes]:
    return {field: data[first:last + 1] for first, last, _, field, _ in rows}


def test_udpcycle_datagram_read_at_the_documented_offsets():
    msgs = [can.Message(arbitration_id=0x201, data=bytes(range(20)), is_fd=True, is_extended_id=False, timestamp=0.25),
            can.Message(arbitration_id=0x1ABCDEF, data=b"\x07", is_extended_id=True, timestamp=0.5)]
    payload = udpcycle.encode_datagram(msgs, sender=0xCAFE, sequence=7, send_time_ns=123_456_789)
    header = reference.layout(udpcycle.HEADER, reference.HEADER_WORDS)
    got = _fields(header, payload)
    assert got["magic"] == b"RXCB" and got["version"] == b"\x01"
    assert int.from_bytes(got["n"], "big") == 2 and int.from_bytes(got["sender id"], "big") == 0xCAFE
    assert int.from_bytes(got["sequence"], "big") == 7 and int.from_bytes(got["send time"], "big") == 123_456_789
    frame = reference.layout(udpcycle.FRAME, reference.FRAME_WORDS)
    at = header[-1][1] + 1
    for msg in msgs:
        f = _fields(frame, payload[at:])
        can_id = int.from_bytes(f["can id"], "big")
        assert can_id & udpcycle.ID_MASK == msg.arbitration_id
        assert bool(can_id >> 31) == msg.is_extended_id
        assert f["length"][0] == len(msg.data) and bool(f["flags"][0] & 1) == msg.is_fd
        assert struct.unpack(">d", f["timestamp"])[0] == msg.timestamp
        start = at + frame[-1][1] + 1
        assert payload[start:start + len(msg.data)] == msg.data
        at = start + len(msg.data)
    assert at == len(payload)


def test_pdo_tables_give_the_offsets_the_telegrams_pack():
    data = telegrams.encode_rpdo1(0x000F, -123456, -50, 9, target_torque=-7, target_velocity=4242,
                                  velocity_offset=-99)
    page = reference.telegrams_markdown(drive_object_dictionary(1))
    rows = {}
    for line in page.splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) == 6 and cells[1].startswith("0x6"):
            span = [int(x) for x in cells[0].split("–")]
            rows.setdefault(cells[2], (span[0], span[-1]))
    assert rows["controlword"] == (0, 1) and rows["target_position"] == (2, 5)
    for field, value, fmt in (("controlword", 0x000F, "<H"), ("target_position", -123456, "<i"),
                              ("torque_offset", -50, "<h"), ("modes_of_operation", 9, "<b"),
                              ("target_torque", -7, "<h"), ("target_velocity", 4242, "<i"),
                              ("velocity_offset", -99, "<i")):
        first, last = rows[field]
        assert struct.unpack(fmt, data[first:last + 1])[0] == value, field


def test_a_struct_that_no_longer_matches_its_words_fails_loudly():
    with pytest.raises(ValueError, match=r"struct '>4sBH' has 3 fields, the reference names 2"):
        reference.layout(">4sBH", [("magic", ""), ("version", "")])
    assert [r[:3] for r in reference.layout("<4sHb", [("a", ""), ("b", ""), ("c", "")])] == \
        [(0, 3, "4 bytes"), (4, 5, "u16"), (6, 6, "i8")]


def test_identifiers_are_the_nodes_constants():
    page = reference.identifiers_markdown()
    for name, base in (("SYNC", telegrams.SYNC_ID), ("RPDO1", telegrams.RPDO1_BASE), ("TPDO1", telegrams.TPDO1_BASE),
                       ("TPDO2", telegrams.TPDO2_BASE)):
        assert f"| {name} | 0x{base:03X}" in page


def test_every_udpcycle_option_is_in_the_options_table():
    import inspect

    page = reference.udpcycle_options_markdown()
    options = [n for n, p in inspect.signature(udpcycle.UdpCycleBus.__init__).parameters.items()
               if p.kind is p.KEYWORD_ONLY]
    # the socket's buffer size is the one option the docstring leaves out (an implementation detail)
    missing = [n for n in options if f"`{n}`" not in page and n != "receive_buffer_bytes"]
    assert not missing, missing
    assert "| `fault_seed`" not in page and "`fault_seed` | `0.0`, `0.0`, `0.0`, `0.0`, `0` |" in page
