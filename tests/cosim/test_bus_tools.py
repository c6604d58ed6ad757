"""Tools we did not write read what the bus of a run carried: ``cantools`` decodes the BLF export of
a short main-job run with the generated DBC into the same position, velocity and torque values the
drives report in the run's time series (``read_series``), and ``cosim device-files`` writes the
device descriptions and the database. The run is the main job's scenario cut to 0.6 s of one mode,
recording the drives' actual values at the bus cycle (the same code path as the main job)."""
from __future__ import annotations

import json
import shutil
import struct
import subprocess
from pathlib import Path

import can
import cantools
import numpy as np
import pytest

from cosim.cli import main
from cosim.results.timeseries import read_series
from fieldbus.blf import to_blf
from fieldbus.canlog import open_log
from fmus.servo_drive.object_dictionary import drive_object_dictionaries
from scenario_files import run_scenario, write_variant

ROOT = Path(__file__).resolve().parents[2]
MODE = "model_based"
QUANTITIES = {"position_actual": ("TPDO1", 0.5), "torque_actual": ("TPDO1", 0.5), "velocity_actual": ("TPDO2", 0.5)}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("bus_tools")
    text = (ROOT / "tests" / "long_forms" / "iso9283.toml").read_text(encoding="utf-8")
    path = write_variant(text, tmp / "short.toml", [
        ('stop_time = "12.6 s"', 'stop_time = "0.6 s"'),
        ('modes = ["standard", "model_based", "model_based_elastic"]', f'modes = ["{MODE}"]'),
        ('settle_time = "0.2 s"', 'settle_time = "0.1 s"'), ("figures = true", "figures = false"),
        ('period = "1 ms"\nsignals = ["drive*.current_demand"]',
         'period = "400 us"\nsignals = ["drive*.position_actual", "drive*.velocity_actual", "drive*.torque_actual"]')])
    code, summary = run_scenario(path, tmp / "run")
    assert code == 0 and summary["status"] == "ok"
    return tmp / "run"


@pytest.fixture(scope="module")
def device_files(tmp_path_factory):
    out = tmp_path_factory.mktemp("device_files")
    assert main(["device-files", str(out), "--scenario", str(ROOT / "scenarios" / "iso9283.toml")]) == 0
    return out


def test_device_files_writes_eds_xdd_and_dbc(device_files):
    names = sorted(p.name for p in device_files.iterdir())
    assert names == ["rx130l_bus.dbc", *sorted(f"servo_drive_node{n}.{s}" for n in range(1, 7) for s in ("eds", "xdd"))]
    # the scenario's per-drive parameters are the defaults (iso9283.toml sets the elastic speed gains)
    eds = (device_files / "servo_drive_node1.eds").read_text()
    assert "DefaultValue=0.3411074334399737" in eds.split("[2002]")[1].split("[")[0]


def test_device_files_refuses_a_bad_scenario(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[fieldbus]\ncycle_time_us = -4\n")
    assert main(["device-files", str(tmp_path / "out"), "--scenario", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cycle_time_us" in err[0]


def _decoded(db, blf: Path) -> dict[str, dict[int, dict]]:
    """{message name: {cycle: raw signal values}}: cycle k = the k-th SYNC (SoC) of the log."""
    out: dict[str, dict[int, dict]] = {}
    cycle = -1
    with can.BLFReader(str(blf)) as reader:
        for msg in reader:
            if msg.arbitration_id == 0x080:
                cycle += 1
                continue
            try:
                message = db.get_message_by_frame_id(msg.arbitration_id)
            except KeyError:
                continue
            out.setdefault(message.name, {})[cycle] = (message.decode(msg.data, scaling=False),
                                                       message.decode(msg.data))
    return out


def test_cantools_decodes_the_blf_into_the_values_of_the_time_series(run, device_files, tmp_path):
    db = cantools.database.load_file(str(device_files / "rx130l_bus.dbc"))
    blf = to_blf(run / f"can_{MODE}.parquet", tmp_path / "bus.blf")
    decoded = _decoded(db, blf)
    names, data = read_series(run / f"timeseries_{MODE}.parquet")
    column = {name: i for i, name in enumerate(names)}
    period = 400e-6
    assert np.allclose(data[:, 0], np.arange(len(data)) * period, rtol=0, atol=1e-12)
    worst = {}
    for od in drive_object_dictionaries():
        n = od.node
        for quantity, (pdo, half) in QUANTITIES.items():
            frames = decoded[f"{pdo}_node{n}"]
            cycles = np.array(sorted(frames))
            assert cycles.size == len(data) and cycles[0] == 0  # one PRes per cycle, none lost
            raw = np.array([frames[k][0][quantity] for k in cycles], dtype=np.int64)
            physical = np.array([frames[k][1][quantity] for k in cycles])
            signal = db.get_message_by_name(f"{pdo}_node{n}").get_signal_by_name(quantity)
            unit = od.rad_per_count if quantity != "torque_actual" else od.newton_metre_per_unit
            assert signal.scale == unit and signal.unit == {"torque_actual": "N m", "velocity_actual": "rad/s"}.get(
                quantity, "rad")
            series = data[cycles, column[f"drive{n}.{quantity}"]]
            # the drive's value at the SoC, encoded as the telegram encodes it: equal counts
            assert np.array_equal(np.floor(series / unit + 0.5).astype(np.int64), raw), (n, quantity)
            deviation = np.abs(physical - series)
            assert deviation.max() <= half * unit * (1 + 1e-9)
            worst[(n, quantity)] = deviation.max() / unit
    # positions: the drive reports whole encoder counts, so equal to the float's rounding
    assert max(v for (n, q), v in worst.items() if q == "position_actual") < 1e-6
    print("cantools vs read_series, max |deviation| in telegram units:", json.dumps(
        {f"{q} node {n}": round(v, 6) for (n, q), v in worst.items()}))


def test_the_project_reader_and_cantools_see_the_same_frames(run, device_files):
    """The DBC covers every frame of the log: SYNC, RPDO1, TPDO1, TPDO2 of each node (and EMCY)."""
    db = cantools.database.load_file(str(device_files / "rx130l_bus.dbc"))
    ids = {m.frame_id for m in db.messages}
    with open_log(run / f"can_{MODE}.parquet") as reader:
        seen = {msg.arbitration_id for msg in reader}
    assert seen <= ids and len(seen) == 19


# ------------------------------------------------------------------------------ Wireshark (tshark)
CANOPEN = ("-d", "can.subdissector,canopen")  # decode CAN payloads as CANopen
#: Wireshark tries its openSAFETY heuristic on every POWERLINK PDO payload and takes about 1 in
#: 6000 of ours for an openSAFETY frame, which it then finds malformed (67 of the main job's
#: 378 012 PReq/PRes of one mode); our PDOs carry no openSAFETY, so the analysis switches it off
NO_OPENSAFETY = ("--disable-protocol", "opensafety")


def _tshark(*args: str) -> list[str]:
    """tshark's output lines; the test fails (not skips) without tshark (.ci/run installs it)."""
    exe = shutil.which("tshark")
    assert exe, "tshark is not installed: .ci/run installs it (apt-get install tshark)"
    result = subprocess.run([exe, *args], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    return [line for line in result.stdout.splitlines() if line]


def _problems(path: Path, *extra: str) -> tuple[int, int]:
    """(malformed frames, frames with an expert-info error) as tshark dissects ``path``."""
    return (len(_tshark("-r", str(path), *extra, "-Y", "_ws.malformed")),
            len(_tshark("-r", str(path), *extra, "-Y", "_ws.expert.severity == error")))


def _log_telegrams(log: Path) -> list:
    """The run's CAN log through the project's reader: [(arbitration id, decoded telegram)]."""
    from fieldbus.telegrams import decode

    with open_log(log) as reader:
        return [(msg.arbitration_id, decode(msg)) for msg in reader]


@pytest.fixture(scope="module")
def captures(run, tmp_path_factory):
    out = tmp_path_factory.mktemp("captures")
    assert main(["export-pcap", str(run), "-o", str(out)]) == 0
    return out


def test_tshark_dissects_the_powerlink_capture_like_the_can_log(run, captures):
    from fieldbus.telegrams import RxPdo1, Sync, TxPdo1

    path = captures / f"powerlink_{MODE}.pcapng"
    frames = _tshark("-r", str(path), *NO_OPENSAFETY, "-T", "fields", "-E", "separator=;", "-e", "frame.protocols",
                     "-e", "epl.mtyp", "-e", "epl.src", "-e", "epl.dest", "-e", "data.data")
    assert all(line.split(";")[0].startswith("eth:ethertype:epl") for line in frames)
    assert _problems(path, *NO_OPENSAFETY) == (0, 0)
    # with openSAFETY on, anything malformed is a payload its heuristic took for openSAFETY
    stacks = _tshark("-r", str(path), "-Y", "_ws.malformed", "-T", "fields", "-e", "frame.protocols")
    assert all(stack.endswith(":opensafety") for stack in stacks)
    log = _log_telegrams(run / f"can_{MODE}.parquet")
    socs = [f for f in frames if f.split(";")[1] == "1"]
    assert len(socs) == sum(isinstance(t, Sync) for _, t in log) == len(_tshark("-r", str(path), "-Y", "epl.soc"))
    preqs = [f.split(";") for f in frames if f.split(";")[1] == "3"]
    pres = [f.split(";") for f in frames if f.split(";")[1] == "4"]
    want_preq = [t for _, t in log if isinstance(t, RxPdo1)]
    want_pres = [t for _, t in log if isinstance(t, TxPdo1)]
    assert [(int(s), int(d)) for _, _, s, d, _ in preqs] == [(240, t.node) for t in want_preq]
    assert [(int(s), int(d)) for _, _, s, d, _ in pres] == [(t.node, 255) for t in want_pres]
    assert {t.node for t in want_preq} == set(range(1, 7))
    # the position set-points (0x607A, bytes 2-5 of the PReq payload) and actual positions (0x6064)
    setpoints = [struct.unpack_from("<i", bytes.fromhex(p[4]), 2)[0] for p in preqs]
    assert setpoints == [t.target_position for t in want_preq] and len(set(setpoints)) > 100
    actuals = [struct.unpack_from("<i", bytes.fromhex(p[4]), 2)[0] for p in pres]
    assert actuals == [t.position_actual for t in want_pres]
    soas = [f for f in frames if f.split(";")[1] == "5"]
    assert len(soas) == len(socs) and len(frames) == len(socs) + len(preqs) + len(pres) + len(soas)
    print(f"tshark POWERLINK: {len(frames)} frames dissected ({len(socs)} SoC, {len(preqs)} PReq, {len(pres)} PRes, "
          f"{len(soas)} SoA), 0 malformed, 0 expert errors")


def test_tshark_dissects_the_can_capture_as_canopen_like_the_can_log(run, captures):
    from fieldbus.telegrams import RxPdo1, Sync

    path = captures / f"can_{MODE}.pcapng"
    frames = _tshark("-r", str(path), *CANOPEN, "-T", "fields", "-E", "separator=;", "-e", "can.id",
                     "-e", "canopen.sync.counter", "-e", "canopen.pdo.data.bytes", "-e", "frame.protocols")
    assert _problems(path, *CANOPEN) == (0, 0)
    log = _log_telegrams(run / f"can_{MODE}.parquet")
    assert [int(f.split(";")[0]) for f in frames] == [i for i, _ in log]
    assert all(f.split(";")[3].endswith("canopen") for f in frames)
    counters = [int(f.split(";")[1]) for f in frames if f.split(";")[1]]
    assert counters == [t.counter for _, t in log if isinstance(t, Sync)]
    rpdo = [bytes.fromhex(f.split(";")[2]) for f in frames if 0x201 <= int(f.split(";")[0]) <= 0x27F]
    assert [struct.unpack_from("<i", d, 2)[0] for d in rpdo] == [t.target_position for _, t in log
                                                                 if isinstance(t, RxPdo1)]
    print(f"tshark CAN: {len(frames)} frames dissected as CANopen, 0 malformed, 0 expert errors")


def test_emcy_and_corrupted_frames_in_both_captures(tmp_path):
    """A CAN log with an EMCY and a corrupted TPDO1: the POWERLINK capture invites the node with a
    StatusRequest and carries the EMCY as its StatusResponse's error entry, leaves the corrupted
    PRes out; the CAN capture has the EMCY and an error frame; tshark finds nothing malformed."""
    from fieldbus import telegrams
    from fieldbus.canlog import RECORD_DTYPE, CanLogWriter

    records = []

    def add(t, arbitration_id, data, error=False):
        r = np.zeros(1, RECORD_DTYPE)
        r["t"], r["id"], r["error"], r["length"] = t, arbitration_id, error, len(data)
        r["data"][0, :len(data)] = np.frombuffer(data, np.uint8)
        records.append(r)

    for k in range(3):
        t0 = k * 400e-6
        add(t0, 0x080, bytes([k + 1]))
        for n in (1, 2):
            add(t0 + 10e-6 * n, 0x200 + n, telegrams.encode_rpdo1(0x0F, 1000 * n + k, 5))
            add(t0 + 10e-6 * n + 5e-6, 0x180 + n, telegrams.encode_tpdo1(0x1237, 1000 * n + k, 3), error=(k, n) == (1, 2))
            add(t0 + 10e-6 * n + 5e-6, 0x280 + n, telegrams.encode_tpdo2(77, 0, 8))
    add(800e-6 + 200e-6, 0x082, struct.pack("<HBBHH", 0x8100, 0x11, 3, 16, 15))
    writer = CanLogWriter(tmp_path / "can_x.parquet")
    writer.write_records(np.concatenate(records))
    writer.close()
    assert main(["export-pcap", str(tmp_path / "can_x.parquet"), "-o", str(tmp_path)]) == 0
    epl, can_capture = tmp_path / "powerlink_x.pcapng", tmp_path / "can_x.pcapng"
    assert _problems(epl, *NO_OPENSAFETY) == (0, 0) and _problems(can_capture, *CANOPEN) == (0, 0)
    assert len(_tshark("-r", str(epl), "-Y", "epl.pres")) == 5  # the corrupted PRes is left out
    soa = _tshark("-r", str(epl), "-Y", "epl.soa.svid == 2", "-T", "fields", "-e", "epl.soa.svtg")
    assert soa == ["2"]
    entry = _tshark("-r", str(epl), "-Y", "epl.asnd", "-T", "fields", "-E", "occurrence=f", "-e", "epl.src",
                    "-e", "epl.asnd.svid", "-e", "epl.asnd.sres.el.entry.code", "-e", "epl.asnd.sres.el.entry.type.profile")
    assert entry == ["2\t0x02\t33024\t402"]
    emcy = _tshark("-r", str(can_capture), *CANOPEN, "-Y", "canopen.em.err_code", "-T", "fields",
                   "-e", "can.id", "-e", "canopen.em.err_code", "-e", "canopen.em.err_reg")
    assert emcy == ["130\t0x8100\t0x11"]
    assert len(_tshark("-r", str(can_capture), "-Y", "can.flags.err == 1")) == 1


def test_tshark_finds_what_is_wrong_in_a_broken_capture(tmp_path):
    """The checks above can fail: a PReq whose size field exceeds its frame is an expert error, a SoC
    cut short is malformed."""
    from pcapng import FileWriter, blocks

    header = bytes.fromhex("0200000000f0") + b"\x88\xab"
    frames = [bytes.fromhex("020000000001") + header + struct.pack("<BBBBBBBBH", 3, 1, 240, 0, 1, 0, 0, 0, 200)
              + bytes(36), bytes.fromhex("01111e000001") + header + bytes((1, 255, 240, 0, 0))]
    shb = blocks.SectionHeader()
    shb.new_member(blocks.InterfaceDescription, link_type=1)
    path = tmp_path / "broken.pcapng"
    with open(path, "wb") as handle:
        writer = FileWriter(handle, shb)
        for frame in frames:
            packet = shb.new_member(blocks.EnhancedPacket)
            packet.packet_data = frame
            writer.write_block(packet)
    assert _problems(path) == (1, 2)


def test_export_pcap_refuses_a_folder_without_a_can_log(tmp_path, capsys):
    assert main(["export-pcap", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "can_*.parquet" in err[0]
    assert main(["export-pcap", str(tmp_path / "can_nothing.parquet")]) == 2
