"""Sweep throughput on Dask: variants per minute with 1 and 2 worker processes.

Each variant is a CPU-bound run of the generic ``fmus`` job: scenarios/plant_drop.toml (the
project's rx130l_plant FMU alone, the arm falling under gravity from a bent pose) without
its recorder, ``--sim-time`` simulated seconds at a 200 us macro step (a few seconds of
wall time each). The
variants differ in the start pose. For each worker count an embedded LocalCluster
(one thread per worker process) is started and warmed up (every worker runs one
short scenario with the ordinary runner), then the timed sweep runs every variant anew
(``resume=False``). Worker counts are interleaved over ``--repeats`` rounds; medians
are printed, with the ratio 2 workers / 1 worker (target >= 1.8 on a 2-core machine).

    python benchmarks/bench_sweep.py [--variants 8] [--sim-time 40] [--repeats 2] [--nice -10]
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import textwrap
import time
import tomllib
from pathlib import Path

import tomli_w

ROOT = Path(__file__).resolve().parents[1]


def base_scenario(stop: float) -> str:
    """scenarios/plant_drop.toml run for ``stop`` simulated seconds, without its recorder."""
    with open(ROOT / "scenarios" / "plant_drop.toml", "rb") as f:
        document = tomllib.load(f)
    document["scenario"]["name"] = "bench_drop"
    document["simulation"]["stop_time"] = stop
    del document["record"]
    return tomli_w.dumps(document)


def write_sweep(folder: Path, name: str, stop: float, variants: int) -> Path:
    """A base scenario and a sweep over ``variants`` start angles of joint 2."""
    (folder / f"{name}_base.toml").write_text(base_scenario(stop), encoding="utf-8")
    values = ", ".join(f"{-0.4 + 0.8 * i / max(1, variants - 1):.4f}" for i in range(variants))
    path = folder / f"{name}.toml"
    path.write_text(textwrap.dedent(f"""
        [sweep]
        name = "{name}"
        base = "{name}_base.toml"

        [[axes]]
        key = 'fmus[0].parameters."q0[2]"'
        values = [{values}]
        """), encoding="utf-8")
    return path


def _warm_worker(scenario: str, out_root: str) -> int:
    """Import the runner and run one short scenario in this worker (before timing)."""
    from cosim.cli import main as cosim_main

    cosim_main(["run", scenario, "--out", str(Path(out_root) / str(os.getpid())), "--quiet"])
    return os.getpid()


def measure(workers: int, sweep_path: Path, warm_path: Path, out: Path) -> tuple[float, float, int, float]:
    """(variants per minute, mean variant wall time s, workers that ran variants, CPU share) of one timed sweep.

    CPU share = CPU seconds of the variants / (sweep wall time x workers): 1.0 when every
    worker had a core of its own throughout; less when other processes took CPU time.
    """
    from cosim.sweep import dask_client, load_sweep, run_sweep

    sweep = load_sweep(sweep_path)
    with dask_client(workers=workers) as client:
        client.wait_for_workers(workers)
        client.run(_warm_worker, str(warm_path), str(out / f"warm{workers}"))
        start = time.perf_counter()
        result = run_sweep(sweep, out / f"timed{workers}", client=client, progress=False, resume=False)
        wall = time.perf_counter() - start
    if result.failed:
        raise RuntimeError(f"{result.failed} variants failed: {[r['reason'] for r in result.rows if r['reason']]}")
    mean_variant = statistics.mean(r["wall_time_s"] for r in result.rows)
    cpu_share = sum(r["cpu_time_s"] for r in result.rows) / (wall * workers)
    return len(result.rows) / wall * 60.0, mean_variant, len({r["worker"] for r in result.rows}), cpu_share


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variants", type=int, default=8, help="variants per timed sweep (even: both workers busy)")
    parser.add_argument("--sim-time", type=float, default=40.0, help="simulated seconds per variant")
    parser.add_argument("--repeats", type=int, default=2, help="interleaved rounds of 1 and 2 workers")
    parser.add_argument("--nice", type=int, default=0,
                        help="niceness for this process, its cluster and its session's autogroup (negative needs root; "
                        "on a machine shared with other jobs, e.g. -10 measures the cluster, not the neighbours)")
    args = parser.parse_args()
    if args.nice:
        os.nice(args.nice)  # before any thread or worker process exists: all of them inherit it
        # Linux autogroup scheduling shares the CPU fairly between sessions first, whatever the
        # processes' niceness: set the niceness of this session's group too (when the kernel has it)
        autogroup = Path("/proc/self/autogroup")
        if autogroup.exists():
            try:
                autogroup.write_text(str(args.nice))
            except OSError as exc:
                print(f"note: could not set the autogroup niceness ({exc}); the CPU share stays per session")
    with tempfile.TemporaryDirectory(prefix="bench_sweep_") as tmp:
        folder = Path(tmp)
        sweep_path = write_sweep(folder, "bench", args.sim_time, args.variants)
        write_sweep(folder, "warm", 0.1, 1)
        warm_path = folder / "warm_base.toml"
        rates: dict[int, list[float]] = {1: [], 2: []}
        variant_times: dict[int, list[float]] = {1: [], 2: []}
        print(f"{args.variants} variants of {args.sim_time:g} s simulated (rx130l_plant, 200 us), "
              f"{os.cpu_count()} CPUs, niceness {os.nice(0)}, load average {os.getloadavg()[0]:.2f} at start")
        for round_ in range(args.repeats):
            for workers in (1, 2):
                rate, mean_variant, used, cpu_share = measure(workers, sweep_path, warm_path, folder / f"r{round_}")
                rates[workers].append(rate)
                variant_times[workers].append(mean_variant)
                print(f"  round {round_ + 1}, {workers} worker(s): {rate:6.2f} variants/min "
                      f"(mean variant wall time {mean_variant:.2f} s, {used} worker process(es) used, "
                      f"CPU share {cpu_share:.2f}, load average {os.getloadavg()[0]:.2f})")
        one, two = statistics.median(rates[1]), statistics.median(rates[2])
        print(f"median variants/min: 1 worker {one:.2f}, 2 workers {two:.2f}; "
              f"ratio {two / one:.2f} (target >= 1.8)")
        print(f"median variant wall time: 1 worker {statistics.median(variant_times[1]):.2f} s, "
              f"2 workers {statistics.median(variant_times[2]):.2f} s")


if __name__ == "__main__":
    main()
