"""Measurement CSV: format, round trip, and clear errors for bad files."""
import csv
import math

import numpy as np
import pytest

from calibration.measurements import (
    MeasurementError,
    Measurements,
    MeasurementUnitError,
    read_measurements_csv,
    write_measurements_csv,
)
from robot.kinematics import rotation_from_cardan

HEADER = ["q1", "q2", "q3", "q4", "q5", "q6", "x", "y", "z", "alpha", "beta", "gamma"]
ROW = [0.1, -0.2, 0.3, 0.4, 0.5, -0.6, 1.2, 0.1, 0.9, 0.2, -0.3, 1.0]


def _write(path, header, rows):
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        writer.writerows(rows)
    return path


def test_read_and_round_trip(tmp_path):
    path = _write(tmp_path / "m.csv", HEADER, [ROW, ROW])
    meas = read_measurements_csv(path)
    assert meas.count == 2 and meas.has_orientation
    assert np.allclose(meas.rotations[0], rotation_from_cardan(ROW[9:]))
    again = read_measurements_csv(write_measurements_csv(tmp_path / "again.csv", meas))
    assert np.allclose(again.q, meas.q, atol=0) and np.allclose(again.rotations, meas.rotations, atol=1e-15)
    # columns in any order, position only
    order = [6, 7, 8, 0, 1, 2, 3, 4, 5]
    pos_only = read_measurements_csv(_write(tmp_path / "p.csv", [HEADER[i] for i in order],
                                            [[ROW[i] for i in order]]))
    assert not pos_only.has_orientation and np.allclose(pos_only.positions, [ROW[6:9]])


@pytest.mark.parametrize(
    "header, row, pattern",
    [
        (HEADER[:6] + ["x", "y"], ROW[:8], r"missing columns \['z'\]"),
        (["q_1"] + HEADER[1:], ROW, r"'q_1' \(did you mean 'q1'\?\)"),
        (HEADER[:6] + ["X", "y", "z"], ROW[:9], r"unknown columns 'X' \(did you mean 'x'\?\)"),
        (HEADER[:11], ROW[:11], r"triple: missing \['gamma'\]"),
        (HEADER, ROW[:5] + ["nan"] + ROW[6:], r"row 1, column 'q6' is 'nan'; expected a finite number"),
        (HEADER, ROW[:7] + ["abc"] + ROW[8:], r"row 1, column 'y' is 'abc'; expected a number"),
        (HEADER, ROW[:6] + [1200.0, 100.0, 900.0] + ROW[9:], r"column 'x'.*expected m \(metres.*millimetres"),
        (HEADER, [10.0] + ROW[1:], r"column 'q1'.*expected rad.*degrees"),
        (HEADER, ROW[:9] + [20.0, -30.0, 100.0], r"column 'alpha'.*Cardan.*degrees"),
        (HEADER, ROW[:11], r"row 1 has 11 fields"),
    ],
)
def test_bad_files_give_clear_errors(tmp_path, header, row, pattern):
    path = _write(tmp_path / "bad.csv", header, [row])
    with pytest.raises(MeasurementError, match=pattern) as info:
        read_measurements_csv(path)
    assert "bad.csv" in str(info.value)


def test_unit_error_is_a_value_error_subclass(tmp_path):
    path = _write(tmp_path / "mm.csv", HEADER, [ROW[:6] + [1200.0, 100.0, 900.0] + ROW[9:]])
    with pytest.raises(MeasurementUnitError):
        read_measurements_csv(path)
    assert issubclass(MeasurementUnitError, ValueError)


def test_empty_and_missing_files(tmp_path):
    with pytest.raises(MeasurementError, match="does not exist"):
        read_measurements_csv(tmp_path / "nope.csv")
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(MeasurementError, match="empty"):
        read_measurements_csv(tmp_path / "empty.csv")
    with pytest.raises(MeasurementError, match="no measurement rows"):
        read_measurements_csv(_write(tmp_path / "h.csv", HEADER, []))


def test_array_measurements_are_checked():
    q = np.zeros((3, 6))
    with pytest.raises(MeasurementError, match="row 2, column 'y'"):
        Measurements(q, np.array([[1.0, 0, 1], [1.0, math.nan, 1], [1.0, 0, 1]]))
    with pytest.raises(MeasurementUnitError, match="millimetres"):
        Measurements(q, np.full((3, 3), 800.0))
