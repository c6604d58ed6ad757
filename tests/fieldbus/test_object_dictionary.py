"""The object dictionary is the one description of the drives' bus interface: its PDO mappings are
the byte layouts the telegrams, the compiled codec and the CAN log use; the EDS it generates loads
in the ``canopen`` library (a CANopen stack nobody here wrote) with every object equal; the XDD is
structurally what EPSG DS 311 asks for (no XML schema of it ships in any package we can install,
so lxml checks the required elements and every object); the reference page is current."""
from __future__ import annotations

import random
import struct
from pathlib import Path

import canopen
import numpy as np
import pytest
from lxml import etree

from fieldbus import telegrams
from fieldbus.canlog import LAYOUTS
from fieldbus.device_files import reference_markdown, to_eds, to_xdd, xdd_objects
from fieldbus.config import FieldbusConfig
from fieldbus.object_dictionary import DATA_TYPES, ObjectDictionaryError, build
from fmus.servo_drive.object_dictionary import drive_object_dictionaries, drive_object_dictionary, drive_values
from fmus.servo_drive.params import drive_start_values

ROOT = Path(__file__).resolve().parents[2]
NS = {"x": "http://www.ethernet-powerlink.org"}
XSI_TYPE = "{http://www.w3.org/2001/XMLSchema-instance}type"
DEFAULTS = FieldbusConfig.from_dict({})  # powerlink_defaults.toml


@pytest.fixture(scope="module")
def ods():
    return drive_object_dictionaries()


def test_the_pdo_mappings_are_the_telegrams_layouts(ods):
    by_name = {"RPDO1": telegrams.RPDO1_SIGNED, "TPDO1": telegrams.TPDO1, "TPDO2": telegrams.TPDO2}
    bases = {"RPDO1": telegrams.RPDO1_BASE, "TPDO1": telegrams.TPDO1_BASE, "TPDO2": telegrams.TPDO2_BASE}
    canlog = {(lo, n): dtype.names for lo, _, n, dtype in LAYOUTS}
    for od in ods:
        assert [p.name for p in od.pdos] == ["RPDO1", "TPDO1", "TPDO2"]
        for pdo in od.pdos:
            assert pdo.struct.format == by_name[pdo.name].format
            assert pdo.length == by_name[pdo.name].size
            assert pdo.cob_id == bases[pdo.name] + od.node
            # the CAN log's columns are the mapped objects' signal names, in payload order
            assert tuple(f.name for f in pdo.fields) == canlog[(bases[pdo.name] + 1, pdo.length)]
            # 0x1600/0x1A00 entries: index << 16 | sub << 8 | bits, in payload order
            mapping = od.objects[pdo.mapping_index].entries
            assert mapping[0].default == len(pdo.fields)
            assert [e.default for e in mapping[1:]] == [f.mapping_value for f in pdo.fields]
            assert od.entry(pdo.communication_index, 1).default == pdo.cob_id
            assert od.entry(pdo.communication_index, 2).default == 1  # synchronous, every SYNC
        assert od.entry(0x1600, 5).default == 0x00050008  # the reserved byte: dummy UNSIGNED8


def test_what_the_codec_packs_unpacks_by_the_dictionarys_mapping(ods):
    od = ods[2]
    rng = random.Random(3)
    fields = {f.name: f for p in od.pdos for f in p.fields}

    def draw(name):
        low, high = {"b": (8, 10)}.get(DATA_TYPES[fields[name].entry.data_type][2], None) or _range(fields[name])
        return rng.randint(low, high)

    for _ in range(200):
        rx = {n: draw(n) for n in ("controlword", "target_position", "torque_offset", "modes_of_operation",
                                   "target_torque", "target_velocity", "velocity_offset")}
        data = telegrams.encode_rpdo1(**rx)
        assert dict(zip([f.name for f in od.pdo("RPDO1").fields], od.pdo("RPDO1").struct.unpack(data))) == {
            **rx, "reserved": 0}
        tx1 = {n: draw(n) for n in ("statusword", "position_actual", "torque_actual")}
        assert od.pdo("TPDO1").struct.unpack(telegrams.encode_tpdo1(**tx1)) == tuple(tx1.values())
        tx2 = {n: draw(n) for n in ("velocity_actual", "error_code", "modes_of_operation_display")}
        assert od.pdo("TPDO2").struct.unpack(telegrams.encode_tpdo2(**tx2)) == tuple(tx2.values())


def _range(field):
    bits = field.bits
    if field.entry.data_type.startswith("UNSIGNED"):
        return 0, (1 << bits) - 1
    return -(1 << (bits - 1)), (1 << (bits - 1)) - 1


def test_with_a_setpoint_buffer_the_tpdo2_maps_the_actual_buffer_size():
    config = FieldbusConfig.from_dict({"setpoint_lookahead": 4, "setpoint_buffer": 64})
    od = drive_object_dictionary(1, config)
    assert od.pdo("TPDO2").struct.format == telegrams.TPDO2_BUFFERED.format
    assert od.pdo("TPDO2").fields[-1].mapping_value == 0x60C40208
    assert od.entry(0x60C4, 1).default == 64


def test_defaults_come_from_the_drive_parameter_files(ods):
    for od in ods:
        start = drive_start_values(od.node)
        counts_per_rad = 1.0 / od.rad_per_count
        assert od.entry(0x2001).default == start["position_kv"]
        assert od.entry(0x2002).default == start["speed_kp"]
        assert od.entry(0x605A).default == start["quick_stop_option_code"]
        assert od.entry(0x6065).default == round(start["following_error_window"] * abs(counts_per_rad))
        assert od.entry(0x6072).default == round(start["torque_limit"] / od.newton_metre_per_unit)
        assert od.entry(0x6085).default == round(start["quick_stop_deceleration"] * abs(counts_per_rad))
        # the protection limits of [protection] in drive_params.toml (CiA objects named there)
        assert od.entry(0x6080).default == round(start["max_motor_speed"] * start["gear_ratio"] * 60 / (2 * np.pi))
        assert od.entry(0x607D, 1).default == round(start["position_limit_min"] * counts_per_rad)
        assert od.entry(0x607D, 2).default == round(start["position_limit_max"] * counts_per_rad)
        assert od.entry(0x6066).default == round(start["following_error_time"] * 1e3)
        assert od.entry(0x6075).default == round(start["rated_current"] * 1e3)
        assert od.entry(0x6073).default == round(start["current_limit"] / start["rated_current"] * 1e3)
        assert (od.entry(0x2020).default, od.entry(0x2021).default) == (start["peak_current_time"], start["i2t_release"])
        assert od.entry(0x1006).default == 400 and od.entry(0x1019).default == 240
        assert od.entry(0x1014).default == 0x80 + od.node and od.entry(0x1018, 4).default == od.node


def test_a_missing_or_out_of_range_parameter_is_a_clear_error():
    values = drive_values(1)
    del values["speed_kp"]
    with pytest.raises(ObjectDictionaryError, match="speed_kp"):
        build(1, values, counts_per_rad=1e6, rated_torque=350.0, config=DEFAULTS)
    values = drive_values(1)
    values["standstill_velocity"] = 1.0  # 1 rad/s is 1e6 counts/s: beyond 0x606F's UNSIGNED16
    with pytest.raises(ObjectDictionaryError, match="0x606F.*does not fit UNSIGNED16"):
        build(1, values, counts_per_rad=1e6, rated_torque=350.0, config=DEFAULTS)
    with pytest.raises(ObjectDictionaryError, match="node = 0"):
        build(0, drive_values(1), counts_per_rad=1e6, rated_torque=350.0, config=DEFAULTS)


def test_the_canopen_library_loads_the_eds_with_every_object_equal(ods, tmp_path):
    for od in ods:
        path = tmp_path / f"node{od.node}.eds"
        path.write_text(to_eds(od), encoding="utf-8", newline="")
        loaded = canopen.import_od(str(path), node_id=od.node)
        # the dictionary's objects, and the dummy UNSIGNED8 entry [DummyUsage] declares for the RPDO1
        assert sorted(loaded.indices) == sorted([*od.objects, 0x0005])
        assert loaded.device_information.product_name == od.identity["product_name"]
        info = loaded.device_information
        assert (info.vendor_number, info.product_number, info.revision_number) == (
            od.identity["vendor_id"], od.identity["product_code"], od.identity["revision"])
        assert (info.nr_of_RXPDO, info.nr_of_TXPDO) == (1, 2)
        compared = 0
        for obj in od:
            item = loaded[obj.index]
            assert item.name == obj.name
            for e in obj.entries:
                var = item if obj.object_type == "VAR" else item[e.subindex]
                assert (var.index, var.subindex, var.data_type, var.access_type, var.pdo_mappable) == (
                    e.index, e.subindex, e.data_type_index, e.access, e.pdo), (hex(e.index), e.subindex)
                if e.data_type == "REAL32":
                    assert var.default == pytest.approx(e.default, rel=0, abs=0)
                else:
                    assert var.default == e.default, (hex(e.index), e.subindex)
                assert (var.unit or "") == e.unit
                assert (var.min, var.max) == (e.low, e.high)
                compared += 1
        assert compared == sum(1 for _ in od.entries()) == 96


def test_the_canopen_library_reads_the_pdo_mappings_and_decodes_what_the_codec_packs(ods, tmp_path):
    """canopen's PDO objects, configured from the EDS (``read(from_od=True)``), map the fields the
    codec packs (offset, length) and decode frames of ``fieldbus.telegrams`` to the same values."""
    for od in ods:
        path = tmp_path / f"node{od.node}.eds"
        path.write_text(to_eds(od), encoding="utf-8", newline="")
        network = canopen.Network()  # not connected: frames are handed to the PDO objects directly
        node = canopen.RemoteNode(od.node, str(path))
        network.add_node(node)
        node.rpdo.read(from_od=True)
        node.tpdo.read(from_od=True)
        maps = {"RPDO1": node.rpdo[1], "TPDO1": node.tpdo[1], "TPDO2": node.tpdo[2]}
        for name, pdo_map in maps.items():
            pdo = od.pdo(name)
            assert pdo_map.cob_id == pdo.cob_id and pdo_map.trans_type == 1 and pdo_map.enabled
            assert [(v.index, v.subindex, v.offset, v.length) for v in pdo_map.map] == [
                (f.index, f.subindex, f.offset, f.bits) for f in pdo.fields]
        frames = {"RPDO1": telegrams.encode_rpdo1(0x001F, -1234567, -321, 9, 55, 7654321, -42),
                  "TPDO1": telegrams.encode_tpdo1(0x1237, 2**31 - 5, -77),
                  "TPDO2": telegrams.encode_tpdo2(-98765, 0x8611, 10)}
        for name, data in frames.items():
            maps[name].on_message(od.pdo(name).cob_id, data, 0.0)
            assert tuple(v.raw for v in maps[name].map) == od.pdo(name).struct.unpack(data)


def test_the_xdd_holds_the_required_elements_and_every_object(ods):
    for od in ods:
        root = etree.fromstring(to_xdd(od).encode())
        assert root.tag == "{http://www.ethernet-powerlink.org}ISO15745ProfileContainer"
        profiles = root.findall("x:ISO15745Profile", NS)
        assert len(profiles) == 2
        classes = [p.findtext("x:ProfileHeader/x:ProfileClassID", namespaces=NS) for p in profiles]
        assert classes == ["Device", "CommunicationNetwork"]
        assert [p.findtext("x:ProfileHeader/x:ProfileIdentification", namespaces=NS) for p in profiles] == [
            "Powerlink_Device_Profile", "Powerlink_Communication_Profile"]
        bodies = [p.find("x:ProfileBody", NS) for p in profiles]
        assert [b.get(XSI_TYPE) for b in bodies] == ["ProfileBody_Device_Powerlink",
                                                       "ProfileBody_CommunicationNetwork_Powerlink"]
        for body in bodies:
            for attribute in ("fileName", "fileCreator", "fileCreationDate", "fileVersion"):
                assert body.get(attribute)
        identity = bodies[0].find("x:DeviceIdentity", NS)
        assert identity.findtext("x:vendorName", namespaces=NS) == od.identity["vendor_name"]
        assert int(identity.findtext("x:vendorID", namespaces=NS), 16) == od.identity["vendor_id"]
        comm = bodies[1]
        for path in ("x:ApplicationLayers/x:identity", "x:ApplicationLayers/x:DataTypeList",
                     "x:ApplicationLayers/x:ObjectList", "x:TransportLayers", "x:NetworkManagement/x:GeneralFeatures",
                     "x:NetworkManagement/x:CNFeatures"):
            assert comm.find(path, NS) is not None, path
        assert comm.find("x:NetworkManagement/x:GeneralFeatures", NS).get("NMTCycleTimeMin") == "400"
        types = {d.get("dataType"): etree.QName(d[0]).localname
                 for d in comm.iterfind("x:ApplicationLayers/x:DataTypeList/x:defType", NS)}
        # EPSG DS 311 type names (as Wireshark's POWERLINK profile parser reads them)
        assert types["0006"] == "Unsigned16" and types["0004"] == "Integer32" and types["0008"] == "Real32"
        declared = set(types)
        listed = {int(o.get("index"), 16): o for o in comm.iterfind("x:ApplicationLayers/x:ObjectList/x:Object", NS)}
        expected = xdd_objects(od)
        assert sorted(listed) == [o.index for o in expected]
        for obj in expected:
            element = listed[obj.index]
            assert element.get("name") == obj.name and int(element.get("objectType")) == obj.object_code
            subs = [element] if obj.object_type == "VAR" else element.findall("x:SubObject", NS)
            assert len(subs) == len(obj.entries)
            for sub, e in zip(subs, obj.entries):
                if obj.object_type != "VAR":
                    assert int(sub.get("subIndex"), 16) == e.subindex and len(sub.get("subIndex")) == 2
                assert sub.get("dataType") in declared and int(sub.get("dataType"), 16) == e.data_type_index
                assert sub.get("accessType") == e.access
                assert sub.get("PDOmapping") in ("no", "default", "optional", "TPDO", "RPDO")
                text = sub.get("defaultValue")
                value = float(text) if e.data_type == "REAL32" else text if e.data_type == "VISIBLE_STRING" \
                    else int(text, 0)
                assert value == e.default
        # POWERLINK's mapping: the PReq's payload is the RPDO1, the PRes's TPDO1 then TPDO2
        for index, pdos in ((0x1600, ["RPDO1"]), (0x1A00, ["TPDO1", "TPDO2"])):
            subs = listed[index].findall("x:SubObject", NS)[1:]
            layout = [(int(s.get("defaultValue"), 0) & 0xFFFF, (int(s.get("defaultValue"), 0) >> 16) & 0xFF,
                       (int(s.get("defaultValue"), 0) >> 32) & 0xFFFF, int(s.get("defaultValue"), 0) >> 48) for s in subs]
            offset, want = 0, []
            for name in pdos:
                pdo = od.pdo(name)
                want += [(f.index, f.subindex, offset + f.offset, f.bits) for f in pdo.fields]
                offset += 8 * pdo.length
            assert layout == want


def test_the_reference_page_gets_the_generated_table(ods):
    """The docs site's hook puts the table generated from the data file into the reference page."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("mkdocs_hooks", ROOT / "mkdocs_hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    page = (ROOT / "docs" / "reference" / "object_dictionary.md").read_text(encoding="utf-8")
    assert page.count(hooks.OBJECT_DICTIONARY_MARKER) == 1
    table = reference_markdown(ods[0])
    assert table not in page  # not a copy in the repository
    assert table in hooks.object_dictionary_markdown(page)


def test_struct_codes_match_the_data_type_sizes():
    for name, (_, bits, code) in DATA_TYPES.items():
        if code and name != "BOOLEAN":
            assert struct.calcsize("<" + code) * 8 == bits
