"""The object dictionary of a virtual servo drive: CiA 301 communication area + CiA 402 profile.

One data file, ``object_dictionary.toml`` beside this module, lists every object (index,
sub-indices, data type, access, PDO mappability, unit, where its default comes from) and the
PDOs the bus sends every cycle. :func:`build` resolves it for one node: node-relative COB-IDs,
the fieldbus configuration's values (cycle time, SYNC counter overflow, set-point buffer) and
the drive's parameters, which the caller hands in as SI numbers (fieldbus imports no code of
the floors above it; ``fmus.servo_drive.object_dictionary`` passes the servo-drive FMU's start
values). From the result come:

* the PDO communication and mapping objects (0x1400/0x1600, 0x1800/0x1A00/0x1A01) and each
  PDO's byte layout (:meth:`Pdo.struct`; ``tests/fieldbus/test_object_dictionary.py`` checks it
  against what ``fieldbus.telegrams`` and the compiled codec pack),
* the device descriptions: an EDS (CiA 306, :func:`to_eds`) and a POWERLINK XDD (EPSG DS 311,
  :func:`to_xdd`),
* the signal database: a DBC of every cyclic telegram with scaling to rad, rad/s and N·m
  (:func:`to_dbc`, written with ``cantools``),
* the reference page ``docs/reference/object_dictionary.md`` (:func:`reference_markdown`).

Defaults are in the bus units (counts, 0.1 % of rated torque, ms, ...), rounded to the nearest
integer (ties upwards) from the SI value for integer objects.
"""
from __future__ import annotations

import math
import struct
import tomllib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

DATA_PATH = Path(__file__).with_name("object_dictionary.toml")
FORMAT = "rx130l-cosim object dictionary 1"

#: CiA 301 data types: name -> (data type index, bits, struct code, signed)
DATA_TYPES: dict[str, tuple[int, int | None, str | None]] = {
    "BOOLEAN": (0x0001, 1, "?"),
    "INTEGER8": (0x0002, 8, "b"),
    "INTEGER16": (0x0003, 16, "h"),
    "INTEGER32": (0x0004, 32, "i"),
    "UNSIGNED8": (0x0005, 8, "B"),
    "UNSIGNED16": (0x0006, 16, "H"),
    "UNSIGNED32": (0x0007, 32, "I"),
    "REAL32": (0x0008, 32, "f"),
    "VISIBLE_STRING": (0x0009, None, None),
    "UNSIGNED64": (0x001B, 64, "Q"),
}
ACCESS = ("ro", "wo", "rw", "const")
OBJECT_CODES = {"VAR": 7, "ARRAY": 8, "RECORD": 9}
#: the dummy mapping entry of the RPDO1's reserved byte (CiA 301: data type UNSIGNED8 as index)
DUMMY8 = (0x0005, 0x00)

_INT_RANGES = {"INTEGER8": (-(1 << 7), (1 << 7) - 1), "INTEGER16": (-(1 << 15), (1 << 15) - 1),
               "INTEGER32": (-(1 << 31), (1 << 31) - 1), "UNSIGNED8": (0, 0xFF), "UNSIGNED16": (0, 0xFFFF),
               "UNSIGNED32": (0, 0xFFFFFFFF), "UNSIGNED64": (0, (1 << 64) - 1), "BOOLEAN": (0, 1)}


class ObjectDictionaryError(ValueError):
    """The data file or a value handed in does not make a valid object dictionary."""


@dataclass(frozen=True)
class Entry:
    """One sub-index of an object (sub-index 0 for a VAR)."""

    index: int
    subindex: int
    name: str
    data_type: str
    access: str
    default: int | float | str
    pdo: bool = False
    unit: str = ""
    signal: str | None = None
    quantity: str | None = None
    source: str = ""
    node_offset: int | None = None  # default = node id + node_offset ("$NODEID+0x...") when not None
    description: str = ""
    low: int | float | None = None  # the lowest value a write may set (besides the data type's range)
    high: int | float | None = None  # the highest

    @property
    def bits(self) -> int | None:
        return DATA_TYPES[self.data_type][1]

    @property
    def data_type_index(self) -> int:
        return DATA_TYPES[self.data_type][0]

    @property
    def writable(self) -> bool:
        return self.access in ("rw", "wo")

    def in_range(self, value: int | float) -> bool:
        """Whether ``value`` fits the entry's data type."""
        if self.data_type == "REAL32":
            return isinstance(value, (int, float)) and math.isfinite(value)
        low, high = _INT_RANGES[self.data_type]
        return isinstance(value, int) and low <= value <= high


@dataclass(frozen=True)
class DictObject:
    """One object: a VAR (one entry, sub-index 0) or an ARRAY/RECORD (sub 0 = highest sub-index)."""

    index: int
    name: str
    object_type: str
    entries: tuple[Entry, ...]
    description: str = ""

    @property
    def object_code(self) -> int:
        return OBJECT_CODES[self.object_type]


@dataclass(frozen=True)
class PdoField:
    """One mapped field: the object entry (None for the dummy byte), its offset and length in bits."""

    index: int
    subindex: int
    bits: int
    offset: int
    entry: Entry | None
    name: str

    @property
    def mapping_value(self) -> int:
        """The CiA 301 mapping entry: index << 16 | sub-index << 8 | length in bits."""
        return (self.index << 16) | (self.subindex << 8) | self.bits


@dataclass(frozen=True)
class Pdo:
    """A PDO as the node sends or receives it every cycle."""

    name: str
    direction: str  # "receive" (RPDO: MN -> drive) or "transmit" (TPDO: drive -> MN)
    number: int
    cob_id: int
    transmission_type: int
    fields: tuple[PdoField, ...]
    description: str = ""

    @property
    def communication_index(self) -> int:
        return (0x1400 if self.direction == "receive" else 0x1800) + self.number - 1

    @property
    def mapping_index(self) -> int:
        return (0x1600 if self.direction == "receive" else 0x1A00) + self.number - 1

    @property
    def length(self) -> int:
        """Data bytes."""
        return sum(f.bits for f in self.fields) // 8

    @property
    def struct(self) -> struct.Struct:
        """The little-endian byte layout of the mapped fields."""
        return struct.Struct("<" + "".join(DATA_TYPES[f.entry.data_type][2] if f.entry else "B" for f in self.fields))


@dataclass(frozen=True)
class ObjectDictionary:
    """The object dictionary of one node (see the module docstring)."""

    node: int
    objects: Mapping[int, DictObject]
    pdos: tuple[Pdo, ...]
    identity: Mapping[str, Any]
    rad_per_count: float
    newton_metre_per_unit: float
    source: str = ""

    def __iter__(self) -> Iterator[DictObject]:
        return iter(self.objects[i] for i in sorted(self.objects))

    def entries(self) -> Iterator[Entry]:
        """Every entry, by index and sub-index."""
        for obj in self:
            yield from obj.entries

    def entry(self, index: int, subindex: int = 0) -> Entry:
        obj = self.objects.get(index)
        for e in obj.entries if obj else ():
            if e.subindex == subindex:
                return e
        raise KeyError(f"no object 0x{index:04X} sub {subindex} in the object dictionary")

    def pdo(self, name: str) -> Pdo:
        for p in self.pdos:
            if p.name == name:
                return p
        raise KeyError(f"no PDO {name!r}: expected one of {[p.name for p in self.pdos]}")

    def physical_scale(self, entry: Entry) -> tuple[float, str]:
        """(SI per bus unit, SI unit) of an entry with a quantity the telegrams scale (1, unit otherwise)."""
        return {"position": (self.rad_per_count, "rad"), "velocity": (self.rad_per_count, "rad/s"),
                "acceleration": (self.rad_per_count, "rad/s^2"),
                "torque": (self.newton_metre_per_unit, "N m")}.get(entry.quantity or "", (1.0, entry.unit))


# ------------------------------------------------------------------------------- building
@lru_cache(maxsize=4)
def _document(path: str) -> dict[str, Any]:
    try:
        with open(path, "rb") as handle:
            doc = tomllib.load(handle)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ObjectDictionaryError(f"{path}: cannot read the object dictionary: {exc}") from None
    if doc.get("format") != FORMAT:
        raise ObjectDictionaryError(f"{path}: key 'format' = {doc.get('format')!r}, expected {FORMAT!r}")
    return doc


def pdo_layout(name: str, *, setpoint_buffer: bool = False, path: str | Path | None = None) -> str:
    """The ``struct`` format (little endian) of the PDO ``name`` as the data file maps it, from the
    mapped objects' data types alone (no node, no parameters): what ``fieldbus.telegrams`` packs.
    ``setpoint_buffer``: with the entries mapped when ``[fieldbus] setpoint_buffer > 0``."""
    where = str(Path(path or DATA_PATH))
    doc = _document(where)
    objects = {o.get("index"): o for o in doc.get("objects", [])}
    for item in doc.get("pdos", []):
        if item.get("name") != name:
            continue
        codes = []
        for text in list(item.get("map", [])) + (list(item.get("with_setpoint_buffer", [])) if setpoint_buffer else []):
            if text == "dummy8":
                codes.append("B")
                continue
            index_text, _, sub_text = str(text).partition(":")
            obj = objects.get(int(index_text, 16), {})
            entry = obj if obj.get("object", "VAR") == "VAR" else next(
                (s for s in obj.get("subs", []) if s.get("sub") == int(sub_text or "0")), {})
            code = DATA_TYPES.get(entry.get("data_type"), (0, None, None))[2]
            if code is None:
                raise ObjectDictionaryError(f"{where}: PDO {name} maps {text!r}: expected a mapped object with a "
                                            "numeric data type")
            codes.append(code)
        return "<" + "".join(codes)
    raise ObjectDictionaryError(f"{where}: no PDO {name!r} in [[pdos]]")


def _round(x: float) -> int:
    return math.floor(x + 0.5)


def _parse_node_relative(text: str) -> int | None:
    if isinstance(text, str) and text.replace(" ", "").upper().startswith("$NODEID+"):
        return int(text.replace(" ", "")[8:], 0)
    return None


class _Context:
    def __init__(self, node: int, values: Mapping[str, float], config: Any, counts_per_rad: float,
                 rated_torque: float, torque_units_per_rated: int, identity: Mapping[str, Any], path: str) -> None:
        self.node, self.values, self.config, self.cpr = node, values, config, counts_per_rad
        self.rated_torque, self.units, self.identity, self.path = rated_torque, torque_units_per_rated, identity, path

    def convert(self, where: str, quantity: str | None, value: float, data_type: str) -> int | float:
        v = float(value)
        gear = lambda: float(self._need(where, "gear_ratio"))  # noqa: E731
        kt = lambda: float(self._need(where, "torque_constant"))  # noqa: E731
        signed = not data_type.startswith("UNSIGNED")
        cpr = self.cpr if signed else abs(self.cpr)
        scaled = {
            None: lambda: v, "none": lambda: v,
            "position": lambda: v * cpr, "velocity": lambda: v * cpr, "acceleration": lambda: v * cpr,
            "torque": lambda: v / self.rated_torque * self.units,
            "motor_speed_rpm": lambda: v * abs(gear()) * 60.0 / (2.0 * math.pi),
            "milli": lambda: v * 1e3, "micro": lambda: v * 1e6,
            "per_mille_rated_current": lambda: v / float(self._need(where, "rated_current")) * 1000.0,
            "motor_rated_current_ma": lambda: v / abs(gear()) / kt() * 1e3,
            "motor_rated_torque_mnm": lambda: v / abs(gear()) * 1e3,
            "interpolation_value": lambda: _interpolation(v)[0],
            "interpolation_index": lambda: _interpolation(v)[1],
        }.get(quantity)
        if scaled is None:
            raise ObjectDictionaryError(f"{self.path}: {where}: quantity = {quantity!r}, expected one of position, "
                                        "velocity, acceleration, torque, motor_speed_rpm, milli, micro, ...")
        result = scaled()
        return float(result) if data_type == "REAL32" else _round(result)

    def _need(self, where: str, name: str) -> Any:
        if name not in self.values:
            raise ObjectDictionaryError(f"{self.path}: {where} needs the drive parameter {name!r}, "
                                        f"which the caller did not hand in (given: {sorted(self.values)})")
        return self.values[name]


def _interpolation(period_s: float) -> tuple[int, int]:
    """(value, index) with value x 10^index = period_s, value an integer below 256 (0x60C2)."""
    for index in range(0, -10, -1):
        value = period_s / 10.0 ** index
        if abs(value - round(value)) < 1e-6 * max(1.0, value) and round(value) < 256:
            return round(value), index
    raise ObjectDictionaryError(f"cycle time {period_s} s cannot be written as 0x60C2 value x 10^index")


def _entry(ctx: _Context, index: int, item: Mapping[str, Any], subindex: int, where: str) -> Entry:
    name = item.get("name")
    data_type = item.get("data_type")
    access = item.get("access")
    if not isinstance(name, str) or not name:
        raise ObjectDictionaryError(f"{ctx.path}: {where}: name = {name!r}, expected a non-empty string")
    if data_type not in DATA_TYPES:
        raise ObjectDictionaryError(f"{ctx.path}: {where}: data_type = {data_type!r}, expected one of {list(DATA_TYPES)}")
    if access not in ACCESS:
        raise ObjectDictionaryError(f"{ctx.path}: {where}: access = {access!r}, expected one of {list(ACCESS)}")
    sources = [k for k in ("default", "param", "config", "identity") if k in item]
    if len(sources) != 1:
        raise ObjectDictionaryError(f"{ctx.path}: {where}: has {sources or 'no default'}, expected exactly one of "
                                    "default, param, config, identity")
    kind = sources[0]
    quantity = item.get("quantity")
    node_offset = None
    if kind == "default":
        default = item["default"]
        node_offset = _parse_node_relative(default)
        if node_offset is not None:
            default = ctx.node + node_offset
        source = "fieldbus/object_dictionary.toml"
    elif kind == "param":
        default = ctx.convert(where, quantity, ctx._need(where, item["param"]), data_type)
        source = f"drive parameter {item['param']}"
    elif kind == "config":
        if not hasattr(ctx.config, item["config"]):
            raise ObjectDictionaryError(f"{ctx.path}: {where}: config = {item['config']!r} is not a fieldbus setting")
        default = ctx.convert(where, quantity, getattr(ctx.config, item["config"]), data_type)
        source = f"[fieldbus] {item['config']}"
    else:
        if item["identity"] not in ctx.identity:
            raise ObjectDictionaryError(f"{ctx.path}: {where}: identity = {item['identity']!r} is not in [identity]")
        default = ctx.identity[item["identity"]]
        source = "fieldbus/object_dictionary.toml [identity]"
    e = Entry(index=index, subindex=subindex, name=name, data_type=data_type, access=access, default=default,
              pdo=bool(item.get("pdo", False)), unit=str(item.get("unit", "")), signal=item.get("signal"),
              quantity=quantity, source=source, node_offset=node_offset, description=str(item.get("description", "")),
              low=item.get("low"), high=item.get("high"))
    for limit in (e.low, e.high):
        if limit is not None and (data_type == "VISIBLE_STRING" or not e.in_range(limit)):
            raise ObjectDictionaryError(f"{ctx.path}: {where}: limit {limit!r} does not fit {data_type}")
    if data_type == "VISIBLE_STRING":
        if not isinstance(default, str):
            raise ObjectDictionaryError(f"{ctx.path}: {where}: default = {default!r}, expected a string")
    elif not e.in_range(default):
        raise ObjectDictionaryError(f"{ctx.path}: {where}: default {default!r} ({source}) does not fit {data_type}")
    return e


def _u(ctx: _Context, index: int, sub: int, name: str, data_type: str, access: str, default: int,
       node_offset: int | None = None, description: str = "") -> Entry:
    return Entry(index=index, subindex=sub, name=name, data_type=data_type, access=access, default=default,
                 source="generated from [[pdos]]", node_offset=node_offset, description=description)


def _pdo_objects(ctx: _Context, pdo: Pdo, cob_offset: int | None) -> list[DictObject]:
    i_comm, i_map = pdo.communication_index, pdo.mapping_index
    kind = "RPDO" if pdo.direction == "receive" else "TPDO"
    comm = DictObject(i_comm, f"{kind}{pdo.number} communication parameter", "RECORD", (
        _u(ctx, i_comm, 0, "Highest sub-index supported", "UNSIGNED8", "const", 2),
        _u(ctx, i_comm, 1, f"COB-ID used by {kind}{pdo.number}", "UNSIGNED32", "rw", pdo.cob_id, cob_offset),
        _u(ctx, i_comm, 2, "Transmission type", "UNSIGNED8", "rw", pdo.transmission_type,
           description="1: synchronous, every SYNC (SoC)"),
    ), pdo.description)
    mapping = [_u(ctx, i_map, 0, "Number of mapped objects", "UNSIGNED8", "rw", len(pdo.fields))]
    for k, f in enumerate(pdo.fields, start=1):
        mapping.append(_u(ctx, i_map, k, f"Mapped object {k}", "UNSIGNED32", "rw", f.mapping_value,
                          description=f.name))
    return [comm, DictObject(i_map, f"{kind}{pdo.number} mapping parameter", "RECORD", tuple(mapping), pdo.description)]


def build(node: int, values: Mapping[str, float], *, counts_per_rad: float, rated_torque: float,
          config: Any, torque_units_per_rated: int | None = None,
          path: str | Path | None = None) -> ObjectDictionary:
    """The object dictionary of node ``node`` (1..127).

    ``values``: the drive parameters the data file's ``param`` keys name, SI (the servo-drive
    FMU's start values of this axis plus ``rated_torque``, ``position_limit_min``/``_max``);
    ``counts_per_rad``: encoder counts per joint radian of this axis; ``rated_torque``: joint-side
    rated torque in N·m (the base of the 0.1 % unit); ``config``: the bus's ``FieldbusConfig``
    (``FieldbusConfig.from_dict({})`` for ``powerlink_defaults.toml``; the configuration builds on
    the telegrams, which build on this module, so it is given, never made here). Raises :class:`ObjectDictionaryError` naming the file and key.
    """
    if isinstance(node, bool) or not isinstance(node, int) or not 1 <= node <= 127:
        raise ObjectDictionaryError(f"node = {node!r}: expected a node id 1..127")
    where_file = str(Path(path or DATA_PATH))
    doc = _document(where_file)
    units = torque_units_per_rated or config.scaling.torque_units_per_rated
    # the config attributes the data file names, in its units
    cfg = _ConfigView(config)
    ctx = _Context(node, dict(values), cfg, float(counts_per_rad), float(rated_torque), units,
                   doc.get("identity", {}), where_file)
    objects: dict[int, DictObject] = {}
    for n, item in enumerate(doc.get("objects", [])):
        index = item.get("index")
        where = f"objects[{n}] (0x{index:04X})" if isinstance(index, int) else f"objects[{n}]"
        if not isinstance(index, int) or not 0x1000 <= index <= 0x9FFF or index in objects:
            raise ObjectDictionaryError(f"{where_file}: {where}: index = {index!r}, expected a new index 0x1000..0x9FFF")
        otype = item.get("object", "VAR")
        if otype == "VAR":
            entries = (_entry(ctx, index, item, 0, where),)
        elif otype in ("ARRAY", "RECORD"):
            subs = [_entry(ctx, index, s, int(s.get("sub", -1)), f"{where} sub {s.get('sub')}")
                    for s in item.get("subs", []) if s.get("sub") != 0]
            explicit0 = [s for s in item.get("subs", []) if s.get("sub") == 0]
            if explicit0:
                first = _entry(ctx, index, explicit0[0], 0, f"{where} sub 0")
            else:
                first = Entry(index, 0, "Highest sub-index supported", "UNSIGNED8", "const",
                              max(s.subindex for s in subs), source="generated")
            entries = (first, *subs)
        else:
            raise ObjectDictionaryError(f"{where_file}: {where}: object = {otype!r}, expected VAR, ARRAY or RECORD")
        if index == 0x607D:  # software position limits: counts of a negative gear ratio swap the ends
            lo, hi = sorted((entries[1].default, entries[2].default))
            entries = (entries[0], _replace(entries[1], default=lo), _replace(entries[2], default=hi))
        objects[index] = DictObject(index, str(item.get("name", "")), otype, entries, str(item.get("description", "")))
    pdos = []
    for n, item in enumerate(doc.get("pdos", [])):
        pdo, offset = _pdo(ctx, objects, item, n, config)
        pdos.append(pdo)
        for obj in _pdo_objects(ctx, pdo, offset):
            objects[obj.index] = obj
    cpr = float(counts_per_rad)
    return ObjectDictionary(node=node, objects=dict(sorted(objects.items())), pdos=tuple(pdos),
                            identity=dict(doc.get("identity", {})), rad_per_count=1.0 / cpr,
                            newton_metre_per_unit=float(rated_torque) / units, source=where_file)


def _replace(entry: Entry, **changes: Any) -> Entry:
    from dataclasses import replace

    return replace(entry, **changes)


class _ConfigView:
    """The fieldbus configuration's values under the names the data file uses."""

    def __init__(self, config: Any) -> None:
        self.cycle_time_s = config.cycle_time_s
        self.sync_counter_overflow = config.scaling.sync_counter_overflow
        self.setpoint_buffer = config.setpoint_buffer
        self.setpoint_lookahead = config.setpoint_lookahead


def _pdo(ctx: _Context, objects: Mapping[int, DictObject], item: Mapping[str, Any], n: int, config: Any):
    where = f"pdos[{n}]"
    direction = item.get("direction")
    if direction not in ("receive", "transmit"):
        raise ObjectDictionaryError(f"{ctx.path}: {where}: direction = {direction!r}, expected receive or transmit")
    offset = _parse_node_relative(item.get("cob_id", ""))
    cob_id = ctx.node + offset if offset is not None else int(item.get("cob_id", -1))
    names = list(item.get("map", []))
    if getattr(ctx.config, "setpoint_buffer", 0):
        names += list(item.get("with_setpoint_buffer", []))
    fields, bit = [], 0
    for text in names:
        if text == "dummy8":
            index, sub, entry, name = *DUMMY8, None, "reserved"
        else:
            index_text, _, sub_text = str(text).partition(":")
            index, sub = int(index_text, 16), int(sub_text or "0")
            obj = objects.get(index)
            entry = next((e for e in obj.entries if e.subindex == sub), None) if obj else None
            if entry is None or not entry.pdo:
                raise ObjectDictionaryError(f"{ctx.path}: {where}: maps {text!r}, which is not a PDO-mappable object")
            name = entry.signal or entry.name
        bits = entry.bits if entry else 8
        fields.append(PdoField(index, sub, bits, bit, entry, name))
        bit += bits
    if bit > 64 * 8:
        raise ObjectDictionaryError(f"{ctx.path}: {where}: maps {bit // 8} bytes, more than a CAN FD frame's 64")
    pdo = Pdo(name=str(item.get("name")), direction=direction, number=int(item.get("number", 0)), cob_id=cob_id,
              transmission_type=int(item.get("transmission_type", 1)), fields=tuple(fields),
              description=str(item.get("description", "")))
    return pdo, offset


__all__ = ["ACCESS", "DATA_PATH", "DATA_TYPES", "DictObject", "Entry", "ObjectDictionary", "ObjectDictionaryError",
           "Pdo", "PdoField", "build", "pdo_layout"]
