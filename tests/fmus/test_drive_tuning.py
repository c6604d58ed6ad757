"""drive_params.toml: the gains are the tuning rules applied to its inputs, the inertia
range is what pinocchio gives, every axis' start values are accepted by the FMU, and a
malformed file is rejected naming the key."""
import numpy as np
import pytest

from fmus.build import ensure_fmus
from fmus.fmu import Fmu
from fmus.servo_drive.params import DriveParameterError, drive_start_values, load_drive_parameters
from fmus.servo_drive.tuning import cascade_gains, inertia_range, symmetric_optimum_a

DRIVE = load_drive_parameters()


@pytest.mark.parametrize("section, key, field", [
    ("current_loop", "kp", "current_kp"), ("current_loop", "tn", "current_tn"),
    ("speed_loop", "kp", "speed_kp"), ("speed_loop", "tn", "speed_tn"), ("position_loop", "kv", "position_kv"),
])
def test_gains_follow_the_tuning_rules(section, key, field):
    np.testing.assert_allclose(DRIVE.get(section, key), getattr(cascade_gains(), field), rtol=1e-5)


def test_inertia_range_is_what_pinocchio_gives():
    lo, hi = inertia_range(samples=20000, seed=0)
    np.testing.assert_allclose(DRIVE.get("tuning", "inertia_min"), lo, rtol=1e-4)
    np.testing.assert_allclose(DRIVE.get("tuning", "inertia_max"), hi, rtol=1e-4)


def test_symmetric_optimum_a_gives_the_phase_margin():
    for r in (1.0, 1.8, 3.66):
        a = symmetric_optimum_a(r, 50.0)
        for w in (1.0 / r, r):  # crossover at both ends of the inertia range (units of 1/(a T_sigma))
            phase_margin = np.degrees(np.arctan(w * a) - np.arctan(w / a))
            assert phase_margin == pytest.approx(50.0, abs=1e-9)
    assert symmetric_optimum_a(1.0, np.degrees(np.arctan(0.75))) == pytest.approx(2.0)  # the classic SO


def test_every_axis_initialises():
    path = ensure_fmus()["servo_drive"]
    for axis in range(1, 7):
        values = drive_start_values(axis)
        with Fmu(path, f"axis{axis}", values).start() as drive:
            assert drive.get_value("gear_ratio") == values["gear_ratio"]
            assert drive.get_value("statusword") & 0x6F == 0x40


def test_bad_axis_and_bad_file(tmp_path):
    with pytest.raises(DriveParameterError, match="axis = 7"):
        drive_start_values(7)
    text = (DRIVE.source_path).read_text().replace("kv = { value = [54.5678", "kv = { value = [-54.5678")
    bad = tmp_path / "drive_params.toml"
    bad.write_text(text)
    with pytest.raises(DriveParameterError, match=r"\[position_loop\] kv.*expected a list of 6 finite numbers >= 0"):
        load_drive_parameters(bad)
    bad.write_text("[sample_times]\ncurrent = 5e-5\n")
    with pytest.raises(DriveParameterError, match=r"\[sample_times\] current.*expected a table"):
        load_drive_parameters(bad)
