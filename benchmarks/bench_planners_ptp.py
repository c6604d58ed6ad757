"""Benchmark of the PtP planners on the paper line: solve times, durations,
constraint ratios, the energy-weighting table and Figure 9.

Run: ``python benchmarks/bench_planners_ptp.py [--repeats N] [--out DIR] [--quick]``.
Prints medians over N repeats of the solver wall time (``solve_time_s``: warm start +
IPOPT calls; problem building reported separately) and of the process CPU time of
``plan`` (more robust when the machine is shared). Targets: own PtP (eq. 40, 100
intervals) solved in <= 5 s (the paper's MUSCOD-II: about 3 minutes), duration <= 0.7 x
own CP duration and shorter than ruckig_feasible, max_constraint_ratio <= 1.001.
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MPLBACKEND", "Agg")

from planners.cp_optimal import OwnCPPlanner  # noqa: E402
from planners.paper_line import paper_cp_problem  # noqa: E402
from planners.ptp_figures import plot_ptp_torques_velocities  # noqa: E402
from planners.ptp_nodes import node_functions  # noqa: E402
from planners.ptp_optimal import OptimalPtPPlanner, paper_ptp_problem  # noqa: E402
from planners.report import energy_table, planner_summary  # noqa: E402
from planners.ruckig_baseline import FeasibleRuckigPlanner, RuckigPlanner  # noqa: E402
from planners.toppra_baseline import ToppraPlanner  # noqa: E402
from robot.dynamics import RobotDynamics  # noqa: E402
from robot.symbolic import chain_structure  # noqa: E402


def _runs(planner, problem, repeats):
    """(last result, median solve wall time, median plan CPU time, median plan wall time)."""
    results, cpu, wall = [], [], []
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        results.append(planner.plan(problem))
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return (results[-1], statistics.median(r.solve_time_s for r in results), statistics.median(cpu),
            statistics.median(wall))


def _line(name, res, summary, solve, cpu, extra=""):
    if summary["duration_s"] is None:
        return f"  {name:16s}: {res.status.value:10s} {res.message[:60]}"
    return (f"  {name:16s}: {res.status.value:9s} duration {summary['duration_s']:.4f} s  "
            f"ratio {summary['max_constraint_ratio']:.4f}  energy {summary['energy']:.4g}  "
            f"solve median {solve:.3f} s  cpu median {cpu:.3f} s{extra}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path("results") / "planners_ptp")
    parser.add_argument("--quick", action="store_true", help="skip the N, regularisation and continuation studies")
    args = parser.parse_args()
    print(f"load average at start: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    dyn = RobotDynamics()

    print("\n== node library (per-node functions with exact Jacobian/Hessian, gcc) ==")
    t0 = time.perf_counter()
    nodes = node_functions(chain_structure())
    print(f"  load (cached library) {time.perf_counter() - t0:.3f} s: {nodes.library}")
    if not args.quick:
        from planners import ptp_nodes

        with tempfile.TemporaryDirectory() as tmp:
            build_dirs = ptp_nodes._build_dirs
            ptp_nodes._build_dirs = lambda: [Path(tmp)]
            ptp_nodes._LOADED.clear()
            t0 = time.perf_counter()
            fresh = node_functions(chain_structure())
            print(f"  fresh symbolic build + compile ({' '.join(ptp_nodes.CFLAGS[:1])}): "
                  f"{time.perf_counter() - t0:.1f} s (compiled: {fresh.compiled})")
            ptp_nodes._build_dirs = build_dirs
            ptp_nodes._LOADED.clear()

    print("\n== the CP reference on the paper line ==")
    cp_problem = paper_cp_problem(dynamics=dyn)
    cp = OwnCPPlanner().plan(cp_problem)
    cp_summary = planner_summary(cp, cp_problem.limits, dyn)
    top_problem = paper_cp_problem(dynamics=dyn, kinematic_only_limits=True)
    top = ToppraPlanner().plan(top_problem)
    top_summary = planner_summary(top, top_problem.limits, dyn)
    print(f"  own_cp (all limits)           : {cp.status.value} duration {cp_summary['duration_s']:.4f} s")
    print(f"  toppra (vel/acc/torque, eq.38): {top.status.value} duration {top_summary['duration_s']:.4f} s")

    print("\n== PtP, paper eq. 40 limits (torque, torque rate, velocity, position), 100 intervals ==")
    problem = paper_ptp_problem(dynamics=dyn)
    OptimalPtPPlanner().plan(problem)  # first call builds the NLP
    rows = {}
    for planner in (RuckigPlanner(), FeasibleRuckigPlanner(), OptimalPtPPlanner()):
        res, solve, cpu, wall = _runs(planner, problem, args.repeats)
        summary = planner_summary(res, problem.limits, dyn)
        rows[planner.name] = (res, summary)
        extra = ""
        if planner.name == "own_ptp":
            extra = (f"  wall median {wall:.3f} s  iterations {[a['iterations'] for a in res.info['attempts']]}"
                     f"  warm start {res.info['warm_start_time_s']:.3f} s")
        if planner.name == "ruckig_feasible":
            extra = f"  scale {res.info['scale']:.4f}"
        print(_line(planner.name, res, summary, solve, cpu, extra))
    own = rows["own_ptp"][1]["duration_s"]
    print(f"  own_ptp / own_cp        = {own / cp_summary['duration_s']:.3f}  (target <= 0.7; paper 0.67/1.04 = 0.644)")
    print(f"  own_ptp / toppra CP     = {own / top_summary['duration_s']:.3f}")
    print(f"  own_ptp / ruckig_feasible = {own / rows['ruckig_feasible'][1]['duration_s']:.3f}  (target < 1)")
    path = plot_ptp_torques_velocities(rows["own_ptp"][0].trajectory, problem.limits, args.out / "figure9.png", dyn)
    print(f"  Figure 9: {path}")

    print("\n== PtP keeping every robot limit (acceleration and jerk too), 100 intervals ==")
    problem_all = paper_ptp_problem(dynamics=dyn, paper_limits=False)
    for planner in (RuckigPlanner(), FeasibleRuckigPlanner(), OptimalPtPPlanner()):
        res, solve, cpu, _ = _runs(planner, problem_all, 1)
        print(_line(planner.name, res, planner_summary(res, problem_all.limits, dyn), solve, cpu))

    print("\n== energy weighting (eq. 40 limits, 100 intervals, k1 = 1) ==")
    sweep = []
    for k2 in (0.0, 1e-7, 1e-6, 1e-5, 3e-5, 1e-4):
        res = OptimalPtPPlanner().plan(paper_ptp_problem(dynamics=dyn, k2=k2))
        sweep.append((k2, res))
    print(energy_table(sweep))

    if not args.quick:
        print("\n== number of intervals (eq. 40) ==")
        for n in (50, 100, 150):
            res, solve, cpu, _ = _runs(OptimalPtPPlanner(), paper_ptp_problem(dynamics=dyn, n_intervals=n), 1)
            s = planner_summary(res, problem.limits, dyn)
            print(_line(f"N = {n}", res, s, solve, cpu,
                        f"  iterations {[a['iterations'] for a in res.info['attempts']]}  build {res.build_time_s:.2f} s"))
        print("\n== jerk regularisation and Coulomb continuation (eq. 40, 100 intervals) ==")
        variants = {
            "default (1e-5, (10,))": OptimalPtPPlanner(),
            "no regularisation": OptimalPtPPlanner(jerk_regularisation=0.0),
            "no continuation": OptimalPtPPlanner(coulomb_continuation=()),
        }
        for name, planner in variants.items():
            res, solve, cpu, _ = _runs(planner, problem, 1)
            s = planner_summary(res, problem.limits, dyn)
            print(_line(name, res, s, solve, cpu, f"  iterations {[a['iterations'] for a in res.info['attempts']]}"))
        print("\n== random PtP problems (eq. 40 limits, positions in 80 % of the ranges, N = 100, seed 7) ==")
        import numpy as np

        from planners.base import PtPProblem
        from planners.ptp_optimal import eq40_limits

        limits = eq40_limits()
        rng = np.random.default_rng(7)
        for i in range(6):
            q0 = rng.uniform(0.8 * limits.position_lower, 0.8 * limits.position_upper)
            qe = rng.uniform(0.8 * limits.position_lower, 0.8 * limits.position_upper)
            random_problem = PtPProblem(q0, qe, limits, dynamics=dyn)
            res, solve, cpu, _ = _runs(OptimalPtPPlanner(), random_problem, 1)
            tuned = FeasibleRuckigPlanner().plan(random_problem)
            s = planner_summary(res, limits, dyn)
            ratio = (f"  / ruckig_feasible {s['duration_s'] / tuned.trajectory.duration:.3f}"
                     if res.ok and tuned.ok else "")
            print(_line(f"problem {i}", res, s, solve, cpu,
                        f"  iterations {[a['iterations'] for a in res.info['attempts']]}{ratio}"))
    print(f"\nload average at end: {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
