"""The elastic-joint plant FMU (elastic_joints = 1), stepped by fmpy, against an
independent monolithic solve (tests/elastic_reference.py: pinocchio ABA for the links
+ the same gear and motor equations in numpy, scipy solve_ivp DOP853 at rtol = atol =
1e-12, inputs held over each 1 ms step); the stiff limit against the rigid plant; the
outputs in Initialization Mode; the refusals of bad gear parameters."""
import re
from functools import lru_cache

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

from elastic_reference import ElasticArm, solve
from fmus.build import ensure_fmus
from robot.dynamics import RobotDynamics
from robot.parameters import load_parameters
from robot.true_robot import make_true_robot

Q0 = np.array([0.3, -0.6, 1.2, 0.4, 0.8, -0.2])
H = 1e-3  # communication step, s
ELASTIC_STEP = 25e-6  # s, RK4 sub-step for the comparisons (50 us: 7e-10 rad on smooth drive torques,
# 4e-8 rad on the external torque pulses, which ring the 500 Hz wrist-gear mode)
NOMINAL = RobotDynamics()
G0 = NOMINAL.gravity(Q0)
ROBOT = load_parameters()
# the monolithic reference has no mechanical end stops: they are moved out of reach here (the
# arm under gravity passes its joint range within the second); tests/fmus/test_end_stops.py checks them
FREE_JOINTS = {f"end_stop_{side}[{k}]": sign * 100.0 for k in range(1, 7) for side, sign in (("lower", -1), ("upper", 1))}


@pytest.fixture(scope="module")
def plant():
    path = ensure_fmus()["rx130l_plant"]
    md = read_model_description(str(path))
    return md, extract(str(path)), {v.name: v.valueReference for v in md.modelVariables}


def _joint(name):
    return [f"{name}[{k}]" for k in range(1, 7)]


def open_fmu(plant, q0=Q0, elastic=1, start=None, logger=None):
    md, unzipped, vr = plant
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier="rx130l_plant", instanceName="plant",
                    fmiCallLogger=None)
    fmu.instantiate(loggingOn=False, callbacks=None)
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setInteger([vr["elastic_joints"]], [elastic])
    fmu.setReal([vr[n] for n in _joint("q0")], list(q0))
    for name, value in {**FREE_JOINTS, **(start or {})}.items():
        fmu.setReal([vr[name]], [value])
    return fmu


def run_fmu(plant, tau_of_t, duration, tau_ext_of_t=None, start=None, **kw):
    _, _, vr = plant
    fmu = open_fmu(plant, start={"integration_step": ELASTIC_STEP, **(start or {})}, **kw)
    fmu.exitInitializationMode()
    tau_vr, ext_vr = [vr[n] for n in _joint("tau")], [vr[n] for n in _joint("tau_ext")]
    out_vr = [vr[n] for name in ("q", "qd", "q_motor", "qd_motor", "tau_gear") for n in _joint(name)]
    rows = []
    for k in range(int(round(duration / H))):
        fmu.setReal(tau_vr, list(tau_of_t(k * H)))
        if tau_ext_of_t is not None:
            fmu.setReal(ext_vr, list(tau_ext_of_t(k * H)))
        fmu.doStep(k * H, H)
        rows.append(fmu.getReal(out_vr))
    fmu.terminate()
    fmu.freeInstance()
    return np.array(rows)


PROFILES = {
    "gravity plus torque steps": (lambda t: G0 + np.array([50, -80, 40, 5, -4, 1.0]) * (t >= 0.2), None),
    "sinusoids with reversals": (lambda t: G0 + np.array([200, 300, 100, 10, 8, 2])
                                 * np.sin(2 * np.pi * np.array([1, 1.5, 2, 3, 4, 5]) * t), None),
    "external torque pulses on the links": (lambda t: G0, lambda t: np.array([-60, 90, 40, -3, 2, 0.5])
                                            * ((t % 0.25) < 0.05)),
}


@lru_cache(maxsize=None)
def reference_of(profile: str) -> np.ndarray:
    tau_of_t, ext_of_t = PROFILES[profile]
    arm = ElasticArm(NOMINAL.parameter_vector(), [0, 0, 0, 0])
    return solve(arm, arm.start_state(Q0), tau_of_t, H, 1.0, ext_of_t)


@pytest.mark.parametrize("profile", sorted(PROFILES))
def test_elastic_plant_matches_monolithic_solve(plant, profile):
    """integration_step 25 us: link and motor angles within 1e-8 rad over 1 s."""
    tau_of_t, ext_of_t = PROFILES[profile]
    fmu = run_fmu(plant, tau_of_t, 1.0, ext_of_t)
    ref = reference_of(profile)
    q_err = np.abs(fmu[:, :6] - ref[:, :6]).max()
    qm_err = np.abs(fmu[:, 12:18] - ref[:, 12:18]).max()
    assert q_err < 1e-8, f"{profile}: max |q_fmu - q_ref| = {q_err:.3e} rad"
    assert qm_err < 1e-8, f"{profile}: max |q_motor_fmu - q_motor_ref| = {qm_err:.3e} rad"
    # speeds: the angle bound times the ~3000 rad/s of the fastest (wrist 6) gear mode
    assert np.abs(fmu[:, 6:12] - ref[:, 6:12]).max() < 3e-5
    assert np.abs(fmu[:, 18:24] - ref[:, 18:]).max() < 3e-5
    arm = ElasticArm(NOMINAL.parameter_vector(), [0, 0, 0, 0])
    np.testing.assert_allclose(fmu[:, 24:30], np.array([arm.gear_torque(x) for x in ref]), atol=1e-2)
    assert np.abs(ref[:, 12:18] - ref[:, :6]).max() > 1e-4  # the gears really deflect
    assert np.ptp(ref[:, :6], axis=0).max() > 0.01  # and the arm moves


def test_true_robot_payload_and_nonlinear_gear(plant):
    """True-robot parameters, a 10 kg payload, backlash and a stiffening gear; start state
    from the FMU's own static solve, checked to hold the links at rest."""
    true = make_true_robot(7, payload=[10.0, 0.02, -0.01, 0.08])
    gear = {"backlash": np.full(6, 3e-4), "stiffness_cubic": np.array([2e11, 2e11, 1e11, 1e9, 1e9, 5e8])}
    start = {f"p[{k + 1}]": float(v) for k, v in enumerate(true.dynamic_parameters)}
    start.update({"payload_mass": 10.0, "payload_com[1]": 0.02, "payload_com[2]": -0.01, "payload_com[3]": 0.08})
    for name, values in gear.items():
        start.update({n: float(v) for n, v in zip(_joint(name), values)})
    _, _, vr = plant
    fmu = open_fmu(plant, start=start)
    x0 = np.array(fmu.getReal([vr[n] for name in ("q", "qd", "q_motor", "qd_motor") for n in _joint(name)]))
    fmu.freeInstance()
    arm = ElasticArm(true.dynamic_parameters, true.payload, gear)
    tau_hold = arm.gear_torque(x0)
    assert np.abs(arm.rhs(x0, tau_hold, np.zeros(6))[6:12]).max() < 1e-9  # links at rest at the start
    tau_of_t = PROFILES["gravity plus torque steps"][0]
    out = run_fmu(plant, tau_of_t, 0.5, start=start)
    ref = solve(arm, x0, tau_of_t, H, 0.5)
    assert np.abs(out[:, :6] - ref[:, :6]).max() < 1e-8
    assert np.abs(out[:, 12:18] - ref[:, 12:18]).max() < 1e-8


def test_geometric_errors_enter_the_elastic_links(plant):
    """Seed-1 true robot (8 kg payload) with its 39 geometric errors and gears as the cell sets
    them: links against pinocchio built with the true geometry (ElasticArm(model=...))."""
    from cosim.cell.wiring import gear_start_values, plant_start_values

    true = make_true_robot(1, payload=[8.0, 0.0, 0.0, 0.08])
    start = {k: v for k, v in {**gear_start_values(true), **plant_start_values(true, Q0)}.items()
             if not k.startswith(("q0[", "qd0["))}
    tau_of_t = PROFILES["sinusoids with reversals"][0]
    out = run_fmu(plant, tau_of_t, 0.5, start=start)
    gear = {"stiffness": true.gear_stiffness}
    arm = ElasticArm(true.dynamic_parameters, true.payload, gear, model=true.kinematic_model())
    ref = solve(arm, arm.start_state(Q0), tau_of_t, H, 0.5)
    nominal = ElasticArm(true.dynamic_parameters, true.payload, gear)
    ref_nominal = solve(nominal, nominal.start_state(Q0), tau_of_t, H, 0.5)
    error = max(np.abs(out[:, :6] - ref[:, :6]).max(), np.abs(out[:, 12:18] - ref[:, 12:18]).max())
    effect = np.abs(ref_nominal[:, :6] - ref[:, :6]).max()
    assert error < 1e-8, f"max |q_fmu - q_ref(true geometry)| = {error:.3e} rad over 0.5 s"
    assert effect > 1000 * error, f"the geometry changes q by only {effect:.3e} rad"


def stiff_limit_errors(plant, factors=(1e1, 1e2, 1e3)):
    """max |q_elastic - q_rigid| (rad, 0.3 s) for the gear stiffness scaled by each factor
    (damping by sqrt(factor): same damping ratio), Stribeck off, 1 us sub-steps."""
    tau_of_t = PROFILES["sinusoids with reversals"][0]
    rigid = run_fmu(plant, tau_of_t, 0.3, elastic=0, start={"integration_step": 1e-6})
    errors = []
    for f in factors:
        start = {"integration_step": 2e-6 if f < 1e3 else 1e-6}
        start.update({n: float(v) * f for n, v in zip(_joint("stiffness"), ROBOT.stiffness)})
        start.update({n: float(v) * np.sqrt(f) for n, v in zip(_joint("damping"), ROBOT.gear_damping)})
        start.update({n: 0.0 for n in _joint("stribeck_torque")})
        elastic = run_fmu(plant, tau_of_t, 0.3, start=start)
        errors.append(np.abs(elastic[:, :6] - rigid[:, :6]).max())
    return errors


def test_stiff_gears_reproduce_the_rigid_plant(plant):
    errors = stiff_limit_errors(plant)
    # static deflection ~ tau / k: the gap shrinks like 1/factor
    assert errors[-1] < 1e-5, errors
    assert errors[0] / errors[-1] > 50, errors


def test_outputs_in_initialization_mode(plant):
    _, _, vr = plant
    names = [n for name in ("q", "qd", "q_motor", "qd_motor") for n in _joint(name)]
    for elastic in (0, 1):
        fmu = open_fmu(plant, elastic=elastic)
        before = np.array(fmu.getReal([vr[n] for n in names]))
        fmu.exitInitializationMode()
        after = np.array(fmu.getReal([vr[n] for n in names]))
        fmu.terminate()  # (step mode)
        fmu.freeInstance()
        np.testing.assert_array_equal(before, after)
        np.testing.assert_array_equal(before[:6], Q0)
        if elastic:  # the motor leads the sagging link by tau_hold / k
            arm = ElasticArm(NOMINAL.parameter_vector(), [0, 0, 0, 0])
            np.testing.assert_allclose(before[12:18], arm.start_state(Q0)[12:18], rtol=0, atol=1e-15)
            assert np.abs(before[12:18] - Q0).max() > 1e-4
        else:
            np.testing.assert_array_equal(before[12:18], Q0)


def _collecting_callbacks(messages):
    """fmi2 callbacks whose logger appends the FMU's messages to ``messages`` (with
    fmpy's proxy for the variadic logger, as fmus.instance does)."""
    import ctypes

    from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions,
                           fmi2CallbackLoggerTYPE)
    from fmpy.logging import addLoggerProxy

    def logger(env, instance, status, category, message):
        messages.append(message.decode("utf-8", "replace") if message else "")

    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(logger)
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(ctypes.cdll.LoadLibrary(None).calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(ctypes.cdll.LoadLibrary(None).free)
    addLoggerProxy(ctypes.byref(cb))
    return cb


def _exit_error(plant, start):
    """The FMU's log messages if exitInitializationMode (or a set) fails with ``start``, else []."""
    messages = []
    _, unzipped, vr = plant
    md = plant[0]
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier="rx130l_plant", instanceName="plant")
    callbacks = _collecting_callbacks(messages)
    fmu.instantiate(callbacks=callbacks)
    failed = False
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setInteger([vr["elastic_joints"]], [1])
    fmu.setReal([vr[n] for n in _joint("q0")], list(Q0))
    try:
        for name, value in start.items():
            fmu.setReal([vr[name]], [value])
        fmu.exitInitializationMode()
    except Exception:  # fmpy raises FMICallException; the log has the reason
        failed = True
    finally:
        fmu.freeInstance()
    del callbacks
    return messages if failed else []


def _log_of(plant, start):
    messages = _exit_error(plant, start)
    assert messages, f"{start} was accepted"
    return "\n".join(messages)


def test_too_stiff_for_the_step_is_refused_with_the_largest_stable_stiffness(plant):
    text = _log_of(plant, {"stiffness[6]": 1e8})
    assert "stiffness[6] = 1e+08 N.m/rad" in text and "integration_step = 5e-05 s" in text, text
    largest = float(re.search(r"stable up to stiffness\[6\] = ([0-9.e+]+) N.m/rad", text).group(1))
    assert 1e6 < largest < 1e8
    assert not _exit_error(plant, {"stiffness[6]": 0.99 * largest})
    assert _exit_error(plant, {"stiffness[6]": 1.01 * largest})


@pytest.mark.parametrize("start, expected", [
    ({"stiffness[2]": 0.0}, "stiffness[2] = 0 N.m/rad, expected a gear stiffness > 0"),
    ({"stiffness[3]": -5.0}, "stiffness[3]=-5 is outside its range"),
    ({"backlash[1]": 0.01}, "backlash[1]=0.01 is outside its range [0, 0.001]"),
    ({"p[64]": 0.0}, "p[64] (rotor inertia Ia4) = 0 kg.m2, expected > 0"),
])
def test_bad_gear_parameters_are_refused_naming_the_key(plant, start, expected):
    assert expected in _log_of(plant, start)
