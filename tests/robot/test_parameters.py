"""The parameter-file loader: nominal contents and clear errors for malformed files."""
from __future__ import annotations

import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from robot.description import PARAMS_PATH, URDF_PATH
from robot.parameters import ParameterFileError, RobotParameters, load_parameters

from error_checks import assert_names_file_and_fragments

NOMINAL_TEXT = PARAMS_PATH.read_text(encoding="utf-8")


def _write_variant(tmp_path: Path, key: str, new_line: str | None) -> Path:
    """Copy of the nominal file with the line ``key = ...`` replaced (or removed when None).

    ``[meta] urdf`` points to the project's URDF by absolute path so the copy loads.
    """
    pattern = re.compile(rf"^{re.escape(key)} = .*$", re.MULTILINE)
    assert len(pattern.findall(NOMINAL_TEXT)) == 1, key
    text = pattern.sub(lambda _: new_line or "", NOMINAL_TEXT)
    text = text.replace('urdf = "rx130l.urdf"', f"urdf = {str(URDF_PATH)!r}".replace("'", '"'))
    path = tmp_path / "params.toml"
    path.write_text(text, encoding="utf-8")
    return path


def test_nominal_file_matches_toml_and_urdf() -> None:
    params = load_parameters()
    raw = tomllib.loads(NOMINAL_TEXT)
    assert isinstance(params, RobotParameters)
    np.testing.assert_array_equal(params.gear_ratio, raw["drive_train"]["gear_ratio"]["value"])
    np.testing.assert_array_equal(params.viscous, raw["friction"]["viscous"]["value"])
    np.testing.assert_array_equal(params.torque_rate_limit, raw["limits"]["torque_rate"]["value"])
    assert params.encoder_counts_per_motor_rev == 65536
    assert params.coulomb_smoothing_velocity == pytest.approx(0.01)
    assert params.payload_rated_mass == pytest.approx(10.0)
    np.testing.assert_array_equal(params.payload, [0.0, 0.0, 0.0, 0.0])
    # URDF limits ride along
    np.testing.assert_allclose(params.effort_limit, [700, 1000, 450, 70, 60, 35])
    np.testing.assert_allclose(params.position_upper[0], 2.792526803)
    assert params.velocity_limit.shape == (6,)
    assert params.units["friction.viscous"] == "N m s / rad"
    assert "robot-data.md" in params.sources["friction.coulomb"]
    assert params.urdf_path == URDF_PATH.resolve()


def test_parameters_are_immutable() -> None:
    params = load_parameters()
    with pytest.raises(ValueError):
        params.gear_ratio[0] = 1.0
    with pytest.raises(AttributeError):
        params.coulomb_smoothing_velocity = 1.0  # type: ignore[misc]


@pytest.mark.parametrize(
    ("key", "new_line", "expected_fragments"),
    [
        ("gear_ratio", None, ["[drive_train] gear_ratio", "None", "expected a table"]),
        ("viscous", 'viscous = { value = [1.0, 2.0, 3.0], unit = "N m s / rad", source = "x" }',
         ["[friction] viscous", "[1.0, 2.0, 3.0]", "a list of 6 finite numbers >= 0"]),
        ("coulomb", 'coulomb = { value = "21", unit = "N m", source = "x" }',
         ["[friction] coulomb", "'21'", "a list of 6"]),
        ("rotor_inertia", 'rotor_inertia = { value = [2.0, -2.0, 0.8, 0.15, 0.15, 0.05], unit = "kg m^2", '
                          'source = "x" }',
         ["[drive_train] rotor_inertia", "-2.0", "finite numbers >= 0"]),
        ("gear_ratio", 'gear_ratio = { value = [100.0, 0.0, 80.0, 60.0, 60.0, 50.0], unit = "1", source = "x" }',
         ["[drive_train] gear_ratio", "0.0", "finite numbers > 0"]),
        ("jerk", 'jerk = { value = [150.0, 150.0, 200.0, 300.0, 300.0, 500.0], source = "x" }',
         ["[limits] jerk", "unit = None", "non-empty string"]),
        ("acceleration", 'acceleration = { value = [12.0, 12.0, 15.0, 25.0, 25.0, 40.0], unit = "rad/s^2" }',
         ["[limits] acceleration", "source = None", "non-empty string"]),
        ("coulomb_smoothing_velocity", 'coulomb_smoothing_velocity = { value = -0.01, unit = "rad/s", source = "x" }',
         ["[friction] coulomb_smoothing_velocity", "-0.01", "a single number: finite numbers > 0"]),
        ("encoder_counts_per_motor_rev", 'encoder_counts_per_motor_rev = { value = 65536.5, unit = "counts", '
                                         'source = "x" }',
         ["[drive_train] encoder_counts_per_motor_rev", "65536.5", "an integer > 0"]),
        ("center_of_mass", 'center_of_mass = { value = [0.0, true, 0.0], unit = "m", source = "x" }',
         ["[payload] center_of_mass", "True", "a list of 3 finite numbers"]),
        ("mass", 'mass = { unit = "kg", source = "x" }', ["[payload] mass", "no 'value' given"]),
        ("flange_frame", 'flange_frame = "flange"', ["[meta] flange_frame", "'flange'", "expected a frame"]),
    ],
)
def test_malformed_file_names_file_key_value_and_expectation(
        tmp_path: Path, key: str, new_line: str | None, expected_fragments: list[str]) -> None:
    path = _write_variant(tmp_path, key, new_line)
    with pytest.raises(ParameterFileError) as info:
        load_parameters(path)
    assert_names_file_and_fragments(info.value, path, expected_fragments)


def test_missing_file_and_broken_toml(tmp_path: Path) -> None:
    with pytest.raises(ParameterFileError, match="does not exist"):
        load_parameters(tmp_path / "nothing.toml")
    broken = tmp_path / "broken.toml"
    broken.write_text("[drive_train\ngear_ratio = 3", encoding="utf-8")
    with pytest.raises(ParameterFileError, match="not valid TOML"):
        load_parameters(broken)


def test_missing_urdf_is_reported_with_the_meta_key(tmp_path: Path) -> None:
    path = tmp_path / "params.toml"
    path.write_text(NOMINAL_TEXT, encoding="utf-8")  # relative "rx130l.urdf" is not beside the copy
    with pytest.raises(ParameterFileError, match=r"\[meta\] urdf"):
        load_parameters(path)


def test_valid_variant_loads_and_reload_sees_changes(tmp_path: Path) -> None:
    path = _write_variant(tmp_path, "viscous",
                          'viscous = { value = [1, 2, 3, 4, 5, 6], unit = "N m s / rad", source = "test" }')
    params = load_parameters(path)
    np.testing.assert_array_equal(params.viscous, [1, 2, 3, 4, 5, 6])
    assert params.viscous.dtype == float
    assert params.sources["friction.viscous"] == "test"
