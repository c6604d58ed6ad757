"""The scenario files in scenarios/ that use the generic 'fmus' job validate and run with the
project's own FMUs (``builtin = ...`` resolved through fmus.build.build_fmu)."""
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from cosim.cli import main
from cosim.results import read_csv
from cosim.scenario import load_scenario

SCENARIOS = Path(__file__).resolve().parents[3] / "scenarios"
GENERIC = sorted(p for p in SCENARIOS.glob("*.toml")
                 if tomllib.loads(p.read_text()).get("scenario", {}).get("job") == "fmus")


def test_there_is_a_generic_scenario():
    assert any(p.name == "plant_drop.toml" for p in GENERIC)


@pytest.mark.parametrize("path", GENERIC, ids=[p.name for p in GENERIC])
def test_generic_scenarios_validate(path):
    scenario = load_scenario(path)
    for fmu in scenario.data["fmus"]:
        assert Path(fmu["path"]).is_file()


def test_plant_drop_runs_and_the_arm_falls(tmp_path):
    text = (SCENARIOS / "plant_drop.toml").read_text()
    assert "stop_time = 0.5" in text
    short = tmp_path / "plant_drop_short.toml"  # builtin FMUs: no relative paths to keep
    short.write_text(text.replace("stop_time = 0.5", "stop_time = 0.1"))
    assert main(["run", str(short), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["status"] == "ok" and summary["sim_time_s"] == pytest.approx(0.1)
    columns, data = read_csv(tmp_path / "out" / "timeseries.csv")
    assert len(data) == 101
    q2, q3 = data[:, columns.index("plant.q[2]")], data[:, columns.index("plant.q[3]")]
    # zero torque: the bent arm starts at rest and accelerates under gravity
    assert q2[0] == pytest.approx(-0.3) and q3[0] == pytest.approx(1.2)
    qdd3 = data[0, columns.index("plant.qdd[3]")]
    assert abs(qdd3) > 1.0
    assert np.sign(q3[-1] - q3[0]) == np.sign(qdd3)
