"""Measured motion records for identification: the CSV format and its checks.

A record holds, per time sample, the joint angles and the joint torques, optionally
the joint speeds and accelerations. CSV columns (header row, comma separated, any
order):

============  ========  ===============================================
column        unit      meaning
============  ========  ===============================================
``t``         s         time, strictly increasing, uniform steps
``q1..q6``    rad       joint angles
``tau1..6``   N m       joint-side torques (motor torque times gear ratio,
                        i.e. what drives the rigid body, rotor and friction)
``qd1..6``    rad/s     optional, all six or none
``qdd1..6``   rad/s^2   optional, all six or none
============  ========  ===============================================

Anything else (a missing or unknown column, a duplicate, an empty or non-numeric
cell, NaN/inf, times that go backwards or jump) raises
:class:`~identification.errors.IdentificationDataError` naming the file, the
column, the row and what was expected.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from identification.errors import IdentificationDataError
from identification.signals import sample_time_of
from robot.joints import N_JOINTS
from robot.textfiles import csv_rows

Q_COLUMNS = tuple(f"q{i}" for i in range(1, 7))
TAU_COLUMNS = tuple(f"tau{i}" for i in range(1, 7))
QD_COLUMNS = tuple(f"qd{i}" for i in range(1, 7))
QDD_COLUMNS = tuple(f"qdd{i}" for i in range(1, 7))
REQUIRED_COLUMNS = ("t",) + Q_COLUMNS + TAU_COLUMNS
OPTIONAL_GROUPS = {"qd": QD_COLUMNS, "qdd": QDD_COLUMNS}
PREDICTION_COLUMNS = ("t",) + tuple(f"tau_pred{i}" for i in range(1, 7))


@dataclass(frozen=True)
class MotionRecord:
    """A validated record: ``t`` (n,) s, ``q`` (n, 6) rad, ``tau`` (n, 6) N m, optional
    ``qd`` (n, 6) rad/s and ``qdd`` (n, 6) rad/s^2; ``source`` names where it came from."""

    t: np.ndarray
    q: np.ndarray
    tau: np.ndarray
    qd: np.ndarray | None = None
    qdd: np.ndarray | None = None
    source: str = "arrays"

    @property
    def samples(self) -> int:
        return int(self.t.size)

    @property
    def sample_time(self) -> float:
        return float(np.median(np.diff(self.t)))

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])


def motion_record(t: ArrayLike, q: ArrayLike, tau: ArrayLike, qd: ArrayLike | None = None,
                  qdd: ArrayLike | None = None, source: str = "arrays") -> MotionRecord:
    """Build a :class:`MotionRecord` from arrays, with the checks of the CSV reader."""
    t = np.array(t, dtype=float).reshape(-1)
    sample_time_of(t, f"{source}: t")
    arrays = {"q": q, "tau": tau, "qd": qd, "qdd": qdd}
    checked: dict[str, np.ndarray | None] = {}
    for name, value in arrays.items():
        if value is None and name in ("q", "tau"):
            raise IdentificationDataError(f"{source}: no {name} given, expected ({t.size}, 6) values")
        if value is None:
            checked[name] = None
            continue
        arr = np.array(value, dtype=float)
        if arr.shape != (t.size, N_JOINTS):
            raise IdentificationDataError(f"{source}: {name} has shape {arr.shape}, expected ({t.size}, 6)")
        bad = ~np.isfinite(arr)
        if np.any(bad):
            row, col = (int(v[0]) for v in np.nonzero(bad))
            raise IdentificationDataError(
                f"{source}: column '{name}{col + 1}' has {arr[row, col]!r} at sample {row} (t = {t[row]!r} s), expected "
                f"finite numbers ({int(bad.sum())} non-finite value(s) in total)")
        checked[name] = arr
    return MotionRecord(t, checked["q"], checked["tau"], checked["qd"], checked["qdd"], source)


def read_motion_csv(path: str | Path) -> MotionRecord:
    """Read and check a record CSV (see module docstring)."""
    path = Path(path)
    where = f"{path}"
    if not path.is_file():
        raise IdentificationDataError(f"{where}: file not found, expected a CSV record (t, q1..q6, tau1..tau6)")
    try:
        rows = csv_rows(path)  # UTF-8, a byte-order mark dropped (robot.textfiles)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise IdentificationDataError(f"{where}: cannot read as CSV text ({exc})") from exc
    rows = [r for r in rows if r and any(cell.strip() for cell in r)]
    if not rows:
        raise IdentificationDataError(f"{where}: empty file, expected a header row {', '.join(REQUIRED_COLUMNS)}")
    header = [cell.strip() for cell in rows[0]]
    _check_header(where, header)
    index = {name: k for k, name in enumerate(header)}
    data = np.empty((len(rows) - 1, len(header)))
    for r, row in enumerate(rows[1:], start=2):
        if len(row) != len(header):
            raise IdentificationDataError(f"{where}: line {r} has {len(row)} cells, expected {len(header)} "
                                          f"(one per header column)")
        for c, cell in enumerate(row):
            try:
                value = float(cell)
            except ValueError:
                raise IdentificationDataError(
                    f"{where}: column {header[c]!r}, line {r}: {cell!r} is not a number, expected a value in "
                    f"{_unit(header[c])}") from None
            if not math.isfinite(value):
                raise IdentificationDataError(
                    f"{where}: column {header[c]!r}, line {r}: {cell.strip()!r}, expected a finite number in "
                    f"{_unit(header[c])} (NaN/inf are not accepted; drop or repair those samples)")
            data[r - 2, c] = value

    def group(columns: tuple[str, ...]) -> np.ndarray | None:
        if columns[0] not in index:
            return None
        return data[:, [index[c] for c in columns]]

    return motion_record(data[:, index["t"]], group(Q_COLUMNS), group(TAU_COLUMNS), group(QD_COLUMNS),
                         group(QDD_COLUMNS), source=where)


def _unit(column: str) -> str:
    if column == "t":
        return "s"
    if column.startswith("qdd"):
        return "rad/s^2"
    if column.startswith("qd"):
        return "rad/s"
    if column.startswith("q"):
        return "rad"
    return "N m"


def _check_header(where: str, header: list[str]) -> None:
    seen = set()
    for name in header:
        if name in seen:
            raise IdentificationDataError(f"{where}: column {name!r} appears twice in the header")
        seen.add(name)
    allowed = set(REQUIRED_COLUMNS) | set(QD_COLUMNS) | set(QDD_COLUMNS)
    unknown = [n for n in header if n not in allowed]
    if unknown:
        raise IdentificationDataError(
            f"{where}: unknown column(s) {unknown}, expected t, q1..q6 (rad), tau1..tau6 (N m), optionally qd1..qd6 "
            "(rad/s) and qdd1..qdd6 (rad/s^2)")
    missing = [n for n in REQUIRED_COLUMNS if n not in seen]
    if missing:
        raise IdentificationDataError(
            f"{where}: missing column(s) {missing}, expected t (s), q1..q6 (rad) and tau1..tau6 (N m joint side)")
    for group, columns in OPTIONAL_GROUPS.items():
        present = [c for c in columns if c in seen]
        if present and len(present) != N_JOINTS:
            absent = [c for c in columns if c not in seen]
            raise IdentificationDataError(
                f"{where}: {group} columns {present} given but {absent} missing, expected all six or none")


def write_motion_csv(path: str | Path, record: MotionRecord, include_derivatives: bool = True) -> Path:
    """Write a record in the CSV format of this module (round-trip precision)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    columns = [record.t[:, None], record.q, record.tau]
    header = list(REQUIRED_COLUMNS)
    if include_derivatives and record.qd is not None:
        columns.append(record.qd)
        header += QD_COLUMNS
    if include_derivatives and record.qdd is not None:
        columns.append(record.qdd)
        header += QDD_COLUMNS
    _write(path, header, np.hstack(columns))
    return path


def write_prediction_csv(path: str | Path, t: ArrayLike, tau_pred: ArrayLike) -> Path:
    """``t, tau_pred1..tau_pred6`` (s, N m)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _write(path, list(PREDICTION_COLUMNS), np.column_stack((np.asarray(t, dtype=float), np.asarray(tau_pred))))
    return path


def _write(path: Path, header: list[str], table: np.ndarray) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for row in table:
            writer.writerow([repr(float(v)) for v in row])
