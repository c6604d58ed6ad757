"""FMUs built from a user's C source (fmus/source_fmu.py, [[fmus]] source = ...): the example payload
FMU validates, its joint torques equal pinocchio's gravity torque of the same payload, bad folders fail
with a clear message."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.validation import validate_fmu

from cosim.results import read_series
from fmus.source_fmu import SourceFmuError, build_source_fmu
from robot.dynamics import RobotDynamics

ROOT = Path(__file__).resolve().parents[2]
PAYLOAD = ROOT / "examples" / "fmus" / "payload"


@pytest.fixture(scope="module")
def payload_fmu():
    path = build_source_fmu(PAYLOAD)
    assert validate_fmu(str(path)) == []
    return path


def _slave(path: Path, parameters: dict[str, float]):
    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)), modelIdentifier="payload", instanceName="p")
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.setReal([vr[k] for k in parameters], list(parameters.values()))
    slave.exitInitializationMode()
    return slave, vr


def test_payload_torques_equal_pinocchio_gravity_of_the_payload(payload_fmu):
    payload = [7.0, 0.02, -0.03, 0.11]
    slave, vr = _slave(payload_fmu, {"mass": payload[0], "com[1]": payload[1], "com[2]": payload[2],
                                     "com[3]": payload[3]})
    bare, loaded = RobotDynamics(payload=[0, 0, 0, 0]), RobotDynamics(payload=payload)
    q_vr, tau_vr = [vr[f"q[{j}]"] for j in range(1, 7)], [vr[f"tau[{j}]"] for j in range(1, 7)]
    worst = 0.0
    for q in np.random.default_rng(1).uniform(-2.0, 2.0, (25, 6)):
        slave.setReal(q_vr, list(q))
        tau = np.array(slave.getReal(tau_vr))
        reference = -(loaded.gravity(q) - bare.gravity(q))      # the payload's share of g(q), opposite sign
        worst = max(worst, float(np.abs(tau - reference).max()))
    assert worst < 1e-9                                          # measured 1.1e-13 N m
    slave.terminate()
    slave.freeInstance()


def test_payload_is_picked_and_released_at_the_given_times(payload_fmu):
    slave, vr = _slave(payload_fmu, {"pick_time": 0.001, "release_time": 0.002})
    slave.setReal([vr[f"q[{j}]"] for j in range(1, 7)], [0.0, 0.4, 1.8, 0.0, 0.9, 3.14])
    masses, torques, t = [], [], 0.0
    for _ in range(30):
        masses.append(slave.getReal([vr["load_mass"]])[0])
        torques.append(slave.getReal([vr["tau[2]"]])[0])
        slave.doStep(t, 1e-4)
        t += 1e-4
    assert masses[:10] == [0.0] * 10 and masses[10:20] == [5.0] * 10 and masses[20:] == [0.0] * 10
    assert torques[0] == 0.0 and abs(torques[15]) > 10.0
    slave.terminate()
    slave.freeInstance()


def test_bad_source_folders_fail_clearly(tmp_path):
    with pytest.raises(SourceFmuError, match="no modelDescription.xml"):
        build_source_fmu(tmp_path)
    broken = tmp_path / "payload"
    shutil.copytree(PAYLOAD, broken)
    shutil.copy(PAYLOAD.parent / "fmi2_cs_template.h", tmp_path)
    (broken / "payload.c").write_text((PAYLOAD / "payload.c").read_text().replace("r[VR_LOAD] = mass;",
                                                                                  "r[VR_LOAD] = mass"))
    with pytest.raises(SourceFmuError, match=r"(?s)compiling failed.*payload.c:\d+:\d+: error: expected"):
        build_source_fmu(broken)


def test_feedforward_controller_fmu_computes_its_documented_law():
    path = build_source_fmu(ROOT / "examples" / "fmus" / "feedforward_controller")
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)), modelIdentifier="feedforward_controller",
                      instanceName="c")
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    rng = np.random.default_rng(2)
    q, qd, qdd = rng.uniform(-2, 2, 6), rng.uniform(-1, 1, 6), rng.uniform(-5, 5, 6)
    for name, values in (("q_ref", q), ("qd_ref", qd), ("qdd_ref", qdd)):
        slave.setReal([vr[f"{name}[{j}]"] for j in range(1, 7)], list(values))
    slave.doStep(0.0, 4e-4)
    inertia = np.array([27.0, 35.8, 19.9, 0.390, 0.469, 0.0508])
    viscous, coulomb = np.array([24.0, 17.0, 6.0, 1.7, 2.8, 1.0]), np.array([21.0, 25.0, 19.0, 3.7, 4.5, 0.4])
    expected = inertia * qdd + viscous * qd + coulomb * np.tanh(qd / 0.01)
    assert np.allclose(slave.getReal([vr[f"torque_offset[{j}]"] for j in range(1, 7)]), expected, rtol=1e-14,
                       atol=1e-12)
    assert slave.getReal([vr[f"target_position[{j}]"] for j in range(1, 7)]) == list(q)
    slave.terminate()
    slave.freeInstance()


def test_payload_example_picks_a_part_through_tau_ext(tmp_path):
    """examples/payload_pick.toml as a user runs it: the payload FMU (built from C) hangs 3 kg on the
    flange at 0.6 s through the plant's tau_ext; the three controllers run and are ranked."""
    import json

    from cosim.cli import main

    out = tmp_path / "out"
    assert main(["run", str(ROOT / "examples" / "payload_pick.toml"), "--out", str(out), "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    rows = {r["controller"]: r for r in summary["table"]}
    assert set(rows) == {"standard", "model_based", "pd_gravity"}
    assert all(r["status"] == "ok" for r in rows.values()) and rows["model_based"]["rank"] == 1
    columns, data = read_series(out / "timeseries_model_based__pick_place_joint.parquet")
    series = [dict(zip(columns, row)) for row in data]
    mass = {round(float(r["time"]), 4): float(r["payload.load_mass"]) for r in series}
    assert mass[0.599] == 0.0 and mass[0.602] == 3.0 and mass[1.5] == 3.0
    # its weight on axis 2 is about m g times the horizontal reach of the flange (> 1 m here)
    assert 3.0 * 9.81 * 0.9 < abs(float(series[1000]["payload.tau[2]"])) < 3.0 * 9.81 * 1.6
