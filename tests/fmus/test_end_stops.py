"""The plant's mechanical end stops against an independent solve: joint 1 of the nominal arm
runs into its upper stop at about 2.3 rad/s (the other joints held by their gravity torques); the
same contact law (unilateral spring-damper beyond the stop, robot/rx130l_params.toml
[end_stops]) added to pinocchio's forward dynamics (robot.dynamics) and integrated by scipy
solve_ivp (DOP853, rtol 1e-11) gives the impact time and speed, the largest penetration and
the rebound speed the FMU reports."""
import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from scipy.integrate import solve_ivp

from fmus.build import ensure_fmus
from robot.dynamics import RobotDynamics
from robot.parameters import load_parameters

Q0 = np.array([2.6, -0.6, 1.2, 0.4, 0.8, -0.2])
QD0 = np.array([3.0, 0.0, 0.0, 0.0, 0.0, 0.0])
H = 1e-3
DURATION = 0.4
ROBOT = load_parameters()
NOMINAL = RobotDynamics()
TAU = NOMINAL.gravity(Q0)  # holds joints 2..6; joint 1 (vertical axis) has no gravity torque


def run_fmu():
    path = ensure_fmus()["rx130l_plant"]
    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)), modelIdentifier="rx130l_plant",
                    instanceName="plant")
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setReal([vr[f"q0[{k}]"] for k in range(1, 7)], list(Q0))
    fmu.setReal([vr[f"qd0[{k}]"] for k in range(1, 7)], list(QD0))
    fmu.exitInitializationMode()
    fmu.setReal([vr[f"tau[{k}]"] for k in range(1, 7)], list(TAU))
    reals = [vr[n] for n in ("q[1]", "qd[1]", "end_stop_penetration[1]", "end_stop_max_penetration[1]",
                             "end_stop_impact_speed[1]", "end_stop_impact_time[1]")]
    rows, contacts = [], []
    for k in range(int(round(DURATION / H))):
        fmu.doStep(k * H, H)
        rows.append(fmu.getReal(reals))
        contacts.append(fmu.getInteger([vr["end_stop_contacts[1]"]])[0])
    fmu.terminate()
    fmu.freeInstance()
    return np.array(rows), np.array(contacts)


def contact_torque(q, qd):
    out = np.zeros(6)
    k, c = ROBOT.end_stop_stiffness, ROBOT.end_stop_damping
    up, down = q - ROBOT.end_stop_upper, ROBOT.end_stop_lower - q
    for j in range(6):
        if up[j] > 0:
            out[j] = min(0.0, -(k[j] * up[j] + c[j] * qd[j]))
        elif down[j] > 0:
            out[j] = max(0.0, k[j] * down[j] - c[j] * qd[j])
    return out


def reference():
    def f(t, s):
        return np.concatenate((s[6:], NOMINAL.forward_dynamics(s[:6], s[6:], TAU + contact_torque(s[:6], s[6:]))))

    def hits(t, s):
        return s[0] - ROBOT.end_stop_upper[0]

    sol = solve_ivp(f, (0.0, DURATION), np.concatenate((Q0, QD0)), method="DOP853", rtol=1e-11, atol=1e-12,
                    dense_output=True, events=hits, max_step=2e-4)
    t_in, t_out = sol.t_events[0][0], sol.t_events[0][1]
    fine = np.linspace(t_in, t_out, 4001)
    states = sol.sol(fine)
    return {"t_in": t_in, "v_in": sol.y_events[0][0][6], "t_out": t_out, "v_out": sol.y_events[0][1][6],
            "max_penetration": float((states[0] - ROBOT.end_stop_upper[0]).max()), "sol": sol}


def test_end_stop_contact_matches_an_independent_solve():
    rows, contacts = run_fmu()
    ref = reference()
    # one contact, then the arm rebounds and stays clear within the run
    assert contacts[-1] == 1 and contacts[0] == 0
    impact_speed, impact_time, max_pen = rows[-1, 4], rows[-1, 5], rows[-1, 3]
    assert impact_time == pytest.approx(ref["t_in"], abs=1e-6)   # measured 1.5e-8 s
    assert impact_speed == pytest.approx(ref["v_in"], rel=1e-4)  # measured 8.4e-6 relative
    assert max_pen == pytest.approx(ref["max_penetration"], rel=1e-2)  # measured 3.2e-3 relative
    # the rebound: speed when the link leaves the stop, from the recorded speed after the contact
    after = int(np.ceil(ref["t_out"] / H)) + 1
    v_ref = ref["sol"].sol(after * H)[6]
    assert rows[after - 1, 1] == pytest.approx(v_ref, rel=1e-2)  # measured 3.5e-3 relative
    # physics: a damped contact returns less than it got (0.37 for a linear spring-damper of damping
    # ratio 0.3; less here: the stop never pulls, the damping ratio at this pose's inertia is 0.33
    # and friction brakes: measured 0.165) and the largest penetration is below the undamped
    # v sqrt(J / k) with the joint's inertia at this pose (measured 2.6 mm-rad vs 6.2)
    restitution = -ref["v_out"] / ref["v_in"]
    assert 0.1 < restitution < 0.37
    inertia = NOMINAL.mass_matrix(Q0)[0, 0]
    assert max_pen < ref["v_in"] * np.sqrt(inertia / ROBOT.end_stop_stiffness[0])
    assert (rows[:, 2] >= 0).all() and rows[:, 2].max() <= max_pen
