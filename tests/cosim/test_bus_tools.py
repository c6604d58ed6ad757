"""Tools we did not write read what the bus of a run carried: ``cantools`` decodes the BLF export of
a short main-job run with the generated DBC into the same position, velocity and torque values the
drives report in the run's time series (``read_series``), and ``cosim device-files`` writes the
device descriptions and the database. The run is the main job's scenario cut to 0.6 s of one mode,
recording the drives' actual values at the bus cycle (the same code path as the main job)."""
from __future__ import annotations

import json
from pathlib import Path

import can
import cantools
import numpy as np
import pytest

from cosim.cli import main
from cosim.results.timeseries import read_series
from fieldbus.canlog import open_log, to_blf
from fmus.servo_drive.object_dictionary import drive_object_dictionaries
from scenario_files import run_scenario, write_variant

ROOT = Path(__file__).resolve().parents[2]
MODE = "model_based"
QUANTITIES = {"position_actual": ("TPDO1", 0.5), "torque_actual": ("TPDO1", 0.5), "velocity_actual": ("TPDO2", 0.5)}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("bus_tools")
    text = (ROOT / "scenarios" / "iso9283.toml").read_text(encoding="utf-8")
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
