"""Own time/energy-optimal point-to-point planner (paper eq. 40), CasADi + IPOPT.

Problem (eq. 40, free final time T, full rigid-body dynamics with rotor inertia and the
problem's friction model)::

    minimise   k1 T + k2 integral_0^T tau^T tau dt
    subject to tau = ID(q, qd, qdd)                        (inverse dynamics, robot.symbolic)
               |tau| <= tau_max,  |d tau_s/dt| <= taudot_max,  |qd| <= qd_max,
               q_min <= q <= q_max,  |qdd| <= qdd_max and |qddd| <= qddd_max where finite
               q(0) = q0, qd(0) = qd0, q(T) = qe, qd(T) = qde,  qdd(0) = qdd(T) = 0

``tau_s`` is the torque without the Coulomb term (``planners.ptp_dynamics``); qdd = 0 at
both ends makes the torque continuous with holding the boundary states. Every finite
limit of ``problem.limits`` is imposed; the paper's eq. 40 has no acceleration and jerk
limits (give them as ``math.inf`` to get eq. 40 exactly).

Transcription -- why this one. The joint motion is a piecewise-cubic polynomial on N
equal intervals of length h = T / N: the states (q, qd, qdd) at the N + 1 nodes and one
constant jerk per interval, linked by the exact integrator of q''' = jerk (no
integration error). The dynamics enter implicitly: tau = ID(q, qd, qdd) is evaluated,
not integrated, so no mass-matrix inverse or forward simulation is needed (implicit
collocation solved PtP problems 25-50x faster than multiple shooting in the project's first
trials; not re-measured, docs/explanation/planners.md).
Because the motion is an explicit polynomial, the dense output at 1 ms is the
optimiser's own motion, and its torque is the inverse dynamics of the dense (q, qd, qdd)
-- exactly what the constraints saw at the nodes. Acceleration is piecewise linear, so
its limit at the nodes holds everywhere; the torque rate is the exact time derivative
(forward-mode AD of the RNEA) on both sides of every node, where the jerk jumps; the
velocity is also bounded at the interval midpoints. Between those points only the
torque, the torque rate and the velocity can bulge -- most of all when a joint reverses
between two nodes, where the Coulomb term switches by 2 fc (up to 15 % of a wrist torque
limit). The dense result is checked at ``check_dt`` and, if a ratio exceeds
``ratio_tolerance`` (1.001), the limits of the offending joints are tightened by twice
their excess and the problem re-solved from the previous primal-dual solution.

Numerics. Every variable is scaled by its limit (position by its half range; velocity,
acceleration, jerk by their limits or, where infinite, by typical values of the warm
start; T by the warm start's duration) and every constraint by its limit. The NLP's
derivatives are assembled from per-node functions with exact symbolic Jacobians and
Hessians (``planners.ptp_nodes``, compiled C, mapped over the nodes), because CasADi's
automatic differentiation through a mapped function costs 10-40x more per iteration and
expanding the whole problem to SX costs 10-30 s of building. The built problem depends
only on the kinematic structure and N (dynamic parameters, limits, scales and weights
are NLP parameters) and is cached. A tiny jerk regularisation (``jerk_regularisation``
x the mean squared scaled jerk, default 1e-5) makes the time-optimal solution unique
(joints that do not limit the motion have a free path otherwise) and IPOPT converge in
fewer iterations (paper line: 36 instead of 53); it lengthens T by about 0.06 %
(docs/explanation/planners.md). The
warm start is Ruckig tuned to the torque limits (``planners.ruckig_baseline``), sampled
at the nodes. The Coulomb term fc tanh(qd / v_s) with v_s = 0.01 rad/s is nearly a
step, which makes IPOPT crawl (100-200 iterations instead of 20-40 without it), so the
problem is first solved with a 10x smoother Coulomb term and the real problem is then
solved from that primal-dual solution (a few iterations); re-solves after a tightening
start from the previous primal-dual solution too (``IPOPT_WARM_RESTART``).

Only IPOPT's ``Solve_Succeeded`` gives status OPTIMAL; ``Solved_To_Acceptable_Level``
gives FEASIBLE (if the dense check passes), ``Infeasible_Problem_Detected`` INFEASIBLE,
anything else FAILED. Units: SI, joint side.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from planners.base import JointLimits, N_JOINTS, Planner, PlannerInputError, PlanResult, PlanStatus, PtPProblem
from planners.ptp_dynamics import PtPDynamics, ptp_dynamics
from planners.ptp_nodes import N_NODE_INPUTS, NodeFunctions, node_functions
from planners.ruckig_baseline import (
    RuckigMotion, _check_request, kinematic_limits, ruckig_motion, torque_tuned_motion,
)
from planners.trajectory import DEFAULT_CHECK_DT, RATIO_KINDS, Trajectory, uniform_times
from robot.inverse_kinematics import AnalyticIK, UnreachablePoseError
from robot.kinematics import transform_from_pose
from robot.symbolic import chain_structure

RATIO_TOLERANCE = 1.001
"""Largest accepted |value| / limit of the dense trajectory; above it the offending joints' limits are
tightened and the problem is solved again (docs/explanation/planners.md)."""
CHECKED_KINDS: tuple[str, ...] = ("velocity", "acceleration", "jerk", "torque", "torque_rate", "position")
"""Limit kinds checked on the dense trajectory (each only where its limit is finite)."""
DEFAULT_JERK_REGULARISATION = 1e-5
"""Weight of the mean squared scaled jerk added to the scaled cost (dimensionless)."""
IPOPT_DEFAULTS: dict[str, Any] = {
    "print_level": 0, "sb": "yes", "max_iter": 1000, "tol": 1e-8, "mu_strategy": "adaptive",
    # the warm start is feasible and good: do not push it far into the interior
    "bound_push": 1e-6, "bound_frac": 1e-6,
    # AMD ordering: fewer inertia corrections than MUMPS' automatic choice on this KKT structure
    "mumps_pivot_order": 0,
}
"""IPOPT options (73 -> 56 iterations on the paper-like line with bound_push/frac, docs/explanation/planners.md)."""
IPOPT_WARM_RESTART: dict[str, Any] = {
    "warm_start_init_point": "yes", "mu_init": 1e-6, "warm_start_bound_push": 1e-9,
    "warm_start_bound_frac": 1e-9, "warm_start_slack_bound_push": 1e-9, "warm_start_slack_bound_frac": 1e-9,
    "warm_start_mult_bound_push": 1e-9,
}
"""Extra IPOPT options of a re-solve (tightened limits, continuation) from the previous
primal-dual solution."""
DEFAULT_COULOMB_CONTINUATION: tuple[float, ...] = (10.0,)
"""Factors of the Coulomb smoothing velocity of the preliminary solves (10: 0.1 rad/s)."""
_STATES = 3 * N_JOINTS
_BLOCK = _STATES + N_JOINTS  # node states + the jerk of the interval that follows

# NLP parameter vector: scales, cost weights and the arm's dynamic parameters.
_P_FIELDS = (("s_q", 6), ("s_qd", 6), ("s_qdd", 6), ("s_jerk", 6), ("s_tau", 6), ("s_rate", 6),
             ("s_time", 1), ("s_cost", 1), ("k1", 1), ("k2", 1), ("reg", 1), ("dp", 83))
_P_INDEX: dict[str, slice] = {}
_offset = 0
for _name, _len in _P_FIELDS:
    _P_INDEX[_name] = slice(_offset, _offset + _len)
    _offset += _len
_P_SIZE = _offset
_SCALE_NAMES = ("s_q", "s_qd", "s_qdd", "s_jerk", "s_tau", "s_rate")


# -----------------------------------------------------------------------------------
# decision-vector layout
# -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Layout:
    """z = [x_0, j_0, x_1, j_1, ..., x_{N-1}, j_{N-1}, x_N, T] (all scaled).

    x_k = (q, qd, qdd)_k / scales (18), j_k the jerk of interval k / s_jerk (6).
    """

    n: int

    @property
    def size(self) -> int:
        return _BLOCK * self.n + _STATES + 1

    @property
    def t_index(self) -> int:
        return self.size - 1

    def x_index(self, k: int) -> np.ndarray:
        return _BLOCK * k + np.arange(_STATES)

    def j_index(self, k: int) -> np.ndarray:
        return _BLOCK * k + _STATES + np.arange(N_JOINTS)

    def x_matrix(self) -> np.ndarray:
        """Indices (18, N+1) of the node states."""
        return np.column_stack([self.x_index(k) for k in range(self.n + 1)])

    def j_matrix(self) -> np.ndarray:
        """Indices (6, N) of the interval jerks."""
        return np.column_stack([self.j_index(k) for k in range(self.n)])

    def node_columns(self, k: int) -> np.ndarray:
        """Global index of each of the 30 node inputs of node k (-1: no such variable)."""
        before = self.j_index(k - 1) if k > 0 else np.full(N_JOINTS, -1)
        after = self.j_index(k) if k < self.n else np.full(N_JOINTS, -1)
        return np.concatenate([self.x_index(k), before, after])

    def pack(self, x: np.ndarray, j: np.ndarray, t_scaled: float) -> np.ndarray:
        """z from x (18, N+1), j (6, N) and T / s_time."""
        z = np.empty(self.size)
        z[self.x_matrix().T.reshape(-1)] = x.T.reshape(-1)
        z[self.j_matrix().T.reshape(-1)] = j.T.reshape(-1)
        z[self.t_index] = t_scaled
        return z

    def unpack(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        return z[self.x_matrix()], z[self.j_matrix()], float(z[self.t_index])


# -----------------------------------------------------------------------------------
# the NLP with assembled exact derivatives
# -----------------------------------------------------------------------------------


class _Accumulator:
    """Collects (row, col, source index) triplets of several nonzero vectors and builds
    the union sparsity plus one constant sparse matrix per source that scatters (and
    sums) that source's values into the union's nonzeros."""

    def __init__(self, shape: tuple[int, int], upper: bool = False) -> None:
        self.shape = shape
        self.upper = upper
        self.parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, int]] = []

    def add(self, rows: np.ndarray, cols: np.ndarray, source: np.ndarray, source_size: int) -> int:
        rows, cols = np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64)
        if self.upper:
            rows, cols = np.minimum(rows, cols), np.maximum(rows, cols)
        self.parts.append((rows, cols, np.asarray(source, dtype=np.int64), int(source_size)))
        return len(self.parts) - 1

    def build(self) -> tuple[ca.Sparsity, list[ca.DM]]:
        rows = np.concatenate([p[0] for p in self.parts])
        cols = np.concatenate([p[1] for p in self.parts])
        keys = cols * self.shape[0] + rows  # column-major (CCS) order
        unique, inverse = np.unique(keys, return_inverse=True)
        sparsity = ca.Sparsity.triplet(self.shape[0], self.shape[1], (unique % self.shape[0]).tolist(),
                                       (unique // self.shape[0]).tolist())
        matrices = []
        start = 0
        for p_rows, _, source, size in self.parts:
            target = inverse[start:start + p_rows.size]
            start += p_rows.size
            matrices.append(ca.DM.triplet(target.tolist(), source.tolist(), np.ones(target.size).tolist(),
                                          unique.size, size))
        return sparsity, matrices


@dataclass
class _Transcription:
    """The built NLP for one kinematic structure and N (reused for every request)."""

    layout: _Layout
    nodes: NodeFunctions
    nlp: dict
    functions: dict[str, ca.Function]
    n_constraints: dict[str, int]
    build_time_s: float
    solvers: dict

    def solver(self, ipopt_options: dict) -> ca.Function:
        key = tuple(sorted((k, repr(v)) for k, v in ipopt_options.items()))
        if key not in self.solvers:
            options = {"print_time": False, "calc_lam_p": False, "no_nlp_grad": True, "grad_f": self.functions["grad_f"], "jac_g": self.functions["jac_g"],
                       "hess_lag": self.functions["hess_lag"],
                       "ipopt": dict(IPOPT_DEFAULTS)}
            options["ipopt"].update(ipopt_options)
            self.solvers[key] = ca.nlpsol("own_ptp", "ipopt", self.nlp, options)
        return self.solvers[key]


def _build(nodes: NodeFunctions, n: int) -> _Transcription:
    start = time.perf_counter()
    layout = _Layout(n)
    nz, nodes_count = layout.size, n + 1
    xm, jm, it = layout.x_matrix(), layout.j_matrix(), layout.t_index

    # -- the simple part in SX: defects, midpoint velocities, time and regularisation terms
    zs, ps = ca.SX.sym("z", nz), ca.SX.sym("p", _P_SIZE)
    sc = {name: ps[_P_INDEX[name]] for name in _P_INDEX}
    x = ca.reshape(zs[xm.T.reshape(-1).tolist()], _STATES, nodes_count)
    jerk_s = ca.reshape(zs[jm.T.reshape(-1).tolist()], N_JOINTS, n)

    def scaled(block: Any, scale: Any, cols: int) -> Any:
        return ca.repmat(scale, 1, cols) * block

    q, qd, qdd = (scaled(x[6 * i:6 * i + 6, :], sc[name], nodes_count)
                  for i, name in enumerate(("s_q", "s_qd", "s_qdd")))
    jerk = scaled(jerk_s, sc["s_jerk"], n)
    h = sc["s_time"] * zs[it] / n
    q0, qd0, qdd0 = q[:, :-1], qd[:, :-1], qdd[:, :-1]
    d_q = (q[:, 1:] - (q0 + h * qd0 + h**2 / 2 * qdd0 + h**3 / 6 * jerk)) / ca.repmat(sc["s_q"], 1, n)
    d_qd = (qd[:, 1:] - (qd0 + h * qdd0 + h**2 / 2 * jerk)) / ca.repmat(sc["s_qd"], 1, n)
    d_qdd = (qdd[:, 1:] - (qdd0 + h * jerk)) / ca.repmat(sc["s_qdd"], 1, n)
    mid_qd = (qd0 + h / 2 * qdd0 + h**2 / 8 * jerk) / ca.repmat(sc["s_qd"], 1, n)
    g_simple = ca.vertcat(ca.vec(ca.vertcat(d_q, d_qd, d_qdd)), ca.vec(mid_qd))
    f_simple = sc["k1"] * sc["s_time"] * zs[it] / sc["s_cost"] + sc["reg"] * ca.sumsqr(jerk_s) / n
    n_simple = int(g_simple.numel())
    lam_s, sigma_s = ca.SX.sym("lam", n_simple), ca.SX.sym("sigma")
    jac_simple = ca.jacobian(g_simple, zs)
    grad_simple = ca.gradient(f_simple, zs)
    hess_simple = ca.triu(ca.hessian(sigma_s * f_simple + ca.dot(lam_s, g_simple), zs)[0])
    simple = ca.Function("ptp_simple", [zs, ps, sigma_s, lam_s],
                         [f_simple, g_simple, ca.densify(grad_simple), ca.vertcat(*jac_simple.nonzeros()),
                          ca.vertcat(*hess_simple.nonzeros())], {"cse": True})

    # -- node part: mapped per-node functions
    node_cols = np.column_stack([layout.node_columns(k) for k in range(nodes_count)])  # (30, N+1)
    gather = np.where(node_cols >= 0, node_cols, nz)  # index nz -> an appended zero
    jsp, hsp = nodes.jacobian_sparsity, nodes.hessian_sparsity
    j_rows, j_cols = (np.asarray(a) for a in jsp.get_triplet())
    h_rows, h_cols = (np.asarray(a) for a in hsp.get_triplet())
    n_jnz, n_hnz = j_rows.size, h_rows.size
    ng = n_simple + 18 * nodes_count
    node_row0 = n_simple + 18 * np.arange(nodes_count)

    # Jacobian of g: simple rows, then node rows (tau, rate before, rate after)
    jac_acc = _Accumulator((ng, nz))
    sr, scol = (np.asarray(a) for a in jac_simple.sparsity().get_triplet())
    jac_acc.add(sr, scol, np.arange(sr.size), sr.size)
    rows, cols, src = [], [], []
    for k in range(nodes_count):
        gcol = node_cols[j_cols, k]
        ok = gcol >= 0
        rows.append(node_row0[k] + j_rows[ok])
        cols.append(gcol[ok])
        src.append(k * n_jnz + np.flatnonzero(ok))
    jac_acc.add(np.concatenate(rows), np.concatenate(cols), np.concatenate(src), n_jnz * nodes_count)
    jac_sp, (a_jac_simple, a_jac_nodes) = jac_acc.build()


    # Hessian of the Lagrangian (upper triangle)
    hess_acc = _Accumulator((nz, nz), upper=True)
    hr, hc = (np.asarray(a) for a in hess_simple.sparsity().get_triplet())
    hess_acc.add(hr, hc, np.arange(hr.size), hr.size)
    rows, cols, src = [], [], []
    for k in range(nodes_count):
        ga, gb = node_cols[h_rows, k], node_cols[h_cols, k]
        ok = (ga >= 0) & (gb >= 0)
        rows.append(ga[ok])
        cols.append(gb[ok])
        src.append(k * n_hnz + np.flatnonzero(ok))
    hess_acc.add(np.concatenate(rows), np.concatenate(cols), np.concatenate(src), n_hnz * nodes_count)
    tx_rows = np.concatenate([node_cols[:_STATES, k] for k in range(nodes_count)])
    hess_acc.add(tx_rows, np.full(tx_rows.size, it), np.arange(tx_rows.size), tx_rows.size)
    hess_sp, (a_hess_simple, a_hess_nodes, a_hess_tx) = hess_acc.build()
    grad_x_rows = tx_rows
    a_grad = ca.DM.triplet(grad_x_rows.tolist(), list(range(grad_x_rows.size)), [1.0] * grad_x_rows.size,
                           nz, grad_x_rows.size)

    # -- MX assembly
    z, p = ca.MX.sym("x", nz), ca.MX.sym("p", _P_SIZE)
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", ng)
    pm = {name: p[_P_INDEX[name]] for name in _P_INDEX}
    s_all = ca.vertcat(*(pm[name] for name in _SCALE_NAMES))
    v = ca.reshape(ca.vertcat(z, 0)[gather.T.reshape(-1).tolist()], N_NODE_INPUTS, nodes_count)
    weights = np.ones(nodes_count)
    weights[[0, -1]] = 0.5
    h_mx = pm["s_time"] * z[it] / n
    c_energy = pm["k2"] / pm["s_cost"]
    outputs = nodes.f.map(nodes_count)(v, s_all, pm["dp"])
    energy_sum = ca.mtimes(outputs[18, :], ca.DM(weights))
    simple_out = simple(z, p, 0.0, ca.DM.zeros(n_simple))
    f_mx = simple_out[0] + c_energy * h_mx * energy_sum
    g_mx = ca.vertcat(simple_out[1], ca.vec(outputs[0:18, :]))
    jac_nodes = nodes.j.map(nodes_count)(v, s_all, pm["dp"])  # (n_jnz, N+1)
    e_grad = nodes.e.map(nodes_count)(v, s_all, pm["dp"]) * ca.repmat(ca.DM(weights).T, _STATES, 1)  # (18, N+1)
    t_unit = ca.DM.zeros(nz)
    t_unit[it] = 1.0
    grad_mx = (simple_out[2] + c_energy * h_mx * ca.mtimes(a_grad, ca.vec(e_grad))
               + t_unit * (c_energy * pm["s_time"] / n * energy_sum))
    jac_nz = ca.mtimes(a_jac_simple, simple_out[3]) + ca.mtimes(a_jac_nodes, ca.vec(jac_nodes))
    jac_mx = ca.sparsity_cast(jac_nz, jac_sp)
    lam_nodes = ca.vertcat(ca.reshape(lam_g[n_simple:], 18, nodes_count),
                           (lam_f * c_energy * h_mx) * ca.DM(weights).T)
    hess_nodes = nodes.h.map(nodes_count)(v, s_all, pm["dp"], lam_nodes)
    hess_nz = (ca.mtimes(a_hess_simple, simple(z, p, lam_f, lam_g[:n_simple])[4]) + ca.mtimes(a_hess_nodes, ca.vec(hess_nodes))
               + ca.mtimes(a_hess_tx, ca.vec(e_grad) * (lam_f * c_energy * pm["s_time"] / n)))
    hess_mx = ca.sparsity_cast(hess_nz, hess_sp)
    functions = {
        "grad_f": ca.Function("nlp_grad_f", [z, p], [f_mx, grad_mx], ["x", "p"], ["f", "grad_f_x"]),
        "jac_g": ca.Function("nlp_jac_g", [z, p], [g_mx, jac_mx], ["x", "p"], ["g", "jac_g_x"]),
        "hess_lag": ca.Function("nlp_hess_l", [z, p, lam_f, lam_g], [hess_mx],
                                ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"]),
        "fg": ca.Function("nlp_fg", [z, p], [f_mx, g_mx]),
    }
    counts = {"defects": _STATES * n, "midpoint_velocity": N_JOINTS * n, "node": 18 * nodes_count,
              "total": ng}
    nlp = {"x": z, "p": p, "f": f_mx, "g": g_mx}
    return _Transcription(layout, nodes, nlp, functions, counts, time.perf_counter() - start, {})


_BUILT: dict[tuple, _Transcription] = {}


def _transcription(dyn: PtPDynamics, n: int, compile_code: bool) -> tuple[_Transcription, float]:
    """The built NLP (cached) and the time spent building it now [s]."""
    start = time.perf_counter()
    structure = chain_structure(dyn.dynamics.model, dyn.dynamics.parameters)
    nodes = node_functions(structure, compile_code)
    key = (nodes.library or id(nodes), n)
    if key not in _BUILT:
        if len(_BUILT) >= 8:
            _BUILT.clear()
        _BUILT[key] = _build(nodes, n)
        return _BUILT[key], time.perf_counter() - start
    return _BUILT[key], 0.0


# -----------------------------------------------------------------------------------
# the planner
# -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class PiecewiseCubicMotion:
    """The planner's motion: node times (N+1,), node states q, qd, qdd (N+1, 6), jerk (N, 6).

    :meth:`sample` evaluates the exact piecewise-cubic q(t) and its derivatives.
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    jerk: np.ndarray

    @property
    def duration(self) -> float:
        return float(self.t[-1])

    def sample(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(q, qd, qdd, qddd) at ``times`` (m,) in s, arrays (m, 6)."""
        times = np.clip(np.asarray(times, dtype=float), self.t[0], self.t[-1])
        k = np.clip(np.searchsorted(self.t, times, side="right") - 1, 0, self.t.size - 2)
        s = (times - self.t[k])[:, None]
        j = self.jerk[k]
        q = self.q[k] + s * self.qd[k] + s**2 / 2 * self.qdd[k] + s**3 / 6 * j
        qd = self.qd[k] + s * self.qdd[k] + s**2 / 2 * j
        qdd = self.qdd[k] + s * j
        return q, qd, qdd, j


class OptimalPtPPlanner(Planner):
    """Own time/energy-optimal PtP planner (eq. 40); see the module docstring.

    ``sample_dt``: output sample time [s]; ``check_dt``: sample time of the dense limit
    check [s]; ``ratio_tolerance``: largest accepted dense |value| / limit;
    ``max_tightenings``: re-solves with tightened limits before giving up;
    ``ipopt_options``: extra IPOPT options (e.g. ``{"max_iter": 200}``);
    ``jerk_regularisation``: weight of the mean squared scaled jerk in the scaled cost;
    ``warm_start_check_dt``: check step of the Ruckig warm start [s];
    ``compile_code``: compile the node functions with gcc (else CasADi's virtual machine);
    ``coulomb_continuation``: factors of the Coulomb smoothing velocity v_s of preliminary
    solves, each started from the previous solution (() to solve the real problem directly);
    ``solve_time_limit_s``: wall-time limit of each IPOPT call (IPOPT ``max_wall_time``;
    proving infeasibility can take IPOPT minutes).
    The number of intervals N is ``problem.n_intervals`` (default 100).
    """

    name = "own_ptp"
    kind = "ptp"

    def __init__(self, sample_dt: float = DEFAULT_CHECK_DT, check_dt: float = DEFAULT_CHECK_DT,
                 ratio_tolerance: float = RATIO_TOLERANCE, max_tightenings: int = 3,
                 ipopt_options: dict | None = None, jerk_regularisation: float = DEFAULT_JERK_REGULARISATION,
                 warm_start_check_dt: float = 4e-3, compile_code: bool = True,
                 coulomb_continuation: tuple[float, ...] = DEFAULT_COULOMB_CONTINUATION,
                 solve_time_limit_s: float = 60.0) -> None:
        for arg, value in (("sample_dt", sample_dt), ("check_dt", check_dt),
                           ("warm_start_check_dt", warm_start_check_dt)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                raise PlannerInputError(f"OptimalPtPPlanner {arg}: expected a positive time in s, got {value!r}")
        if not (isinstance(ratio_tolerance, (int, float)) and ratio_tolerance >= 1.0):
            raise PlannerInputError(f"OptimalPtPPlanner ratio_tolerance: expected a number >= 1, got {ratio_tolerance!r}")
        if not (isinstance(max_tightenings, int) and max_tightenings >= 0):
            raise PlannerInputError(f"OptimalPtPPlanner max_tightenings: expected an integer >= 0, got {max_tightenings!r}")
        if not (isinstance(jerk_regularisation, (int, float)) and jerk_regularisation >= 0.0):
            raise PlannerInputError(
                f"OptimalPtPPlanner jerk_regularisation: expected a number >= 0, got {jerk_regularisation!r}")
        self.sample_dt = float(sample_dt)
        self.check_dt = float(check_dt)
        self.ratio_tolerance = float(ratio_tolerance)
        self.max_tightenings = int(max_tightenings)
        self.ipopt_options = dict(ipopt_options or {})
        self.jerk_regularisation = float(jerk_regularisation)
        self.warm_start_check_dt = float(warm_start_check_dt)
        self.compile_code = bool(compile_code)
        self.coulomb_continuation = tuple(float(f) for f in coulomb_continuation)
        if not (isinstance(solve_time_limit_s, (int, float)) and solve_time_limit_s > 0.0):
            raise PlannerInputError(
                f"OptimalPtPPlanner solve_time_limit_s: expected a positive time in s, got {solve_time_limit_s!r}")
        self.solve_time_limit_s = float(solve_time_limit_s)

    # -- public -------------------------------------------------------------------
    def plan(self, problem: PtPProblem) -> PlanResult:
        refused = _check_request(problem, self.name)
        if refused is not None:
            return refused
        n = int(problem.n_intervals)
        if n < 4:
            raise PlannerInputError(f"PtPProblem.n_intervals: expected an integer >= 4, got {problem.n_intervals!r}")
        limits = problem.limits
        dyn = ptp_dynamics(problem.dynamics, problem.friction)
        transcription, build_time = _transcription(dyn, n, self.compile_code)
        layout = transcription.layout

        t_start = time.perf_counter()
        warm = self._warm_start(problem, dyn)
        warm_time = time.perf_counter() - t_start
        if warm is None:
            return PlanResult(self.name, PlanStatus.FAILED, None, warm_time, build_time,
                              message="no warm start: Ruckig found no trajectory for the boundary states",
                              info={"warm_start_time_s": warm_time})
        scales = _scales(problem, dyn, warm)
        z0 = _initial_guess(layout, warm, scales)
        energy0 = _trapezoid_energy(dyn.torques(warm.q, warm.qd, warm.qdd), warm.t)
        params = _parameters(scales, problem, dyn, warm.duration, energy0, self.jerk_regularisation)
        factors = {kind: np.ones(N_JOINTS) for kind in CHECKED_KINDS}  # per-joint limit tightening
        history: list[dict] = []
        solve_time = warm_time
        status, message, motion, ratios = PlanStatus.FAILED, "", None, {}
        smoothing = _P_INDEX["dp"].stop - 1
        previous: dict | None = None  # last solution and multipliers: re-solves start from it

        def solve(p_values: np.ndarray, note: dict) -> tuple[str, dict]:
            nonlocal solve_time
            lbx, ubx, lbg, ubg = _bounds(transcription, problem, scales, factors)
            limit = {"max_wall_time": self.solve_time_limit_s}
            if previous is None:
                args = {"x0": z0}
                chosen = transcription.solver({**limit, **self.ipopt_options})
            else:
                args = {"x0": previous["x"], "lam_x0": previous["lam_x"], "lam_g0": previous["lam_g"]}
                chosen = transcription.solver({**limit, **self.ipopt_options, **IPOPT_WARM_RESTART})
            t0 = time.perf_counter()
            sol = chosen(p=p_values, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg, **args)
            solve_time += time.perf_counter() - t0
            stats = chosen.stats()
            text = str(stats.get("return_status", ""))
            history.append({"return_status": text, "iterations": int(stats.get("iter_count", -1)), **note})
            return text, {k: np.asarray(sol[k]).reshape(-1) for k in ("x", "lam_x", "lam_g")}

        for factor in self.coulomb_continuation:
            # a smoother Coulomb term first: its solution starts the real problem
            smooth_params = params.copy()
            smooth_params[smoothing] *= factor
            text, result = solve(smooth_params, {"coulomb_smoothing_factor": factor})
            if _status(text).has_trajectory:
                previous = result
        for attempt in range(self.max_tightenings + 1):
            message, result = solve(params, {"factors": {k: v.tolist() for k, v in factors.items()
                                                         if np.any(v != 1.0)}})
            status = _status(message)
            if not status.has_trajectory:
                motion = None
                break
            previous = result
            motion = _motion(layout, result["x"], scales)
            times = uniform_times(0.0, motion.duration, self.check_dt)
            q, qd, qdd, _ = motion.sample(times)
            ratios = dyn.ratios(times, q, qd, qdd, limits)
            excess = {k: float(np.max(ratios[k])) for k in CHECKED_KINDS if k == "position" or limits.active(k)}
            history[-1]["max_ratio"] = max(excess.values())
            worst = {k: v for k, v in excess.items() if v > self.ratio_tolerance}
            if not worst:
                break
            if attempt == self.max_tightenings:
                status = PlanStatus.FAILED
                message = (f"{message}, but the dense check at {self.check_dt:g} s still exceeds the limits after "
                           f"{self.max_tightenings} tightenings: "
                           + ", ".join(f"{k} ratio {v:.4f}" for k, v in worst.items()))
                motion = None
                break
            for kind in worst:
                # tighten the offending joints by twice their excess: the bulge between
                # nodes tends to move when its limit is shrunk by the excess alone
                over = ratios[kind] > self.ratio_tolerance
                factors[kind][over] *= 1.0 - 2.0 * (ratios[kind][over] - 1.0) - 5e-4
        info: dict[str, Any] = {
            "iterations": sum(h["iterations"] for h in history), "attempts": history,
            "warm_start_time_s": warm_time, "warm_start_duration_s": warm.duration, "n_intervals": n,
            "constraints": transcription.n_constraints, "compiled": transcription.nodes.compiled,
            "transcription": f"piecewise-cubic q (constant jerk per interval), implicit inverse dynamics, N={n}",
        }
        if motion is None:
            explain = {PlanStatus.INFEASIBLE: "infeasible request (IPOPT: Infeasible_Problem_Detected): the "
                                              "limits cannot be met between these boundary states",
                       PlanStatus.FAILED: "no certified solution"}[status]
            return PlanResult(self.name, status, None, solve_time, build_time, message=f"{explain} [{message}]",
                              info=info)
        trajectory = self._trajectory(motion, dyn, problem, status, solve_time)
        info.update({"max_constraint_ratio": float(max(np.max(ratios[k]) for k in RATIO_KINDS)),
                     "ratios": {k: v.tolist() for k, v in ratios.items()},
                     "energy": _trapezoid_energy(trajectory.tau, trajectory.t),
                     "motion": motion})
        return PlanResult(self.name, status, trajectory, solve_time, build_time, message=message, info=info)

    # -- steps --------------------------------------------------------------------
    def _warm_start(self, problem: PtPProblem, dyn: PtPDynamics) -> RuckigMotion | None:
        """Ruckig tuned to the torque limits (stand-ins for missing kinematic limits);
        if no scale makes it torque-feasible, the unscaled Ruckig profile."""
        tuned = torque_tuned_motion(problem, dyn, self.warm_start_check_dt, scale_resolution=0.05)
        if tuned is not None:
            return tuned.motion
        velocity, acceleration, jerk, _ = kinematic_limits(problem)
        motion = ruckig_motion(problem, velocity, acceleration, jerk, self.warm_start_check_dt)
        return motion if motion.ok else None

    def _trajectory(self, motion: PiecewiseCubicMotion, dyn: PtPDynamics, problem: PtPProblem,
                    status: PlanStatus, solve_time: float) -> Trajectory:
        times = uniform_times(0.0, motion.duration, self.sample_dt)
        q, qd, qdd, _ = motion.sample(times)
        tau = dyn.torques(q, qd, qdd)
        metadata = {"planner": self.name, "status": status.value, "solve_time_s": solve_time,
                    "k1": problem.k1, "k2": problem.k2, "friction": problem.friction,
                    "n_intervals": int(problem.n_intervals)}
        return Trajectory(times, q, qd, qdd, tau, metadata=metadata)


# -----------------------------------------------------------------------------------
# problems: the paper's PtP and PtP between Cartesian end points
# -----------------------------------------------------------------------------------


def eq40_limits(limits: JointLimits | None = None) -> JointLimits:
    """The limits of the paper's eq. 40: torque, torque rate, velocity and position of
    ``limits`` (default the robot's), acceleration and jerk switched off (inf)."""
    return (limits or JointLimits.from_robot()).replace(acceleration=math.inf, jerk=math.inf)


def paper_ptp_problem(limits: JointLimits | None = None, dynamics: Any = None, k1: float = 1.0, k2: float = 0.0,
                      friction: str = "full", n_intervals: int = 100, paper_limits: bool = True) -> PtPProblem:
    """PtP at rest between the end points of the paper line (``planners.paper_line``, the
    same IK branch as the CP path), paper sec. 5.5. ``paper_limits``: use
    :func:`eq40_limits` of ``limits`` (the paper's PtP limits); False keeps every limit."""
    from planners.paper_line import paper_line_configurations

    q0, qe = paper_line_configurations()
    lim = limits or JointLimits.from_robot()
    if paper_limits:
        lim = eq40_limits(lim)
    return PtPProblem(q0, qe, lim, dynamics=dynamics, k1=k1, k2=k2, friction=friction, n_intervals=n_intervals)


class PtPUnreachableError(PlannerInputError, UnreachablePoseError):
    """A PtP end pose is out of the arm's reach (or has no IK solution within the joint limits)."""


def ptp_problem_from_poses(start_pose: Any, end_pose: Any, limits: JointLimits, q_hint: Any,
                           **problem_fields: Any) -> PtPProblem:
    """A PtPProblem between two flange poses (the paper's z_E,0 and z_E,end).

    Poses: Cardan poses (x, y, z [m], alpha, beta, gamma [rad]) or 4x4 transforms of
    ``tool0`` in ``base_link``. ``q_hint`` (6,) [rad] picks the IK branch of the start;
    the end takes the branch nearest to the start. Nominal arm (analytic IK). Further
    PtPProblem fields (qd0, qde, dynamics, k1, k2, friction, n_intervals) pass through.
    Raises PtPUnreachableError naming the pose when a pose is out of reach.
    """
    ik = AnalyticIK()
    configurations = []
    seed = np.asarray(q_hint, dtype=float)
    for name, pose in (("start_pose", start_pose), ("end_pose", end_pose)):
        arr = np.asarray(pose, dtype=float)
        target = transform_from_pose(arr) if arr.shape == (6,) else arr
        if target.shape != (4, 4):
            raise PlannerInputError(f"{name}: expected a Cardan pose (6,) or a 4x4 transform, got shape {arr.shape}")
        try:
            seed = ik.nearest(target, seed)
        except UnreachablePoseError as exc:
            raise PtPUnreachableError(f"{name} {np.round(arr, 4).tolist()}: {exc}") from exc
        configurations.append(seed)
    return PtPProblem(configurations[0], configurations[1], limits, **problem_fields)


# -----------------------------------------------------------------------------------
# helpers
# -----------------------------------------------------------------------------------


def _status(return_status: str) -> PlanStatus:
    if return_status == "Solve_Succeeded":
        return PlanStatus.OPTIMAL
    if return_status == "Solved_To_Acceptable_Level":
        return PlanStatus.FEASIBLE
    if return_status == "Infeasible_Problem_Detected":
        return PlanStatus.INFEASIBLE
    return PlanStatus.FAILED


def _trapezoid_energy(tau: np.ndarray, t: np.ndarray) -> float:
    """integral tau^T tau dt [N^2 m^2 s] by the trapezoidal rule."""
    power = np.sum(tau**2, axis=1)
    return float(np.sum(0.5 * (power[1:] + power[:-1]) * np.diff(t)))


def _finite_or(values: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    return np.where(np.isfinite(values), values, fallback)


def _scales(problem: PtPProblem, dyn: PtPDynamics, warm: RuckigMotion) -> dict[str, np.ndarray]:
    """Scale of each variable/constraint block: its limit where finite, else a typical value."""
    lim = problem.limits
    bounded = np.isfinite(lim.position_lower) & np.isfinite(lim.position_upper)
    half_range = np.where(bounded, 0.5 * (lim.position_upper - lim.position_lower), math.pi)
    typical_qdd = np.maximum(np.max(np.abs(warm.qdd), axis=0), 1.0)
    jerk_warm = np.abs(np.diff(warm.qdd, axis=0) / np.diff(warm.t)[:, None])
    typical_jerk = np.maximum(np.max(jerk_warm, axis=0), 10.0)
    typical_tau = np.maximum(np.max(np.abs(dyn.torques(warm.q, warm.qd, warm.qdd)), axis=0), 1.0)
    return {
        "s_q": half_range,
        "s_qd": _finite_or(lim.velocity, np.maximum(np.max(np.abs(warm.qd), axis=0), 1.0)),
        "s_qdd": _finite_or(lim.acceleration, 2.0 * typical_qdd),
        "s_jerk": _finite_or(lim.jerk, 2.0 * typical_jerk),
        "s_tau": _finite_or(lim.torque, typical_tau),
        "s_rate": _finite_or(lim.torque_rate, 10.0 * typical_tau),
    }


def _parameters(scales: dict[str, np.ndarray], problem: PtPProblem, dyn: PtPDynamics, duration: float,
                energy0: float, regularisation: float) -> np.ndarray:
    par = np.zeros(_P_SIZE)
    for name in _SCALE_NAMES:
        par[_P_INDEX[name]] = scales[name]
    par[_P_INDEX["s_time"]] = duration
    par[_P_INDEX["s_cost"]] = problem.k1 * duration + problem.k2 * energy0
    par[_P_INDEX["k1"]] = problem.k1
    par[_P_INDEX["k2"]] = problem.k2
    par[_P_INDEX["reg"]] = regularisation
    par[_P_INDEX["dp"]] = np.concatenate([dyn.parameter_vector, np.asarray(dyn.dynamics.payload, dtype=float),
                                          [dyn.smoothing_velocity]])
    scales["s_time"] = np.array([duration])
    return par


def _initial_guess(layout: _Layout, warm: RuckigMotion, scales: dict[str, np.ndarray]) -> np.ndarray:
    n = layout.n
    nodes = np.linspace(0.0, warm.duration, n + 1)

    def at_nodes(values: np.ndarray) -> np.ndarray:
        return np.column_stack([np.interp(nodes, warm.t, values[:, j]) for j in range(N_JOINTS)])

    q, qd, qdd = at_nodes(warm.q), at_nodes(warm.qd), at_nodes(warm.qdd)
    qdd[0] = qdd[-1] = 0.0
    jerk = np.diff(qdd, axis=0) / (warm.duration / n)
    x = np.vstack([(q / scales["s_q"]).T, (qd / scales["s_qd"]).T, (qdd / scales["s_qdd"]).T])
    return layout.pack(x, (jerk / scales["s_jerk"]).T, 1.0)


def _bounds(tr: _Transcription, problem: PtPProblem, scales: dict[str, np.ndarray],
            factors: dict[str, float]) -> tuple[np.ndarray, ...]:
    layout, n = tr.layout, tr.layout.n
    lim = problem.limits
    lower, upper = lim.position_lower.copy(), lim.position_upper.copy()
    bounded = np.isfinite(lower) & np.isfinite(upper)
    mid = np.where(bounded, 0.5 * (lower + upper), 0.0)
    half = np.where(bounded, 0.5 * (upper - lower), np.inf)
    lower = np.where(bounded, mid - factors["position"] * half, lower)
    upper = np.where(bounded, mid + factors["position"] * half, upper)
    vel = lim.velocity * factors["velocity"] / scales["s_qd"]
    acc = lim.acceleration * factors["acceleration"] / scales["s_qdd"]
    jerk = lim.jerk * factors["jerk"] / scales["s_jerk"]
    x_lo = np.tile(np.concatenate([lower / scales["s_q"], -vel, -acc])[:, None], (1, n + 1))
    x_hi = np.tile(np.concatenate([upper / scales["s_q"], vel, acc])[:, None], (1, n + 1))
    for col, (q, qd) in ((0, (problem.q0, problem.qd0)), (n, (problem.qe, problem.qde))):
        fixed = np.concatenate([q / scales["s_q"], qd / scales["s_qd"], np.zeros(N_JOINTS)])
        x_lo[:, col] = x_hi[:, col] = fixed
    j_hi = np.tile(jerk[:, None], (1, n))
    lbx = layout.pack(x_lo, -j_hi, 1e-2)
    ubx = layout.pack(x_hi, j_hi, 1e2)
    counts = tr.n_constraints
    tau = lim.torque * factors["torque"] / scales["s_tau"]
    rate = lim.torque_rate * factors["torque_rate"] / scales["s_rate"]
    node = np.tile(np.concatenate([tau, rate, rate])[:, None], (1, n + 1))
    node[6:12, 0] = np.inf  # no interval before the first node
    node[12:18, n] = np.inf  # no interval after the last node
    mid_vel = np.tile(vel, n)
    lbg = np.concatenate([np.zeros(counts["defects"]), -mid_vel, -node.T.reshape(-1)])
    ubg = np.concatenate([np.zeros(counts["defects"]), mid_vel, node.T.reshape(-1)])
    return lbx, ubx, lbg, ubg


def _motion(layout: _Layout, z: np.ndarray, scales: dict[str, np.ndarray]) -> PiecewiseCubicMotion:
    x, jerk, t_scaled = layout.unpack(z)
    duration = t_scaled * float(scales["s_time"][0])
    q = (x[0:6] * scales["s_q"][:, None]).T
    qd = (x[6:12] * scales["s_qd"][:, None]).T
    qdd = (x[12:18] * scales["s_qdd"][:, None]).T
    return PiecewiseCubicMotion(np.linspace(0.0, duration, layout.n + 1), q, qd, qdd,
                                (jerk * scales["s_jerk"][:, None]).T)
