"""Calibration benchmark: candidate grid, optimal configuration selection, index ratios.

Run: ``python benchmarks/bench_calibration.py`` (about 1-2 min; ``--quick`` for ~20 s).
Targets (issue 7): selecting 32 of about 4,000 candidates in at most 10 s (paper: about
five minutes), observation index at least 18.5 times a linear scan of the same size.

Prints, for the campaign's candidate set (13^6 grid, default tracker: 3,680 visible)
and a 4,000-candidate set (looser tracker, thinned evenly), the median wall and CPU
time of a 5-restart selection, the per-sweep cost of the bounded exact search against
a brute-force sweep (one p x p eigenvalue problem per candidate), and the index ratios
against the linear scan, the median random selection and all candidates.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from identification.calibration_candidates import visible_candidates
from identification.calibration_config_selection import (
    _Search,
    linear_scan_indices,
    random_selection_values,
    select_configurations,
)
from identification.calibration_identifiability import identifiable_parameters
from identification.calibration_observability import OBSERVATION_INDICES, get_index, observation_index
from identification.calibration_tracker import TrackerNoise, TrackerSetup
from robot.geometric_errors import default_error_model

TARGET_TIME_S = 10.0
TARGET_RATIO = 18.5


def selection_problem(setup: TrackerSetup, max_candidates: int | None, orientation: bool = True,
                      values_per_axis: int | None = None):
    """Noise-weighted, column-normalised identifiable Jacobians of the visible candidates
    (``values_per_axis``: grid values per joint, default the campaign's)."""
    grid = {} if values_per_axis is None else {"values_per_axis": values_per_axis}
    cands = visible_candidates(setup, max_candidates=max_candidates, **grid)
    model = default_error_model()
    rows = 6 if orientation else 3
    jac = model.identification_jacobian(cands.q)[:, :rows] / TrackerNoise().row_sigmas(orientation)[None, :, None]
    report = identifiable_parameters(jac, list(model.parameter_names))
    theta = jac[:, :, report.identifiable]
    theta = theta / np.sqrt(np.sum(theta**2, axis=(0, 1)) / theta.shape[0])
    return cands, theta


def time_selection(theta: np.ndarray, index: str, repeats: int, restarts: int):
    walls, cpus, results = [], [], []
    for seed in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        res = select_configurations(theta, 32, index=index, restarts=restarts, seed=seed)
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
        results.append(res)
    return np.median(walls), np.median(cpus), results


def sweep_costs(theta: np.ndarray, index: str) -> tuple[float, float]:
    """Median time of one best-addition sweep: bounded exact search vs brute force (s)."""
    search = _Search(theta, get_index(index))
    rng = np.random.default_rng(0)
    bounded, brute = [], []
    for _ in range(5):
        subset = rng.choice(theta.shape[0], 31, replace=False)
        lam = search.information(subset)
        excluded = np.zeros(theta.shape[0], dtype=bool)
        excluded[subset] = True
        t0 = time.perf_counter()
        j, _ = search.best_addition(lam, excluded)
        bounded.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        vals = search.index.value(np.linalg.eigvalsh(lam[None] + search.gram))
        vals[excluded] = -np.inf
        brute.append(time.perf_counter() - t0)
        assert int(np.argmax(vals)) == j
    return float(np.median(bounded)), float(np.median(brute))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one repeat, min_eigenvalue only")
    args = parser.parse_args()
    repeats = 1 if args.quick else 3

    t0 = time.perf_counter()
    cands = visible_candidates(TrackerSetup())
    print(f"candidate grid 13^6 = {cands.n_grid}: {cands.n_visible} visible, "
          f"{time.perf_counter() - t0:.2f} s (vectorised FK by composition)")

    sets = {
        "campaign set (default tracker)": (TrackerSetup(), None),
        "4000 set (25/30 deg tracker, thinned)": (TrackerSetup(fov_half_angle_deg=25.0, probe_max_angle_deg=30.0), 4000),
    }
    indices = ["min_eigenvalue"] if args.quick else list(OBSERVATION_INDICES)
    for label, (setup, max_c) in sets.items():
        cands, theta = selection_problem(setup, max_c)
        n, k, p = theta.shape
        print(f"\n{label}: N = {n} candidates, k = {k} rows, p = {p} identifiable parameters")
        bounded, brute = sweep_costs(theta, "min_eigenvalue")
        print(f"  one best-addition sweep (min_eigenvalue): bounded exact {bounded * 1e3:.1f} ms, "
              f"brute force {brute * 1e3:.1f} ms ({brute / bounded:.0f}x)")
        for index in indices:
            wall, cpu, results = time_selection(theta, index, repeats, restarts=5)
            best = max(results, key=lambda r: r.index_value)
            lin = observation_index(theta[linear_scan_indices(n, 32)], index)
            rnd = np.median(random_selection_values(theta, 32, index=index, draws=200))
            full = observation_index(theta, index)
            ok_time = "ok" if wall <= TARGET_TIME_S else "MISSED"
            ok_ratio = "ok" if best.index_value / lin >= TARGET_RATIO else "MISSED"
            print(f"  {index:20s} 32 of {n}, 5 restarts: median wall {wall:5.2f} s, CPU {cpu:5.2f} s "
                  f"[{ok_time} <= {TARGET_TIME_S:g} s]; exchanges {best.exchanges}, exact eig "
                  f"{best.exact_evaluations}, Ritz {best.ritz_evaluations}")
            print(f"  {'':20s} ratio vs linear scan {best.index_value / lin:6.2f} [{ok_ratio} >= {TARGET_RATIO}], "
                  f"vs median random {best.index_value / rnd:6.2f}, all {n} candidates / selected "
                  f"{full / best.index_value:6.1f}; restarts {np.round(best.restart_values, 4).tolist()}")


if __name__ == "__main__":
    main()
