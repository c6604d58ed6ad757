"""The plant FMU, stepped by fmpy, against an independent solve: pinocchio forward
dynamics (ABA with armature) + friction from robot.dynamics, integrated by scipy
solve_ivp (DOP853, rtol = atol = 1e-12) with the same zero-order-hold torques."""
import tomllib
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from scipy.integrate import solve_ivp

from fmus.build import ensure_fmus
from robot.dynamics import RobotDynamics
from robot.true_robot import make_true_robot

Q0 = np.array([0.3, -0.6, 1.2, 0.4, 0.8, -0.2])
# the reference has no mechanical end stops: they are moved out of reach here (a falling arm
# passes its joint range within the second); tests/fmus/test_end_stops.py checks them
FREE_JOINTS = {f"end_stop_{side}[{k}]": sign * 100.0 for k in range(1, 7) for side, sign in (("lower", -1), ("upper", 1))}
H = 1e-3  # communication step, s
DURATION = 1.0


@pytest.fixture(scope="module")
def plant():
    path = ensure_fmus()["rx130l_plant"]
    md = read_model_description(str(path))
    return md, extract(str(path)), {v.name: v.valueReference for v in md.modelVariables}


def run_fmu(plant, tau_of_t, q0=Q0, start=None, duration=DURATION):
    md, unzipped, vr = plant
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier="rx130l_plant", instanceName="plant")
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setReal([vr[f"q0[{k}]"] for k in range(1, 7)], list(q0))
    for name, value in {**FREE_JOINTS, **(start or {})}.items():
        fmu.setReal([vr[name]], [value])
    fmu.exitInitializationMode()
    tau_vr = [vr[f"tau[{k}]"] for k in range(1, 7)]
    out_vr = [vr[f"{n}[{k}]"] for n in ("q", "qd", "qdd") for k in range(1, 7)]
    rows = []
    for k in range(int(round(duration / H))):
        fmu.setReal(tau_vr, list(tau_of_t(k * H)))
        fmu.doStep(k * H, H)
        rows.append(fmu.getReal(out_vr))
    fmu.terminate()
    fmu.freeInstance()
    return np.array(rows)


def run_reference(dynamics, tau_of_t, q0=Q0, duration=DURATION):
    x = np.concatenate((q0, np.zeros(6)))
    rows = []
    for k in range(int(round(duration / H))):
        tau = np.asarray(tau_of_t(k * H), dtype=float)
        sol = solve_ivp(lambda t, s: np.concatenate((s[6:], dynamics.forward_dynamics(s[:6], s[6:], tau))),
                        (k * H, (k + 1) * H), x, method="DOP853", rtol=1e-12, atol=1e-12)
        x = sol.y[:, -1]
        rows.append(x.copy())
    return np.array(rows)


NOMINAL = RobotDynamics()
G0 = NOMINAL.gravity(Q0)
PROFILES = {
    "gravity plus torque steps": lambda t: G0 + np.array([50, -80, 40, 5, -4, 1.0]) * (t >= 0.2),
    "sinusoids with reversals": lambda t: G0 + np.array([200, 300, 100, 10, 8, 2])
    * np.sin(2 * np.pi * np.array([1, 1.5, 2, 3, 4, 5]) * t),
    "zero torque (falling arm)": lambda t: np.zeros(6),
}


@lru_cache(maxsize=None)
def reference_of(profile: str) -> np.ndarray:
    return run_reference(NOMINAL, PROFILES[profile])


@pytest.mark.parametrize("profile", sorted(PROFILES))
def test_plant_matches_pinocchio_solve_ivp(plant, profile):
    fmu = run_fmu(plant, PROFILES[profile])
    ref = reference_of(profile)
    error = np.abs(fmu[:, :6] - ref[:, :6]).max()
    assert error < 1e-8, f"{profile}: max |q_fmu - q_ref| = {error:.3e} rad over 1 s"
    assert np.abs(fmu[:, 6:12] - ref[:, 6:]).max() < 1e-6  # rad/s
    assert np.ptp(ref[:, :6], axis=0).max() > 0.5  # the arm really moved


def main_job_integration_step() -> float:
    scenario = Path(__file__).resolve().parents[2] / "scenarios" / "iso9283_rigid.toml"
    plant = next(f for f in tomllib.loads(scenario.read_text())["fmus"] if f["name"] == "plant")
    return float(plant.get("parameters", {}).get("integration_step", 50e-6))


@pytest.mark.parametrize("profile", sorted(PROFILES))
def test_plant_at_the_main_jobs_integration_step(plant, profile):
    """The RK4 sub-step the rigid-plant main job (scenarios/iso9283_rigid.toml) chooses (100 us)
    keeps the 1e-8 rad bound (the elastic main job's step: tests/fmus/test_plant_elastic.py)."""
    step = main_job_integration_step()
    assert step >= 50e-6
    fmu = run_fmu(plant, PROFILES[profile], start={"integration_step": step})
    error = np.abs(fmu[:, :6] - reference_of(profile)[:, :6]).max()
    assert error < 1e-8, f"{profile}: integration_step {step} s: max |q_fmu - q_ref| = {error:.3e} rad over 1 s"


def test_qdd_output_is_the_forward_dynamics_at_the_step_end(plant):
    tau_of_t = PROFILES["sinusoids with reversals"]
    fmu = run_fmu(plant, tau_of_t, duration=0.05)
    for k in (0, 17, 49):
        expected = NOMINAL.forward_dynamics(fmu[k, :6], fmu[k, 6:12], tau_of_t(k * H))
        np.testing.assert_allclose(fmu[k, 12:], expected, rtol=1e-9, atol=1e-9)


def test_gravity_torque_holds_the_arm_still(plant):
    for q0 in (Q0, np.array([-1.0, 0.7, -0.4, 2.0, -1.1, 0.5])):
        g = NOMINAL.gravity(q0)
        fmu = run_fmu(plant, lambda t: g, q0=q0)
        assert np.abs(fmu[:, :6] - q0).max() < 1e-10
        assert np.abs(fmu[:, 6:12]).max() < 1e-9


def test_parameters_and_payload_of_a_true_robot(plant):
    """Non-nominal inertias, friction, rotor inertia and a 10 kg payload set as FMU parameters."""
    true = make_true_robot(7, payload=[10.0, 0.02, -0.01, 0.08])
    dynamics = RobotDynamics(true.dynamic_parameters, true.payload)  # nominal kinematics, as the plant
    start = {f"p[{k + 1}]": float(v) for k, v in enumerate(true.dynamic_parameters)}
    start.update({"payload_mass": 10.0, "payload_com[1]": 0.02, "payload_com[2]": -0.01, "payload_com[3]": 0.08})
    tau_of_t = PROFILES["gravity plus torque steps"]
    fmu = run_fmu(plant, tau_of_t, start=start, duration=0.5)
    ref = run_reference(dynamics, tau_of_t, duration=0.5)
    nominal = run_reference(NOMINAL, tau_of_t, duration=0.5)
    assert np.abs(fmu[:, :6] - ref[:, :6]).max() < 1e-8
    assert np.abs(nominal[:, :6] - ref[:, :6]).max() > 1e-2  # the parameters matter


def test_geometric_errors_of_a_true_robot(plant):
    """The true robot's 39 geometric errors as FMU parameters (set by the cell, as for the
    tracker) enter the plant's dynamics: against pinocchio built with the true geometry."""
    from cosim.cell.wiring import plant_start_values

    true = make_true_robot(1, payload=[8.0, 0.0, 0.0, 0.08])
    start = {k: v for k, v in plant_start_values(true, Q0).items() if not k.startswith(("q0[", "qd0["))}
    assert sum(k.startswith("geometric_errors[") for k in start) == 39
    tau_of_t = PROFILES["sinusoids with reversals"]
    fmu = run_fmu(plant, tau_of_t, start=start, duration=0.5)
    ref = run_reference(true.dynamics(), tau_of_t, duration=0.5)  # pinocchio on the true geometry
    nominal_geometry = run_reference(RobotDynamics(true.dynamic_parameters, true.payload), tau_of_t, duration=0.5)
    error = np.abs(fmu[:, :6] - ref[:, :6]).max()
    effect = np.abs(nominal_geometry[:, :6] - ref[:, :6]).max()
    assert error < 1e-8, f"max |q_fmu - q_pinocchio(true geometry)| = {error:.3e} rad over 0.5 s"
    assert effect > 1000 * error, f"the geometry changes q by only {effect:.3e} rad"
