"""The machine's protection in whole cell runs (docs/explanation/fmus.md "Protection"): a user's controller
commanding 1e6 N·m in torque mode is clamped at the drive's max torque, faulted at the software
position limit (0x8612, EMCY on the bus) and stopped by the end stop within its contact
deflection; a following error beyond its window for its time faults with 0x8611 and an EMCY;
the main job's modes have no protection event; bad protection parameters are refused naming
the file, the key and the allowed range (exit code 2)."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from cosim.cli import main
from cosim.results import read_series
from cosim.scenario import ScenarioError, load_scenario
from fieldbus.canlog import CanLogReader
from fmus.servo_drive.params import drive_start_values, load_drive_parameters
from robot.parameters import load_parameters
from scenario_files import run_scenario, write_variant

ROOT = Path(__file__).resolve().parents[3]
MAIN = (ROOT / "tests" / "long_forms" / "iso9283.toml").read_text()
MODES_LINE = 'modes = ["standard", "model_based", "model_based_elastic"]'
ROBOT = load_parameters()


def emcy_codes(path: Path) -> list[tuple[int, int]]:
    """(node, error code) of every EMCY frame (0x081..0x0FF) in a CAN log."""
    return [(f.arbitration_id - 0x80, int.from_bytes(bytes(f.data[:2]), "little")) for f in CanLogReader(path)
            if 0x80 < f.arbitration_id <= 0xFF and len(f.data) == 8]


def violations(summary: dict, mode: str) -> list[dict]:
    return summary["modes"][mode]["violations"]


@pytest.fixture(scope="module")
def runaway(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("runaway")
    shutil.copy(Path(__file__).with_name("runaway_torque.py"), tmp / "runaway_torque.py")
    path = write_variant(MAIN, tmp / "runaway.toml", [
        ('stop_time = "12.6 s"', 'stop_time = "1.0 s"'),
        (MODES_LINE, 'modes = []\nclass = "runaway_torque.py:RunawayTorque"'),
        ("figures = true", "figures = false")])
    out = tmp / "out"
    code, summary = run_scenario(path, out)
    return code, summary, out


def test_1e6_newton_metres_are_clamped_faulted_and_stopped_by_the_end_stop(runaway):
    code, summary, out = runaway
    assert code == 4 and summary["status"] == "limit"  # completed with a protection limit
    events = violations(summary, "RunawayTorque")
    first = {}
    for e in events:
        first.setdefault((e["kind"], e["joint"]), e)
    names, data = read_series(out / "timeseries_RunawayTorque.parquet")
    col = {n: data[:, k] for k, n in enumerate(names)}
    # the torque limit (0x6072): reached on joint 3, and the drive never gives more than it allows
    drive3 = drive_start_values(3)
    torque = first[("torque_limit", 3)]
    assert torque["limit"] == drive3["torque_limit"] == 450.0 and torque["reaction"] == "none"
    peak = np.abs(col["drive3.tau_out"]).max()
    assert 0.99 * 450.0 < peak < 1.02 * 450.0  # measured 455 N m: the current loop's overshoot
    # joint 3 runs into its software position limit (0x607D): fault 0x8612, fault reaction
    position = first[("position_limit", 3)]
    assert position["error_code"] == "0x8612" and position["reaction"] == "fault"
    assert position["limit"] == pytest.approx(ROBOT.position_upper[2])
    assert (3, 0x8612) in emcy_codes(out / "can_RunawayTorque.parquet")
    # never beyond the max motor speed (0x6080, 1.3x the URDF speed; the unprotected cell reached 2x)
    assert np.abs(col["plant.qd[3]"]).max() < drive3["max_motor_speed"]
    # the end stop takes the rest: no joint beyond its stop by more than the contact deflection of
    # its impact (undamped spring v sqrt(J_max / k)) plus the drive's peak torque on the spring
    inertia_max = load_drive_parameters().get("tuning", "inertia_max")
    stop = first[("end_stop", 3)]
    assert stop["impact_speed_rad_s"] > 1.0 and stop["stop_rad"] == pytest.approx(ROBOT.end_stop_upper[2])
    for j in range(6):
        q = col[f"plant.q[{j + 1}]"]
        beyond = max(0.0, q.max() - ROBOT.end_stop_upper[j], ROBOT.end_stop_lower[j] - q.min())
        speeds = [e["impact_speed_rad_s"] for e in events if e["kind"] == "end_stop" and e["joint"] == j + 1]
        k = ROBOT.end_stop_stiffness[j]
        deflection = max(speeds, default=0.0) * np.sqrt(inertia_max[j] / k) + ROBOT.effort_limit[j] / k
        assert beyond <= deflection, (j + 1, beyond, deflection)
        if j == 2:
            assert 0.01 < beyond < deflection  # measured 0.0246 rad against 0.0289 rad
    assert summary["modes"]["RunawayTorque"]["first_violation"]["kind"] == "torque_limit"


def test_following_error_faults_with_8611_and_an_emcy(tmp_path):
    """The standard cascade lags axis 1 by qd/Kv (34 mrad at the path's speed): a 10 mrad window
    (0x6065) exceeded for the 10 ms time-out (0x6066) raises 0x8611; the drive's node sends EMCY
    0x8611 on the bus; the run completes with verdict limit."""
    path = write_variant(MAIN, tmp_path / "fe.toml", [
        ('stop_time = "12.6 s"', 'stop_time = "1.0 s"'), (MODES_LINE, 'modes = ["standard"]'),
        ('settle_time = "0.2 s"', 'settle_time = "0.05 s"'), ("figures = true", "figures = false"),
        ('name = "drive1"\nbuiltin = "servo_drive"      # gains: drive_params.toml (axis 1), speed loop for an '
         'elastic axis\n[fmus.parameters]\n',
         'name = "drive1"\nbuiltin = "servo_drive"\n[fmus.parameters]\nfollowing_error_window = 0.01\n')])
    code, summary = run_scenario(path, tmp_path / "out")
    assert code == 4 and summary["status"] == "limit"
    fe = [e for e in violations(summary, "standard") if e["kind"] == "following_error"]
    assert fe and fe[0]["joint"] == 1 and fe[0]["error_code"] == "0x8611" and fe[0]["reaction"] == "fault"
    assert fe[0]["limit"] == 0.01 and fe[0]["value"] > 0.01
    assert (1, 0x8611) in emcy_codes(tmp_path / "out" / "can_standard.parquet")
    tally = summary["modes"]["standard"]["fieldbus"]["event_tally"]
    assert tally["cn.drive_error.emcy_sent"] == 1 and tally["mn.emcy.emcy_received"] == 1


def test_the_main_job_modes_have_no_protection_event(tmp_path):
    """The main job's three modes (1 s of it) run without any drive limit or end-stop event."""
    path = write_variant(MAIN, tmp_path / "main.toml", [
        ('stop_time = "12.6 s"', 'stop_time = "1.0 s"'), ("figures = true", "figures = false"),
        ("can_log = true", "can_log = false")])
    code, summary = run_scenario(path, tmp_path / "out")
    assert code == 0 and summary["status"] == "ok"
    for mode in ("standard", "model_based", "model_based_elastic"):
        assert summary["modes"][mode]["verdict"] == "ok" and violations(summary, mode) == []


@pytest.mark.parametrize("fmu, key, value, expected", [
    ("drive3", "torque_limit", 600.0, r"max torque \(0x6072\) in \(0, 455.6\] N.m"),
    ("drive3", "current_limit", 9.0, r"max current \(0x6073\) in \(0, 6.7\] A"),
    ("drive3", "position_limit_max", 2.7, r"within \[-2.66799, 2.66799\] rad \(the plant's mechanical end stops"),
    ("drive2", "following_error_window", -0.01, r"expected a value >= 0 rad"),  # the FMU's declared range
    ("drive5", "rated_current", 5.0, r"motor rated current \(0x6075\) in \(0, 1.9\] A"),
])
def test_protection_parameters_outside_the_drives_range_are_refused(tmp_path, fmu, key, value, expected):
    header = f'name = "{fmu}"\nbuiltin = "servo_drive"'
    start = MAIN.index(header)
    params = MAIN.index("[fmus.parameters]\n", start) + len("[fmus.parameters]\n")
    path = tmp_path / "bad.toml"
    path.write_text(MAIN[:params] + f"{key} = {value}\n" + MAIN[params:])
    with pytest.raises(ScenarioError, match=rf"bad.toml.*fmus\[{int(fmu[-1])}\]\.parameters\.{key}.*{expected}"):
        load_scenario(path)


def test_a_bad_limit_is_a_one_line_error_with_exit_code_2(tmp_path, capsys):
    text = MAIN.replace('speed_kp = 0.39502959500596646', 'speed_kp = 0.39502959500596646\ntorque_limit = 1e6', 1)
    path = tmp_path / "bad.toml"
    path.write_text(text)
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "torque_limit" in err[0] and "bad.toml" in err[0] and "455.6" in err[0]
    assert "Traceback" not in err[0]


def test_end_stops_inside_the_software_limits_are_refused(tmp_path):
    header = 'name = "plant"\nbuiltin = "rx130l_plant"'
    start = MAIN.index(header)
    params = MAIN.index("[fmus.parameters]\n", start) + len("[fmus.parameters]\n")
    path = tmp_path / "stops.toml"
    path.write_text(MAIN[:params] + '"end_stop_upper[2]" = 2.0\n' + MAIN[params:])
    with pytest.raises(ScenarioError, match=r"fmus\[2\]\.parameters\.position_limit_max.*within \[-2.44983, 2\] rad.*end stops of joint 2"):
        load_scenario(path)


def test_events_reach_the_split_execution(runaway, tmp_path):
    """--split runs drives and plant in another process: the same events come back."""
    shutil.copy(Path(__file__).with_name("runaway_torque.py"), tmp_path / "runaway_torque.py")
    path = write_variant(MAIN, tmp_path / "split.toml", [
        ('stop_time = "12.6 s"', 'stop_time = "0.4 s"'),
        (MODES_LINE, 'modes = []\nclass = "runaway_torque.py:RunawayTorque"'),
        ("figures = true", "figures = false"), ("can_log = true", "can_log = false")])
    out = tmp_path / "out"
    code = main(["run", str(path), "--out", str(out), "--quiet", "--split"])
    summary = json.loads((out / "summary.json").read_text())
    assert code == 4 and summary["execution"]["mode"] == "split"
    kinds = {(e["kind"], e["joint"]) for e in violations(summary, "RunawayTorque")}
    assert ("torque_limit", 3) in kinds
