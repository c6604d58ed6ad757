"""Coupling study on a short horizon: plant + six drive FMUs co-simulated at macro steps
of 400/200/100/50 us against the monolithic reference (oracle drives, continuous winding
currents and arm in solve_ivp). See docs/explanation/fmus.md for the full 0.6 s table."""
import numpy as np
import pytest

from fmus.build import ensure_fmus
from cosim.coupling_study import cosimulate
from fmus.coupling import controller_commands, coupling_errors, desired_motion, monolithic_reference
from fmus.servo_drive.params import drive_start_values

DURATION = 0.04  # s: enable, then 20 ms of the move
COUNTS = np.array([2 * np.pi / (drive_start_values(a)["gear_ratio"] * 65536) for a in range(1, 7)])


@pytest.fixture(scope="module")
def study():
    paths = ensure_fmus()
    commands = controller_commands(DURATION)
    reference = monolithic_reference(commands, DURATION)
    runs = {h: cosimulate(paths, commands, h, DURATION) for h in (400e-6, 200e-6, 100e-6, 50e-6)}
    gauss_seidel = cosimulate(paths, commands, 100e-6, DURATION, coupling="gauss_seidel")
    return reference, runs, coupling_errors(reference, {**runs, "gs100": gauss_seidel})


def test_reference_tracks_the_motion(study):
    reference, _, _ = study
    q_d = desired_motion(reference.t)[0]
    assert np.ptp(q_d, axis=0).min() > 1e-4  # every joint moves (start of a quintic)
    assert np.abs(q_d - reference.q).max() < 2e-5  # feed-forward tracking, rad


def test_coupling_error_shrinks_with_the_macro_step(study):
    _, _, errors = study
    worst = {h: e.max() for h, e in errors.items() if h != "gs100"}
    assert worst[400e-6] > 1.5 * worst[200e-6] > 1.5 * 1.3 * worst[100e-6]
    assert np.all(errors[100e-6] < COUNTS)  # the default macro step: below one encoder count
    assert np.all(errors[50e-6] < COUNTS)
    assert np.all(errors["gs100"] < COUNTS)  # Gauss-Seidel (drives first) at the default step


def test_the_study_gives_the_same_q_with_either_engine(study):
    """The master's Python engine and compiled kernel give the study bit-identical q. (The cost of
    each macro step is measured by benchmarks/coupling_study.py, not here: runs of a few ms on the
    shared, loaded machine made a wall- or CPU-time comparison flaky.)"""
    _, runs, _ = study
    python = cosimulate(ensure_fmus(), controller_commands(DURATION), 400e-6, DURATION, engine="python")
    assert np.array_equal(python.q, runs[400e-6].q) and np.array_equal(python.t, runs[400e-6].t)


def test_the_study_runs_on_the_master_the_jobs_use(study):
    """The co-simulation of the study is cosim.master.Master (compiled kernel) with the cell's wiring;
    a hand-written Jacobi loop over the same FMUs (the study's former loop) gives the same q."""
    from cosim.master import Master
    from fmus.coupling import CONTROLLER_PERIOD, Q0

    _, runs, _ = study
    paths = ensure_fmus()
    commands = controller_commands(DURATION)
    master = Master(100e-6)
    plant = master.add_fmu("plant", paths["rx130l_plant"], start_values={f"q0[{j}]": Q0[j - 1] for j in range(1, 7)})
    drives = [master.add_fmu(f"d{a}", paths["servo_drive"], start_values=drive_start_values(a)) for a in range(1, 7)]
    master.initialize(DURATION)
    try:  # hand-written Jacobi loop on the instances' raw FMI 2.0 functions (no master stepping)
        q = np.zeros(12)
        vr_q = np.array([plant.variables[f"q[{j}]"].valueReference for j in range(1, 7)]
                        + [plant.variables[f"qd[{j}]"].valueReference for j in range(1, 7)], dtype=np.uint32)
        vr_tau = np.array([plant.variables[f"tau[{j}]"].valueReference for j in range(1, 7)], dtype=np.uint32)
        names = ("target_position", "torque_offset", "q_meas", "qd_meas")
        vr_in = np.array([drives[0].variables[n].valueReference for n in names], dtype=np.uint32)
        vr_cw = np.array([drives[0].variables["controlword"].valueReference], dtype=np.uint32)
        vr_tau_out = np.array([drives[0].variables["tau_out"].valueReference], dtype=np.uint32)
        tau, u, cw, out = np.zeros(6), np.zeros(4), np.zeros(1, dtype=np.intc), np.zeros(1)
        positions = []
        for k in range(round(DURATION / 100e-6)):
            t = k * 100e-6
            plant.get_fn["Real"](plant.component, vr_q.ctypes.data, 12, q.ctypes.data)
            if k % round(CONTROLLER_PERIOD / 100e-6) == 0:
                positions.append(q[:6].copy())
            target, offset, word = commands.at(t)
            plant.set_fn["Real"](plant.component, vr_tau.ctypes.data, 6, tau.ctypes.data)
            for j, d in enumerate(drives):
                u[:] = (target[j], offset[j], q[j], q[6 + j])
                cw[0] = word
                d.set_fn["Integer"](d.component, vr_cw.ctypes.data, 1, cw.ctypes.data)
                d.set_fn["Real"](d.component, vr_in.ctypes.data, 4, u.ctypes.data)
                assert d.do_step_fn(d.component, t, 100e-6, 1) == 0
                d.get_fn["Real"](d.component, vr_tau_out.ctypes.data, 1, out.ctypes.data)
                tau[j] = out[0]
            assert plant.do_step_fn(plant.component, t, 100e-6, 1) == 0
    finally:
        master.close()
    hand = np.array(positions)
    assert np.abs(runs[100e-6].q[:len(hand)] - hand).max() < 1e-15
