"""Optimal exciting trajectories (paper eq. 29-30).

Problem: choose the Fourier coefficients ``a``, ``b`` and offsets ``q0`` of
:class:`~identification.fourier.FourierTrajectory` (order N, common
``omega_f``) to minimise the condition number of the column-normalised base
regressor ``Theta_f`` stacked over ``k`` samples of one period, subject to, at every
constraint sample: joint positions inside the limits (with a margin), ``|qd| <=
qd_max``, ``|qdd| <= qdd_max``, ``|tau| <= tau_max`` (the controller's model, here
the nominal one, by the flatness of eq. 4) and the flange position inside an
allowed box (eq. 30). In addition the series starts at rest (qd(0) = qdd(0) = 0,
linear equalities) so the arm can run it from standstill and repeat it.

Objective and solver. The paper minimises ``cond(Theta_f^T Theta_f)`` =
``cond(Theta_f)^2``; we minimise ``f = log(sigma_max / sigma_min)`` of the
column-normalised ``Theta_f`` (same minimiser, better scaled). ``f`` is smooth
wherever the extreme singular values are simple (always, in practice), with the
exact gradient ``df = (u_1 v_1^T / s_1 - u_n v_n^T / s_n) : dTheta_n`` taken through
the column normalisation and one reverse-mode sweep of the CasADi regressor
(:mod:`identification.symbolic`). With 66 unknowns, an exact objective and a
few thousand inequality constraints of which q, qd, qdd are linear in the unknowns,
SciPy's SLSQP (sequential quadratic programming with a BFGS Hessian) converges in
a few hundred iterations; no smooth surrogate is needed. IPOPT on the smooth
surrogate ``log tr((Theta_n^T Theta_n)^-1)`` (A-optimality; with unit columns
``tr(Theta_n^T Theta_n) = n`` so ``cond^2 <= n tr(...)``) is measured against it in
``benchmarks/bench_identification.py``: on a reduced problem (order 2, k = 30, same start,
100 iterations each) SLSQP reached cond 13.1 in 7.3 s, IPOPT on the surrogate 23.5 in 60 s.

The random baseline (:func:`random_feasible_trajectory`): Gaussian coefficients of
the same order, projected on the start-at-rest equalities, offsets at the centre
pose, amplitude scaled by bisection to the largest feasible value.
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import scipy.optimize
from numpy.typing import ArrayLike
from threadpoolctl import threadpool_limits

from identification.base_parameters import BaseParameters, nominal_base_parameters
from identification.errors import ExcitationDesignError
from identification.fourier import (DEFAULT_OMEGA_F, DEFAULT_ORDER, DEFAULT_SAMPLES, N_JOINTS,
                                            FourierTrajectory, basis, rest_constraint_matrix)
from identification.symbolic import SampleFunctions, sample_functions
from robot.dynamics import nominal_parameter_vector
from robot.parameters import RobotParameters, load_parameters

DEFAULT_TCP_BOX = ((0.3, -1.2, 0.3), (1.8, 1.2, 2.0))
"""Allowed flange positions (m, base_link): in front of the arm (x >= 0.3 m keeps the
flange out of the base and column), above a 0.3 m high table, inside the reach."""
DEFAULT_CENTRE = (0.0, 0.4, 1.2, 0.0, 0.6, 0.0)
"""Centre pose (rad) of the random baseline and the offsets' start: flange at about
(1.14, 0, 1.08) m, elbow and wrist away from singularities."""
DEFAULT_POSITION_MARGIN = math.radians(5.0)
"""Joint position margin inside the URDF limits, rad."""
DEFAULT_TORQUE_FRACTION = 0.8
"""Fraction of the URDF effort limit the model torque may use: the rest is left for the
feedback, for a payload and for model errors (the true arm differs)."""
FINE_SAMPLES_PER_PERIOD = 2000
"""Samples per period on which a result is verified (4 ms at the default period)."""


@dataclass(frozen=True)
class ExcitationLimits:
    """Bounds of eq. 30: arrays (6,) rad, rad/s, rad/s^2, N m; TCP box corners (3,) m."""

    q_lower: np.ndarray
    q_upper: np.ndarray
    qd_max: np.ndarray
    qdd_max: np.ndarray
    tau_max: np.ndarray
    tcp_lower: np.ndarray
    tcp_upper: np.ndarray

    def __post_init__(self) -> None:
        for name, length in (("q_lower", 6), ("q_upper", 6), ("qd_max", 6), ("qdd_max", 6), ("tau_max", 6),
                             ("tcp_lower", 3), ("tcp_upper", 3)):
            value = np.array(getattr(self, name), dtype=float).reshape(-1)
            if value.shape != (length,) or not np.all(np.isfinite(value)):
                raise ExcitationDesignError(f"ExcitationLimits.{name} = {getattr(self, name)!r}, "
                                            f"expected {length} finite numbers")
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        if np.any(self.q_upper <= self.q_lower):
            raise ExcitationDesignError(f"ExcitationLimits: q_lower {self.q_lower.tolist()} must be below q_upper "
                                        f"{self.q_upper.tolist()} (rad)")
        if np.any(self.tcp_upper <= self.tcp_lower):
            raise ExcitationDesignError(f"ExcitationLimits: tcp box lower corner {self.tcp_lower.tolist()} must be "
                                        f"below the upper corner {self.tcp_upper.tolist()} (m)")
        for name in ("qd_max", "qdd_max", "tau_max"):
            if np.any(getattr(self, name) <= 0.0):
                raise ExcitationDesignError(f"ExcitationLimits.{name}: expected positive numbers")

    @classmethod
    def from_parameters(cls, parameters: RobotParameters | None = None, *,
                        position_margin: float = DEFAULT_POSITION_MARGIN, velocity_fraction: float = 1.0,
                        acceleration_fraction: float = 1.0, torque_fraction: float = DEFAULT_TORQUE_FRACTION,
                        tcp_box: tuple[ArrayLike, ArrayLike] = DEFAULT_TCP_BOX) -> "ExcitationLimits":
        """Limits of the robot description (URDF + parameter file) scaled by the given fractions."""
        p = parameters or load_parameters()
        for name, value in (("velocity_fraction", velocity_fraction), ("acceleration_fraction", acceleration_fraction),
                            ("torque_fraction", torque_fraction)):
            if not (isinstance(value, (int, float)) and 0.0 < value <= 1.0):
                raise ExcitationDesignError(f"{name} = {value!r}, expected a number in (0, 1]")
        return cls(p.position_lower + position_margin, p.position_upper - position_margin,
                   p.velocity_limit * velocity_fraction, p.acceleration_limit * acceleration_fraction,
                   p.effort_limit * torque_fraction, np.asarray(tcp_box[0], dtype=float),
                   np.asarray(tcp_box[1], dtype=float))

    def to_dict(self) -> dict[str, Any]:
        return {k: np.asarray(v).tolist() for k, v in asdict(self).items()}


@dataclass(frozen=True)
class ExcitationSettings:
    """Discretisation and solver settings.

    ``order`` N, ``omega_f`` rad/s, ``samples`` k per period for the objective (eq. 30),
    ``constraint_samples`` per period for the constraints (denser: fewer violations
    between samples), ``max_iterations`` and ``tolerance`` of SLSQP (on f = log cond),
    ``margin``: every constraint is tightened by this fraction of its limit (of the half
    range for positions, of the box size for the TCP) so that the continuous trajectory,
    not only its samples, stays inside.
    """

    order: int = DEFAULT_ORDER
    omega_f: float = DEFAULT_OMEGA_F
    samples: int = DEFAULT_SAMPLES
    constraint_samples: int = 2 * DEFAULT_SAMPLES
    max_iterations: int = 300
    tolerance: float = 1e-7
    margin: float = 0.005

    def __post_init__(self) -> None:
        for name in ("order", "samples", "constraint_samples", "max_iterations"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ExcitationDesignError(f"ExcitationSettings.{name} = {value!r}, expected a positive integer")
        if self.samples * N_JOINTS < 2 * (2 * self.order + 1):
            raise ExcitationDesignError(f"ExcitationSettings.samples = {self.samples} is too few for order "
                                        f"{self.order}")
        if not (isinstance(self.omega_f, (int, float)) and math.isfinite(self.omega_f) and self.omega_f > 0):
            raise ExcitationDesignError(f"ExcitationSettings.omega_f = {self.omega_f!r}, expected rad/s > 0")
        if not (isinstance(self.margin, (int, float)) and 0.0 <= self.margin < 0.5):
            raise ExcitationDesignError(f"ExcitationSettings.margin = {self.margin!r}, expected a fraction in [0, 0.5)")

    @property
    def period(self) -> float:
        return 2.0 * math.pi / self.omega_f


@dataclass(frozen=True)
class Feasibility:
    """Largest ratio |value| / limit per kind on a grid (<= 1: feasible); ``tcp_violation_m``
    the largest distance outside the box (0: inside); ``position`` as the largest ratio of the
    distance from the range centre to the half range."""

    position: float
    velocity: float
    acceleration: float
    torque: float
    tcp_violation_m: float
    samples: int

    @property
    def feasible(self) -> bool:
        return (max(self.position, self.velocity, self.acceleration, self.torque) <= 1.0 + 1e-6
                and self.tcp_violation_m <= 1e-6)

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "feasible": self.feasible}


class ExcitationProblem:
    """Objective, constraints and their derivatives of eq. 30 for one robot model."""

    def __init__(self, base: BaseParameters | None = None, limits: ExcitationLimits | None = None,
                 settings: ExcitationSettings | None = None, *, parameter_vector: ArrayLike | None = None,
                 payload: ArrayLike | None = None) -> None:
        self.base = base or nominal_base_parameters()
        self.limits = limits or ExcitationLimits.from_parameters()
        self.settings = settings or ExcitationSettings()
        params = load_parameters()
        self.parameter_vector = np.asarray(nominal_parameter_vector() if parameter_vector is None
                                           else parameter_vector, dtype=float)
        self.payload = np.asarray(params.payload if payload is None else payload, dtype=float)
        s = self.settings
        self.n_block = 2 * s.order + 1
        self.n_x = N_JOINTS * self.n_block
        self._objective_times = np.arange(s.samples) * s.period / s.samples
        self._constraint_times = np.arange(s.constraint_samples) * s.period / s.constraint_samples
        self._obj = sample_functions(self.base, self.parameter_vector, self.payload, s.samples)
        self._con = sample_functions(self.base, self.parameter_vector, self.payload, s.constraint_samples)
        self._obj_basis = basis(self._objective_times, s.order, s.omega_f)
        self._con_basis = basis(self._constraint_times, s.order, s.omega_f)
        self._linear = self._linear_constraints()
        rest = rest_constraint_matrix(s.order, s.omega_f)
        self.rest_matrix = np.kron(np.eye(N_JOINTS), rest)  # (12, n_x)
        self._cache: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    # -- building blocks (for other solvers) ------------------------------------------------
    @property
    def objective_functions(self) -> SampleFunctions:
        """CasADi functions mapped over the objective samples."""
        return self._obj

    @property
    def constraint_functions(self) -> SampleFunctions:
        """CasADi functions mapped over the constraint samples."""
        return self._con

    @property
    def objective_basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Bq, Bqd, Bqdd) (k, 2N+1) of one joint's block at the objective samples."""
        return self._obj_basis

    @property
    def constraint_basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Bq, Bqd, Bqdd) at the constraint samples."""
        return self._con_basis

    @property
    def linear_constraints(self) -> tuple[np.ndarray, np.ndarray]:
        """(A, b) of the position, velocity and acceleration constraints ``A x + b >= 0``."""
        return self._linear

    # -- trajectories -------------------------------------------------------------------
    def trajectory(self, x: ArrayLike) -> FourierTrajectory:
        return FourierTrajectory.from_vector(x, self.settings.order, self.settings.omega_f)

    @staticmethod
    def _states(x: np.ndarray, bases: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
        blocks = x.reshape(N_JOINTS, -1)
        return tuple(b @ blocks.T for b in bases)  # (samples, 6) each

    # -- objective -------------------------------------------------------------------
    def regressor(self, x: ArrayLike) -> np.ndarray:
        """Stacked base regressor (k, 6, n_base) over the objective samples (not normalised)."""
        q, qd, qdd = self._states(np.asarray(x, dtype=float), self._obj_basis)
        return self._obj.base_regressor(q, qd, qdd)

    def condition_number(self, x: ArrayLike) -> float:
        """cond of the column-normalised stacked base regressor (eq. 30's objective, square root)."""
        a = self.regressor(x).reshape(-1, self.base.count)
        return _normalised_condition(a)

    @threadpool_limits.wrap(limits=1, user_api="blas")
    def objective(self, x: ArrayLike) -> tuple[float, np.ndarray]:
        """f = log cond(Theta_n) and its gradient (n_x,)."""
        x = np.asarray(x, dtype=float)
        q, qd, qdd = self._states(x, self._obj_basis)
        y = self._obj.base_regressor(q, qd, qdd)
        a = y.reshape(-1, self.base.count)
        norms = np.linalg.norm(a, axis=0)
        norms = np.where(norms > 0.0, norms, 1e-300)
        an = a / norms
        u, s, vt = np.linalg.svd(an, full_matrices=False)
        f = math.log(s[0] / s[-1])
        g_n = np.outer(u[:, 0], vt[0]) / s[0] - np.outer(u[:, -1], vt[-1]) / s[-1]
        # through the column normalisation: d a_n_j = (I - a_n_j a_n_j^T) d a_j / |a_j|
        g = (g_n - an * np.sum(an * g_n, axis=0)) / norms
        gq, gqd, gqdd = self._obj.regressor_gradient(q, qd, qdd, g.reshape(y.shape))
        bq, bqd, bqdd = self._obj_basis
        grad = (gq.T @ bq + gqd.T @ bqd + gqdd.T @ bqdd).reshape(-1)
        return f, grad

    # -- constraints (all as c(x) >= 0, scaled to order 1) --------------------------------
    def _linear_constraints(self) -> tuple[np.ndarray, np.ndarray]:
        lim = self.limits
        bq, bqd, bqdd = self._con_basis
        m = bq.shape[0]
        rows, offsets = [], []
        centre, half = (lim.q_upper + lim.q_lower) / 2, (lim.q_upper - lim.q_lower) / 2
        for j in range(N_JOINTS):
            for mat, bound, shift in ((bq, half[j], centre[j]), (bqd, lim.qd_max[j], 0.0),
                                      (bqdd, lim.qdd_max[j], 0.0)):
                block = np.zeros((2 * m, self.n_x))
                cols = slice(j * self.n_block, (j + 1) * self.n_block)
                # 1 - (v - shift)/bound >= 0 and 1 + (v - shift)/bound >= 0
                block[:m, cols] = -mat / bound
                block[m:, cols] = mat / bound
                rows.append(block)
                offsets.append(np.concatenate((np.full(m, 1.0 + shift / bound), np.full(m, 1.0 - shift / bound))))
        return np.vstack(rows), np.concatenate(offsets) - self.settings.margin

    def nonlinear_constraints(self, x: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Torque and TCP-box constraints c(x) >= 0 and their Jacobian (n_c, n_x) (last x cached)."""
        x = np.asarray(x, dtype=float)
        if self._cache is not None and np.array_equal(self._cache[0], x):
            return self._cache[1], self._cache[2]
        lim = self.limits
        q, qd, qdd = self._states(x, self._con_basis)
        bq, bqd, bqdd = self._con_basis
        m = q.shape[0]
        tau, jtau = self._con.torques(q, qd, qdd)  # (m, 6), (m, 6, 18)
        # d tau[k, i] / d x[j, :] = J_q[k,i,j] bq[k] + J_qd[k,i,j] bqd[k] + J_qdd[k,i,j] bqdd[k]
        dtau = (np.einsum("kij,kc->kijc", jtau[:, :, :6], bq) + np.einsum("kij,kc->kijc", jtau[:, :, 6:12], bqd)
                + np.einsum("kij,kc->kijc", jtau[:, :, 12:], bqdd)).reshape(m * N_JOINTS, self.n_x)
        scale_tau = np.tile(1.0 / lim.tau_max, m)
        tau_flat = tau.reshape(-1) * scale_tau
        dtau = dtau * scale_tau[:, None]
        r, jr = self._con.flange_positions(q)  # (m, 3), (m, 3, 6)
        dr = np.einsum("kij,kc->kijc", jr, bq).reshape(m * 3, self.n_x)
        span = np.tile(lim.tcp_upper - lim.tcp_lower, m)
        lower, upper = np.tile(lim.tcp_lower, m), np.tile(lim.tcp_upper, m)
        r_flat = r.reshape(-1)
        values = np.concatenate((1.0 - tau_flat, 1.0 + tau_flat, (r_flat - lower) / span, (upper - r_flat) / span))
        jac = np.vstack((-dtau, dtau, dr / span[:, None], -dr / span[:, None]))
        self._cache = (x.copy(), values - self.settings.margin, jac)
        return self._cache[1], jac

    def constraints(self, x: ArrayLike) -> np.ndarray:
        """All inequality constraints c(x) >= 0 (linear q/qd/qdd first, then torque and TCP)."""
        x = np.asarray(x, dtype=float)
        a, b = self._linear
        return np.concatenate((a @ x + b, self.nonlinear_constraints(x)[0]))

    def constraints_jacobian(self, x: ArrayLike) -> np.ndarray:
        return np.vstack((self._linear[0], self.nonlinear_constraints(x)[1]))

    # -- verification ---------------------------------------------------------------------
    def feasibility(self, x: ArrayLike, samples: int = FINE_SAMPLES_PER_PERIOD) -> Feasibility:
        """Largest limit ratios over ``samples`` points per period (pinocchio-free: same CasADi
        model as the constraints, evaluated on the finer grid)."""
        traj = self.trajectory(x)
        t = np.arange(samples) * traj.period / samples
        s = traj.sample(t)
        lim = self.limits
        centre, half = (lim.q_upper + lim.q_lower) / 2, (lim.q_upper - lim.q_lower) / 2
        fine = sample_functions(self.base, self.parameter_vector, self.payload, samples) \
            if samples != self.settings.constraint_samples else self._con
        tau = fine.torques(s.q, s.qd, s.qdd)[0]
        r = fine.flange_positions(s.q)[0]
        outside = np.maximum(np.maximum(lim.tcp_lower - r, r - lim.tcp_upper), 0.0)
        return Feasibility(float(np.max(np.abs(s.q - centre) / half)), float(np.max(np.abs(s.qd) / lim.qd_max)),
                           float(np.max(np.abs(s.qdd) / lim.qdd_max)), float(np.max(np.abs(tau) / lim.tau_max)),
                           float(outside.max()), samples)

    def is_feasible(self, x: ArrayLike) -> bool:
        """All constraints on the constraint grid and the start-at-rest equalities hold."""
        x = np.asarray(x, dtype=float)
        return bool(np.min(self.constraints(x)) >= -1e-9 and np.max(np.abs(self.rest_matrix @ x)) <= 1e-9)


@dataclass(frozen=True)
class ExcitationResult:
    """An optimised exciting trajectory and how it compares with random ones.

    ``condition_number``: of the column-normalised base regressor over the k samples;
    ``random_condition_numbers``: of the random feasible baselines (same order, same
    limits); ``initial_condition_number``: of the start point; ``solve_time_s``: wall
    time of the SLSQP run; ``feasibility``: on the fine grid; ``history``: condition
    number at the start and after each SLSQP iteration.
    """

    trajectory: FourierTrajectory
    condition_number: float
    initial_condition_number: float
    random_condition_numbers: tuple[float, ...]
    solve_time_s: float
    iterations: int
    function_evaluations: int
    status: str
    success: bool
    feasibility: Feasibility
    settings: ExcitationSettings
    limits: ExcitationLimits
    random_trajectories: tuple[FourierTrajectory, ...] = field(default=(), repr=False)
    history: tuple[float, ...] = field(default=(), repr=False)

    @property
    def random_median(self) -> float:
        return float(np.median(self.random_condition_numbers)) if self.random_condition_numbers else math.nan

    @property
    def improvement_over_random(self) -> float:
        """median random condition number / optimised condition number."""
        return self.random_median / self.condition_number

    def to_dict(self) -> dict[str, Any]:
        return {
            "condition_number": self.condition_number,
            "condition_number_of_information_matrix": self.condition_number ** 2,
            "initial_condition_number": self.initial_condition_number,
            "random_condition_numbers": list(self.random_condition_numbers),
            "random_median_condition_number": self.random_median,
            "random_best_condition_number": min(self.random_condition_numbers, default=math.nan),
            "improvement_over_random_median": self.improvement_over_random,
            "solve_time_s": self.solve_time_s,
            "iterations": self.iterations,
            "function_evaluations": self.function_evaluations,
            "status": self.status,
            "success": self.success,
            "feasibility_fine_grid": self.feasibility.to_dict(),
            "settings": asdict(self.settings),
            "limits": self.limits.to_dict(),
            "trajectory": self.trajectory.to_dict(),
        }


def _normalised_condition(a: np.ndarray) -> float:
    norms = np.linalg.norm(a, axis=0)
    if np.any(norms == 0.0):
        return math.inf
    with threadpool_limits(limits=1, user_api="blas"):
        s = np.linalg.svd(a / norms, compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else math.inf


def random_feasible_trajectory(problem: ExcitationProblem, rng: np.random.Generator,
                               centre: ArrayLike = DEFAULT_CENTRE, bisection_steps: int = 30) -> np.ndarray:
    """A random start-at-rest series of the problem's order, scaled to the largest feasible amplitude.

    Coefficients ~ N(0, 1) per joint scaled by the joint's velocity limit / N, projected on
    the rest equalities; offsets ``q0`` at ``centre`` (rad); amplitude factor found by
    bisection on the constraint grid. Raises ExcitationDesignError if ``centre`` itself
    (standstill) is infeasible.
    """
    centre = np.asarray(centre, dtype=float)
    s = problem.settings
    x = np.zeros((N_JOINTS, problem.n_block))
    rest = rest_constraint_matrix(s.order, s.omega_f)[:, :2 * s.order]
    projector = np.eye(2 * s.order) - np.linalg.pinv(rest) @ rest
    for j in range(N_JOINTS):
        x[j, :-1] = projector @ (rng.normal(size=2 * s.order) * problem.limits.qd_max[j] / s.order)
    x[:, -1] = centre
    shape = x.copy()
    shape[:, -1] = 0.0

    def candidate(scale: float) -> np.ndarray:
        out = shape * scale
        out[:, -1] = centre
        return out.reshape(-1)

    if not problem.is_feasible(candidate(0.0)):
        raise ExcitationDesignError(f"centre pose {centre.tolist()} (rad) violates the limits or the TCP box at rest")
    lo, hi = 0.0, 1.0
    while problem.is_feasible(candidate(hi)) and hi < 1e3:
        lo, hi = hi, 2.0 * hi
    for _ in range(bisection_steps):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if problem.is_feasible(candidate(mid)) else (lo, mid)
    return candidate(lo)


def optimise_excitation(problem: ExcitationProblem, x0: ArrayLike) -> tuple[np.ndarray, scipy.optimize.OptimizeResult,
                                                                            float, list[float]]:
    """SLSQP from ``x0``: (best feasible x, SciPy result, wall time s, condition number per iteration)."""
    x0 = np.asarray(x0, dtype=float)
    lin_a, lin_b = problem.linear_constraints
    constraints = [
        {"type": "ineq", "fun": lambda x: lin_a @ x + lin_b, "jac": lambda x: lin_a},
        {"type": "ineq", "fun": lambda x: problem.nonlinear_constraints(x)[0],
         "jac": lambda x: problem.nonlinear_constraints(x)[1]},
        {"type": "eq", "fun": lambda x: problem.rest_matrix @ x, "jac": lambda x: problem.rest_matrix},
    ]
    best = {"x": x0.copy(), "f": problem.objective(x0)[0]}
    last: dict[str, Any] = {"x": None, "f": math.nan}
    history = [math.exp(best["f"])]

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        f, g = problem.objective(x)
        last.update(x=x.copy(), f=f)
        if f < best["f"] and problem.is_feasible(x):
            best.update(x=x.copy(), f=f)
        return f, g

    def callback(x: np.ndarray) -> None:
        f = last["f"] if last["x"] is not None and np.array_equal(last["x"], x) else problem.objective(x)[0]
        history.append(math.exp(f))

    s = problem.settings
    wall0 = time.perf_counter()
    with threadpool_limits(limits=1, user_api="blas"):
        result = scipy.optimize.minimize(fun, x0, jac=True, method="SLSQP", constraints=constraints,
                                         callback=callback,
                                         options={"maxiter": s.max_iterations, "ftol": s.tolerance})
    wall = time.perf_counter() - wall0
    x = result.x if problem.is_feasible(result.x) and result.fun <= best["f"] + 1e-12 else best["x"]
    return x, result, wall, history


def design_excitation(problem: ExcitationProblem | None = None, *, seed: int = 0, random_baselines: int = 10,
                      centre: ArrayLike = DEFAULT_CENTRE) -> ExcitationResult:
    """Random feasible baselines, then SLSQP from the best of them (see module docstring)."""
    problem = problem or ExcitationProblem()
    if isinstance(random_baselines, bool) or not isinstance(random_baselines, int) or random_baselines < 1:
        raise ExcitationDesignError(f"random_baselines = {random_baselines!r}, expected an integer >= 1")
    rng = np.random.default_rng(seed)
    randoms = [random_feasible_trajectory(problem, rng, centre) for _ in range(random_baselines)]
    conds = [problem.condition_number(x) for x in randoms]
    start = randoms[int(np.argmin(conds))]
    x, result, wall, history = optimise_excitation(problem, start)
    return ExcitationResult(
        trajectory=problem.trajectory(x), condition_number=problem.condition_number(x),
        initial_condition_number=float(min(conds)), random_condition_numbers=tuple(float(c) for c in conds),
        solve_time_s=wall, iterations=int(result.get("nit", 0)), function_evaluations=int(result.get("nfev", 0)),
        status=str(result.message), success=bool(result.success), feasibility=problem.feasibility(x),
        settings=problem.settings, limits=problem.limits,
        random_trajectories=tuple(problem.trajectory(r) for r in randoms), history=tuple(history))
