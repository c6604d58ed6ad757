"""Finite Fourier series joint trajectories for identification (paper eq. 29).

Per joint ``i`` (rad, s)::

    q_i(t)   = sum_l  a_il/(w l) sin(w l t) - b_il/(w l) cos(w l t) + q_i0
    qd_i(t)  = sum_l  a_il cos(w l t) + b_il sin(w l t)
    qdd_i(t) = sum_l -a_il w l sin(w l t) + b_il w l cos(w l t)

``l = 1..N`` (the order), ``w = omega_f`` (rad/s) common to all joints, so every joint
is periodic with ``T_f = 2 pi / omega_f`` and ``q(0) = q(T_f)`` by construction. The
coefficients ``a_il``, ``b_il`` are velocity amplitudes (rad/s). A series *starts at
rest* when ``qd(0) = sum_l a_il = 0`` and ``qdd(0) = w sum_l l b_il = 0``: then the
arm can run it from standstill, repeat it any number of periods and stop, with
continuous position, velocity and acceleration.

The decision vector of the optimisation is the per-joint stack ``x = [a_i1..a_iN,
b_i1..b_iN, q_i0]`` for i = 1..6 (``6 (2N + 1)`` numbers); :func:`basis` gives the
linear maps from one joint's block to q, qd, qdd at given times.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from identification.errors import ExcitationDesignError
from robot.joints import N_JOINTS

DEFAULT_ORDER = 5
"""N of eq. 29 (paper: 5)."""
DEFAULT_OMEGA_F = 0.8
"""Base angular frequency omega_f, rad/s (paper: 0.8, period 7.85 s)."""
DEFAULT_SAMPLES = 80
"""Discretisation points per period k (paper: 80)."""


def basis(times: ArrayLike, order: int, omega_f: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Matrices (m, 2N+1) mapping one joint's block ``[a_1..a_N, b_1..b_N, q0]`` to q, qd, qdd."""
    t = np.asarray(times, dtype=float).reshape(-1, 1)
    w = omega_f * np.arange(1, order + 1)[None, :]
    s, c = np.sin(w * t), np.cos(w * t)
    ones, zeros = np.ones((t.shape[0], 1)), np.zeros((t.shape[0], 1))
    bq = np.hstack((s / w, -c / w, ones))
    bqd = np.hstack((c, s, zeros))
    bqdd = np.hstack((-w * s, w * c, zeros))
    return bq, bqd, bqdd


def rest_constraint_matrix(order: int, omega_f: float) -> np.ndarray:
    """(2, 2N+1) matrix E of one joint's block: ``E x_i = 0`` iff qd(0) = qdd(0) = 0."""
    e = np.zeros((2, 2 * order + 1))
    e[0, :order] = 1.0
    e[1, order:2 * order] = omega_f * np.arange(1, order + 1)
    return e


@dataclass(frozen=True)
class JointSamples:
    """q, qd, qdd (m, 6) at the times ``t`` (m,), rad, rad/s, rad/s^2."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray


@dataclass(frozen=True)
class FourierTrajectory:
    """A 6-joint finite Fourier series (eq. 29).

    ``a``, ``b``: (6, N) velocity amplitudes in rad/s; ``q0``: (6,) offsets in rad;
    ``omega_f``: rad/s.
    """

    a: np.ndarray
    b: np.ndarray
    q0: np.ndarray
    omega_f: float = DEFAULT_OMEGA_F

    def __post_init__(self) -> None:
        a, b = np.array(self.a, dtype=float), np.array(self.b, dtype=float)
        q0 = np.array(self.q0, dtype=float).reshape(-1)
        if a.ndim != 2 or a.shape[0] != N_JOINTS or a.shape[1] < 1 or b.shape != a.shape:
            raise ExcitationDesignError(f"a, b have shapes {a.shape}, {b.shape}, expected equal (6, N >= 1)")
        if q0.shape != (N_JOINTS,):
            raise ExcitationDesignError(f"q0 has shape {q0.shape}, expected (6,) rad")
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and np.all(np.isfinite(q0))):
            raise ExcitationDesignError("a, b, q0: expected finite numbers")
        if not (isinstance(self.omega_f, (int, float)) and math.isfinite(self.omega_f) and self.omega_f > 0):
            raise ExcitationDesignError(f"omega_f = {self.omega_f!r}, expected a finite number > 0 rad/s")
        for name, value in (("a", a), ("b", b), ("q0", q0)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "omega_f", float(self.omega_f))

    @property
    def order(self) -> int:
        return int(self.a.shape[1])

    @property
    def period(self) -> float:
        """T_f = 2 pi / omega_f, s."""
        return 2.0 * math.pi / self.omega_f

    @classmethod
    def from_vector(cls, x: ArrayLike, order: int, omega_f: float) -> "FourierTrajectory":
        """From the decision vector ``[a_i, b_i, q0_i]`` per joint (6 (2N+1),)."""
        x = np.asarray(x, dtype=float).reshape(N_JOINTS, 2 * order + 1)
        return cls(x[:, :order], x[:, order:2 * order], x[:, -1], omega_f)

    def vector(self) -> np.ndarray:
        """The decision vector (6 (2N+1),)."""
        return np.hstack((self.a, self.b, self.q0[:, None])).reshape(-1)

    def sample(self, times: ArrayLike) -> JointSamples:
        """q, qd, qdd at ``times`` (s, any real values: the series is periodic)."""
        t = np.asarray(times, dtype=float).reshape(-1)
        bq, bqd, bqdd = basis(t, self.order, self.omega_f)
        x = np.hstack((self.a, self.b, self.q0[:, None]))  # (6, 2N+1)
        return JointSamples(t, bq @ x.T, bqd @ x.T, bqdd @ x.T)

    def period_samples(self, k: int = DEFAULT_SAMPLES) -> JointSamples:
        """``k`` samples of one period at ``i T_f / k``, i = 0..k-1 (the eq. 30 grid)."""
        if isinstance(k, bool) or not isinstance(k, int) or k < 2:
            raise ExcitationDesignError(f"k = {k!r}, expected an integer >= 2 samples per period")
        return self.sample(np.arange(k) * self.period / k)

    def starts_at_rest(self, tolerance: float = 1e-9) -> bool:
        """True if qd(0) and qdd(0) vanish (|.| <= tolerance in rad/s, rad/s^2)."""
        s = self.sample([0.0])
        return bool(np.all(np.abs(s.qd) <= tolerance) and np.all(np.abs(s.qdd) <= tolerance))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: omega_f (rad/s), period (s), order, a and b (rad/s), q0 (rad)."""
        return {"omega_f_rad_s": self.omega_f, "period_s": self.period, "order": self.order,
                "a_rad_s": self.a.tolist(), "b_rad_s": self.b.tolist(), "q0_rad": self.q0.tolist()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "FourierTrajectory":
        """Inverse of :meth:`to_dict`."""
        try:
            return cls(np.array(data["a_rad_s"]), np.array(data["b_rad_s"]), np.array(data["q0_rad"]),
                       float(data["omega_f_rad_s"]))
        except KeyError as exc:
            raise ExcitationDesignError(f"Fourier trajectory: missing key {exc.args[0]!r}, expected a_rad_s, "
                                        "b_rad_s, q0_rad, omega_f_rad_s") from exc
