"""Benchmark of the CP planners on the paper line: solve times, durations,
constraint ratios, and the energy-weighting table.

Run: ``python benchmarks/bench_planners_cp.py [--repeats N]``. Prints medians over
N repeats (solver call only; problem building reported separately). Target: own CP,
time-optimal, 200 intervals, solved in <= 0.2 s (the paper's MUSCOD-II: 1 s).
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("MPLBACKEND", "Agg")

from planners.base import CPProblem  # noqa: E402
from planners.cp_optimal import OwnCPPlanner  # noqa: E402
from planners.paper_line import paper_cp_problem, paper_line_joint_path  # noqa: E402
from planners.report import energy_table, planner_summary  # noqa: E402
from planners.toppra_baseline import ToppraPlanner  # noqa: E402
from robot.dynamics import RobotDynamics  # noqa: E402


def _median_runs(planner, problem, repeats):
    results = [planner.plan(problem) for _ in range(repeats)]
    return results[-1], statistics.median(r.solve_time_s for r in results), statistics.median(
        r.build_time_s for r in results)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    dyn = RobotDynamics()
    t0 = time.perf_counter()
    paper_line_joint_path()
    print(f"joint path of the paper line (IK, 1001 points): {time.perf_counter() - t0:.3f} s")

    print("\n== time-optimal, velocity/acceleration/torque limits (eq. 38), 200 intervals ==")
    for friction in ("coulomb", "full"):
        problem = paper_cp_problem(dynamics=dyn, friction=friction, kinematic_only_limits=True)
        own, own_solve, own_build = _median_runs(OwnCPPlanner(), problem, args.repeats)
        top, top_solve, top_build = _median_runs(ToppraPlanner(), problem, args.repeats)
        s_own = planner_summary(own, problem.limits, dyn)
        s_top = planner_summary(top, problem.limits, dyn)
        print(f"friction={friction}")
        print(f"  own_cp : {own.message:24s} duration {s_own['duration_s']:.4f} s  ratio {s_own['max_constraint_ratio']:.4f}"
              f"  solve median {own_solve:.3f} s  build median {own_build:.3f} s  iterations {own.info['iterations']}"
              f"  rows {own.info.get('constraint_rows')}")
        print(f"  toppra : {top.message:24s} duration {s_top['duration_s']:.4f} s  ratio {s_top['max_constraint_ratio']:.4f}"
              f"  solve median {top_solve:.3f} s  build median {top_build:.3f} s")
        print(f"  duration own / toppra = {s_own['duration_s'] / s_top['duration_s']:.5f}")

    print("\n== with jerk and torque-rate limits (smooth transcription), friction=full ==")
    problem = paper_cp_problem(dynamics=dyn, friction="full")
    own, own_solve, own_build = _median_runs(OwnCPPlanner(), problem, max(1, args.repeats // 2))
    top = ToppraPlanner().plan(problem)
    s_own = planner_summary(own, problem.limits, dyn)
    s_top = planner_summary(top, problem.limits, dyn)
    print(f"  own_cp : {own.message:24s} duration {s_own['duration_s']:.4f} s  ratios {s_own['constraint_ratios']}"
          f"  solve median {own_solve:.3f} s  build median {own_build:.3f} s")
    print(f"  toppra : duration {s_top['duration_s']:.4f} s  jerk ratio {s_top['constraint_ratios']['jerk']:.1f}"
          f"  torque-rate ratio {s_top['constraint_ratios']['torque_rate']:.2f}")

    print("\n== energy weighting (eq. 38, k1 = 1), friction=full, kinematic-only limits ==")
    base = paper_cp_problem(dynamics=dyn, friction="full", kinematic_only_limits=True)
    rows = []
    for k2 in (0.0, 1e-6, 1e-5, 3e-5, 1e-4):
        res = OwnCPPlanner().plan(CPProblem(base.path, base.limits, dyn, k1=1.0, k2=k2, friction="full"))
        rows.append((k2, res))
    print(energy_table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
