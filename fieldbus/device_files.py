"""Files generated from the object dictionary (:mod:`fieldbus.object_dictionary`).

* :func:`to_eds`: the CANopen electronic data sheet (CiA 306 v4.0) of one drive node; COB-IDs
  written node-relative (``$NODEID+0x200``), the other defaults those of that axis (counts per
  radian and rated torque differ per axis). The CANopen PDOs: RPDO1, TPDO1, TPDO2.
* :func:`to_xdd`: the POWERLINK XML device description (EPSG DS 311) of one node: the same
  objects, with POWERLINK's PDO objects (0x1400/0x1800 node id + mapping version, 0x1600/0x1A00
  UNSIGNED64 entries: length, offset, sub-index, index) - the PReq payload is the RPDO1, the
  PRes payload TPDO1 followed by TPDO2.
* :func:`to_dbc`: the signal database of the whole bus (SYNC, and per node RPDO1, TPDO1,
  TPDO2, EMCY), signals scaled to rad, rad/s and N·m, written with ``cantools``.
* :func:`reference_markdown`: the reference table of docs/reference/object_dictionary.md.
"""
from __future__ import annotations

from collections.abc import Sequence
from xml.sax.saxutils import escape, quoteattr

from fieldbus.object_dictionary import DATA_TYPES, DictObject, Entry, ObjectDictionary, Pdo
from fieldbus.telegrams import EMCY_BASE, SYNC_ID

EDS_VERSION = "4.0"
XDD_NAMESPACE = "http://www.ethernet-powerlink.org"
XSI_NAMESPACE = "http://www.w3.org/2001/XMLSchema-instance"
FILE_DATE = "2026-01-01"  # fixed, so generated files are reproducible (a test checks the docs are current)
POWERLINK_PDO_INDICES = (0x1400, 0x1600, 0x1800, 0x1801, 0x1A00, 0x1A01)


def _number(entry: Entry, node_relative: bool = True) -> str:
    value = entry.default
    if node_relative and entry.node_offset is not None:
        return f"$NODEID+0x{entry.node_offset:X}"
    if entry.data_type == "VISIBLE_STRING":
        return str(value)
    if entry.data_type == "REAL32":
        return repr(float(value))
    if entry.data_type.startswith("UNSIGNED") and int(value) > 9:
        return f"0x{int(value):0{max(2, (entry.bits or 8) // 4)}X}"
    return str(int(value))


def _pdo_mapping_flag(entry: Entry) -> int:
    return 1 if entry.pdo else 0


# ------------------------------------------------------------------------------------ EDS
def to_eds(od: ObjectDictionary, file_name: str | None = None) -> str:
    """The EDS (CiA 306) of node ``od.node`` as text."""
    ident = od.identity
    file_name = file_name or f"servo_drive_node{od.node}.eds"
    lines: list[str] = []

    def section(name: str, items: Sequence[tuple[str, object]]) -> None:
        lines.append(f"[{name}]")
        lines.extend(f"{k}={v}" for k, v in items)
        lines.append("")

    section("FileInfo", [("FileName", file_name), ("FileVersion", 1), ("FileRevision", 0),
                         ("EDSVersion", EDS_VERSION),
                         ("Description", f"{ident['product_name']}, axis {od.node} (generated from "
                                         "fieldbus/object_dictionary.toml)"),
                         ("CreationTime", "12:00AM"), ("CreationDate", "01-01-2026"), ("CreatedBy", "rx130l-cosim"),
                         ("ModificationTime", "12:00AM"), ("ModificationDate", "01-01-2026"),
                         ("ModifiedBy", "rx130l-cosim")])
    rx = sum(p.direction == "receive" for p in od.pdos)
    section("DeviceInfo", [("VendorName", ident["vendor_name"]), ("VendorNumber", f"0x{ident['vendor_id']:08X}"),
                           ("ProductName", ident["product_name"]), ("ProductNumber", f"0x{ident['product_code']:08X}"),
                           ("RevisionNumber", f"0x{ident['revision']:08X}"), ("OrderCode", ident["order_code"]),
                           *[(f"BaudRate_{r}", 1 if r == 1000 else 0) for r in (10, 20, 50, 125, 250, 500, 800, 1000)],
                           ("SimpleBootUpMaster", 0), ("SimpleBootUpSlave", 1), ("Granularity", 8),
                           ("DynamicChannelsSupported", 0), ("CompactPDO", 0), ("GroupMessaging", 0),
                           ("NrOfRXPDO", rx), ("NrOfTXPDO", len(od.pdos) - rx), ("LSS_Supported", 0)])
    section("DummyUsage", [(f"Dummy{i:04X}", 1 if i == 0x0005 else 0) for i in range(1, 8)])
    comments = ["Virtual servo drive of the rx130l-cosim testbed (CiA 402, cyclic synchronous modes 8, 9, 10).",
                "RPDO1 is a 20-byte CAN FD frame (CiA 1301); units: counts, counts/s, 0.1 % of rated torque.",
                f"Axis {od.node}: 1 count = {od.rad_per_count!r} rad, 1 torque unit = {od.newton_metre_per_unit!r} N m."]
    section("Comments", [("Lines", len(comments)), *[(f"Line{i}", c) for i, c in enumerate(comments, 1)]])
    mandatory = [i for i in (0x1000, 0x1001, 0x1018) if i in od.objects]
    optional = [i for i in od.objects if i not in mandatory and not 0x2000 <= i <= 0x5FFF]
    manufacturer = [i for i in od.objects if 0x2000 <= i <= 0x5FFF]
    for name, indices in (("MandatoryObjects", mandatory), ("OptionalObjects", optional),
                          ("ManufacturerObjects", manufacturer)):
        section(name, [("SupportedObjects", len(indices)), *[(str(k), f"0x{i:04X}") for k, i in enumerate(indices, 1)]])
    for obj in od:
        if obj.object_type == "VAR":
            section(f"{obj.index:04X}", _eds_variable(obj.entries[0], obj.name, obj.description))
        else:
            section(f"{obj.index:04X}", [("ParameterName", obj.name), ("ObjectType", f"0x{obj.object_code:X}"),
                                          ("SubNumber", len(obj.entries))])
            for e in obj.entries:
                section(f"{obj.index:04X}sub{e.subindex:X}", _eds_variable(e, e.name, e.description))
    return "\r\n".join(lines)


def _eds_variable(e: Entry, name: str, description: str) -> list[tuple[str, object]]:
    items: list[tuple[str, object]] = [("ParameterName", name), ("ObjectType", "0x7"),
                                       ("DataType", f"0x{e.data_type_index:04X}"), ("AccessType", e.access),
                                       ("DefaultValue", _number(e)), ("PDOMapping", _pdo_mapping_flag(e))]
    if e.low is not None:
        items.append(("LowLimit", repr(float(e.low)) if e.data_type == "REAL32" else str(e.low)))
    if e.high is not None:
        items.append(("HighLimit", repr(float(e.high)) if e.data_type == "REAL32" else str(e.high)))
    if e.unit:
        items.append(("Unit", e.unit))  # not in CiA 306; read by the canopen library, ignored by others
    if description:
        items.append(("Description", description))
    return items


# ------------------------------------------------------------------------------------ XDD
def powerlink_pdo_objects(od: ObjectDictionary) -> list[DictObject]:
    """POWERLINK's PDO objects of the node: 0x1400/0x1600 (the PReq's payload from the MN, node 0)
    and 0x1800/0x1A00 (the PRes's payload, broadcast: TPDO1 then TPDO2), entries UNSIGNED64 =
    length << 48 | offset << 32 | sub-index << 16 | index (bits)."""
    rx = [p for p in od.pdos if p.direction == "receive"]
    tx = [p for p in od.pdos if p.direction == "transmit"]
    objects = []
    for comm, mapp, pdos, kind in ((0x1400, 0x1600, rx, "Rx"), (0x1800, 0x1A00, tx, "Tx")):
        objects.append(DictObject(comm, f"PDO_{kind}CommParam_00h_REC", "RECORD", (
            Entry(comm, 0, "NumberOfEntries", "UNSIGNED8", "const", 2),
            Entry(comm, 1, "NodeID_U8", "UNSIGNED8", "rw", 0,
                  description="0: from the MN (PReq)" if kind == "Rx" else "0: PRes, received by every node"),
            Entry(comm, 2, "MappingVersion_U8", "UNSIGNED8", "rw", 0))))
        entries = [Entry(mapp, 0, "NumberOfEntries", "UNSIGNED8", "rw", sum(len(p.fields) for p in pdos))]
        offset = 0
        for p in pdos:
            for f in p.fields:
                value = (f.bits << 48) | ((offset + f.offset) << 32) | (f.subindex << 16) | f.index
                entries.append(Entry(mapp, len(entries), f"ObjectMapping_U64 ({f.name})", "UNSIGNED64", "rw", value))
            offset += p.length * 8
        objects.append(DictObject(mapp, f"PDO_{kind}MappParam_00h_AU64", "ARRAY", tuple(entries)))
    return objects


def xdd_objects(od: ObjectDictionary) -> list[DictObject]:
    """The objects the XDD lists: the dictionary's, POWERLINK's PDO objects instead of CANopen's."""
    objects = {i: o for i, o in od.objects.items() if i not in POWERLINK_PDO_INDICES}
    objects.update({o.index: o for o in powerlink_pdo_objects(od)})
    return [objects[i] for i in sorted(objects)]


def _xdd_pdo_flag(e: Entry) -> str:
    if not e.pdo:
        return "no"
    return "RPDO" if e.access in ("rw", "wo") else "TPDO"


def _xdd_attrs(e: Entry, name: str) -> str:
    attrs = [("name", name), ("objectType", "7"), ("dataType", f"{e.data_type_index:04X}"),
             ("accessType", e.access), ("defaultValue", _number(e, node_relative=False)),
             ("PDOmapping", _xdd_pdo_flag(e))]
    attrs += [(key, value) for key, value in (("lowLimit", e.low), ("highLimit", e.high)) if value is not None]
    return " ".join(f"{k}={quoteattr(str(v))}" for k, v in attrs)


def to_xdd(od: ObjectDictionary, file_name: str | None = None, *, cycle_time_us: int | None = None) -> str:
    """The POWERLINK XDD (EPSG DS 311) of node ``od.node`` as text."""
    ident = od.identity
    file_name = file_name or f"servo_drive_node{od.node}.xdd"
    cycle = cycle_time_us if cycle_time_us is not None else int(od.entry(0x1006).default)
    header = ('<ProfileHeader><ProfileIdentification>{ident}</ProfileIdentification><ProfileRevision>1'
              '</ProfileRevision><ProfileName>{name}</ProfileName><ProfileSource/><ProfileClassID>{cls}'
              '</ProfileClassID><ISO15745Reference><ISO15745Part>4</ISO15745Part><ISO15745Edition>1'
              '</ISO15745Edition><ProfileTechnology>Powerlink</ProfileTechnology></ISO15745Reference>'
              '</ProfileHeader>')
    body_attrs = (f'fileName={quoteattr(file_name)} fileCreator="rx130l-cosim" fileCreationDate="{FILE_DATE}" '
                  'fileVersion="1"')
    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           f'<ISO15745ProfileContainer xmlns="{XDD_NAMESPACE}" xmlns:xsi="{XSI_NAMESPACE}" '
           f'xsi:schemaLocation="{XDD_NAMESPACE} Powerlink_Main.xsd">',
           "<ISO15745Profile>",
           header.format(ident="Powerlink_Device_Profile", name=escape(ident["product_name"]), cls="Device"),
           f'<ProfileBody xsi:type="ProfileBody_Device_Powerlink" {body_attrs}>',
           "<DeviceIdentity>",
           f"<vendorName>{escape(ident['vendor_name'])}</vendorName>",
           f"<vendorID>0x{ident['vendor_id']:08X}</vendorID>",
           f"<productName>{escape(ident['product_name'])}</productName>",
           f"<productID>0x{ident['product_code']:08X}</productID>",
           f'<version versionType="SW">{ident["revision"] >> 16}.{ident["revision"] & 0xFFFF}</version>',
           "</DeviceIdentity>",
           "<DeviceFunction><capabilities><characteristicsList><characteristic><characteristicName>"
           '<label lang="en">Device profile</label></characteristicName><characteristicContent>'
           '<label lang="en">CiA 402 servo drive, cyclic synchronous position/velocity/torque</label>'
           "</characteristicContent></characteristic></characteristicsList></capabilities></DeviceFunction>",
           "</ProfileBody>",
           "</ISO15745Profile>",
           "<ISO15745Profile>",
           header.format(ident="Powerlink_Communication_Profile", name=escape(ident["product_name"]) + " communication",
                         cls="CommunicationNetwork"),
           f'<ProfileBody xsi:type="ProfileBody_CommunicationNetwork_Powerlink" {body_attrs}>',
           "<ApplicationLayers>",
           f"<identity><vendorID>0x{ident['vendor_id']:08X}</vendorID>"
           f"<productID>0x{ident['product_code']:08X}</productID></identity>",
           "<DataTypeList>"]
    tags = {"BOOLEAN": "Boolean", "INTEGER8": "Integer8", "INTEGER16": "Integer16", "INTEGER32": "Integer32",
            "UNSIGNED8": "Unsigned8", "UNSIGNED16": "Unsigned16", "UNSIGNED32": "Unsigned32", "REAL32": "Real32",
            "VISIBLE_STRING": "Visible_String", "UNSIGNED64": "Unsigned64"}
    for name, (index, _, _) in DATA_TYPES.items():
        out.append(f'<defType dataType="{index:04X}"><{tags[name]}/></defType>')
    out.append("</DataTypeList>")
    out.append("<ObjectList>")
    for obj in xdd_objects(od):
        if obj.object_type == "VAR":
            out.append(f'<Object index="{obj.index:04X}" {_xdd_attrs(obj.entries[0], obj.name)}/>')
            continue
        out.append(f'<Object index="{obj.index:04X}" name={quoteattr(obj.name)} objectType="{obj.object_code}">')
        for e in obj.entries:
            out.append(f'<SubObject subIndex="{e.subindex:02X}" {_xdd_attrs(e, e.name)}/>')
        out.append("</Object>")
    out += ["</ObjectList>", "</ApplicationLayers>",
            "<TransportLayers/>",
            "<NetworkManagement>",
            f'<GeneralFeatures DLLFeatureMN="false" NMTBootTimeNotActive="3000000" NMTCycleTimeMax="{cycle}" '
            f'NMTCycleTimeMin="{cycle}" NMTErrorEntries="8" NWLIPSupport="false" PDORPDOChannels="1" '
            f'PDOTPDOChannels="1" SDOServer="false"/>',
            '<CNFeatures DLLCNFeatureMultiplex="false" NMTCNPreOp2ToReady2Op="0" NMTCNSoC2PReq="0"/>',
            "<Diagnostic/>",
            "</NetworkManagement>",
            "</ProfileBody>",
            "</ISO15745Profile>",
            "</ISO15745ProfileContainer>", ""]
    return "\n".join(out)


# ------------------------------------------------------------------------------------ DBC
def dbc_database(ods: Sequence[ObjectDictionary]):
    """The ``cantools`` database of every cyclic telegram (and EMCY) of the nodes ``ods``."""
    from collections import OrderedDict

    from cantools.database.can import Database, Message, Node, Signal
    from cantools.database.can.formats.dbc.dbc_attribute import DbcAttribute
    from cantools.database.can.formats.dbc.dbc_attribute_definition import DbcAttributeDefinition
    from cantools.database.can.formats.dbc.dbc_specifics import DbcSpecifics
    from cantools.database.conversion import BaseConversion

    def signals_of(od: ObjectDictionary, pdo: Pdo) -> list:
        out = []
        for f in pdo.fields:
            if f.entry is None:
                continue
            scale, unit = od.physical_scale(f.entry)
            out.append(Signal(f.name, f.offset, f.bits, "little_endian",
                              is_signed=not f.entry.data_type.startswith("UNSIGNED"),
                              conversion=BaseConversion.factory(scale=scale, offset=0.0, is_float=False),
                              unit=unit or None, comment=f"0x{f.index:04X} sub {f.subindex}: {f.entry.name}"))
        return out

    messages = [Message(SYNC_ID, "SYNC", 1, [Signal("sync_counter", 0, 8, "little_endian", comment="SoC counter")],
                        senders=["MN"], comment="SYNC = POWERLINK SoC (counter 1..0x1019)")]
    for od in ods:
        n = od.node
        for pdo in od.pdos:
            sender = "MN" if pdo.direction == "receive" else f"Drive{n}"
            messages.append(Message(pdo.cob_id, f"{pdo.name}_node{n}", pdo.length, signals_of(od, pdo),
                                    senders=[sender], is_fd=pdo.length > 8, cycle_time=round(od.entry(0x1006).default / 1000) or None,
                                    comment=pdo.description))
        messages.append(Message(EMCY_BASE + n, f"EMCY_node{n}", 8, [
            Signal("error_code", 0, 16, "little_endian"), Signal("error_register", 16, 8, "little_endian"),
            Signal("counter_id", 24, 8, "little_endian"), Signal("counter_value", 32, 16, "little_endian"),
            Signal("counter_threshold", 48, 16, "little_endian")], senders=[f"Drive{n}"],
            comment="emergency: error code, 0x1001, the threshold counter that tripped, its value and threshold"))
    nodes = [Node("MN", comment="managing node (controller)")] + [Node(f"Drive{od.node}") for od in ods]
    # BusType "CAN FD": the DBC writer then marks the 20-byte RPDO1s VFrameFormat StandardCAN_FD
    bus_type = DbcAttributeDefinition("BusType", default_value="CAN", kind=None, type_name="STRING")
    dbc = DbcSpecifics(attributes=OrderedDict(BusType=DbcAttribute("CAN FD", bus_type)),
                       attribute_definitions=OrderedDict(BusType=bus_type))
    return Database(messages=messages, nodes=nodes, version="1", dbc_specifics=dbc)


def to_dbc(ods: Sequence[ObjectDictionary]) -> str:
    """The DBC text of :func:`dbc_database`."""
    return dbc_database(ods).as_dbc_string()


# ------------------------------------------------------------------------------------ docs
def reference_markdown(od: ObjectDictionary) -> str:
    """The reference table of every object of one drive (the defaults of axis ``od.node``)."""
    rows = ["| index | sub | name | type | access | PDO | unit | default (axis {node}) | from |".format(node=od.node),
            "|---|---|---|---|---|---|---|---|---|"]
    for obj in od:
        for e in obj.entries:
            default = _number(e)
            if e.data_type == "UNSIGNED32" and obj.index in (0x1600, 0x1A00, 0x1A01):
                default = f"0x{e.default:08X}"
            pdo = "RPDO" if e.pdo and e.writable else "TPDO" if e.pdo else ""
            name = e.name if obj.object_type == "VAR" else f"{obj.name}: {e.name}"
            rows.append(f"| 0x{obj.index:04X} | {e.subindex} | {name} | {e.data_type} | {e.access} | {pdo} | "
                        f"{e.unit} | {default} | {e.source} |")
    pdo_rows = ["| PDO | COB-ID | bytes | mapping (offset: object) |", "|---|---|---|---|"]
    for p in od.pdos:
        fields = "; ".join(f"{f.offset // 8}: 0x{f.index:04X} {f.name}" for f in p.fields)
        pdo_rows.append(f"| {p.name} (0x{p.communication_index:04X}/0x{p.mapping_index:04X}) | "
                        f"0x{p.cob_id - od.node:03X} + node | {p.length} | {fields} |")
    return "\n".join(rows) + "\n\n" + "\n".join(pdo_rows) + "\n"


__all__ = ["dbc_database", "powerlink_pdo_objects", "reference_markdown", "to_dbc", "to_eds", "to_xdd", "xdd_objects"]
