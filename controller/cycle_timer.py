"""Wall-clock compute time of each controller cycle and deadline misses.

The controller brackets its own work in every cycle with ``time.perf_counter_ns`` (wall
clock) and ``time.thread_time_ns`` (CPU time of its thread) and stores both durations in
preallocated arrays (no allocation in the cycle). A cycle whose wall-clock compute time
exceeds the budget is a deadline miss. The CPU time excludes the time the operating
system gave other processes while the cycle ran: on a shared machine the wall-clock
tail (p99, max) shows preemption, the CPU time shows what the computation costs. On a real industrial PC the
budget is what the 400 µs cycle leaves for the controller; here it is a scenario
value (default 100 µs, the main job's target for the p99 compute time, docs/main_job.md).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TimingSummary:
    """Compute-time statistics in µs over the timed cycles."""

    cycles: int
    p50_us: float
    p99_us: float
    max_us: float
    mean_us: float
    budget_us: float
    deadline_misses: int
    cpu_p50_us: float
    cpu_p99_us: float
    cpu_max_us: float

    def as_dict(self) -> dict[str, float | int]:
        """``{"p50", "p99", "max", "mean", "budget", "cycles", "deadline_misses", "cpu_p50", "cpu_p99",
        "cpu_max"}`` (µs, counts)."""
        return {"p50": self.p50_us, "p99": self.p99_us, "max": self.max_us, "mean": self.mean_us,
                "budget": self.budget_us, "cycles": self.cycles, "deadline_misses": self.deadline_misses,
                "cpu_p50": self.cpu_p50_us, "cpu_p99": self.cpu_p99_us, "cpu_max": self.cpu_max_us}


class CycleTimer:
    """Keeps per-cycle compute times (ns) for up to ``capacity`` cycles (then grows by doubling)."""

    def __init__(self, budget_s: float, capacity: int = 65536) -> None:
        if not budget_s > 0.0:
            raise ValueError(f"CycleTimer budget_s = {budget_s!r}: expected a compute budget > 0 s")
        self.budget_ns = int(round(budget_s * 1e9))
        self.durations_ns = np.zeros(max(int(capacity), 16), dtype=np.int64)
        self.cpu_ns = np.zeros_like(self.durations_ns)
        self.count = 0
        self.deadline_misses = 0

    def record(self, duration_ns: int, cpu_ns: int = -1) -> None:
        """Store one cycle's compute time in ns (wall clock; CPU time, -1: not measured)."""
        if self.count == self.durations_ns.size:
            self.durations_ns = np.concatenate([self.durations_ns, np.zeros_like(self.durations_ns)])
            self.cpu_ns = np.concatenate([self.cpu_ns, np.zeros_like(self.cpu_ns)])
        self.durations_ns[self.count] = duration_ns
        self.cpu_ns[self.count] = cpu_ns
        self.count += 1
        if duration_ns > self.budget_ns:
            self.deadline_misses += 1

    @property
    def durations_us(self) -> np.ndarray:
        """Compute times of the recorded cycles in µs (a new array)."""
        return self.durations_ns[:self.count] * 1e-3

    def summary(self) -> TimingSummary:
        """p50/p99/max/mean in µs and the number of deadline misses (NaN stats when no cycle)."""
        d = self.durations_us
        nan = float("nan")
        if d.size == 0:
            return TimingSummary(0, nan, nan, nan, nan, self.budget_ns * 1e-3, 0, nan, nan, nan)
        p50, p99 = np.percentile(d, [50.0, 99.0])
        cpu = self.cpu_ns[:self.count]
        cpu = cpu[cpu >= 0] * 1e-3
        c50, c99, cmax = (np.percentile(cpu, [50.0, 99.0]).tolist() + [float(cpu.max())]) if cpu.size else [nan] * 3
        return TimingSummary(int(d.size), float(p50), float(p99), float(d.max()), float(d.mean()),
                             self.budget_ns * 1e-3, self.deadline_misses, float(c50), float(c99), float(cmax))
