"""Coupling study on a short horizon: plant + six drive FMUs co-simulated at macro steps
of 400/200/100/50 us against the monolithic reference (oracle drives, continuous winding
currents and arm in solve_ivp). See docs/fmus.md for the full 0.6 s table."""
import numpy as np
import pytest

from fmus.build import ensure_fmus
from fmus.coupling import controller_commands, cosimulate, coupling_errors, desired_motion, monolithic_reference
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


def test_cosimulation_is_faster_at_larger_steps(study):
    _, runs, _ = study
    assert runs[400e-6].wall_time < runs[50e-6].wall_time
