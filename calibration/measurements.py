"""Calibration measurements: the data type and its CSV file format.

CSV columns (header row required, any column order, comma separated):

========================  =====================================================
``q1`` ... ``q6``         joint angles (rad) the controller reported at the pose
``x``, ``y``, ``z``       measured flange origin (m) in the robot base frame
``alpha``, ``beta``,      optional: measured flange orientation as the paper's
``gamma``                 Cardan angles (rad), ``R = Rx(alpha) Ry(beta) Rz(gamma)``
========================  =====================================================

Checks with clear errors (subclasses of ValueError naming file, row and column):
missing or misnamed columns, a partial orientation triple, non-numeric or NaN
entries, and units that look wrong: a position component beyond
:data:`MAX_ABS_POSITION_M` (millimetres where metres are expected), a joint angle
beyond 2 pi (degrees where radians are expected), a Cardan angle beyond pi.
"""
from __future__ import annotations

import csv
import difflib
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from robot.kinematics import cardan_from_rotation, rotation_from_cardan
from robot.textfiles import open_text

JOINT_COLUMNS = tuple(f"q{i}" for i in range(1, 7))
POSITION_COLUMNS = ("x", "y", "z")
ORIENTATION_COLUMNS = ("alpha", "beta", "gamma")
REQUIRED_COLUMNS = JOINT_COLUMNS + POSITION_COLUMNS
ALL_COLUMNS = REQUIRED_COLUMNS + ORIENTATION_COLUMNS

MAX_ABS_POSITION_M = 5.0
"""Largest plausible |x|, |y|, |z| of the flange in the base frame (m): the arm
reaches 1.66 m (2.21 m above the base), so 5 m leaves room for any base
registration while a value in millimetres (hundreds or more) is caught."""

MAX_ABS_JOINT_RAD = 2.0 * math.pi
"""Largest plausible joint angle (rad); axes 4 and 6 turn +-270 deg = 4.71 rad. A
larger value suggests degrees."""

MAX_ABS_CARDAN_RAD = math.pi + 1e-9
"""Cardan angles lie in [-pi, pi]; a larger value suggests degrees."""


class MeasurementError(ValueError):
    """Calibration measurements are malformed (file, columns, values or units)."""


class MeasurementUnitError(MeasurementError):
    """A column's values look like they are in the wrong unit (mm for m, deg for rad)."""


@dataclass(frozen=True)
class Measurements:
    """Tracker measurements at n robot configurations.

    ``q`` (n, 6) rad; ``positions`` (n, 3) m, flange origin in base_link;
    ``rotations`` (n, 3, 3) flange orientation in base_link, or None when only
    positions were measured; ``source`` names the origin (file path or "array").
    """

    q: np.ndarray
    positions: np.ndarray
    rotations: np.ndarray | None = None
    source: str = "array"

    def __post_init__(self) -> None:
        q = np.asarray(self.q, dtype=float)
        pos = np.asarray(self.positions, dtype=float)
        n = q.shape[0] if q.ndim == 2 else -1
        if q.ndim != 2 or q.shape[1] != 6:
            raise MeasurementError(f"{self.source}: joint angles must have shape (n, 6), got {q.shape}")
        if pos.shape != (n, 3):
            raise MeasurementError(f"{self.source}: positions must have shape ({n}, 3), got {pos.shape}")
        _check_finite(self.source, q, JOINT_COLUMNS)
        _check_finite(self.source, pos, POSITION_COLUMNS)
        if self.rotations is not None:
            rot = np.asarray(self.rotations, dtype=float)
            if rot.shape != (n, 3, 3):
                raise MeasurementError(f"{self.source}: rotations must have shape ({n}, 3, 3), got {rot.shape}")
            if not np.all(np.isfinite(rot)):
                row = int(np.flatnonzero(~np.isfinite(rot).all(axis=(1, 2)))[0])
                raise MeasurementError(f"{self.source}: orientation of pose {row + 1} is not finite (NaN or inf)")
        _check_units(self.source, q, pos, None)

    @property
    def count(self) -> int:
        """Number of measured poses."""
        return int(np.asarray(self.q).shape[0])

    @property
    def has_orientation(self) -> bool:
        """True when orientations were measured (6 rows per pose, else 3)."""
        return self.rotations is not None

    def transforms(self) -> np.ndarray:
        """Measured flange transforms (n, 4, 4); identity rotation when position-only."""
        out = np.zeros((self.count, 4, 4))
        out[:, :3, :3] = np.eye(3) if self.rotations is None else self.rotations
        out[:, :3, 3] = self.positions
        out[:, 3, 3] = 1.0
        return out

    def subset(self, rows: np.ndarray) -> "Measurements":
        """Measurements of the given pose indices only."""
        rot = None if self.rotations is None else np.asarray(self.rotations)[rows]
        return Measurements(np.asarray(self.q)[rows], np.asarray(self.positions)[rows], rot, self.source)


def _check_finite(source: str, values: np.ndarray, columns: tuple[str, ...]) -> None:
    bad = ~np.isfinite(values)
    if np.any(bad):
        row, col = (int(i) for i in np.argwhere(bad)[0])
        raise MeasurementError(
            f"{source}: row {row + 1}, column {columns[col]!r} is {values[row, col]!r}; "
            "expected a finite number"
        )


def _check_units(source: str, q: np.ndarray, pos: np.ndarray, cardan: np.ndarray | None) -> None:
    for values, columns, limit, unit, wrong in (
        (pos, POSITION_COLUMNS, MAX_ABS_POSITION_M, "m (metres, flange origin in the base frame)", "millimetres"),
        (q, JOINT_COLUMNS, MAX_ABS_JOINT_RAD, "rad", "degrees"),
        (cardan, ORIENTATION_COLUMNS, MAX_ABS_CARDAN_RAD, "rad (Cardan angles in [-pi, pi])", "degrees"),
    ):
        if values is None:
            continue
        over = np.abs(values) > limit
        if np.any(over):
            row, col = (int(i) for i in np.argwhere(over)[0])
            raise MeasurementUnitError(
                f"{source}: column {columns[col]!r} has {values[row, col]!r} in row {row + 1} "
                f"(|value| > {limit:.4g}); expected {unit}. The values look like {wrong}."
            )


def read_measurements_csv(path: str | Path) -> Measurements:
    """Read and check a measurement CSV (see the module docstring for the format)."""
    file = Path(path)
    where = f"measurement file {str(file)!r}"
    if not file.is_file():
        raise MeasurementError(f"{where} does not exist")
    with open_text(file) as handle:  # UTF-8, a byte-order mark dropped
        reader = csv.reader(handle)
        try:
            header = next(reader)
        except StopIteration:
            raise MeasurementError(f"{where} is empty; expected a header row {', '.join(REQUIRED_COLUMNS)}") from None
        rows = [r for r in reader if any(cell.strip() for cell in r)]
    header = [h.strip() for h in header]
    _check_header(where, header)
    if not rows:
        raise MeasurementError(f"{where} has a header but no measurement rows")
    has_orientation = all(c in header for c in ORIENTATION_COLUMNS)
    columns = ALL_COLUMNS if has_orientation else REQUIRED_COLUMNS
    index = {name: header.index(name) for name in columns}
    data = np.empty((len(rows), len(columns)))
    for r, row in enumerate(rows):
        if len(row) != len(header):
            raise MeasurementError(
                f"{where}: row {r + 1} has {len(row)} fields, the header has {len(header)}"
            )
        for c, name in enumerate(columns):
            text = row[index[name]].strip()
            try:
                value = float(text)
            except ValueError:
                raise MeasurementError(
                    f"{where}: row {r + 1}, column {name!r} is {text!r}; expected a number"
                ) from None
            if not math.isfinite(value):
                raise MeasurementError(
                    f"{where}: row {r + 1}, column {name!r} is {text!r}; expected a finite number"
                )
            data[r, c] = value
    q, pos = data[:, 0:6], data[:, 6:9]
    cardan = data[:, 9:12] if has_orientation else None
    _check_units(where, q, pos, cardan)
    rotations = None if cardan is None else rotation_from_cardan(cardan)
    return Measurements(q, pos, rotations, source=where)


def _check_header(where: str, header: list[str]) -> None:
    duplicates = sorted({h for h in header if header.count(h) > 1})
    if duplicates:
        raise MeasurementError(f"{where}: duplicate columns {duplicates}")
    unknown = [h for h in header if h not in ALL_COLUMNS]
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    orientation = [c for c in ORIENTATION_COLUMNS if c in header]
    problems = []
    if missing:
        problems.append(f"missing columns {missing}")
    if unknown:
        hints = []
        for name in unknown:
            close = difflib.get_close_matches(name.lower(), ALL_COLUMNS, n=1, cutoff=0.5)
            hints.append(f"{name!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
        problems.append("unknown columns " + ", ".join(hints))
    if orientation and len(orientation) != 3:
        absent = [c for c in ORIENTATION_COLUMNS if c not in header]
        problems.append(f"orientation columns must come as a triple: missing {absent}")
    if problems:
        raise MeasurementError(
            f"{where}: " + "; ".join(problems) + ". Expected columns q1..q6 (rad), x, y, z (m, "
            "flange origin in the base frame) and optionally alpha, beta, gamma (rad, Cardan "
            "angles R = Rx(alpha) Ry(beta) Rz(gamma))"
        )


def write_measurements_csv(path: str | Path, measurements: Measurements) -> Path:
    """Write ``measurements`` in the CSV format above (17 significant digits)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    columns = ALL_COLUMNS if measurements.has_orientation else REQUIRED_COLUMNS
    data = [np.asarray(measurements.q), np.asarray(measurements.positions)]
    if measurements.has_orientation:
        data.append(cardan_from_rotation(measurements.rotations))
    table = np.concatenate(data, axis=1)
    with out.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(columns)
        for row in table:
            writer.writerow([repr(float(v)) for v in row])
    return out
