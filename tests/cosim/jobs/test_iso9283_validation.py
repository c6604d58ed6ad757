"""scenarios/iso9283.toml is validated before anything runs: each mistake is a ScenarioError
naming the file, the key and what was expected; the CLI exits with 2 and writes nothing."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from cosim.cli import main
from cosim.scenario import ScenarioError, load_scenario
from error_checks import assert_names_file_and_fragments
from scenario_files import write_variant

ROOT = Path(__file__).resolve().parents[3]
# the validation cases edit the rigid-plant variant (its drive tables have no [fmus.parameters]);
# the main job itself is validated by test_the_main_scenario_is_valid
SCENARIO = (ROOT / "tests" / "long_forms" / "iso9283_rigid.toml").read_text(encoding="utf-8")


def variant(tmp_path: Path, old: str, new: str) -> Path:
    return write_variant(SCENARIO, tmp_path / "iso.toml", [(old, new)])


def test_the_main_scenario_is_valid():
    scenario = load_scenario(ROOT / "scenarios" / "iso9283.toml")
    assert scenario.job.name == "iso9283"
    assert scenario.data["controller"]["modes"] == ["standard", "model_based", "model_based_elastic"]
    ctrl = scenario.data["controller"]
    assert [ctrl[m]["drive_speed_feedforward"] for m in ctrl["modes"]] == [False, True, True]
    assert scenario.data["simulation"]["macro_step"] == pytest.approx(100e-6)
    assert scenario.data["controller"]["period"] == pytest.approx(400e-6)


DRIVE3_BLOCK = re.search(r'\[\[fmus\]\]\nname = "drive3"\n[^\n]*\n', SCENARIO).group(0)

CASES = [
    ("unknown key", 'settle_time = "0.2 s"', 'settle_time = "0.2 s"\nsettle_mode = "fast"',
     ["controller.settle_mode", "unknown key"]),
    ("wrong type", "seed = 1 ", 'seed = "one" ', ["true_robot.seed", "expected an integer", "'one'"]),
    ("wrong unit", 'period = "400 us"', 'period = "400 mm"', ["controller.period", "a number in s", "'400 mm'"]),
    ("out of range", 'payload_mass = "8 kg"', 'payload_mass = "12 kg"', ["true_robot.payload_mass", "10"]),
    ("missing FMU", DRIVE3_BLOCK, "", ["fmus", "drive3", "missing"]),
    ("bad connection", "[scenario]", 'connections = ["plant.qd[1] -> drive1.qd_meas", "plant.q[7] -> drive1.q_meas"]'
     "\n[scenario]", ["connections[1]", "unknown variable 'q[7]'"]),
    ("connection from an unknown FMU", "[scenario]", 'connections = ["payload.tau -> plant.tau[1]"]\n[scenario]',
     ["connections[0]", "unknown instance 'payload'"]),
    ("missing FMU file", 'name = "drive6"\nbuiltin = "servo_drive"', 'name = "drive6"\npath = "nowhere/drive.fmu"',
     ["fmus[6].path", "does not exist"]),
    ("fieldbus key", "cycle_time_us = 400", "cycle_time_us = 400\ncycle_time = 400", ["fieldbus.cycle_time"]),
    ("fieldbus vs controller", "cycle_time_us = 400", "cycle_time_us = 800", ["controller.period", "800"]),
    ("plant parameter set by the job", "integration_step = 1e-4      # s",
     'integration_step = 1e-4\n"q0[1]" = 0.1', ["fmus[0]", "q0[1]", "set by the job"]),
    ("tracker period vs macro step", 'period = "1 ms"              # Leica', 'period = "1.05 ms"  # Leica',
     ["tracker.period", "multiple of macro_step"]),
    ("unknown mode", 'modes = ["standard", "standard_speed_ff", "model_based"]', 'modes = ["standard", "adaptive"]',
     ["controller.modes[1]", "'adaptive'", "'model_based'", "'standard_speed_ff'"]),
    ("per-mode drive speed feed-forward type", "[controller.standard]\ndrive_speed_feedforward = false",
     '[controller.standard]\ndrive_speed_feedforward = "off"', ["controller.standard.drive_speed_feedforward",
                                                                "'off'"]),
    ("per-mode unknown key", "[controller.standard]\n", "[controller.standard]\ntorque_feedforward = true\n",
     ["controller.standard.torque_feedforward", "unknown key"]),
    ("drive speed feed-forward set by the job", DRIVE3_BLOCK,
     DRIVE3_BLOCK + "[fmus.parameters]\nspeed_feedforward_gain = 0.5\n",
     ["fmus[3].parameters.speed_feedforward_gain", "set by the job", "drive_speed_feedforward"]),
]


@pytest.mark.parametrize("name, old, new, expected", CASES, ids=[c[0] for c in CASES])
def test_scenario_errors_name_file_key_and_expectation(tmp_path, name, old, new, expected):
    path = variant(tmp_path, old, new)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert_names_file_and_fragments(info.value, path, expected)


def test_cli_rejects_invalid_scenario_before_running(tmp_path, capsys):
    path = variant(tmp_path, 'period = "400 us"', 'period = "400 mm"')
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 2
    assert "controller.period" in capsys.readouterr().err
    assert not out.exists()


def test_connections_are_generated_and_a_scenario_lists_only_what_differs(tmp_path):
    """The 42 connections are generated; a scenario connection into an input the cell drives
    replaces the generated one (here drive 1's speed measurement from the plant's joint 2)."""
    from cosim.cell.wiring import cell_connections, merged_connections

    assert "connections" not in load_scenario(ROOT / "scenarios" / "iso9283.toml").data or \
        not load_scenario(ROOT / "scenarios" / "iso9283.toml").data["connections"]
    from cosim.cell.wiring import drive_variables_of

    path = variant(tmp_path, "[scenario]", 'connections = ["plant.qd[2] -> drive1.qd_meas"]\n[scenario]')
    doc = load_scenario(path).data
    servo = drive_variables_of(doc["fmus"])
    generated = cell_connections(servo)
    assert len(generated) == 66 and merged_connections([], servo) == generated  # all inputs of servo_drive
    assert merged_connections(generated, servo) == generated  # an old file listing them gives the same wiring
    merged = merged_connections(doc["connections"], servo)
    assert merged[0] == "plant.qd[2] -> drive1.qd_meas" and "plant.qd_motor[1] -> drive1.qd_meas" not in merged
    assert len(merged) == 66
    # a drive of the minimal interface gets only its required inputs (5 per axis)
    minimal = cell_connections({d: {"q_meas", "qd_meas", "target_position", "controlword"} for d in servo})
    assert len(minimal) == 30 and not any("torque_offset" in c or "fault_code" in c for c in minimal)
