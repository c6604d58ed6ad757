"""The wire-format reference, generated from the code: the tables of docs/reference/fieldbus.md.

The docs site's hook (mkdocs_hooks.py) puts each table in place of its marker line when the
site is built, so the page's offsets, sizes, identifiers, bit positions and units are those of
the structs and constants the bus packs with (``fieldbus.telegrams``, ``fieldbus.udpcycle``,
``fieldbus.canopen_node``, ``fieldbus.sdo``) and of the drives' object dictionary, never a copy.
The words of each field are here, next to the struct they describe; a struct whose field count
no longer matches its words raises :class:`ValueError` and fails the site build.
"""
from __future__ import annotations

import re
import struct
from collections.abc import Sequence

from fieldbus import canopen_node, sdo, telegrams, udpcycle
from fieldbus.nodes import COUNTER_IDS
from fieldbus.object_dictionary import ObjectDictionary

_TYPES = {"B": "u8", "b": "i8", "H": "u16", "h": "i16", "I": "u32", "i": "i32", "Q": "u64", "q": "i64",
          "d": "f64", "f": "f32"}
_ORDER = {"<": "little-endian", ">": "big-endian (network order)", "!": "big-endian (network order)"}


def layout(fmt: struct.Struct | str, words: Sequence[tuple[str, str]]) -> list[tuple[int, int, str, str, str]]:
    """(first byte, last byte, type, field, meaning) of each item of the struct format ``fmt``,
    named by ``words`` = [(field, meaning), ...], one per item."""
    text = fmt.format if isinstance(fmt, struct.Struct) else fmt
    order, items = text[0], re.findall(r"(\d*)([a-zA-Z?])", text[1:])
    codes = [(int(n or 1), c) if c == "s" else (1, c) for n, c in items for _ in range(1 if c == "s" else int(n or 1))]
    if len(codes) != len(words):
        raise ValueError(f"struct {text!r} has {len(codes)} fields, the reference names {len(words)}: "
                         f"{[w for w, _ in words]}")
    rows, offset = [], 0
    for (count, code), (field, meaning) in zip(codes, words):
        size = struct.calcsize(order + (f"{count}s" if code == "s" else code))
        kind = f"{count} bytes" if code == "s" else _TYPES[code]
        rows.append((offset, offset + size - 1, kind, field, meaning))
        offset += size
    return rows


def _table(rows: list[tuple[int, int, str, str, str]]) -> list[str]:
    out = ["| bytes | type | field | meaning |", "|---|---|---|---|"]
    for first, last, kind, field, meaning in rows:
        span = str(first) if first == last else f"{first}–{last}"
        out.append(f"| {span} | {kind} | {field} | {meaning} |")
    return out


# ------------------------------------------------------------------------ CAN identifiers
def identifiers_markdown() -> str:
    """The COB-IDs of every frame on the bus, from the constants the nodes send with."""
    t = telegrams
    rows = [
        ("NMT command", canopen_node.NMT_ID, False, "master → nodes", "2",
         "asynchronous slot after the SoA (docs/how-to/sdo_nmt.md); `cosim serve` CANopen side"),
        ("SYNC", t.SYNC_ID, False, "managing node → all", "0 or 1 (counter)", "the POWERLINK SoC: starts cycle k at t_k"),
        ("EMCY", t.EMCY_BASE, True, "node → managing node", str(t.EMCY.size), "asynchronous slot after the SoA"),
        ("TPDO1", t.TPDO1_BASE, True, "node → managing node", str(t.TPDO1.size), "PRes payload, part 1"),
        ("RPDO1", t.RPDO1_BASE, True, "managing node → node",
         f"{t.RPDO1_SIGNED.size} (CAN FD; {t.RPDO1_CLASSIC.size} classic; "
         f"{', '.join(map(str, t.RPDO1_LOOKAHEAD_LENGTHS))} with look-ahead)", "PReq payload"),
        ("TPDO2", t.TPDO2_BASE, True, "node → managing node",
         f"{t.TPDO2.size} ({t.TPDO2_BUFFERED.size} with a set-point buffer)", "PRes payload, part 2"),
        ("SDO response", sdo.SDO_TX_BASE, True, "node → client", "8", "asynchronous slot; `cosim serve` CANopen side"),
        ("SDO request", sdo.SDO_RX_BASE, True, "client → node", "8", "asynchronous slot; `cosim serve` CANopen side"),
        ("heartbeat", canopen_node.HEARTBEAT_BASE, True, "node → all", "1 (NMT state)", "CANopen devices only"),
    ]
    out = ["| frame | COB-ID | direction | data bytes | role |", "|---|---|---|---|---|"]
    for name, base, per_node, direction, size, role in rows:
        cob = f"0x{base:03X} + node" if per_node else f"0x{base:03X}"
        out.append(f"| {name} | {cob} | {direction} | {size} | {role} |")
    out += ["", f"Node ids 1–{t.MAX_NODE_ID}; the drive of axis *i* is node *i*. Process data are "
                f"{_ORDER[t.TPDO1.format[0]]}."]
    return "\n".join(out) + "\n"


# ------------------------------------------------------------------------------ telegrams
def _pdo_rows(od: ObjectDictionary, name: str) -> list[str]:
    pdo = next(p for p in od.pdos if p.name == name)
    out = [f"**{pdo.name}** (COB-ID 0x{pdo.cob_id - od.node:03X} + node, {pdo.length} bytes): {pdo.description}.",
           "", "| bytes | object | field | type | bus unit | SI per bus unit (axis 1) |", "|---|---|---|---|---|---|"]
    for f in pdo.fields:
        first, last = f.offset // 8, (f.offset + f.bits) // 8 - 1
        span = str(first) if first == last else f"{first}–{last}"
        if f.entry is None:
            out.append(f"| {span} | — | reserved (0) | UNSIGNED{f.bits} | | |")
            continue
        scale, unit = od.physical_scale(f.entry)
        si = f"{scale:.6g} {unit}" if f.entry.quantity else ""
        out.append(f"| {span} | 0x{f.index:04X} | {f.name} | {f.entry.data_type} | {f.entry.unit} | {si} |")
    return out


#: The fields of one look-ahead entry of the RPDO1 (``telegrams.RPDO1_LOOKAHEAD_ENTRY``).
LOOKAHEAD_ENTRY_WORDS = (
    ("set-point", "the active mode's set-point: target position 0x607A (mode 8, counts), target velocity "
                  "0x60FF (mode 9, counts/s) or target torque 0x6071 (mode 10, 0.1 % rated, sign-extended)"),
    ("torque offset", "0x60B2, 0.1 % rated torque"),
    ("velocity offset", "0x60B1, counts/s"),
)

def _counter_words(key: str) -> str:
    words = {"soc": "SoC", "preq": "PReq", "crc": "CRC"}
    return " ".join(words.get(w, w) for w in key.removeprefix("cn_").split("_"))


#: The fields of an EMCY frame (``telegrams.EMCY``).
EMCY_WORDS = (
    ("error code", f"0x{telegrams.EMCY_COMMUNICATION:04X}: communication (a threshold counter tripped); "
                   "else the drive's error code 0x603F; 0x0000: error reset"),
    ("error register", "0x1001: bit 0 generic, bit 1 current (0x2xxx), bit 4 communication, "
                       "bit 5 device profile (0x8xxx)"),
    ("counter", "manufacturer specific: the threshold counter that tripped ("
                + ", ".join(f"{n} {_counter_words(k)}" for k, n in sorted(COUNTER_IDS.items(), key=lambda kv: kv[1]))
                + "); 0 for a drive error"),
    ("counter value", "manufacturer specific: its value (0 for a drive error)"),
    ("threshold", "manufacturer specific: its threshold (0 for a drive error)"),
)


def telegrams_markdown(od: ObjectDictionary) -> str:
    """The PDO layouts of ``od`` (axis 1's drive), the look-ahead entry, the set-point buffer
    fields and the EMCY frame."""
    t = telegrams
    out = _pdo_rows(od, "RPDO1") + [""] + _pdo_rows(od, "TPDO1") + [""] + _pdo_rows(od, "TPDO2")
    out += ["", f"**Classic RPDO1**: bytes 0–{t.RPDO1_CLASSIC.size - 1} of the RPDO1 alone, accepted from a "
                "controller on classic CAN; read as mode 8 with target torque, target velocity and velocity "
                "offset 0.", ""]
    entry = layout(t.RPDO1_LOOKAHEAD_ENTRY, LOOKAHEAD_ENTRY_WORDS)
    out += [f"**RPDO1 with look-ahead** (`[fieldbus] setpoint_lookahead = k`, 1 ≤ k ≤ {t.MAX_LOOKAHEAD}): "
            f"byte 9 holds k; entry j (1..k) starts at byte {t.RPDO1_SIGNED.size} + "
            f"{t.RPDO1_LOOKAHEAD_ENTRY.size} (j − 1) and is for the j-th cycle after the RPDO1's own set-point; "
            f"zero padding to the CAN FD length ({', '.join(map(str, t.RPDO1_LOOKAHEAD_LENGTHS))} bytes). "
            "One entry:", ""]
    out += _table(entry)
    skip = t.RPDO1_BUFFER_SKIP_OFFSET
    out += ["", f"**Set-point buffer** (`[fieldbus] setpoint_buffer = D`, up to {t.MAX_SETPOINT_BUFFER}): the "
                f"RPDO1 is {t.RPDO1_MAX_BYTES} bytes and bytes {skip}–{skip + t.RPDO1_BUFFER_SKIP.size - 1} "
                f"hold the entry skip s (u16): entry j is for the cycle s + j after the RPDO1's own set-point. "
                f"The TPDO2 is {t.TPDO2_BUFFERED.size} bytes; byte {t.TPDO2.size} (u8, 0x60C4 sub 2) is F: after "
                "this cycle's PReq the drive holds the set-points for the SoCs up to cycle + F.", ""]
    out += [f"**EMCY** ({t.EMCY.size} bytes):", ""] + _table(layout(t.EMCY, EMCY_WORDS))
    return "\n".join(out) + "\n"


# ------------------------------------------------------------------------------- udpcycle
def _bit(mask: int) -> int:
    return mask.bit_length() - 1


#: The fields of a udpcycle datagram header (``udpcycle.HEADER``).
HEADER_WORDS = (
    ("magic", f"ASCII `{udpcycle.MAGIC.decode()}`"),
    ("version", str(udpcycle.VERSION)),
    ("flags", "0 (reserved)"),
    ("n", "number of frames that follow"),
    ("sender id", "random per bus unless the option `sender_id` gives it; a bus ignores its own"),
    ("sequence", "+1 per datagram of this sender, wraps at 2³²"),
    ("send time", "ns since the epoch: the sender's wall clock when it sent the datagram"),
)

#: The fields of one frame in a udpcycle datagram (``udpcycle.FRAME``), followed by its data.
FRAME_WORDS = (
    ("can id", f"bits 0–{udpcycle.ID_MASK.bit_length() - 1} identifier, bit {_bit(udpcycle.ID_EXTENDED)} "
               f"extended id, bit {_bit(udpcycle.ID_REMOTE)} remote, bit {_bit(udpcycle.ID_ERROR)} error frame"),
    ("length", f"data bytes, 0–{udpcycle.MAX_DATA}"),
    ("flags", f"bit {_bit(udpcycle.FLAG_FD)} CAN FD, bit {_bit(udpcycle.FLAG_BRS)} bit-rate switch, "
              f"bit {_bit(udpcycle.FLAG_ESI)} error-state indicator"),
    ("reserved", "0"),
    ("timestamp", "seconds: the frame's time as its sender stamps it (simulated time on our nodes)"),
)


def udpcycle_options_markdown() -> str:
    """The options of :class:`fieldbus.udpcycle.UdpCycleBus` (a scenario's ``[fieldbus.bus.options]``),
    from its signature (defaults) and the ``Args:`` of its docstring (meanings)."""
    import inspect

    defaults = {name: p.default for name, p in inspect.signature(udpcycle.UdpCycleBus.__init__).parameters.items()
                if p.kind is p.KEYWORD_ONLY or name == "channel"}
    doc = inspect.getdoc(udpcycle.UdpCycleBus) or ""
    args = doc.split("Args:", 1)[1] if "Args:" in doc else ""
    entries: list[list[str]] = []
    for line in args.splitlines():
        m = re.match(r"^    (\w[\w, ]*):\s*(.*)$", line)
        if line.startswith("        ") and entries:
            entries[-1][1] = (entries[-1][1] + " " + line.strip()).strip()
        elif m:
            entries.append([m.group(1), m.group(2)])
    out = ["| option | default | meaning |", "|---|---|---|"]
    for names, meaning in entries:
        keys = [n.strip() for n in names.split(",")]
        missing = [k for k in keys if k not in defaults]
        if missing:
            raise ValueError(f"UdpCycleBus docstring names {missing}, not parameters of its constructor")
        shown = ", ".join("required" if defaults[k] is inspect.Parameter.empty or defaults[k] is None and k == "channel"
                          else f"`{defaults[k]!r}`" for k in keys)
        text = re.sub(r":\w+:`([^`]+)`", r"`\1`", meaning.replace("``", "`")).replace("|", "/")
        out.append(f"| {', '.join(f'`{k}`' for k in keys)} | {shown} | {text} |")
    return "\n".join(out) + "\n"


def udpcycle_markdown() -> str:
    """The datagram layout of the ``udpcycle`` interface."""
    header, frame = udpcycle.HEADER, udpcycle.FRAME
    out = [f"Version {udpcycle.VERSION}, all integers {_ORDER[header.format[0]]}. "
           f"A datagram is a {header.size}-byte header:", ""]
    out += _table(layout(header, HEADER_WORDS))
    out += ["", f"then n frames, each {frame.size} bytes followed by its `length` data bytes:", ""]
    out += _table(layout(frame, FRAME_WORDS))
    out += [f"| {frame.size}… | bytes | data | `length` bytes |",
            "", f"A datagram holds at most {udpcycle.MAX_DATAGRAM} bytes."]
    return "\n".join(out) + "\n"


__all__ = ["identifiers_markdown", "layout", "telegrams_markdown", "udpcycle_markdown", "udpcycle_options_markdown"]
