"""Own time/energy-optimal continuous-path planner (paper eq. 38 plus jerk and torque rate).

Problem: move along a fixed joint path q(sigma), sigma in [0, 1], from rest to rest,

    minimise   integral (k1 + k2 tau^T tau) / sigma_dot  d sigma          (eq. 38)
    subject to |qd| <= qd_max, |qdd| <= qdd_max, |tau| <= tau_max          (eq. 38)
               |qddd| <= qddd_max, |tau_dot| <= tau_dot_max                (our extension)

with tau = m a + c b + g + v sqrt(b) + f_c (planners.path_dynamics), transcribed with
CasADi and solved by IPOPT. Two exact transcriptions:

``"b"`` (used when jerk and torque-rate limits are off) -- the sigma_dot^2 form.
    Variables b_i = sigma_dot^2 at the n+1 nodes. b is linear in sigma on every
    interval, so sigma_ddot a_i = (b_{i+1} - b_i) / (2 dsigma) is constant there and
    the time law is exact (t is the integral of dsigma / sqrt(b), done exactly per
    interval: h_i = 2 dsigma / (sqrt b_i + sqrt b_{i+1})). Velocity, acceleration and
    torque are imposed at the start, the middle and the end of every interval (the
    middle point is what keeps the 1 ms resampled trajectory inside the limits between
    grid points; TOPP-RA only imposes the ends). Without viscous friction every
    constraint is linear in b and the time cost is convex in b (1 / (sqrt x + sqrt y)
    is convex), the energy term tau^2 / sqrt(b) too, so IPOPT's local optimum is the
    global one. Viscous friction adds v sqrt(b) (concave): still smooth, no longer
    convex.

``"smooth"`` (used when a jerk or torque-rate limit is finite) -- jerk and torque
    rate depend on d sigma_ddot / dt, which the b form sets to infinity at every node.
    Variables per node: s_i = sigma_dot, a_i = sigma_ddot; per interval its duration
    h_i. sigma(t) is a cubic on every interval (sigma_ddot linear in time, jerk j_i =
    (a_{i+1} - a_i) / h_i), the nodes fixed at the sigma grid:
        s_{i+1} = s_i + h_i (a_i + a_{i+1}) / 2
        dsigma  = s_i h_i + h_i^2 (2 a_i + a_{i+1}) / 6
    so sigma_dot, sigma_ddot are continuous and the law is exact. At every node:
        qd    = q' s,  qdd = q' a + q'' s^2,  tau = m a + c s^2 + g + v s + f_c
        qddd  = q' j + 3 q'' s a + q''' s^3
        taudot= m j + (m' + 2 c) s a + c' s^3 + g' s + v' s^2 + v a
    with the jerk j of the interval on either side (both are imposed); a_0 = a_n = 0
    so the torque is continuous at the start and the end. Non-convex (bilinear
    products); warm-started from the "b" solution, whose durations it lengthens only
    where the new limits bind. The Coulomb term's sign jump at a velocity reversal is
    excluded from the torque rate (no smooth motion avoids it).

Scaling (IPOPT does not converge unscaled): b_i by its velocity bound, s_i by its
square root, a by the acceleration bound along the path, h by the mean interval
duration; every constraint row by its limit; the cost by its value at the start.

Status: only IPOPT's "Solve_Succeeded" is OPTIMAL; "Solved_To_Acceptable_Level" is
FEASIBLE; infeasibility detection gives INFEASIBLE; anything else FAILED.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from planners.base import CPProblem, Planner, PlannerInputError, PlanResult, PlanStatus
from planners.path_dynamics import PathDynamics, TimeLaw, path_dynamics, trajectory_from_time_law
from robot.dynamics import RobotDynamics
from robot.joints import N_JOINTS

DEFAULT_IPOPT_OPTIONS: dict[str, Any] = {
    "ipopt.print_level": 0,
    "ipopt.sb": "yes",
    "print_time": False,
    "ipopt.tol": 1e-9,
    "ipopt.acceptable_tol": 1e-6,
    "ipopt.max_iter": 500,
    "ipopt.mu_strategy": "adaptive",
    "show_eval_warnings": False,
}
SMOOTH_MARGIN = 2e-3
"""Fraction by which the "smooth" transcription tightens every limit: it imposes the
limits at the nodes only, and between nodes (sigma there is not fixed) the 1 ms
resampled values may exceed the node values by about 0.1 %."""
_IPOPT_INFEASIBLE = {"Infeasible_Problem_Detected", "Restoration_Failed"}


def _status_of(ipopt_status: str) -> PlanStatus:
    if ipopt_status == "Solve_Succeeded":
        return PlanStatus.OPTIMAL
    if ipopt_status == "Solved_To_Acceptable_Level":
        return PlanStatus.FEASIBLE
    if ipopt_status in _IPOPT_INFEASIBLE:
        return PlanStatus.INFEASIBLE
    return PlanStatus.FAILED


@dataclass(frozen=True)
class _Points:
    """Path dynamics at interval starts, middles and ends (each (n, 6))."""

    start: PathDynamics
    mid: PathDynamics
    end: PathDynamics


def _take(pd: PathDynamics, idx: slice) -> PathDynamics:
    return PathDynamics(*(getattr(pd, f)[idx] for f in PathDynamics.__dataclass_fields__))


def _needed_rows(pts: PathDynamics, b_cap: np.ndarray, lim: Any) -> tuple[np.ndarray, np.ndarray]:
    """Which acceleration and torque rows (n, 6) can ever be active (exact pruning).

    Every row reads  alpha a + beta b + gamma + nu sqrt(b)  in [-L, L]  with a = sigma_ddot
    and 0 <= b <= b_cap (the velocity limit). Each row, taken alone, bounds a over that
    b range; A_lo <= a <= A_hi is the tightest of these bounds. A row whose extreme
    values over the box [A_lo, A_hi] x [0, b_cap] stay inside its limits is implied by
    the others and the bounds, so dropping it leaves the feasible set unchanged. Rows
    that define A_lo or A_hi are always kept.
    """
    n = b_cap.size
    root = np.sqrt(b_cap)[:, None]
    bc = b_cap[:, None]
    alpha = np.concatenate([pts.dq, pts.m], axis=1)
    beta = np.concatenate([pts.ddq, pts.c], axis=1)
    gamma = np.concatenate([np.zeros_like(pts.g), pts.g + pts.fc], axis=1)
    nu = np.concatenate([np.zeros_like(pts.v), pts.v], axis=1)
    limit = np.concatenate([lim.acceleration, lim.torque])[None, :]
    # extreme values of beta b + nu sqrt(b) over [0, b_cap] (both terms monotone in b)
    rest_max = np.maximum(beta, 0.0) * bc + np.maximum(nu, 0.0) * root
    rest_min = np.minimum(beta, 0.0) * bc + np.minimum(nu, 0.0) * root
    with np.errstate(divide="ignore", invalid="ignore"):
        upper_side = (limit - gamma - rest_min) / alpha  # alpha a <= L - gamma - rest
        lower_side = (-limit - gamma - rest_max) / alpha  # alpha a >= -L - gamma - rest
    pos, neg = alpha > 0.0, alpha < 0.0
    hi_cand = np.where(pos, upper_side, np.where(neg, lower_side, np.inf))
    lo_cand = np.where(pos, lower_side, np.where(neg, upper_side, -np.inf))
    hi_cand = np.where(np.isfinite(hi_cand), hi_cand, np.inf)
    lo_cand = np.where(np.isfinite(lo_cand), lo_cand, -np.inf)
    a_hi = np.min(hi_cand, axis=1, keepdims=True)
    a_lo = np.max(lo_cand, axis=1, keepdims=True)
    value_max = np.maximum(alpha * a_hi, alpha * a_lo) + gamma + rest_max
    value_min = np.minimum(alpha * a_hi, alpha * a_lo) + gamma + rest_min
    margin = 1.0 - 1e-6
    keep = ~((value_max <= margin * limit) & (value_min >= -margin * limit))
    keep[np.arange(n), np.argmin(hi_cand, axis=1)] = True
    keep[np.arange(n), np.argmax(lo_cand, axis=1)] = True
    return keep[:, :N_JOINTS], keep[:, N_JOINTS:]


class OwnCPPlanner(Planner):
    """Our CP planner (module docstring). ``transcription``: "auto", "b" or "smooth"."""

    name = "own_cp"
    kind = "cp"

    def __init__(self, transcription: str = "auto", ipopt_options: dict[str, Any] | None = None,
                 output_dt: float = 1e-3, smooth_margin: float = SMOOTH_MARGIN) -> None:
        if transcription not in ("auto", "b", "smooth"):
            raise PlannerInputError(f"transcription: expected 'auto', 'b' or 'smooth', got {transcription!r}")
        self.transcription = transcription
        self.ipopt_options = {**DEFAULT_IPOPT_OPTIONS, **(ipopt_options or {})}
        self.output_dt = float(output_dt)
        if not 0.0 <= smooth_margin < 0.1:
            raise PlannerInputError(f"smooth_margin: expected a fraction in [0, 0.1), got {smooth_margin!r}")
        self.smooth_margin = float(smooth_margin)

    # ------------------------------------------------------------------ public
    def plan(self, problem: CPProblem) -> PlanResult:
        if not isinstance(problem, CPProblem):
            raise PlannerInputError(f"OwnCPPlanner.plan: expected a CPProblem, got {type(problem).__name__}")
        lim = problem.limits
        for kind in ("velocity", "acceleration", "torque"):
            if not np.all(np.isfinite(getattr(lim, kind))):
                raise PlannerInputError(f"OwnCPPlanner: {kind} limits must be finite (eq. 38), got {getattr(lim, kind)}")
        smooth = lim.active("jerk") or lim.active("torque_rate")
        mode = self.transcription if self.transcription != "auto" else ("smooth" if smooth else "b")
        dyn = problem.dynamics or RobotDynamics()
        for where, q in (("start", problem.path.q[0]), ("end", problem.path.q[-1])):
            hold = np.abs(dyn.gravity(q))
            if np.any(hold > lim.torque):
                j = int(np.argmax(hold / lim.torque))
                return PlanResult(self.name, PlanStatus.INFEASIBLE, None, 0.0, message=(
                    f"infeasible: holding the path {where} at rest needs {hold[j]:.1f} N m on joint {j + 1}, "
                    f"above its torque limit {lim.torque[j]:.1f} N m"))
        t_build = time.perf_counter()
        n = int(problem.n_intervals)
        sigma = np.linspace(0.0, 1.0, n + 1)
        mids = 0.5 * (sigma[:-1] + sigma[1:])
        nodes = path_dynamics(problem.path, sigma, dyn, problem.friction, derivatives=(mode == "smooth"))
        middle = path_dynamics(problem.path, mids, dyn, problem.friction, derivatives=False)
        build_time = time.perf_counter() - t_build
        b_res = self._solve_b(problem, sigma, nodes, middle)
        b_res.build_time_s += build_time
        if mode == "b" or not b_res.status.has_trajectory:
            return self._finish(problem, dyn, b_res, mode="b")
        s_res = self._solve_smooth(problem, sigma, nodes, b_res)
        s_res.build_time_s += build_time + b_res.build_time_s
        s_res.solve_time_s += b_res.solve_time_s
        s_res.info["warm_start_b"] = {"status": b_res.status.value, "duration_s": b_res.info["duration_grid_s"],
                                      "solve_time_s": b_res.solve_time_s}
        return self._finish(problem, dyn, s_res, mode="smooth")

    # ------------------------------------------------------------- b form
    def _solve_b(self, problem: CPProblem, sigma: np.ndarray, nodes: PathDynamics,
                 middle: PathDynamics) -> PlanResult:
        t0 = time.perf_counter()
        lim = problem.limits
        n = sigma.size - 1
        ds = float(sigma[1] - sigma[0])
        vmax, amax, tmax = lim.velocity, lim.acceleration, lim.torque
        with np.errstate(divide="ignore"):
            b_node = np.min((vmax / np.abs(nodes.dq)) ** 2, axis=1)
            b_mid = np.min((vmax / np.abs(middle.dq)) ** 2, axis=1)
        b_scale = np.minimum(b_node, 1e6)
        has_viscous = bool(np.any(nodes.v != 0.0))

        x = ca.SX.sym("bhat", n + 1)
        b = x * ca.DM(b_scale)
        bi, bj = b[:-1], b[1:]
        a = (bj - bi) / (2.0 * ds)
        bm = 0.5 * (bi + bj)
        # IPOPT may relax the bound b >= 0 by ~1e-8 relative: guard the square roots
        eps = ca.DM(1e-10 * b_scale)
        sqrt_b = ca.sqrt(ca.fmax(b, 0.0) + eps)
        si, sj = sqrt_b[:-1], sqrt_b[1:]
        sm = ca.sqrt(ca.fmax(bm, 0.0) + 0.5 * (eps[:-1] + eps[1:]))
        start = _take(nodes, slice(0, n))
        end = _take(nodes, slice(1, n + 1))
        rows, lbg, ubg = [], [], []

        def add(expr, lo, hi):
            rows.append(expr)
            lbg.append(np.broadcast_to(lo, (expr.shape[0],)))
            ubg.append(np.broadcast_to(hi, (expr.shape[0],)))

        # velocity between nodes: (b_i + b_{i+1}) / 2 <= b_mid (linear)
        add(bm / ca.DM(np.minimum(b_mid, 1e6)), -np.inf, 1.0)
        torques = []
        kept = 0
        for pts, bb, ss, bcap in ((start, bi, si, b_node[:-1]), (middle, bm, sm, b_mid), (end, bj, sj, b_node[1:])):
            acc_keep, tau_keep = _needed_rows(pts, np.minimum(bcap, 1e6), lim)
            for j in range(N_JOINTS):
                qdd = ca.DM(pts.dq[:, j]) * a + ca.DM(pts.ddq[:, j]) * bb
                tau = ca.DM(pts.m[:, j]) * a + ca.DM(pts.c[:, j]) * bb + ca.DM(pts.g[:, j] + pts.fc[:, j])
                if has_viscous:
                    tau = tau + ca.DM(pts.v[:, j]) * ss
                torques.append(tau)
                for expr, keep, limit in ((qdd, acc_keep[:, j], amax[j]), (tau, tau_keep[:, j], tmax[j])):
                    idx = np.flatnonzero(keep)
                    if idx.size:
                        add(expr[idx.tolist()] / limit, -1.0, 1.0)
                        kept += idx.size
        h = 2.0 * ds / (si + sj)
        duration = ca.sum1(h)
        cost = problem.k1 * duration
        if problem.k2 > 0.0:
            sq = [ca.sum2(ca.horzcat(*torques[k * N_JOINTS:(k + 1) * N_JOINTS]) ** 2) for k in range(3)]
            energy = ca.sum1(h * (sq[0] + 4.0 * sq[1] + sq[2]) / 6.0)
            cost = cost + problem.k2 * energy
        x0 = self._b_initial_guess(problem, sigma, nodes, b_scale)
        cost_fun = ca.Function("cost", [x], [cost])
        cost_ref = max(float(cost_fun(x0)), 1e-9)
        nlp = {"x": x, "f": cost / cost_ref, "g": ca.vertcat(*rows)}
        solver = ca.nlpsol("own_cp_b", "ipopt", nlp, self.ipopt_options)
        lbx = np.zeros(n + 1)
        ubx = np.ones(n + 1)
        ubx[0] = ubx[-1] = 0.0
        build = time.perf_counter() - t0
        t1 = time.perf_counter()
        sol = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=np.concatenate(lbg), ubg=np.concatenate(ubg))
        solve = time.perf_counter() - t1
        stats = solver.stats()
        ipopt_status = str(stats.get("return_status", "unknown"))
        bsol = np.maximum(np.asarray(sol["x"]).ravel(), 0.0) * b_scale
        bsol[0] = bsol[-1] = 0.0
        status = _status_of(ipopt_status)
        with np.errstate(divide="ignore", invalid="ignore"):
            law = TimeLaw.constant_acceleration(sigma, bsol)
        if status.has_trajectory and not np.isfinite(law.duration):
            status, ipopt_status = PlanStatus.FAILED, f"{ipopt_status} (but the motion stops on the path: infinite duration)"
        info = {"sigma": sigma, "b": bsol, "constraint_rows": kept + n, "sigma_dot": np.sqrt(bsol), "duration_grid_s": law.duration,
                "iterations": int(stats.get("iter_count", -1)), "ipopt_status": ipopt_status,
                "cost": float(sol["f"]) * cost_ref, "law": law, "transcription": "b"}
        return PlanResult(self.name, status, None, solve, build, message=ipopt_status, info=info)

    def _b_initial_guess(self, problem: CPProblem, sigma: np.ndarray, nodes: PathDynamics,
                         b_scale: np.ndarray) -> np.ndarray:
        """A cheap interior guess: the velocity bound, capped by an acceleration-feasible
        ramp from both ends, times 0.5."""
        lim = problem.limits
        with np.errstate(divide="ignore", invalid="ignore"):
            a_bound = np.min(lim.acceleration / (np.abs(nodes.dq) + np.abs(nodes.ddq) * 0.0 + 1e-12), axis=1)
        alpha = 0.25 * float(np.min(a_bound))
        ramp = 2.0 * alpha * np.minimum(sigma, 1.0 - sigma)
        guess = 0.5 * np.minimum(b_scale, ramp) / b_scale
        return np.clip(guess, 0.0, 1.0)

    # --------------------------------------------------------- smooth form
    def _solve_smooth(self, problem: CPProblem, sigma: np.ndarray, nodes: PathDynamics,
                      warm: PlanResult) -> PlanResult:
        t0 = time.perf_counter()
        lim = problem.limits
        n = sigma.size - 1
        ds = np.diff(sigma)
        law: TimeLaw = warm.info["law"]
        s_ref = np.sqrt(np.minimum(np.min((lim.velocity / np.maximum(np.abs(nodes.dq), 1e-12)) ** 2, axis=1), 1e6))
        a_ref = float(np.median(np.abs(law.a))) + 1e-3
        h_ref = float(np.mean(np.diff(law.t)))
        xs = ca.SX.sym("s", n + 1)
        xa = ca.SX.sym("a", n + 1)
        xh = ca.SX.sym("h", n)
        s = xs * ca.DM(s_ref)
        a = xa * a_ref
        h = xh * h_ref
        rows, lbg, ubg = [], [], []

        def add(expr, lo, hi):
            rows.append(expr)
            lbg.append(np.broadcast_to(lo, (expr.shape[0],)))
            ubg.append(np.broadcast_to(hi, (expr.shape[0],)))

        si, sj, ai, aj = s[:-1], s[1:], a[:-1], a[1:]
        add((sj - si - h * (ai + aj) / 2.0) / ca.DM(s_ref[1:]), 0.0, 0.0)
        add((si * h + h**2 * (2.0 * ai + aj) / 6.0 - ca.DM(ds)) / ca.DM(ds), 0.0, 0.0)
        jerk = (aj - ai) / h
        k = 1.0 - self.smooth_margin
        s2 = s * s
        s3 = s2 * s
        nd = nodes
        for j in range(N_JOINTS):
            dq, ddq, dddq = (ca.DM(arr[:, j]) for arr in (nd.dq, nd.ddq, nd.dddq))
            m, c, g, v, fc = (ca.DM(arr[:, j]) for arr in (nd.m, nd.c, nd.g, nd.v, nd.fc))
            dm, dc, dg, dv = (ca.DM(arr[:, j]) for arr in (nd.dm, nd.dc, nd.dg, nd.dv))
            add((dq * a + ddq * s2) / lim.acceleration[j], -k, k)
            add((m * a + c * s2 + g + v * s + fc) / lim.torque[j], -k, k)
            for side, jj in (("left", slice(1, n + 1)), ("right", slice(0, n))):
                jk = jerk
                sk, ak = s[jj], a[jj]
                if np.isfinite(lim.jerk[j]):
                    qddd = dq[jj] * jk + 3.0 * ddq[jj] * sk * ak + dddq[jj] * s3[jj]
                    add(qddd / lim.jerk[j], -k, k)
                if np.isfinite(lim.torque_rate[j]):
                    taud = (m[jj] * jk + (dm[jj] + 2.0 * c[jj]) * sk * ak + dc[jj] * s3[jj] + dg[jj] * sk
                            + dv[jj] * s2[jj] + v[jj] * ak)
                    add(taud / lim.torque_rate[j], -k, k)
        duration = ca.sum1(h)
        cost = problem.k1 * duration
        if problem.k2 > 0.0:
            tau_sq = 0
            for j in range(N_JOINTS):
                tau_j = (ca.DM(nd.m[:, j]) * a + ca.DM(nd.c[:, j]) * s2 + ca.DM(nd.g[:, j] + nd.fc[:, j])
                         + ca.DM(nd.v[:, j]) * s)
                tau_sq = tau_sq + tau_j**2
            cost = cost + problem.k2 * ca.sum1(h * (tau_sq[:-1] + tau_sq[1:]) / 2.0)
        x = ca.vertcat(xs, xa, xh)
        # warm start from the b solution: s, a smoothed, h
        s0 = law.s
        a_nodes = np.concatenate([[0.0], 0.5 * (law.a[:-1] + law.a[1:]), [0.0]])
        h0 = np.diff(law.t)
        x0 = np.concatenate([s0 / s_ref, a_nodes / a_ref, h0 / h_ref])
        cost_fun = ca.Function("cost", [x], [cost])
        cost_ref = max(float(cost_fun(x0)), 1e-9)
        g_all = ca.vertcat(*rows)
        lbg_all = np.concatenate(lbg)
        ubg_all = np.concatenate(ubg)
        nlp = {"x": x, "f": cost / cost_ref, "g": g_all}
        solver = ca.nlpsol("own_cp_smooth", "ipopt", nlp, self.ipopt_options)
        lbx = np.concatenate([np.zeros(n + 1), -np.inf * np.ones(n + 1), 1e-6 * np.ones(n)])
        ubx = np.concatenate([np.full(n + 1, k), np.inf * np.ones(n + 1), np.inf * np.ones(n)])
        lbx[0] = ubx[0] = lbx[n] = ubx[n] = 0.0  # s_0 = s_n = 0
        lbx[n + 1] = ubx[n + 1] = lbx[2 * n + 1] = ubx[2 * n + 1] = 0.0  # a_0 = a_n = 0
        build = time.perf_counter() - t0
        t1 = time.perf_counter()
        sol = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=lbg_all, ubg=ubg_all)
        solve = time.perf_counter() - t1
        stats = solver.stats()
        ipopt_status = str(stats.get("return_status", "unknown"))
        xv = np.asarray(sol["x"]).ravel()
        s_sol = np.maximum(xv[: n + 1] * s_ref, 0.0)
        a_sol = xv[n + 1: 2 * n + 2] * a_ref
        h_sol = xv[2 * n + 2:] * h_ref
        t_nodes = np.concatenate([[0.0], np.cumsum(h_sol)])
        law_s = TimeLaw(t_nodes, sigma, s_sol, a_sol[:-1], np.diff(a_sol) / h_sol)
        info = {"sigma": sigma, "sigma_dot": s_sol, "sigma_ddot": a_sol, "duration_grid_s": law_s.duration,
                "iterations": int(stats.get("iter_count", -1)), "ipopt_status": ipopt_status,
                "cost": float(sol["f"]) * cost_ref, "law": law_s, "transcription": "smooth"}
        return PlanResult(self.name, _status_of(ipopt_status), None, solve, build, message=ipopt_status, info=info)

    # -------------------------------------------------------------- output
    def _finish(self, problem: CPProblem, dyn: RobotDynamics, res: PlanResult, mode: str) -> PlanResult:
        res.info["transcription"] = mode
        if res.status.has_trajectory:
            res.trajectory = trajectory_from_time_law(problem.path, res.info["law"], dyn, dt=self.output_dt, metadata={
                "planner": self.name, "status": res.status.value, "solve_time_s": res.solve_time_s,
                "ipopt_status": res.message, "transcription": mode, "k1": problem.k1, "k2": problem.k2})
        return res
