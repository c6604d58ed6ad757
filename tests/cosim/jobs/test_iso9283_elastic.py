"""The main job, the ISO 9283 path on the elastic-joint plant (scenarios/iso9283.toml), on a short
slice: the three controller modes in order of model depth, the drives tuned for elastic
axes, the vibration fields."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cosim.scenario import load_scenario
from fmus.servo_drive.tuning import elastic_axis_speed_kp
from scenario_files import run_scenario, write_variant

ROOT = Path(__file__).resolve().parents[3]
SCENARIO = ROOT / "scenarios" / "iso9283.toml"  # the main job: the elastic plant
LONG = ROOT / "tests" / "long_forms" / "iso9283.toml"  # the same, written out (tests/long_forms/README.md)


def test_scenario_drive_gains_are_the_elastic_tuning_rule():
    doc = load_scenario(SCENARIO).raw  # the cell of scenarios/cell_elastic.toml, merged
    fmus = {f["name"]: f for f in doc["fmus"]}
    kp = [fmus[f"drive{i}"]["parameters"]["speed_kp"] for i in range(1, 7)]
    np.testing.assert_allclose(kp, elastic_axis_speed_kp(), rtol=1e-15)
    assert fmus["plant"]["parameters"]["elastic_joints"] == 1
    assert "connections" not in doc  # the cell's generated wiring: the encoders see the motors
    from cosim.cell.wiring import cell_connections
    assert all("q_motor" in c for c in cell_connections() if c.endswith(".q_meas"))


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    """0.1 s settling + 0.9 s of the path (most of the first rectangle edge, 1 m/s)."""
    tmp = tmp_path_factory.mktemp("iso_elastic")
    path = write_variant(LONG.read_text(encoding="utf-8"), tmp / "iso.toml",
                         [('stop_time = "12.6 s"', 'stop_time = "1.0 s"'),
                          ('settle_time = "0.2 s"', 'settle_time = "0.1 s"'),
                          ("can_log = true", "can_log = false"), ("figures = true", "figures = false")])
    return run_scenario(path, tmp / "out")


def test_each_level_of_model_buys_accuracy(short_run):
    code, summary = short_run
    assert code == 0 and summary["status"] == "ok"
    std, rigid, elastic = (summary["modes"][m]["tcp_error_max_mm"]
                           for m in ("standard", "model_based", "model_based_elastic"))
    print(f"elastic plant, first 0.9 s of the path: standard {std:.3f} mm, rigid FF {rigid:.3f} mm, "
          f"elastic FF {elastic:.4f} mm")
    assert std > rigid > 3 * elastic
    assert summary["improvement_factor_elastic_vs_model_based"] == pytest.approx(rigid / elastic)
    for mode in ("standard", "model_based", "model_based_elastic"):
        entry = summary["modes"][mode]
        assert entry["tcp_error_spectrum_peak_hz"] >= 2.0
        assert set(entry["residual_vibration"]) >= {"peak_mm", "settling_time_s", "static_offset_mm"}


def test_a_gear_too_stiff_for_the_plant_step_fails_cleanly_naming_the_key(tmp_path):
    path = write_variant(LONG.read_text(encoding="utf-8"), tmp_path / "iso.toml", [
        ("elastic_joints = 1 ", '"stiffness[6]" = 1e8\nelastic_joints = 1 '),
        ('stop_time = "12.6 s"', 'stop_time = "0.5 s"'), ("can_log = true", "can_log = false"),
        ("figures = true", "figures = false")])
    code, summary = run_scenario(path, tmp_path / "out")
    assert code == 3 and summary["status"] == "failed" and summary["failed_component"] == "plant"
    assert "stiffness[6] = 1e+08 N.m/rad" in summary["reason"]
    assert "RK4 is stable up to stiffness[6] = " in summary["reason"]


@pytest.mark.parametrize("setting, fragments", [
    ('"stiffness[2]" = 0.0', ["stiffness[2] = 0 N.m/rad", "expected a gear stiffness > 0"]),
    ('"stiffness[3]" = -5.0', ["stiffness[3]", "-5"]),
    ('"backlash[1]" = 0.01', ["backlash[1]", "0.01", "0.001"]),
])
def test_bad_gear_settings_fail_cleanly_naming_the_key(tmp_path, setting, fragments):
    """Zero or negative stiffness and a backlash wider than plausible (1e-3 rad) set on the
    main job's plant: no traceback, a documented exit code (2: refused while loading the
    scenario, 3: refused by the plant when it initialises) and a message naming the key."""
    path = write_variant(LONG.read_text(encoding="utf-8"), tmp_path / "iso.toml", [
        ("elastic_joints = 1 ", setting + "\nelastic_joints = 1 "),
        ('modes = ["standard", "model_based", "model_based_elastic"]', 'modes = ["standard"]'),
        ('stop_time = "12.6 s"', 'stop_time = "0.3 s"'), ("can_log = true", "can_log = false"),
        ("figures = true", "figures = false")])
    from cosim.cli import main
    from cosim.scenario import ScenarioError, load_scenario

    try:
        load_scenario(path)
    except ScenarioError as exc:  # refused before anything runs
        message = str(exc)
        assert main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    else:
        code, summary = run_scenario(path, tmp_path / "out")
        assert code == 3 and summary["status"] == "failed" and summary["failed_component"] == "plant"
        message = summary["reason"]
    for fragment in fragments:
        assert fragment in message, (fragment, message)
