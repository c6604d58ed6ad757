"""The exciting-trajectory problem of eq. 30 with CasADi/IPOPT on a smooth surrogate objective.

The condition number is not differentiable where the extreme singular values are
multiple, and IPOPT wants a smooth problem. A standard smooth surrogate is the
A-optimality criterion of the column-normalised regressor ``Theta_n``::

    f_A(x) = log tr((Theta_n^T Theta_n)^-1)

With unit columns ``tr(Theta_n^T Theta_n) = n`` (the number of base parameters), so
``lambda_max <= n`` and ``cond(Theta_n)^2 = lambda_max / lambda_min <= n tr(...)``:
driving ``f_A`` down drives an upper bound of the condition number down. The whole
problem (regressor at the samples, normalisation, 52 x 52 solve, torque and TCP
constraints) is one CasADi MX graph with exact first derivatives; IPOPT uses a
limited-memory Hessian. ``benchmarks/bench_identification.py`` compares it with the
SLSQP solution of the exact objective (:func:`identification.excitation.optimise_excitation`).
"""
from __future__ import annotations

import time
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from identification.excitation import ExcitationProblem
from identification.fourier import N_JOINTS


def _states(x: ca.MX, basis: tuple[np.ndarray, ...], n_block: int) -> list[ca.MX]:
    blocks = ca.reshape(x, n_block, N_JOINTS)  # column j = joint j's [a, b, q0]
    return [ca.mtimes(ca.DM(b), blocks) for b in basis]  # (samples, 6) each


def optimise_excitation_ipopt(problem: ExcitationProblem, x0: ArrayLike, *, max_iterations: int = 300,
                              print_level: int = 0) -> tuple[np.ndarray, dict[str, Any]]:
    """IPOPT from ``x0`` on the A-optimality surrogate; returns (x, stats incl. solve_time_s)."""
    x0 = np.asarray(x0, dtype=float)
    n_base = problem.base.count
    x = ca.MX.sym("x", problem.n_x)
    q, qd, qdd = _states(x, problem.objective_basis, problem.n_block)
    y = problem.objective_functions.regressor(q.T, qd.T, qdd.T)  # 6 x (k n_base)
    a = ca.vertcat(*ca.horzsplit(y, n_base))  # (6k) x n_base
    norms = ca.sqrt(ca.sum1(a**2))
    a_n = a / ca.repmat(norms, a.shape[0], 1)
    gram = ca.mtimes(a_n.T, a_n)
    objective = ca.log(ca.trace(ca.solve(gram, ca.DM.eye(n_base))))

    lim = problem.limits
    margin = problem.settings.margin
    qc, qdc, qddc = _states(x, problem.constraint_basis, problem.n_block)
    tau = problem.constraint_functions.torque(qc.T, qdc.T, qddc.T)[0]  # 6 x m
    r = problem.constraint_functions.flange(qc.T)[0]  # 3 x m
    lin_a, lin_b = problem.linear_constraints
    m = qc.shape[0]
    tau_scaled = ca.vec(tau / ca.repmat(ca.DM(lim.tau_max), 1, m))
    r_flat = ca.vec(r)
    lower, upper = np.tile(lim.tcp_lower, m), np.tile(lim.tcp_upper, m)
    g = ca.vertcat(ca.mtimes(ca.DM(lin_a), x), tau_scaled, r_flat, ca.mtimes(ca.DM(problem.rest_matrix), x))
    n_lin, n_tau, n_r = lin_a.shape[0], tau_scaled.shape[0], r_flat.shape[0]
    span = lim.tcp_upper - lim.tcp_lower
    lbg = np.concatenate((margin - lin_b, np.full(n_tau, -1.0 + margin), lower + margin * np.tile(span, m),
                          np.zeros(problem.rest_matrix.shape[0])))
    ubg = np.concatenate((np.full(n_lin, np.inf), np.full(n_tau, 1.0 - margin), upper - margin * np.tile(span, m),
                          np.zeros(problem.rest_matrix.shape[0])))
    options = {"ipopt.max_iter": max_iterations, "ipopt.print_level": print_level, "print_time": False,
               "ipopt.hessian_approximation": "limited-memory", "ipopt.tol": 1e-6,
               "ipopt.acceptable_tol": 1e-4}
    solver = ca.nlpsol("excitation_ipopt", "ipopt", {"x": x, "f": objective, "g": g}, options)
    wall0 = time.perf_counter()
    solution = solver(x0=x0, lbg=lbg, ubg=ubg)
    wall = time.perf_counter() - wall0
    stats = solver.stats()
    x_opt = np.asarray(solution["x"]).reshape(-1)
    return x_opt, {"solve_time_s": wall, "iterations": int(stats.get("iter_count", -1)),
                   "status": str(stats.get("return_status")), "success": bool(stats.get("success")),
                   "surrogate": float(solution["f"]), "n_constraints": int(n_lin + n_tau + n_r)}
