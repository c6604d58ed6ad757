"""User trajectory files: joint-space or Cartesian CSV in, a checked :class:`Trajectory` out.

The file format (docs/how-to/own_controller.md, "Trajectory files") in short:

* UTF-8 CSV, ``,`` separated. Lines starting with ``#`` and blank lines are ignored.
  The first other line is the header; every following line is one sample.
* A column name may carry a unit in brackets, ``q1 [deg]``, ``t [ms]``, ``x [mm]``;
  without one the SI unit applies (:data:`UNITS` lists what is accepted).
* **Joint file**: ``t, q1..q6`` (s, rad), optionally ``qd1..qd6`` (rad/s), then
  ``qdd1..qdd6`` (rad/s^2, only together with ``qd``) and ``tau1..tau6`` (N m, the
  feed-forward torque). Any sample rate, not necessarily uniform; times strictly
  increasing; the first sample is the start of the motion (re-timed to 0 in the cell).
* **Cartesian file**: ``t, x, y, z`` (s, m: the flange ``tool0`` in ``base_link``) plus
  the orientation, either a unit quaternion ``qw, qx, qy, qz`` or Cardan angles
  ``alpha, beta, gamma`` (rad, R = Rx(alpha) Ry(beta) Rz(gamma), as
  :func:`robot.kinematics.rotation_from_cardan`). Each sample is converted by the
  project's numeric IK (:class:`robot.inverse_kinematics.NumericIK`; the first sample
  takes the branch nearest to ``q_seed``, every later one is warm-started from the
  previous solution) and the result is then handled as a joint file with ``q`` only.

What is derived when absent (stated in every loaded trajectory's ``metadata``):

* ``q`` only: per joint a quintic B-spline. ``smoothing = 0`` (default): the
  *interpolating* quintic spline through every sample (C4; with ``boundary = "rest"``,
  the default, velocity and acceleration are 0 at the first and last sample; with
  ``"free"`` scipy's not-a-knot ends). ``smoothing = sigma > 0`` (rad): the quintic
  *smoothing* spline (FITPACK, ``scipy.interpolate.make_splrep``) with
  ``sum (q_i - s(t_i))^2 <= n sigma^2``, i.e. an RMS deviation from the samples of
  at most sigma; qd and qdd are its first and second derivatives.
* ``q`` and ``qd``: qdd at the samples is the derivative of the interpolating cubic
  spline through qd (with ``"rest"``: qdd = 0 at both ends); between samples the
  quintic Hermite polynomial through (q, qd, qdd) at both ends, as
  :meth:`Trajectory.sample`.
* ``q``, ``qd``, ``qdd``: used as given; quintic Hermite between samples.
* ``tau`` absent: inverse dynamics ``M(q) qdd + C(q, qd) qd + g(q) + friction(qd)`` of
  the given :class:`robot.dynamics.RobotDynamics` (by default the nominal arm) on the
  resampled motion; given: interpolated linearly.

The loaded trajectory is sampled every ``sample_dt`` (default 1 ms) from the smooth
interpolant, and checked against the robot's limits (:class:`planners.base.JointLimits`,
default :meth:`JointLimits.from_robot`: position, velocity and torque from the URDF,
acceleration from ``robot/rx130l_params.toml``) at every file sample and every grid
point between them. The first violation in time raises :class:`TrajectoryLimitError`
naming the file, the column, the line (or the two lines it lies between), the time,
the value and the limit. Malformed files raise :class:`TrajectoryFileError` naming the
file, the line and the column.
"""
from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from planners.base import JointLimits
from planners.trajectory import N_JOINTS, Trajectory, TrajectoryError, uniform_times
from robot.textfiles import read_text

DEFAULT_SAMPLE_DT = 1e-3
"""Grid [s] on which a loaded file is sampled and checked between its own samples."""
LIMIT_TOLERANCE = 1e-9
"""Relative slack on every limit (rounding of a file written at the limit)."""
BRANCH_JUMP_RAD = 0.5 * math.pi
"""A joint moving more than this [rad] between two Cartesian samples is an IK branch switch."""
QUATERNION_NORM_TOLERANCE = 1e-3
"""Largest accepted | |quaternion| - 1 | of a Cartesian file's orientation."""

Boundary = Literal["rest", "free"]

JOINT_GROUPS = ("q", "qd", "qdd", "tau")
CARTESIAN_POSITION = ("x", "y", "z")
QUATERNION = ("qw", "qx", "qy", "qz")
CARDAN = ("alpha", "beta", "gamma")

# unit -> factor to SI, per physical quantity
_ANGLE = {"rad": 1.0, "deg": math.pi / 180.0}
_UNIT_TABLE: dict[str, dict[str, float]] = {
    "time": {"s": 1.0, "ms": 1e-3},
    "angle": _ANGLE,
    "angular_velocity": {"rad/s": 1.0, "deg/s": math.pi / 180.0},
    "angular_acceleration": {"rad/s^2": 1.0, "rad/s2": 1.0, "deg/s^2": math.pi / 180.0, "deg/s2": math.pi / 180.0},
    "torque": {"N m": 1.0, "Nm": 1.0, "N.m": 1.0, "N*m": 1.0},
    "length": {"m": 1.0, "mm": 1e-3},
    "unitless": {"1": 1.0, "-": 1.0},
}
UNITS: dict[str, tuple[str, str]] = {
    "t": ("time", "s"), "q": ("angle", "rad"), "qd": ("angular_velocity", "rad/s"),
    "qdd": ("angular_acceleration", "rad/s^2"), "tau": ("torque", "N m"),
    "x": ("length", "m"), "y": ("length", "m"), "z": ("length", "m"),
    "alpha": ("angle", "rad"), "beta": ("angle", "rad"), "gamma": ("angle", "rad"),
    "qw": ("unitless", "1"), "qx": ("unitless", "1"), "qy": ("unitless", "1"), "qz": ("unitless", "1"),
}
"""Column (or joint group) -> (quantity, SI unit); accepted bracket units per quantity in ``_UNIT_TABLE``."""

_LIMIT_OF = {"q": "position", "qd": "velocity", "qdd": "acceleration", "tau": "torque"}
_SI_UNIT = {"q": "rad", "qd": "rad/s", "qdd": "rad/s^2", "tau": "N m"}


class TrajectoryFileError(TrajectoryError):
    """A trajectory file is malformed; ``file``, ``column``, ``line`` name where (None: not one place)."""

    def __init__(self, file: str | Path, message: str, *, column: str | None = None, line: int | None = None) -> None:
        self.file = str(file)
        self.column = column
        self.line = line
        where = [f"trajectory file {self.file!r}"]
        if line is not None:
            where.append(f"line {line}")
        if column is not None:
            where.append(f"column {column!r}")
        super().__init__(", ".join(where) + ": " + message)


class TrajectoryLimitError(TrajectoryFileError):
    """A sample of a trajectory file lies beyond a limit of the robot.

    Attributes: ``file``, ``column`` (e.g. ``"qd3"``), ``line`` (the file line of the
    sample, or of the sample before when the violation lies between two samples),
    ``time`` (s, the file's time axis), ``value`` and ``limit`` (SI units of the
    column), ``kind`` ("position", "velocity", "acceleration", "torque"), ``derived``
    (True when the column is not in the file but derived from it), ``violations``
    (how many checked points of all columns exceed a limit).
    """

    def __init__(self, file: str | Path, *, column: str, line: int, between: int | None, time: float, value: float,
                 limit: Any, kind: str, derived: bool, violations: int) -> None:
        self.time, self.value, self.limit, self.kind = time, value, limit, kind
        self.derived, self.violations = derived, violations
        unit = _SI_UNIT[column.rstrip("0123456789")]
        if isinstance(limit, tuple):
            bound = f"the {kind} range [{limit[0]:.6g}, {limit[1]:.6g}] {unit}"
        else:
            bound = f"the {kind} limit |{column}| <= {limit:.6g} {unit}"
        origin = " (derived, not in the file)" if derived else ""
        place = f"between lines {line} and {between}" if between is not None else f"line {line}"
        msg = (f"first sample beyond a limit at t = {time:.6g} s ({place}): {column}{origin} = {value:.6g} {unit} "
               f"exceeds {bound}")
        if violations > 1:
            msg += f"; {violations} checked points beyond limits in all"
        super().__init__(file, msg, column=column, line=line)


@dataclass(frozen=True)
class _Table:
    """The parsed numbers of a CSV file: header names (unit stripped), SI columns, file line per row."""

    names: list[str]
    columns: dict[str, np.ndarray]
    lines: np.ndarray


_HEADER_RE = re.compile(r"^\s*([A-Za-z_][A-Za-z_0-9]*)\s*(?:\[\s*([^\]]*?)\s*\])?\s*$")


def _quantity(name: str) -> tuple[str, str] | None:
    if name in UNITS:
        return UNITS[name]
    group = name.rstrip("0123456789")
    if group in JOINT_GROUPS and name[len(group):] in {str(j) for j in range(1, N_JOINTS + 1)}:
        return UNITS[group]
    return None


def _read_table(path: Path) -> _Table:
    if not path.is_file():
        raise TrajectoryFileError(path, "no such file")
    try:
        text = read_text(path)  # UTF-8, a byte-order mark dropped
    except (OSError, UnicodeDecodeError) as exc:
        raise TrajectoryFileError(path, f"cannot be read as UTF-8 text: {exc}") from None
    rows: list[tuple[int, list[str]]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        rows.append((number, next(csv.reader([line]))))
    if not rows:
        raise TrajectoryFileError(path, "no header line: expected e.g. 't, q1, q2, q3, q4, q5, q6'")
    header_line, header = rows[0]
    names: list[str] = []
    factors: list[float] = []
    for cell in header:
        m = _HEADER_RE.match(cell)
        if not m:
            raise TrajectoryFileError(path, f"column name {cell.strip()!r}: expected a name with an optional unit "
                                            "in brackets, e.g. 'q1 [deg]'", line=header_line)
        name, unit = m.group(1), m.group(2)
        quantity = _quantity(name)
        if quantity is None:
            raise TrajectoryFileError(path, "unknown column: expected t, q1..q6, qd1..qd6, qdd1..qdd6, tau1..tau6 "
                                            "(joint file) or t, x, y, z with qw, qx, qy, qz or alpha, beta, gamma "
                                            "(Cartesian file)", column=name, line=header_line)
        if name in names:
            raise TrajectoryFileError(path, "column given twice", column=name, line=header_line)
        accepted = _UNIT_TABLE[quantity[0]]
        if unit is None or unit == "":
            factor = 1.0
        elif unit in accepted:
            factor = accepted[unit]
        else:
            raise TrajectoryFileError(path, f"unit [{unit}]: expected one of {list(accepted)}", column=name,
                                      line=header_line)
        names.append(name)
        factors.append(factor)
    data = rows[1:]
    if len(data) < 2:
        raise TrajectoryFileError(path, f"expected at least 2 samples after the header, got {len(data)}")
    values = np.empty((len(data), len(names)))
    lines = np.array([number for number, _ in data])
    for r, (number, cells) in enumerate(data):
        if len(cells) != len(names):
            raise TrajectoryFileError(path, f"{len(cells)} values, expected {len(names)} (one per header column)",
                                      line=number)
        for c, cell in enumerate(cells):
            try:
                v = float(cell)
            except ValueError:
                raise TrajectoryFileError(path, f"value {cell.strip()!r} is not a number", column=names[c],
                                          line=number) from None
            if not math.isfinite(v):
                raise TrajectoryFileError(path, f"value {cell.strip()!r}: expected a finite number (no NaN/inf)",
                                          column=names[c], line=number)
            values[r, c] = v * factors[c]
    return _Table(names, {n: values[:, k] for k, n in enumerate(names)}, lines)


def _check_time(path: Path, table: _Table) -> np.ndarray:
    if "t" not in table.columns:
        raise TrajectoryFileError(path, "missing: expected the time column 't' (s)", column="t")
    t = table.columns["t"]
    step = np.diff(t)
    bad = np.flatnonzero(step <= 0.0)
    if bad.size:
        k = int(bad[0]) + 1
        raise TrajectoryFileError(path, f"t = {t[k]:.9g} s is not after the previous sample's t = {t[k - 1]:.9g} s "
                                        f"(line {table.lines[k - 1]}): expected strictly increasing times",
                                  column="t", line=int(table.lines[k]))
    return t


def _group(path: Path, table: _Table, group: str) -> np.ndarray | None:
    names = [f"{group}{j}" for j in range(1, N_JOINTS + 1)]
    present = [n for n in names if n in table.columns]
    if not present:
        return None
    missing = [n for n in names if n not in table.columns]
    if missing:
        raise TrajectoryFileError(path, f"missing: {group} is given for {present} but not for {missing}; expected "
                                        f"all six of {names}", column=missing[0])
    return np.column_stack([table.columns[n] for n in names])


def file_kind(path: str | Path) -> Literal["joint", "cartesian"]:
    """"joint" or "cartesian" from a file's header (the file is read and its columns checked)."""
    table = _read_table(Path(path))
    return "cartesian" if any(n in table.columns for n in CARTESIAN_POSITION) else "joint"


# --------------------------------------------------------------------------------- derivation
def _spline_q(t: np.ndarray, q: np.ndarray, smoothing: float, boundary: Boundary):
    """Per-joint quintic B-splines through (smoothing 0) or near (smoothing > 0) the samples."""
    from scipy.interpolate import make_interp_spline, make_splrep

    n = t.size
    if smoothing > 0.0:
        if n < 6:
            raise ValueError(f"a quintic smoothing spline needs at least 6 samples, the file has {n}")
        return [make_splrep(t, q[:, j], k=5, s=n * smoothing**2) for j in range(N_JOINTS)]
    if boundary == "rest":
        bc = ([(1, 0.0), (2, 0.0)], [(1, 0.0), (2, 0.0)])
        return [make_interp_spline(t, q[:, j], k=5, bc_type=bc) for j in range(N_JOINTS)]
    if n < 6:
        raise ValueError(f"boundary = 'free' (not-a-knot quintic) needs at least 6 samples, the file has {n}")
    return [make_interp_spline(t, q[:, j], k=5) for j in range(N_JOINTS)]


def _qdd_from_qd(t: np.ndarray, qd: np.ndarray, boundary: Boundary) -> np.ndarray:
    from scipy.interpolate import make_interp_spline

    if boundary == "rest":
        bc = ([(1, 0.0)], [(1, 0.0)])
        return np.column_stack([make_interp_spline(t, qd[:, j], k=3, bc_type=bc).derivative()(t)
                                for j in range(N_JOINTS)])
    if t.size < 4:
        return np.gradient(qd, t, axis=0)
    return np.column_stack([make_interp_spline(t, qd[:, j], k=3).derivative()(t) for j in range(N_JOINTS)])


def _torques(dynamics: Any, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    return np.array([dynamics.inverse_dynamics(q[k], qd[k], qdd[k]) for k in range(q.shape[0])])


# --------------------------------------------------------------------------------- Cartesian
def _cartesian_to_joint(path: Path, table: _Table, kinematic_model: Any, q_seed: Any) -> np.ndarray:
    from robot.inverse_kinematics import NumericIK, UnreachablePoseError
    from robot.kinematics import rotation_from_cardan

    for name in CARTESIAN_POSITION:
        if name not in table.columns:
            raise TrajectoryFileError(path, "missing: a Cartesian file needs t, x, y, z (m) and an orientation",
                                      column=name)
    has_quat = any(n in table.columns for n in QUATERNION)
    has_cardan = any(n in table.columns for n in CARDAN)
    if has_quat and has_cardan:
        raise TrajectoryFileError(path, "both quaternion (qw, qx, qy, qz) and Cardan (alpha, beta, gamma) columns: "
                                        "expected one orientation")
    if not (has_quat or has_cardan):
        raise TrajectoryFileError(path, "missing orientation: expected qw, qx, qy, qz (unit quaternion) or alpha, "
                                        "beta, gamma (rad, Rx Ry Rz)", column="qw")
    group = QUATERNION if has_quat else CARDAN
    for name in group:
        if name not in table.columns:
            raise TrajectoryFileError(path, f"missing: the orientation needs all of {list(group)}", column=name)
    joint_cols = [n for n in table.columns if _quantity(n) is not None and n.rstrip("0123456789") in JOINT_GROUPS
                  and n not in QUATERNION]
    if joint_cols:
        raise TrajectoryFileError(path, "a Cartesian file cannot also carry joint columns: give one kind per file",
                                  column=joint_cols[0])
    position = np.column_stack([table.columns[n] for n in CARTESIAN_POSITION])
    if has_quat:
        quat = np.column_stack([table.columns[n] for n in QUATERNION])
        norm = np.linalg.norm(quat, axis=1)
        bad = np.flatnonzero(np.abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE)
        if bad.size:
            k = int(bad[0])
            raise TrajectoryFileError(path, f"quaternion (qw, qx, qy, qz) has norm {norm[k]:.6g}: expected a unit "
                                            f"quaternion (|norm - 1| <= {QUATERNION_NORM_TOLERANCE})",
                                      column="qw", line=int(table.lines[k]))
        w, x, y, z = (quat / norm[:, None]).T
        rotation = np.empty((w.size, 3, 3))
        rotation[:, 0] = np.column_stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)])
        rotation[:, 1] = np.column_stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)])
        rotation[:, 2] = np.column_stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)])
    else:
        rotation = rotation_from_cardan(np.column_stack([table.columns[n] for n in CARDAN]))
    ik = NumericIK(kinematic_model)
    q = np.empty((position.shape[0], N_JOINTS))
    seed = np.zeros(N_JOINTS) if q_seed is None else np.asarray(q_seed, dtype=float)
    for k in range(position.shape[0]):
        target = np.eye(4)
        target[:3, :3] = rotation[k]
        target[:3, 3] = position[k]
        try:
            q[k] = ik.solve_nearest(target, seed) if k == 0 else ik.solve(target, q[k - 1])
        except UnreachablePoseError as exc:
            raise TrajectoryFileError(path, f"flange pose at t = {table.columns['t'][k]:.6g} s, position "
                                            f"{np.round(position[k], 6).tolist()} m, is not reachable: {exc}",
                                      line=int(table.lines[k])) from None
        if k and np.max(np.abs(q[k] - q[k - 1])) > BRANCH_JUMP_RAD:
            j = int(np.argmax(np.abs(q[k] - q[k - 1])))
            raise TrajectoryFileError(
                path, f"the IK switches branch between lines {table.lines[k - 1]} and {table.lines[k]} (joint {j + 1} "
                      f"jumps from {q[k - 1, j]:.4f} to {q[k, j]:.4f} rad): the path passes a singularity or the "
                      "samples are too far apart", line=int(table.lines[k]))
    return q


# --------------------------------------------------------------------------------- checking
def _check_limits(path: Path, limits: JointLimits, file_t: np.ndarray, lines: np.ndarray, grid: Trajectory,
                  given: set[str]) -> dict[str, float]:
    """Raise TrajectoryLimitError at the earliest violation; return the largest |value|/limit per kind."""
    t = grid.t
    file_idx = np.searchsorted(t, file_t)        # grid contains every file time (see load)
    ratios: dict[str, float] = {}
    first: tuple[float, str, int, float, Any, str] | None = None
    count = 0
    for group in JOINT_GROUPS:
        values = getattr(grid, group)
        kind = _LIMIT_OF[group]
        if kind == "position":
            lo, hi = np.asarray(limits.position_lower), np.asarray(limits.position_upper)
            slack = LIMIT_TOLERANCE * np.maximum(1.0, np.abs(np.where(np.isfinite(hi - lo), hi - lo, 1.0)))
            over = (values < lo - slack) | (values > hi + slack)
            half, mid = 0.5 * (hi - lo), 0.5 * (hi + lo)
            ratio = np.where(np.isfinite(half), np.max(np.abs(values - mid), axis=0) / half, 0.0)
        else:
            lim = np.asarray(getattr(limits, kind), dtype=float)
            over = np.abs(values) > lim * (1.0 + LIMIT_TOLERANCE)
            ratio = np.max(np.abs(values), axis=0) / lim
        ratios[kind] = float(np.max(ratio))
        count += int(over.sum())
        for j in range(N_JOINTS):
            hits = np.flatnonzero(over[:, j])
            if not hits.size:
                continue
            k = int(hits[0])
            if first is None or t[k] < first[0]:
                limit = ((float(limits.position_lower[j]), float(limits.position_upper[j])) if kind == "position"
                         else float(getattr(limits, kind)[j]))
                first = (float(t[k]), f"{group}{j + 1}", k, float(values[k, j]), limit, kind)
    if first is None:
        return ratios
    time, column, k, value, limit, kind = first
    r = int(np.searchsorted(file_idx, k, side="right")) - 1       # file sample at or before grid point k
    exact = file_idx[r] == k
    return _raise_limit(path, column, int(lines[r]), None if exact else int(lines[min(r + 1, lines.size - 1)]),
                        time, value, limit, kind, column not in given, count)


def _raise_limit(path, column, line, between, time, value, limit, kind, derived, count):
    raise TrajectoryLimitError(path, column=column, line=line, between=between, time=time, value=value, limit=limit,
                               kind=kind, derived=derived, violations=count)


class PlanLimitError(TrajectoryError):
    """A planner's trajectory lies beyond a limit of the robot, or does not end where the problem
    asked (:func:`check_planned_trajectory`). Attributes: ``planner`` (its name or class spec),
    ``joint`` (1..6), ``kind`` ("position", "velocity", "acceleration", "torque" or "goal"),
    ``time`` (s, the trajectory's time), ``value``, ``limit`` (SI units; a (low, high) range for
    positions), ``violations`` (checked points beyond limits in all)."""

    def __init__(self, planner: str, message: str, *, joint: int, kind: str, time: float, value: float,
                 limit: Any, violations: int = 1) -> None:
        self.planner, self.joint, self.kind, self.time = planner, joint, kind, time
        self.value, self.limit, self.violations = value, limit, violations
        super().__init__(f"planner {planner}: {message}")


GOAL_TOLERANCE_RAD = 1e-6
"""How far a planned point-to-point trajectory may end from the problem's goal (rad per joint)."""


def check_planned_trajectory(trajectory: Trajectory, planner: str, limits: JointLimits | None = None,
                             goal: Any = None) -> dict[str, float]:
    """Check a planner's trajectory before it runs, with the checker of trajectory files: every
    sample of q, qd, qdd and tau against the robot's limits (``limits``, default
    :meth:`JointLimits.from_robot`; the same slack :data:`LIMIT_TOLERANCE`), and, given the
    problem's ``goal`` (6 angles, rad), that it ends there (:data:`GOAL_TOLERANCE_RAD`): a plan
    that stops halfway is refused too. Returns the largest |value| / limit per kind; raises
    :class:`PlanLimitError` naming the planner, joint, limit and time of the earliest violation."""
    limits = limits or JointLimits.from_robot()
    n = trajectory.t.size
    try:
        ratios = _check_limits(Path(planner), limits, trajectory.t, np.arange(n), trajectory, set(JOINT_GROUPS)
                               | {f"{g}{j}" for g in JOINT_GROUPS for j in range(1, N_JOINTS + 1)})
    except TrajectoryLimitError as exc:
        column = exc.column or ""
        group, joint = column.rstrip("0123456789"), int(column[len(column.rstrip("0123456789")):] or 0)
        unit = _SI_UNIT.get(group, "")
        bound = (f"the {exc.kind} range [{exc.limit[0]:.6g}, {exc.limit[1]:.6g}] {unit}" if isinstance(exc.limit, tuple)
                 else f"the {exc.kind} limit |{column}| <= {exc.limit:.6g} {unit}")
        more = f"; {exc.violations} samples beyond limits in all" if exc.violations > 1 else ""
        raise PlanLimitError(planner, f"joint {joint} beyond its {exc.kind} limit at t = {exc.time:.6g} s: "
                                      f"{column} = {exc.value:.6g} {unit} exceeds {bound}{more}",
                             joint=joint, kind=exc.kind, time=exc.time, value=exc.value, limit=exc.limit,
                             violations=exc.violations) from None
    if goal is not None:
        goal = np.asarray(goal, dtype=float).reshape(-1)
        miss = np.abs(trajectory.q[-1] - goal)
        if goal.size == N_JOINTS and np.any(miss > GOAL_TOLERANCE_RAD):
            j = int(np.argmax(miss))
            raise PlanLimitError(planner, f"ends at t = {trajectory.t[-1]:.6g} s with joint {j + 1} at "
                                          f"{trajectory.q[-1, j]:.6g} rad, {miss[j]:.3g} rad from the goal "
                                          f"{goal[j]:.6g} rad: the plan does not reach the end of the motion",
                                 joint=j + 1, kind="goal", time=float(trajectory.t[-1]),
                                 value=float(trajectory.q[-1, j]), limit=float(goal[j]))
    return ratios


# --------------------------------------------------------------------------------- loading
def load_trajectory_file(
    path: str | Path,
    *,
    kind: Literal["auto", "joint", "cartesian"] = "auto",
    smoothing: float = 0.0,
    boundary: Boundary = "rest",
    limits: JointLimits | None = None,
    dynamics: Any = None,
    kinematic_model: Any = None,
    q_seed: Any = None,
    sample_dt: float = DEFAULT_SAMPLE_DT,
    check: bool = True,
) -> Trajectory:
    """Read, complete and check a user trajectory file (format: module docstring).

    ``kind``: "auto" (Cartesian when the header has x, y, z), "joint" or "cartesian".
    ``smoothing`` [rad] >= 0 and ``boundary`` ("rest" or "free"): how q is splined when
    the file has no velocities (module docstring). ``limits``: the robot's limits
    (default :meth:`JointLimits.from_robot`). ``dynamics``: the
    :class:`robot.dynamics.RobotDynamics` for the torques when the file has none
    (default: the nominal arm). ``kinematic_model`` (pinocchio model, default the
    nominal URDF) and ``q_seed`` (6 rad, the IK branch of the first sample, default
    zeros): Cartesian files only. ``sample_dt`` [s]: the grid the result is sampled and
    checked on (plus every file sample). ``check = False`` skips the limit check.

    Returns a :class:`Trajectory` (times from the file, so ``t[0]`` may be non-zero) with
    the flange position ``x, y, z`` (m, FK of ``kinematic_model``) as Cartesian columns
    and ``metadata``: source, kind, columns given, what was derived and how, the
    largest |value| / limit per limit kind. Raises TrajectoryFileError (malformed file)
    or TrajectoryLimitError (a sample beyond a limit).
    """
    from robot.kinematics import FlangeKinematics

    path = Path(path)
    if kind not in ("auto", "joint", "cartesian"):
        raise TrajectoryFileError(path, f"kind = {kind!r}: expected 'auto', 'joint' or 'cartesian'")
    if boundary not in ("rest", "free"):
        raise TrajectoryFileError(path, f"boundary = {boundary!r}: expected 'rest' or 'free'")
    if not (isinstance(smoothing, (int, float)) and math.isfinite(smoothing) and smoothing >= 0.0):
        raise TrajectoryFileError(path, f"smoothing = {smoothing!r}: expected a number of rad >= 0")
    if not (isinstance(sample_dt, (int, float)) and math.isfinite(sample_dt) and sample_dt > 0.0):
        raise TrajectoryFileError(path, f"sample_dt = {sample_dt!r}: expected a number of s > 0")
    table = _read_table(path)
    t = _check_time(path, table)
    cartesian = any(n in table.columns for n in CARTESIAN_POSITION)
    if kind == "auto":
        kind = "cartesian" if cartesian else "joint"
    if kind == "joint" and cartesian:
        raise TrajectoryFileError(path, "kind = 'joint' but the file has Cartesian columns (x, y, z)", column="x")
    if kind == "cartesian" and not cartesian:
        raise TrajectoryFileError(path, "missing: kind = 'cartesian' needs t, x, y, z (m) and an orientation",
                                  column="x")
    limits = limits or JointLimits.from_robot()
    if kinematic_model is None:
        from robot.description import load_model

        kinematic_model = load_model()
    given: set[str] = set()
    if kind == "cartesian":
        q = _cartesian_to_joint(path, table, kinematic_model, q_seed)
        qd = qdd = tau = None
    else:
        q = _group(path, table, "q")
        if q is None:
            raise TrajectoryFileError(path, "missing: a joint file needs t and q1..q6 (rad), a Cartesian file t, x, "
                                            "y, z and an orientation", column="q1")
        qd, qdd, tau = (_group(path, table, g) for g in ("qd", "qdd", "tau"))
        if qdd is not None and qd is None:
            raise TrajectoryFileError(path, "missing: qdd1..qdd6 given without qd1..qd6; give the velocities too or "
                                            "drop the accelerations", column="qd1")
        for group, arr in (("q", q), ("qd", qd), ("qdd", qdd), ("tau", tau)):
            if arr is not None:
                given |= {f"{group}{j}" for j in range(1, N_JOINTS + 1)}
    times = np.union1d(uniform_times(float(t[0]), float(t[-1]), sample_dt), t)
    if qd is None:
        try:
            splines = _spline_q(t, q, smoothing, boundary)
        except ValueError as exc:
            raise TrajectoryFileError(path, str(exc)) from None
        gq = np.column_stack([s(times) for s in splines])
        gqd = np.column_stack([s(times, 1) for s in splines])
        gqdd = np.column_stack([s(times, 2) for s in splines])
        if smoothing > 0.0:
            how = (f"q smoothed by a quintic smoothing spline (scipy make_splrep, k = 5, s = n sigma^2, sigma = "
                   f"{smoothing:g} rad); qd, qdd its derivatives")
            resid = np.column_stack([s(t) for s in splines]) - q
            dev = float(np.sqrt(np.mean(resid**2)))
        else:
            how = (f"qd, qdd: derivatives of the interpolating quintic spline through q (scipy make_interp_spline, "
                   f"k = 5, {'qd = qdd = 0 at both ends' if boundary == 'rest' else 'not-a-knot ends'})")
            dev = 0.0
    else:
        if qdd is None:
            qdd = _qdd_from_qd(t, qd, boundary)
            how = ("qdd at the samples: derivative of the interpolating cubic spline through qd "
                   f"({'qdd = 0 at both ends' if boundary == 'rest' else 'not-a-knot ends'}); quintic Hermite "
                   "between samples")
        else:
            how = "q, qd, qdd as given; quintic Hermite between samples"
        dense = Trajectory(t, q, qd, qdd, np.zeros_like(q)).sample(times)
        gq, gqd, gqdd = dense.q, dense.qd, dense.qdd
        dev = 0.0
    if tau is None:
        from robot.dynamics import RobotDynamics

        dyn = dynamics if dynamics is not None else RobotDynamics()
        gtau = _torques(dyn, gq, gqd, gqdd)
        how_tau = "tau: inverse dynamics M(q) qdd + C qd + g + friction of the " + (
            "given dynamics" if dynamics is not None else "nominal arm (URDF + rx130l_params.toml)")
    else:
        gtau = np.column_stack([np.interp(times, t, tau[:, j]) for j in range(N_JOINTS)])
        how_tau = "tau as given, linear between samples"
    flange = FlangeKinematics(kinematic_model).transforms(gq)[:, :3, 3]
    metadata = {"source": str(path), "kind": kind, "columns": table.names, "derivation": how,
                "torque": how_tau, "smoothing_rad": float(smoothing), "boundary": boundary,
                "smoothing_rms_deviation_rad": dev, "samples": int(t.size), "sample_dt_s": float(sample_dt)}
    traj = Trajectory(times, gq, gqd, gqdd, gtau, {"x": flange[:, 0], "y": flange[:, 1], "z": flange[:, 2]},
                      metadata)
    if check:
        traj.metadata["limit_ratios"] = _check_limits(path, limits, t, table.lines, traj, given)
    return traj
