"""Cost per step of running an FMU out of process (cosim/master/proxy.py) against in process.

Run: ``python benchmarks/bench_out_of_process.py`` (about 1 min). For the project's plant FMU
(rx130l_plant, one RK4 step per 100 us macro step, zero torques) and the servo-drive FMU, it
times ``Master.run`` over ``--steps`` base steps in process (compiled kernel) and out of
process, ``--repeats`` times each, and prints the medians in microseconds per step and the
extra cost of isolation; the load average is printed with them (the machine may be loaded).
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

from cosim.master import Master
from fmus.build import ensure_fmus


def time_run(path, steps: int, base_step: float, out_of_process: bool, start_values: dict) -> float:
    """Wall seconds of ``Master.run`` over ``steps`` base steps (initialization excluded)."""
    master = Master(base_step)
    master.add_fmu("fmu", path, start_values=start_values, out_of_process=out_of_process)
    try:
        master.initialize(steps * base_step)
        t0 = time.perf_counter()
        master.run()
        return time.perf_counter() - t0
    finally:
        master.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    fmus = ensure_fmus()
    cases = [("rx130l_plant", fmus["rx130l_plant"], 1e-4, {"integration_step": 1e-4}),
             ("servo_drive", fmus["servo_drive"], 1e-4, {})]
    print(f"load average before: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"{'FMU':14s} {'in process us/step':>20s} {'out of process us/step':>24s} {'extra us/step':>14s} {'ratio':>7s}")
    for name, path, base, start in cases:
        inside = [time_run(path, args.steps, base, False, start) / args.steps * 1e6 for _ in range(args.repeats)]
        outside = [time_run(path, args.steps, base, True, start) / args.steps * 1e6 for _ in range(args.repeats)]
        a, b = statistics.median(inside), statistics.median(outside)
        print(f"{name:14s} {a:20.2f} {b:24.2f} {b - a:14.2f} {b / a:7.1f}")
    print(f"load average after: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
