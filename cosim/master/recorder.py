"""Observers that sample signals at a fixed period and stream rows to a sink.

A ``Recorder`` samples its signals at every ``period`` (a multiple of the base step),
after the periodic tasks of that tick ran (see cosim/master/master.py), into a preallocated
block; full blocks, and at least every ``flush_interval_s`` of wall time, are handed
to its sink, so a failed run keeps everything recorded up to the failure.

A sink is any object with ``open(columns, kinds)``, ``write(block)`` (a 2-D float64
array, column 0 = time in s), ``flush()`` and ``close()``. ``MemorySink`` keeps rows in
memory; ``cosim.results.timeseries.CsvSink`` writes CSV.
"""
from __future__ import annotations

import time as _time
from collections.abc import Sequence
from typing import Protocol

import numpy as np


class Sink(Protocol):
    """Destination of recorded rows."""

    def open(self, columns: Sequence[str], kinds: Sequence[str]) -> None:
        """Called once before the first row: column names (``time`` first) and bus types."""

    def write(self, block: np.ndarray) -> None:
        """Append rows (float64, shape (rows, len(columns)))."""

    def flush(self) -> None:
        """Make written rows durable."""

    def close(self) -> None:
        """Flush and release."""


class MemorySink:
    """Sink keeping all rows in memory; ``data`` is the (rows, columns) array, ``columns`` the names."""

    def __init__(self) -> None:
        self.columns: list[str] = []
        self.kinds: list[str] = []
        self._blocks: list[np.ndarray] = []

    def open(self, columns: Sequence[str], kinds: Sequence[str]) -> None:
        self.columns, self.kinds = list(columns), list(kinds)

    def write(self, block: np.ndarray) -> None:
        self._blocks.append(np.array(block, copy=True))

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass

    @property
    def data(self) -> np.ndarray:
        """All rows so far, shape (rows, len(columns))."""
        if not self._blocks:
            return np.zeros((0, len(self.columns)))
        return np.concatenate(self._blocks)

    def column(self, name: str) -> np.ndarray:
        """One column by name (``"time"`` or a signal name)."""
        return self.data[:, self.columns.index(name)]


class Recorder:
    """Samples ``signals`` every ``period_ticks`` base ticks into ``sink``.

    Built by ``Master.add_recorder``; ``bind`` is called by the master at initialization
    with each signal's bus type and index.
    """

    def __init__(self, name: str, signals: Sequence[str], period_ticks: int, sink: Sink,
                 block_rows: int = 1024, flush_interval_s: float = 1.0) -> None:
        self.name = name
        self.signals = list(signals)
        self.period_ticks = int(period_ticks)
        self.sink = sink
        self.block_rows = int(block_rows)
        self.flush_interval_s = float(flush_interval_s)
        self.rows_written = 0
        self.needs_gather = False
        self._block = np.zeros((self.block_rows, 1 + len(self.signals)))
        self._fill = 0
        self._last_flush = _time.perf_counter()
        self._picks: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._open = False

    def bind(self, buses: dict[str, np.ndarray], locations: Sequence[tuple[str, int]], needs_gather: bool) -> None:
        """Resolve signals to (bus type, index); open the sink with the column names."""
        kinds = [kind for kind, _ in locations]
        for bus_type, bus in buses.items():
            cols = np.array([1 + i for i, (kind, _) in enumerate(locations) if kind == bus_type], dtype=np.intp)
            idx = np.array([index for kind, index in locations if kind == bus_type], dtype=np.intp)
            if len(cols):
                self._picks.append((bus, idx, cols))
        self.needs_gather = needs_gather
        self.sink.open(["time", *self.signals], ["Real", *kinds])
        self._open = True

    def sample(self, t: float) -> None:
        """Append one row at simulated time ``t`` (s)."""
        row = self._block[self._fill]
        row[0] = t
        for bus, idx, cols in self._picks:
            row[cols] = bus[idx]
        self._fill += 1
        if self._fill == self.block_rows or _time.perf_counter() - self._last_flush > self.flush_interval_s:
            self.flush()

    def flush(self) -> None:
        """Hand buffered rows to the sink and flush it."""
        if self._fill:
            self.sink.write(self._block[:self._fill])
            self.rows_written += self._fill
            self._fill = 0
        if self._open:
            self.sink.flush()
        self._last_flush = _time.perf_counter()

    def close(self) -> None:
        """Flush and close the sink (idempotent)."""
        if self._open:
            self.flush()
            self.sink.close()
            self._open = False
