"""Dynamic identification figures: base parameters, optimal excitation, identification speed.

    python benchmarks/bench_identification.py            # full problem (order 5, k = 80): ~2-5 min
    python benchmarks/bench_identification.py --quick    # reduced problem only

Prints:
1. the QR base-parameter analysis (count, gap, time);
2. the optimal exciting trajectory of eq. 30 for the paper's settings (order 5,
   omega_f = 0.8 rad/s, k = 80, SLSQP on the exact log condition number) against
   random feasible series of the same order: condition numbers, ratio, solve time,
   iterations, feasibility on a 2000-point grid;
3. solver comparison on a reduced problem (order 2, k = 30) from the same start:
   SLSQP on the exact objective vs IPOPT on the smooth A-optimality surrogate;
4. identification speed (median of 3): regressor, least squares, on a 20 s record;
5. the campaign's gear-stiffness step (median of 3) on one averaged 7.854 s period read by the
   tracker every 1 ms (7854 readings, every 2nd used; stiffness and damping, 3 Gauss-Newton
   passes), with its errors against the synthetic truth.
"""
from __future__ import annotations

import argparse
import statistics
import time

import numpy as np


def _median_time(fn, repeats: int = 3) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_base() -> None:
    from identification.base_parameters import compute_base_parameters

    wall = _median_time(compute_base_parameters)
    base = compute_base_parameters()
    print(f"[base] {base.count} base parameters of 78; pivot gap {base.gap:.2g}; kappa residual "
          f"{base.kappa_residual:.1e}; QR of {6 * base.n_states} x 78 in {wall * 1e3:.0f} ms (median of 3)")


def bench_full_design(seed: int, baselines: int) -> None:
    from identification.excitation import ExcitationProblem, design_excitation

    problem = ExcitationProblem()
    result = design_excitation(problem, seed=seed, random_baselines=baselines)
    conds = np.array(result.random_condition_numbers)
    f = result.feasibility
    print(f"[excitation, order {result.settings.order}, k {result.settings.samples}, omega_f "
          f"{result.settings.omega_f} rad/s] optimised cond {result.condition_number:.3g} "
          f"(cond of Theta^T Theta {result.condition_number ** 2:.3g}); random feasible series ({conds.size}): "
          f"median {np.median(conds):.3g}, best {conds.min():.3g}, worst {conds.max():.3g}; improvement "
          f"{result.improvement_over_random:.1f}x over the median, {conds.min() / result.condition_number:.1f}x over "
          f"the best")
    print(f"             SLSQP {result.iterations} iterations, {result.function_evaluations} evaluations, "
          f"{result.solve_time_s:.1f} s ({result.status}); fine-grid ratios: position {f.position:.3f}, velocity "
          f"{f.velocity:.3f}, acceleration {f.acceleration:.3f}, torque {f.torque:.3f}, TCP outside "
          f"{f.tcp_violation_m * 1e3:.2f} mm -> feasible {f.feasible}")


def bench_solvers(seed: int) -> None:
    from identification.excitation import (ExcitationProblem, ExcitationSettings, optimise_excitation,
                                                   random_feasible_trajectory)
    from identification.excitation_ipopt import optimise_excitation_ipopt

    problem = ExcitationProblem(settings=ExcitationSettings(order=2, samples=30, constraint_samples=40,
                                                            max_iterations=100))
    x0 = random_feasible_trajectory(problem, np.random.default_rng(seed))
    start = problem.condition_number(x0)
    x_s, res, wall_s, _ = optimise_excitation(problem, x0)
    x_i, stats = optimise_excitation_ipopt(problem, x0, max_iterations=100)
    print(f"[solvers, order 2, k 30, same start cond {start:.3g}] SLSQP exact log-cond: cond "
          f"{problem.condition_number(x_s):.3g} in {wall_s:.1f} s ({res.nit} it); IPOPT A-optimality surrogate: cond "
          f"{problem.condition_number(x_i):.3g} in {stats['solve_time_s']:.1f} s ({stats['iterations']} it, "
          f"{stats['status']}, feasible {problem.is_feasible(x_i)})")


def bench_identify(n: int = 5000, repeats: int = 3) -> dict[str, float]:
    """Time the identification of the base parameters from ``n`` samples; returns the medians (s)."""
    from identification.base_parameters import nominal_base_parameters
    from identification.estimation import weighted_least_squares
    from identification.identify import base_regressor

    base = nominal_base_parameters()
    rng = np.random.default_rng(0)
    q, qd, qdd = rng.uniform(-1, 1, (n, 6)), rng.uniform(-2, 2, (n, 6)), rng.uniform(-5, 5, (n, 6))
    t_reg = _median_time(lambda: base_regressor(base, q, qd, qdd), repeats)
    w = base_regressor(base, q, qd, qdd)
    tau = np.einsum("kjn,n->kj", w, rng.normal(size=base.count)) + rng.normal(size=(n, 6)) * 0.1
    t_wls = _median_time(lambda: weighted_least_squares(w, tau, base.base_names), repeats)
    print(f"[identify] base regressor of {n} samples {t_reg:.2f} s ({t_reg / n * 1e6:.0f} us/sample, pinocchio); "
          f"WLS (OLS + 3 weighted passes) on {6 * n} x {base.count}: {t_wls:.2f} s")
    return {"samples": n, "regressor_s": t_reg, "wls_s": t_wls, "identification_s": t_reg + t_wls}


def bench_stiffness(repeats: int = 3) -> dict[str, float]:
    """Time identify_gear_stiffness_periodic on a synthetic periodic record (as the campaign's)."""
    import pinocchio as pin

    from identification.base_parameters import nominal_base_parameters
    from identification.gear_stiffness import identify_gear_stiffness_periodic, link_side_base_values
    from identification.identify import base_regressor
    from identification.signals import periodic_derivatives
    from robot.dynamics import ROTOR_INERTIA_SLICE, RobotDynamics
    from robot.parameters import load_parameters
    from robot.true_robot import make_true_robot

    robot = load_parameters()
    arm = make_true_robot(3, payload=[8.0, 0.02, -0.01, 0.08])
    base = nominal_base_parameters()
    p_b = base.base_values(RobotDynamics(arm.dynamic_parameters, arm.payload).parameter_vector(include_payload=True))
    rotor = np.asarray(arm.dynamic_parameters)[ROTOR_INERTIA_SLICE]
    dt, n = 1e-3, 7854
    t = np.arange(n) * dt
    rng = np.random.default_rng(1)
    th = np.tile([0.0, 0.4, 1.2, 0.0, 0.6, 0.0], (n, 1))
    for j in range(6):
        for h in range(1, 6):
            th[:, j] += rng.uniform(-0.3, 0.3) / h * np.sin(2 * np.pi * h * t / (n * dt) + rng.uniform(0, 6.3))
    th, thd, thdd = periodic_derivatives(th, dt, 8.0)
    link = link_side_base_values(base, p_b, rotor, robot.motor_friction_share)
    tau = np.einsum("kjn,n->kj", base_regressor(base, th, thd, thdd), link)
    model = arm.kinematic_model()
    data, frame, reflector = model.createData(), model.getFrameId("tool0"), np.array([0.10, 0.05, 0.08])
    readings = []
    for q in th - tau / arm.gear_stiffness:
        pin.forwardKinematics(model, data, q)
        readings.append(pin.updateFramePlacement(model, data, frame).act(reflector))
    readings = np.array(readings) + rng.normal(0.0, 2e-6, (n, 3))
    result = {}

    def run():
        result["est"] = identify_gear_stiffness_periodic(
            base, p_b, th, dt, readings, dt, 0.0, model, rotor_inertia=rotor,
            motor_friction_share=robot.motor_friction_share, cutoff_hz=8.0, reflector=reflector, decimate=2)
    wall = _median_time(run, repeats)
    error = 100 * (result["est"].stiffness / arm.gear_stiffness - 1)
    print(f"[stiffness] {n} tracker readings (every 2nd used), stiffness + damping, 3 Gauss-Newton passes: "
          f"{wall:.2f} s (median of {repeats}); stiffness error per axis [%]: "
          + ", ".join(f"{e:+.2f}" for e in error))
    return {"readings": n, "stiffness_s": wall}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="skip the full order-5 design")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--baselines", type=int, default=10)
    args = parser.parse_args()
    bench_base()
    if not args.quick:
        bench_full_design(args.seed, args.baselines)
    bench_solvers(args.seed + 1)
    bench_identify()
    bench_stiffness()


if __name__ == "__main__":
    main()
