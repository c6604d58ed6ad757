"""Wall-clock cost of one 400 us POWERLINK cycle with six nodes (target: <= 80 us).

Runs ``PowerlinkNetwork.run_cycle`` with changing set-points and actual values and
prints the median (and spread) over batches of cycles, for:

* simbus (default interface), no recording       <- the figure the target applies to
* simbus with BLF recording inline / in a background writer process
* python-can's virtual interface, no recording    (for comparison)

Usage: python benchmarks/bench_fieldbus.py [--cycles-per-batch N] [--batches M]
The machine may be shared: the CPU-time median (process_time) is printed too.
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from fieldbus import DriveActuals, JointScaling, PowerlinkNetwork, Setpoints
from fieldbus.cia402 import DriveState, statusword_for

TARGET_US = 80.0
# drive-train values of the RX130L-class arm (robot/rx130l_params.toml); fieldbus
# must not import robot, so the benchmark states them here
GEAR_RATIO = [100.0, 100.0, 80.0, 60.0, 60.0, 50.0]
ENCODER_COUNTS = 65536
RATED_TORQUE = [350.0, 500.0, 220.0, 35.0, 30.0, 17.0]


def measure(config: dict, log_path: Path | None, batches: int, per_batch: int) -> tuple[list[float], list[float]]:
    scaling = JointScaling(GEAR_RATIO, ENCODER_COUNTS, RATED_TORQUE)
    setpoints = Setpoints.zeros(6)
    setpoints.controlword[:] = 0x0F
    actuals = DriveActuals.zeros(6)
    actuals.statusword[:] = statusword_for(DriveState.OPERATION_ENABLED)
    wall: list[float] = []
    cpu: list[float] = []
    with PowerlinkNetwork(config, scaling, log_path=log_path) as network:
        cycle = 0
        q = np.linspace(-1.0, 1.0, 6)
        for batch in range(batches + 1):  # batch 0 warms up
            w0, c0 = time.perf_counter(), time.process_time()
            for _ in range(per_batch):
                phase = cycle * 4e-4
                setpoints.position[:] = q * np.sin(phase)
                setpoints.torque_offset[:] = q * 10.0
                actuals.position[:] = setpoints.position
                actuals.velocity[:] = q * np.cos(phase)
                network.run_cycle(cycle, setpoints, actuals)
                cycle += 1
            w1, c1 = time.perf_counter(), time.process_time()
            if batch:
                wall.append((w1 - w0) / per_batch * 1e6)
                cpu.append((c1 - c0) / per_batch * 1e6)
        # the cost of preparing inputs is not the network's: measure and subtract it
    return wall, cpu


def input_overhead(batches: int, per_batch: int) -> float:
    setpoints = Setpoints.zeros(6)
    actuals = DriveActuals.zeros(6)
    q = np.linspace(-1.0, 1.0, 6)
    samples = []
    for _ in range(batches):
        w0 = time.perf_counter()
        for cycle in range(per_batch):
            phase = cycle * 4e-4
            setpoints.position[:] = q * np.sin(phase)
            setpoints.torque_offset[:] = q * 10.0
            actuals.position[:] = setpoints.position
            actuals.velocity[:] = q * np.cos(phase)
        samples.append((time.perf_counter() - w0) / per_batch * 1e6)
    return statistics.median(samples)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles-per-batch", type=int, default=2000)
    parser.add_argument("--batches", type=int, default=15)
    args = parser.parse_args()
    overhead = input_overhead(args.batches, args.cycles_per_batch)
    print(f"input preparation (numpy, not counted): {overhead:.1f} us per cycle")
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        cases = [
            ("simbus, no recording", {}, None),
            ("simbus, BLF recording inline", {}, Path(tmp) / "inline.blf"),
            ("simbus, BLF recording in background process", {"recording": {"background": True}},
             Path(tmp) / "background.blf"),
            ("python-can virtual, no recording", {"bus": {"interface": "virtual"}}, None),
        ]
        for name, config, log_path in cases:
            wall, cpu = measure(config, log_path, args.batches, args.cycles_per_batch)
            wall_med = statistics.median(wall) - overhead
            cpu_med = statistics.median(cpu) - overhead
            results[name] = wall_med
            print(f"{name:48s} median {wall_med:6.1f} us/cycle wall "
                  f"(min {min(wall) - overhead:6.1f}, max {max(wall) - overhead:6.1f}), "
                  f"cpu median {cpu_med:6.1f} us")
    headline = results["simbus, no recording"]
    verdict = "meets" if headline <= TARGET_US else "MISSES"
    print(f"one 400 us cycle, six nodes: {headline:.1f} us median wall-clock -> {verdict} the "
          f"{TARGET_US:.0f} us target ({400.0 / headline:.1f}x faster than real time)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
