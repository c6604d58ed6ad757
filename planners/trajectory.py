"""The one trajectory type every planner returns, its CSV form, resampling and metrics.

A :class:`Trajectory` is plain data, like Ruckig's output parameters: time ``t`` (n,)
in s (strictly increasing, starting anywhere), joint positions ``q`` [rad], velocities
``qd`` [rad/s], accelerations ``qdd`` [rad/s^2] and joint torques ``tau`` [N m] of
shape (n, 6), sampled densely (1 ms or finer), optional Cartesian columns (name ->
(n,) array, e.g. flange position ``x, y, z`` in m in base_link) and free-form
``metadata`` (planner name, status, solve_time_s, ...).

Between samples :meth:`Trajectory.sample` uses, per joint, the quintic Hermite
polynomial that matches q, qd and qdd at both ends of the interval (so the returned
qd and qdd are the exact derivatives of the returned q), and linear interpolation for
the torque and the Cartesian columns.
"""
from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable

import numpy as np
from numpy.typing import ArrayLike

from robot.joints import N_JOINTS

if TYPE_CHECKING:  # pragma: no cover
    from planners.limits import JointLimits

JOINT_GROUPS: tuple[str, ...] = ("q", "qd", "qdd", "tau")
DEFAULT_CHECK_DT = 1e-3
"""Sample time [s] at which constraint ratios are evaluated: 1 ms, as ``max_constraint_ratio``
is defined in docs/explanation/planners.md."""
RATIO_KINDS: tuple[str, ...] = ("velocity", "acceleration", "torque", "torque_rate")
"""Limit kinds that enter ``max_constraint_ratio`` by default (the paper's section 5 limits)."""


class TrajectoryError(ValueError):
    """A trajectory, its CSV file or a sampling request is malformed."""


@dataclass(frozen=True)
class TrajectorySample:
    """Joint references at one or more times: arrays (6,) for a scalar time, else (m, 6)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray


@dataclass
class Trajectory:
    """Densely sampled joint trajectory (see module docstring for units and layout)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    cartesian: dict[str, np.ndarray] = field(default_factory=dict)
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float).reshape(-1)
        n = self.t.size
        if n < 2:
            raise TrajectoryError(f"Trajectory.t: expected at least 2 samples, got {n}")
        if not np.all(np.isfinite(self.t)) or np.any(np.diff(self.t) <= 0.0):
            raise TrajectoryError("Trajectory.t: expected finite, strictly increasing times in s")
        for name in JOINT_GROUPS:
            arr = np.asarray(getattr(self, name), dtype=float)
            if arr.shape != (n, N_JOINTS):
                raise TrajectoryError(f"Trajectory.{name}: expected shape ({n}, {N_JOINTS}), got {arr.shape}")
            if not np.all(np.isfinite(arr)):
                raise TrajectoryError(f"Trajectory.{name}: expected finite values")
            setattr(self, name, arr)
        columns = {}
        for key, value in dict(self.cartesian).items():
            arr = np.asarray(value, dtype=float)
            if arr.shape != (n,):
                raise TrajectoryError(f"Trajectory.cartesian[{key!r}]: expected shape ({n},), got {arr.shape}")
            if key in ("t",) or _is_joint_column(key):
                raise TrajectoryError(f"Trajectory.cartesian: column name {key!r} clashes with a joint column")
            columns[str(key)] = arr
        self.cartesian = columns
        self.metadata = dict(self.metadata)

    # -- basic properties ---------------------------------------------------
    @property
    def duration(self) -> float:
        """t[-1] - t[0] in s."""
        return float(self.t[-1] - self.t[0])

    @property
    def n_samples(self) -> int:
        return int(self.t.size)

    # -- interpolation ------------------------------------------------------
    def sample(self, t: ArrayLike) -> TrajectorySample:
        """References at time(s) ``t`` [s] (clamped to [t[0], t[-1]]).

        q, qd, qdd come from the quintic Hermite polynomial matching q, qd, qdd at both
        interval ends; tau is interpolated linearly. A scalar ``t`` gives (6,) arrays.
        """
        scalar = np.ndim(t) == 0
        times = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), self.t[0], self.t[-1])
        if not np.all(np.isfinite(times)):
            raise TrajectoryError(f"Trajectory.sample: expected finite times, got {t!r}")
        i = np.clip(np.searchsorted(self.t, times, side="right") - 1, 0, self.t.size - 2)
        h = (self.t[i + 1] - self.t[i])[:, None]
        s = ((times - self.t[i]) / h[:, 0])[:, None]
        q, qd, qdd = _quintic_hermite(
            self.q[i], self.qd[i] * h, self.qdd[i] * h**2,
            self.q[i + 1], self.qd[i + 1] * h, self.qdd[i + 1] * h**2, s,
        )
        qd = qd / h
        qdd = qdd / h**2
        tau = self.tau[i] + s * (self.tau[i + 1] - self.tau[i])
        if scalar:
            return TrajectorySample(times[0], q[0], qd[0], qdd[0], tau[0])
        return TrajectorySample(times, q, qd, qdd, tau)

    def sample_cartesian(self, t: ArrayLike) -> dict[str, np.ndarray]:
        """Cartesian columns at time(s) ``t`` [s], interpolated linearly."""
        times = np.clip(np.asarray(t, dtype=float), self.t[0], self.t[-1])
        return {k: np.interp(times, self.t, v) for k, v in self.cartesian.items()}

    def resample(self, dt: float) -> "Trajectory":
        """A copy sampled every ``dt`` s from t[0], the last sample at t[-1] exactly."""
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0.0):
            raise TrajectoryError(f"Trajectory.resample: dt must be a positive number of seconds, got {dt!r}")
        times = uniform_times(self.t[0], self.t[-1], dt)
        s = self.sample(times)
        return Trajectory(times, s.q, s.qd, s.qdd, s.tau, self.sample_cartesian(times), dict(self.metadata))

    # -- CSV ----------------------------------------------------------------
    def columns(self) -> dict[str, np.ndarray]:
        """All columns by CSV name: t, q1..q6, qd1..qd6, qdd1..qdd6, tau1..tau6, cartesian."""
        out: dict[str, np.ndarray] = {"t": self.t}
        for group in JOINT_GROUPS:
            arr = getattr(self, group)
            for j in range(N_JOINTS):
                out[f"{group}{j + 1}"] = arr[:, j]
        out.update(self.cartesian)
        return out

    def write_csv(self, path: str | Path) -> Path:
        """Write the trajectory as CSV: a ``# metadata: {json}`` line, a header, rows.

        Units: t in s, q in rad, qd in rad/s, qdd in rad/s^2, tau in N m; Cartesian
        columns as given. Returns the path written.
        """
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        cols = self.columns()
        data = np.column_stack(list(cols.values()))
        with open(path, "w", newline="", encoding="utf-8") as handle:
            handle.write("# metadata: " + json.dumps(_jsonable(self.metadata), sort_keys=True) + "\n")
            writer = csv.writer(handle)
            writer.writerow(cols.keys())
            for row in data:
                writer.writerow([repr(float(v)) for v in row])
        return path

    @classmethod
    def read_csv(cls, path: str | Path) -> "Trajectory":
        """Read a file written by :meth:`write_csv` (the metadata line is optional)."""
        path = Path(path)
        if not path.is_file():
            raise TrajectoryError(f"trajectory CSV {str(path)!r} does not exist")
        with open(path, encoding="utf-8") as handle:
            lines = handle.read().splitlines()
        metadata: dict[str, Any] = {}
        if lines and lines[0].startswith("#"):
            first = lines.pop(0)
            if first.startswith("# metadata:"):
                try:
                    metadata = json.loads(first[len("# metadata:"):])
                except json.JSONDecodeError as exc:
                    raise TrajectoryError(f"trajectory CSV {str(path)!r}: metadata line is not JSON: {exc}") from exc
        rows = list(csv.reader(lines))
        if len(rows) < 3:
            raise TrajectoryError(f"trajectory CSV {str(path)!r}: expected a header and at least 2 rows")
        header = rows[0]
        required = ["t"] + [f"{g}{j + 1}" for g in JOINT_GROUPS for j in range(N_JOINTS)]
        missing = [c for c in required if c not in header]
        if missing:
            raise TrajectoryError(f"trajectory CSV {str(path)!r}: missing columns {missing}, expected {required}")
        try:
            data = np.array([[float(v) for v in row] for row in rows[1:]], dtype=float)
        except ValueError as exc:
            raise TrajectoryError(f"trajectory CSV {str(path)!r}: non-numeric entry: {exc}") from exc
        if data.shape[1] != len(header):
            raise TrajectoryError(f"trajectory CSV {str(path)!r}: rows have {data.shape[1]} values, header {len(header)}")
        col = {name: data[:, k] for k, name in enumerate(header)}
        joint = {g: np.column_stack([col[f"{g}{j + 1}"] for j in range(N_JOINTS)]) for g in JOINT_GROUPS}
        cart = {k: v for k, v in col.items() if k != "t" and not _is_joint_column(k)}
        return cls(col["t"], joint["q"], joint["qd"], joint["qdd"], joint["tau"], cart, metadata)


def _is_joint_column(name: str) -> bool:
    for group in JOINT_GROUPS:
        if name.startswith(group) and name[len(group):] in {str(j + 1) for j in range(N_JOINTS)}:
            return True
    return False


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    if hasattr(value, "value") and isinstance(getattr(value, "value"), str):  # enums
        return value.value
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return value


def _quintic_hermite(p0, v0, a0, p1, v1, a1, s):
    """Quintic Hermite on s in [0, 1] with derivatives w.r.t. s (v, a already scaled by h)."""
    s2, s3 = s * s, s * s * s
    s4, s5 = s3 * s, s3 * s2
    h00 = 1 - 10 * s3 + 15 * s4 - 6 * s5
    h10 = s - 6 * s3 + 8 * s4 - 3 * s5
    h20 = 0.5 * (s2 - 3 * s3 + 3 * s4 - s5)
    h01 = 10 * s3 - 15 * s4 + 6 * s5
    h11 = -4 * s3 + 7 * s4 - 3 * s5
    h21 = 0.5 * (s3 - 2 * s4 + s5)
    d00 = -30 * s2 + 60 * s3 - 30 * s4
    d10 = 1 - 18 * s2 + 32 * s3 - 15 * s4
    d20 = 0.5 * (2 * s - 9 * s2 + 12 * s3 - 5 * s4)
    d11 = -12 * s2 + 28 * s3 - 15 * s4
    d21 = 0.5 * (3 * s2 - 8 * s3 + 5 * s4)
    e00 = -60 * s + 180 * s2 - 120 * s3
    e10 = -36 * s + 96 * s2 - 60 * s3
    e20 = 0.5 * (2 - 18 * s + 36 * s2 - 20 * s3)
    e11 = -24 * s + 84 * s2 - 60 * s3
    e21 = 0.5 * (6 * s - 24 * s2 + 20 * s3)
    p = h00 * p0 + h10 * v0 + h20 * a0 + h01 * p1 + h11 * v1 + h21 * a1
    v = d00 * p0 + d10 * v0 + d20 * a0 - d00 * p1 + d11 * v1 + d21 * a1
    a = e00 * p0 + e10 * v0 + e20 * a0 - e00 * p1 + e11 * v1 + e21 * a1
    return p, v, a


def uniform_times(t0: float, t1: float, dt: float) -> np.ndarray:
    """Times t0, t0 + dt, ... and t1 exactly (the last step may be shorter) [s]."""
    n = int(math.floor((t1 - t0) / dt + 1e-9))
    times = t0 + dt * np.arange(n + 1)
    if t1 - times[-1] > 1e-9 * max(1.0, dt):
        times = np.append(times, t1)
    else:
        times[-1] = t1
    return times


# -- metrics ------------------------------------------------------------------


def energy(traj: Trajectory) -> float:
    """The paper's energy measure  integral tau^T tau dt  [N^2 m^2 s] (trapezoidal rule)."""
    power = np.sum(traj.tau**2, axis=1)
    return float(np.sum(0.5 * (power[1:] + power[:-1]) * np.diff(traj.t)))


def _smooth_torque(dynamics: Any, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(full torque, torque without the Coulomb term) by inverse dynamics, N m, (m, 6)."""
    from robot.dynamics import COULOMB_SLICE

    fc = dynamics.parameter_vector()[COULOMB_SLICE]
    vs = dynamics.coulomb_smoothing_velocity
    tau = np.array([dynamics.inverse_dynamics(q[k], qd[k], qdd[k]) for k in range(q.shape[0])])
    return tau, tau - fc * np.tanh(qd / vs)


def constraint_ratios(
    traj: Trajectory,
    limits: "JointLimits",
    dt: float = DEFAULT_CHECK_DT,
    dynamics: Any = None,
) -> dict[str, np.ndarray]:
    """Per joint, the largest |value| / limit of each limit kind, after resampling at ``dt``.

    Kinds: velocity, acceleration, jerk (finite differences of qdd), torque and
    torque_rate (finite differences of the torque), plus ``position`` (largest excursion
    beyond the range, as a ratio: 1 + excursion / half-range; <= 1 means inside).
    With ``dynamics`` (a ``robot.dynamics.RobotDynamics``) the torque is recomputed by
    inverse dynamics from the resampled q, qd, qdd instead of the stored one; the torque
    rate then excludes the Coulomb term, whose jump at a velocity reversal no smooth
    trajectory avoids. Infinite limits give ratio 0.
    """
    r = traj.resample(dt) if dt else traj
    step = np.diff(r.t)[:, None]
    if dynamics is not None:
        tau, tau_smooth = _smooth_torque(dynamics, r.q, r.qd, r.qdd)
    else:
        tau, tau_smooth = r.tau, r.tau
    values = {
        "velocity": np.abs(r.qd),
        "acceleration": np.abs(r.qdd),
        "jerk": np.abs(np.diff(r.qdd, axis=0) / step),
        "torque": np.abs(tau),
        "torque_rate": np.abs(np.diff(tau_smooth, axis=0) / step),
    }
    out = {}
    for kind, val in values.items():
        lim = np.asarray(getattr(limits, kind), dtype=float)
        out[kind] = np.max(val, axis=0) / lim
    lower, upper = np.asarray(limits.position_lower), np.asarray(limits.position_upper)
    bounded = np.isfinite(lower) & np.isfinite(upper)
    lower, upper = np.where(bounded, lower, -1.0), np.where(bounded, upper, 1.0)
    half, mid = 0.5 * (upper - lower), 0.5 * (upper + lower)
    excursion = np.max(np.abs(r.q - mid), axis=0) / half
    out["position"] = np.where(bounded, excursion, 0.0)
    return out


def max_constraint_ratio(
    traj: Trajectory,
    limits: "JointLimits",
    dt: float = DEFAULT_CHECK_DT,
    dynamics: Any = None,
    kinds: Iterable[str] = RATIO_KINDS,
) -> float:
    """Largest |value| / limit over ``kinds`` and joints (the definition in docs/explanation/planners.md).

    Default kinds: velocity, acceleration, torque and torque rate, resampled at 1 ms.
    Kinds whose limits are infinite contribute 0. See :func:`constraint_ratios`.
    """
    ratios = constraint_ratios(traj, limits, dt, dynamics)
    kinds = tuple(kinds)
    unknown = [k for k in kinds if k not in ratios]
    if unknown:
        raise TrajectoryError(f"max_constraint_ratio: unknown kinds {unknown}, expected some of {sorted(ratios)}")
    return float(max(np.max(ratios[k]) for k in kinds))
