"""Compute time of each controller cycle (wall clock and CPU time) and deadline misses.

The controller brackets its own work in every cycle with ``time.perf_counter_ns`` (wall
clock) and ``time.thread_time_ns`` (CPU time of its thread) and stores both durations in
preallocated arrays (no allocation in the cycle). The CPU time excludes the time the
operating system gave other processes while the cycle ran: on a shared machine (the main
job's modes run as sibling processes on the same cores) the wall-clock tail (p99, max) shows
preemption, the CPU time what the controller's computation costs.

A deadline miss is a cycle whose compute time exceeds the budget, judged on the time that
decides (:attr:`TimingSummary.deadline_basis`): in a simulated-time run the CPU time (nothing
waits for the wall clock; wall time there measures the siblings too), in a real-time run
(paced, served) the wall time (the cycle's deadline is on the wall clock):
:meth:`TimingSummary.judged_on`. Both counts are kept (``cpu_over_budget``,
``wall_over_budget``). On a real industrial PC the
budget is what the 400 µs cycle leaves for the controller; here it is a scenario
value (default 100 µs, the main job's target for the p99 compute time).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, replace
from functools import partial

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
    """Cycles over the budget on :attr:`deadline_basis`'s clock."""
    cpu_p50_us: float
    cpu_p99_us: float
    cpu_max_us: float
    wall_over_budget: int = 0
    """Cycles whose wall-clock compute time exceeded the budget."""
    cpu_over_budget: int = 0
    """Cycles whose CPU time exceeded the budget."""
    deadline_basis: str = "wall_time"
    """``"cpu_time"`` or ``"wall_time"``: the clock :attr:`deadline_misses` is judged on."""

    def judged_on(self, basis: str) -> "TimingSummary":
        """This summary with the deadline misses judged on ``basis`` (``"cpu_time"``: a
        simulated-time run; ``"wall_time"``: a real-time run). CPU time not measured (NaN):
        wall time."""
        if basis not in ("cpu_time", "wall_time"):
            raise ValueError(f"deadline basis {basis!r}: expected 'cpu_time' or 'wall_time'")
        if basis == "cpu_time" and not np.isfinite(self.cpu_p50_us):
            basis = "wall_time"
        misses = self.cpu_over_budget if basis == "cpu_time" else self.wall_over_budget
        return replace(self, deadline_misses=misses, deadline_basis=basis)

    def as_dict(self) -> dict[str, float | int | str]:
        """``{"p50", "p99", "max", "mean", "budget", "cycles", "deadline_misses", "deadline_basis",
        "cpu_p50", "cpu_p99", "cpu_max", "wall_over_budget", "cpu_over_budget"}`` (µs, counts;
        p50..mean wall clock)."""
        return {"p50": self.p50_us, "p99": self.p99_us, "max": self.max_us, "mean": self.mean_us,
                "budget": self.budget_us, "cycles": self.cycles, "deadline_misses": self.deadline_misses,
                "deadline_basis": self.deadline_basis, "cpu_p50": self.cpu_p50_us, "cpu_p99": self.cpu_p99_us,
                "cpu_max": self.cpu_max_us, "wall_over_budget": self.wall_over_budget,
                "cpu_over_budget": self.cpu_over_budget}


EXACT_CYCLES = 1 << 18
"""Cycles whose compute times are kept one by one (105 s at 400 µs, 4 MB); longer runs fold
them into :class:`_Histogram` blocks so that memory stays bounded."""
_PAIR = struct.Struct("@2q")  # one cycle held: wall clock, thread CPU time (ns)
BINS_PER_OCTAVE = 256
"""Resolution of the folded histogram: a bin spans a factor 2**(1/256) (0.27 %)."""
_OCTAVES = 48  # 1 ns .. 2.8e14 ns


class _Histogram:
    """Log-spaced counts of durations in ns (bin ``floor(log2(ns) * BINS_PER_OCTAVE)``)."""

    def __init__(self) -> None:
        self.counts = np.zeros(_OCTAVES * BINS_PER_OCTAVE, dtype=np.int64)
        self.total = 0
        self.sum_ns = 0.0
        self.max_ns = -1

    def add(self, ns: np.ndarray) -> None:
        ns = ns[ns >= 0]
        if not ns.size:
            return
        bins = np.clip((np.log2(np.maximum(ns, 1)) * BINS_PER_OCTAVE).astype(np.int64), 0, self.counts.size - 1)
        self.counts += np.bincount(bins, minlength=self.counts.size)
        self.total += int(ns.size)
        self.sum_ns += float(ns.sum(dtype=np.float64))
        self.max_ns = max(self.max_ns, int(ns.max()))

    def percentile_ns(self, p: float) -> float:
        """The geometric centre of the bin of the order statistic at rank ``p`` % (bins span 0.27 %)."""
        rank = p / 100.0 * (self.total - 1)
        k = int(np.searchsorted(np.cumsum(self.counts), rank + 1.0 - 1e-9))
        return float(min(2.0 ** ((k + 0.5) / BINS_PER_OCTAVE), self.max_ns))


class CycleTimer:
    """Keeps per-cycle compute times (ns): one by one for up to :data:`EXACT_CYCLES` cycles
    (exact percentiles), beyond that folded into log-spaced histograms (percentiles to a bin
    of 0.27 % around the order statistic, count, max, mean and deadline misses exact) so that a run of any length holds the same
    memory."""

    def __init__(self, budget_s: float, capacity: int = 65536) -> None:
        if not budget_s > 0.0:
            raise ValueError(f"CycleTimer budget_s = {budget_s!r}: expected a compute budget > 0 s")
        self.budget_ns = int(round(budget_s * 1e9))
        self._alloc(min(max(int(capacity), 16), EXACT_CYCLES))
        self.count = 0
        self.deadline_misses = 0  # wall clock over the budget
        self.cpu_misses = 0  # CPU time over the budget
        self.cpu_measured = True  # every cycle has its CPU time
        self._held = 0  # rows of durations_ns/cpu_ns in use (count minus the folded ones)
        self._folded: tuple[_Histogram, _Histogram] | None = None

    def _alloc(self, size: int, keep: int = 0) -> None:
        """(Re)allocate room for ``size`` cycles (wall, CPU ns side by side in one buffer, so a
        cycle is stored by one ``pack_into``), keeping the first ``keep`` held."""
        pairs = np.zeros((size, 2), dtype=np.int64)
        if keep:
            pairs[:keep] = self._pairs[:keep]
        self._pairs = pairs
        self._size = size
        self.durations_ns = pairs[:, 0]  # views: wall clock and thread CPU time of each cycle held
        self.cpu_ns = pairs[:, 1]
        self._pack = partial(_PAIR.pack_into, memoryview(pairs).cast("B"))

    def record(self, duration_ns: int, cpu_ns: int = -1) -> None:
        """Store one cycle's compute time in ns (wall clock; CPU time, -1: not measured)."""
        k = self._held
        if k == self._size:
            if k < EXACT_CYCLES and self._folded is None:
                self._alloc(min(2 * k, EXACT_CYCLES), keep=k)
            else:
                self._fold()
                k = 0
        self._pack(k << 4, duration_ns, cpu_ns)
        self._held = k + 1
        self.count += 1
        if duration_ns > self.budget_ns:
            self.deadline_misses += 1
        if cpu_ns > self.budget_ns:
            self.cpu_misses += 1
        elif cpu_ns < 0:
            self.cpu_measured = False

    def _fold(self) -> None:
        if self._folded is None:
            self._folded = (_Histogram(), _Histogram())
        self._folded[0].add(self.durations_ns[:self._held])
        self._folded[1].add(self.cpu_ns[:self._held])
        self._held = 0

    @property
    def exact(self) -> bool:
        """True while every cycle's time is kept (percentiles exact)."""
        return self._folded is None

    @property
    def durations_us(self) -> np.ndarray:
        """Compute times in µs of the cycles held one by one (all of them while :attr:`exact`; a new array)."""
        return self.durations_ns[:self._held] * 1e-3

    def summary(self, basis: str = "cpu_time") -> TimingSummary:
        """p50/p99/max/mean in µs and the number of deadline misses judged on ``basis``
        (:meth:`TimingSummary.judged_on`; NaN stats when no cycle)."""
        return self._summary().judged_on(basis if self.cpu_measured else "wall_time")

    def _summary(self) -> TimingSummary:
        nan = float("nan")
        counts = {"wall_over_budget": self.deadline_misses, "cpu_over_budget": self.cpu_misses}
        if self.count == 0:
            return TimingSummary(0, nan, nan, nan, nan, self.budget_ns * 1e-3, 0, nan, nan, nan, **counts)
        if self._folded is not None:
            self._fold()
            wall, cpu = self._folded
            c50, c99, cmax = ([cpu.percentile_ns(50.0) * 1e-3, cpu.percentile_ns(99.0) * 1e-3, cpu.max_ns * 1e-3]
                              if cpu.total else [nan] * 3)
            return TimingSummary(wall.total, wall.percentile_ns(50.0) * 1e-3, wall.percentile_ns(99.0) * 1e-3,
                                 wall.max_ns * 1e-3, wall.sum_ns / wall.total * 1e-3, self.budget_ns * 1e-3,
                                 self.deadline_misses, c50, c99, cmax, **counts)
        d = self.durations_us
        p50, p99 = np.percentile(d, [50.0, 99.0])
        cpu = self.cpu_ns[:self._held]
        cpu = cpu[cpu >= 0] * 1e-3
        c50, c99, cmax = (np.percentile(cpu, [50.0, 99.0]).tolist() + [float(cpu.max())]) if cpu.size else [nan] * 3
        return TimingSummary(int(d.size), float(p50), float(p99), float(d.max()), float(d.mean()),
                             self.budget_ns * 1e-3, self.deadline_misses, float(c50), float(c99), float(cmax),
                             **counts)
