"""Kinematics benchmark: warm-started numeric IK (the 400 us controller's call), analytic
IK, batched FK / identification Jacobian, and the uncalibrated error magnitudes.

Run: ``python benchmarks/bench_ik.py`` (about 20 s). Target: warm-started
``NumericIK.solve`` median < 30 us with the previous cycle's solution as seed.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import pinocchio as pin

from robot.geometric_errors import default_error_model, error_model, random_geometric_errors
from robot.inverse_kinematics import AnalyticIK, NumericIK
from robot.kinematics import FlangeKinematics, pose_error, pose_from_transform

CYCLE_S = 400e-6
TARGET_MEDIAN_US = 30.0


def joint_trajectory(kin: FlangeKinematics, duration_s: float, speed_scale: float) -> np.ndarray:
    """Smooth multi-sine joint motion inside the limits sampled every 400 us (rad)."""
    t = np.arange(0.0, duration_s, CYCLE_S)[:, None]
    centre = np.array([0.2, 0.3, 0.9, 0.4, 0.8, -0.3])
    amplitude = np.array([1.2, 0.6, 0.7, 1.5, 0.6, 2.0])
    omega = speed_scale * np.array([0.9, 1.3, 1.1, 1.7, 2.1, 2.5])
    q = centre + amplitude * np.sin(omega * t + np.arange(6))
    assert np.all(q > kin.lower) and np.all(q < kin.upper)
    return q


def time_warm_ik(solver: NumericIK, targets: list[pin.SE3], q0: np.ndarray, predict: bool):
    times = np.empty(len(targets))
    steps = np.empty(len(targets), dtype=int)
    q_prev = q0.copy()
    q_prev2 = q0.copy()
    out = np.empty((len(targets), 6))
    clock = time.perf_counter_ns
    for k, target in enumerate(targets):
        seed = 2.0 * q_prev - q_prev2 if predict else q_prev
        t0 = clock()
        q = solver.solve(target, seed)
        times[k] = (clock() - t0) * 1e-3
        steps[k] = solver.last_iterations
        out[k] = q
        q_prev2, q_prev = q_prev, q
    return times, steps, out


def report(label: str, times_us: np.ndarray) -> None:
    p50, p90, p99 = np.percentile(times_us, [50, 90, 99])
    print(f"  {label:<58s} median {p50:7.1f} us  p90 {p90:7.1f}  p99 {p99:7.1f}  max {times_us.max():8.1f}")


def bench_numeric_ik(duration_s: float) -> None:
    print("Warm-started numeric IK along a 400 us trajectory (seed = previous solution)")
    nominal = FlangeKinematics()
    for speed_scale in (0.5, 1.0):
        q_ref = joint_trajectory(nominal, duration_s, speed_scale)
        qd = np.abs(np.diff(q_ref, axis=0)).max(axis=0) / CYCLE_S
        for name, model in (("nominal", None), ("with errors (seed 1)", error_model(random_geometric_errors(1)))):
            solver = NumericIK(model)
            transforms = solver.kinematics.transforms(q_ref)
            targets = [pin.SE3(t) for t in transforms]
            flange_speed = np.linalg.norm(np.diff(transforms[:, :3, 3], axis=0), axis=1).max() / CYCLE_S
            for predict in (False, True):
                time_warm_ik(solver, targets[:200], q_ref[0], predict)  # warm up
                times, steps, out = time_warm_ik(solver, targets, q_ref[0], predict)
                err = pose_error(solver.kinematics.transforms(out), transforms)
                seed_kind = "seed 2q[k-1]-q[k-2]" if predict else "seed q[k-1]"
                report(f"{name}, peak {flange_speed:.1f} m/s, {seed_kind}", times)
                hist = np.bincount(steps[steps >= 0], minlength=4)
                print(
                    f"    calls with 0/1/2/3 Newton steps: {'/'.join(str(h) for h in hist[:4])}, "
                    f"fallbacks {int(np.sum(steps < 0))}, "
                    f"max |dx| {np.abs(err[:, :3]).max():.1e} m, {np.abs(err[:, 3:]).max():.1e} rad, "
                    f"peak joint speed {qd.max():.2f} rad/s"
                )
    print(f"  target: median < {TARGET_MEDIAN_US:.0f} us")


def bench_other(n_poses: int) -> None:
    nominal = FlangeKinematics()
    rng = np.random.default_rng(0)
    qs = rng.uniform(nominal.lower, nominal.upper, (n_poses, 6))
    transforms = nominal.transforms(qs)
    print("Other kinematics calls")
    analytic = AnalyticIK()
    t = []
    for k in range(2000):
        t0 = time.perf_counter_ns()
        analytic.nearest(transforms[k], qs[k])
        t.append((time.perf_counter_ns() - t0) * 1e-3)
    report("AnalyticIK.nearest (one pose, all 8 branches)", np.array(t))
    t0 = time.perf_counter()
    analytic.solve_batch(transforms[:, :3, 3], transforms[:, :3, :3])
    print(f"  AnalyticIK.solve_batch, {n_poses} poses: {(time.perf_counter() - t0) * 1e3:.1f} ms")
    solver = NumericIK(error_model(random_geometric_errors(1)))
    far = np.zeros(6)
    t = []
    for k in range(200):
        t0 = time.perf_counter_ns()
        solver.solve_nearest(transforms[k], far)
        t.append((time.perf_counter_ns() - t0) * 1e-3)
    report("NumericIK.solve_nearest, error model, cold (all branches)", np.array(t))
    t = []
    for k in range(min(5000, n_poses)):
        t0 = time.perf_counter_ns()
        nominal.transform(qs[k])
        t.append((time.perf_counter_ns() - t0) * 1e-3)
    report("FlangeKinematics.transform (pinocchio)", np.array(t))
    t = []
    for k in range(min(5000, n_poses)):
        t0 = time.perf_counter_ns()
        nominal.jacobian(qs[k])
        t.append((time.perf_counter_ns() - t0) * 1e-3)
    report("FlangeKinematics.jacobian (pinocchio)", np.array(t))
    errors = random_geometric_errors(1)
    model = default_error_model()
    for label, call in (
        ("FlangeKinematics.jacobians, 4000 configurations", lambda: nominal.jacobians(qs[:4000])),
        ("identification_jacobian, 4000 configurations", lambda: model.identification_jacobian(qs[:4000], errors)),
    ):
        runs = []
        for _ in range(5):
            t0 = time.perf_counter()
            call()
            runs.append(time.perf_counter() - t0)
        print(f"  {label}: median {np.median(runs) * 1e3:.1f} ms")


def bench_error_magnitudes(n_seeds: int) -> None:
    print("Uncalibrated flange errors of random error sets (paper Table 2: 7.8, 19.0, 12.6 mm; 1.1, 1.8, 1.2 deg)")
    nominal = FlangeKinematics()
    qs = np.random.default_rng(123).uniform(nominal.lower, nominal.upper, (4000, 6))
    t_nom = nominal.transforms(qs)
    cardan_nom = pose_from_transform(t_nom)
    upright = np.abs(cardan_nom[:, 4]) < np.radians(45)
    rows = []
    for seed in range(n_seeds):
        t_err = default_error_model().flange_transforms(qs, random_geometric_errors(seed))
        dp = np.abs(t_err[:, :3, 3] - t_nom[:, :3, 3]).max(axis=0) * 1e3
        da = pose_from_transform(t_err)[upright, 3:] - cardan_nom[upright, 3:]
        rows.append(np.r_[dp, np.degrees(np.abs(np.angle(np.exp(1j * da))).max(axis=0))])
    rows = np.array(rows)
    for label, row in (("median", np.median(rows, 0)), ("min", rows.min(0)), ("max", rows.max(0))):
        print(
            f"  {label:<6s} max|e_x|,|e_y|,|e_z| = {row[0]:5.1f} {row[1]:5.1f} {row[2]:5.1f} mm   "
            f"max|e_alpha|,|e_beta|,|e_gamma| = {row[3]:4.2f} {row[4]:4.2f} {row[5]:4.2f} deg"
        )
    print(f"  ({n_seeds} seeds, 4000 random configurations, angles where |beta| < 45 deg)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="shorter runs")
    args = parser.parse_args()
    bench_numeric_ik(duration_s=1.0 if args.quick else 4.0)
    bench_other(n_poses=4000 if args.quick else 10000)
    bench_error_magnitudes(n_seeds=10 if args.quick else 30)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
