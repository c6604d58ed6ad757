"""Holding the simulated clock to the wall clock: one wall deadline per controller cycle.

Cycle ``k`` may start at wall time ``W_k = W_0 + k T`` (``T`` = the controller period,
``W_0`` = when the first paced cycle started). :meth:`Pacer.wait` sleeps until
``W_k - spin`` (``time.sleep``: cheap, but the kernel wakes a sleeper tens of µs late)
and busy-waits on ``time.perf_counter_ns`` for the rest (exact, costs a core). The
cycle's **lateness** is the wall time at which it really starts minus ``W_k`` (>= 0):
a few hundred ns when the loop kept up, more when the previous cycle's work ran past
``W_k`` or the process was not scheduled. Nothing ever runs early.

A cycle late by a whole period or more has let wall ticks go by: like a periodic timer
that counts missed expirations, the pacer drops those ticks (``log.missed_ticks``) and moves
the grid by whole periods, so the following cycles do not run back to back to catch up
(which would compress the plant's time) and the simulated clock lags the wall clock by
the ticks lost.

The clock and sleep functions are injectable (:class:`VirtualClock`) so the pacing and
overrun logic can be tested deterministically, independent of the machine's speed.
"""
from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Iterator

import numpy as np


class VirtualClock:
    """A wall clock that only moves when told to (tests): ``now_ns()``, ``sleep(s)``, ``advance_ns(n)``.

    Use it with ``spin_s = 0`` (a busy-wait on a clock that never moves by itself would not end)."""

    def __init__(self, start_ns: int = 0) -> None:
        self.t_ns = int(start_ns)

    def now_ns(self) -> int:
        return self.t_ns

    def sleep(self, seconds: float) -> None:
        self.t_ns += max(0, int(round(seconds * 1e9)))

    def advance_ns(self, ns: int) -> None:
        """Let ``ns`` nanoseconds of wall time pass (a slow piece of work)."""
        self.t_ns += int(ns)


class LatenessLog:
    """Per-cycle lateness (ns) and overrun flags, preallocated (grows by doubling).

    ``cycles[i]`` is the cycle number of entry ``i``; ``work_ns[i]`` the wall time from the
    start of the previous cycle to the moment this one began waiting (the previous cycle's
    work: bus, controller, FMU steps, tracker, recorder; -1 for the first); ``oversleep_ns[i]``
    how late the OS woke the pacer from its sleep before this cycle's deadline (wake-up time
    minus the requested time; -1: it did not sleep, the cycle was already due)."""

    def __init__(self, capacity: int = 65536) -> None:
        n = max(int(capacity), 16)
        self.cycles = np.zeros(n, dtype=np.int64)
        self.lateness_ns = np.zeros(n, dtype=np.int64)
        self.work_ns = np.zeros(n, dtype=np.int64)
        self.oversleep_ns = np.full(n, -1, dtype=np.int64)
        self.overrun = np.zeros(n, dtype=bool)
        self.count = 0
        self.missed_ticks = 0  # wall ticks dropped by the pacer (cycles late by whole periods)

    def append(self, cycle: int, lateness_ns: int, overrun: bool, work_ns: int = -1, oversleep_ns: int = -1) -> None:
        i = self.count
        if i == self.cycles.size:
            self.cycles = np.concatenate([self.cycles, np.zeros_like(self.cycles)])
            self.lateness_ns = np.concatenate([self.lateness_ns, np.zeros_like(self.lateness_ns)])
            self.work_ns = np.concatenate([self.work_ns, np.zeros_like(self.work_ns)])
            self.oversleep_ns = np.concatenate([self.oversleep_ns, np.full_like(self.oversleep_ns, -1)])
            self.overrun = np.concatenate([self.overrun, np.zeros_like(self.overrun)])
        self.cycles[i] = cycle
        self.lateness_ns[i] = lateness_ns
        self.work_ns[i] = work_ns
        self.oversleep_ns[i] = oversleep_ns
        self.overrun[i] = overrun
        self.count = i + 1

    @property
    def work_us(self) -> np.ndarray:
        """Work of the previous cycle in µs for entries 1.. (a new array)."""
        return self.work_ns[1:self.count] * 1e-3

    @property
    def lateness_us(self) -> np.ndarray:
        """Lateness of the recorded cycles in µs (a new array)."""
        return self.lateness_ns[:self.count] * 1e-3

    @property
    def overrun_cycles(self) -> list[int]:
        """Cycle numbers of the overruns, in order."""
        return self.cycles[:self.count][self.overrun[:self.count]].tolist()


class Pacer:
    """Waits for the wall deadline of each cycle and judges overruns.

    Args:
        period_s: the cycle T, s.
        spin_s: busy-wait this long before each deadline, s (0: sleep only).
        tolerance_s: a cycle whose lateness exceeds this is an overrun, s.
        clock_ns: wall clock in ns (default ``time.perf_counter_ns``).
        sleep: ``sleep(seconds)`` (default ``time.sleep``).
        capacity: expected number of cycles.
    """

    def __init__(self, period_s: float, spin_s: float, tolerance_s: float, *,
                 clock_ns: Callable[[], int] = time.perf_counter_ns, sleep: Callable[[float], None] = time.sleep,
                 capacity: int = 65536) -> None:
        if not period_s > 0.0:
            raise ValueError(f"Pacer period_s = {period_s!r}: expected a cycle time > 0 s")
        if not spin_s >= 0.0 or not tolerance_s >= 0.0:
            raise ValueError(f"Pacer spin_s = {spin_s!r}, tolerance_s = {tolerance_s!r}: expected times >= 0 s")
        self.period_ns = int(round(period_s * 1e9))
        self.spin_ns = int(round(spin_s * 1e9))
        self.tolerance_ns = int(round(tolerance_s * 1e9))
        self._clock = clock_ns
        self._sleep = sleep
        self.origin_ns: int | None = None
        self._started: int | None = None
        self.log = LatenessLog(capacity)
        self.thresholds: dict[str, float] = {}  # named lateness thresholds (s) to report (runner sets them)

    def deadline_ns(self, cycle: int) -> int:
        """W_k in the clock's ns (after the first :meth:`wait`)."""
        if self.origin_ns is None:
            raise RuntimeError("Pacer.deadline_ns before the first wait()")
        return self.origin_ns + cycle * self.period_ns

    def wait(self, cycle: int) -> bool:
        """Wait for the wall deadline of ``cycle``; record its lateness; return True when it is
        an overrun. The first call defines ``W_0`` so that this cycle is on time."""
        clock = self._clock
        now = clock()
        work = now - self._started if self._started is not None else -1
        if self.origin_ns is None:
            self.origin_ns = now - cycle * self.period_ns
        deadline = self.origin_ns + cycle * self.period_ns
        wake = deadline - self.spin_ns
        oversleep = -1
        if now < wake:
            self._sleep((wake - now) * 1e-9)
            now = clock()
            oversleep = now - wake  # > 0: the OS woke the process this late
        while now < deadline:
            now = clock()
        self._started = now
        lateness = now - deadline
        overrun = lateness > self.tolerance_ns
        if lateness >= self.period_ns:
            # whole wall ticks went by without this cycle: they are lost (as a periodic
            # timer that counts missed expirations); later cycles keep the tick grid
            # but do not try to catch up by running back to back
            missed = lateness // self.period_ns
            self.origin_ns += missed * self.period_ns
            self.log.missed_ticks += missed
        self.log.append(cycle, lateness, overrun, work, oversleep)
        return overrun


def _pin(cpu: int | str | None) -> tuple[str, set[int] | None]:
    """Pin this process to one CPU ('auto': the highest-numbered usable one); returns
    (description, previous affinity or None when unchanged)."""
    if cpu is None or cpu == "none" or not hasattr(os, "sched_setaffinity"):
        return "not pinned", None
    previous = os.sched_getaffinity(0)
    target = max(previous) if cpu == "auto" else int(cpu)
    if target not in previous:
        return f"not pinned (CPU {target} not usable: {sorted(previous)})", None
    try:
        os.sched_setaffinity(0, {target})
    except OSError as error:
        return f"not pinned ({error.strerror or error})", None
    return f"CPU {target}", previous


@contextlib.contextmanager
def realtime_scheduling(policy: str, priority: int = 10, cpu: int | str | None = None) -> Iterator[str]:
    """Run the block under SCHED_FIFO at ``priority`` when ``policy == 'fifo'`` and the OS allows
    it, pinned to ``cpu`` ('auto', an index, or None/'none'); yields what was granted, e.g.
    'fifo, CPU 1' or 'normal (SCHED_FIFO refused: ...), not pinned', and restores both after."""
    pinned, previous_affinity = _pin(cpu)
    granted = "normal"
    restore = None
    if policy == "fifo":
        if not hasattr(os, "sched_setscheduler"):
            granted = "normal (SCHED_FIFO not available on this OS)"
        else:
            try:
                restore = (os.sched_getscheduler(0), os.sched_getparam(0))
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
                granted = "fifo"
            except (PermissionError, OSError) as error:
                restore = None
                granted = f"normal (SCHED_FIFO refused: {error.strerror or error})"
    try:
        yield granted if cpu is None else f"{granted}, {pinned}"
    finally:
        if restore is not None:
            try:
                os.sched_setscheduler(0, *restore)
            except OSError:
                pass
        if previous_affinity is not None:
            try:
                os.sched_setaffinity(0, previous_affinity)
            except OSError:
                pass


@contextlib.contextmanager
def no_cyclic_gc() -> Iterator[None]:
    """No cyclic garbage collection inside the block (a collection pass stalls a cycle by ms;
    reference counting still frees what the loop allocates)."""
    import gc

    enabled = gc.isenabled()
    # no gc.collect() first: a full collection of this process's heap (numpy, pinocchio, pyarrow,
    # matplotlib loaded) costs ~55 ms, 20 % of a 2 s closed-loop run; freezing is enough to keep the
    # objects that exist now out of any later collection, and cycles already garbage are collected
    # after the block instead
    gc.freeze()
    gc.disable()
    try:
        yield
    finally:
        gc.unfreeze()
        if enabled:
            gc.enable()


@contextlib.contextmanager
def locked_memory(enabled: bool = True) -> Iterator[str]:
    """``mlockall(MCL_CURRENT | MCL_FUTURE)`` for the block (Linux; needs CAP_IPC_LOCK or a
    large enough RLIMIT_MEMLOCK): no page of the process is paged out or first-touch faulted
    from disk inside a paced loop. Yields what was granted ('locked' or 'not locked (...)');
    unlocks after."""
    if not enabled:
        yield "not locked (off)"
        return
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        mcl_current, mcl_future = 1, 2
        ok = libc.mlockall(mcl_current | mcl_future) == 0
        reason = "" if ok else os.strerror(ctypes.get_errno())
    except (OSError, AttributeError) as error:
        libc, ok, reason = None, False, str(error)
    try:
        yield "locked" if ok else f"not locked ({reason})"
    finally:
        if ok:
            libc.munlockall()
