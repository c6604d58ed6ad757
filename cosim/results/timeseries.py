"""Time series streamed to CSV while a run goes (a ``cosim.master.recorder.Sink``).

The header is ``time,<signal>,...``; time is in s, values in the FMU's units (SI in
this project). Reals are written with ``repr`` (shortest round-trip decimal), Integer
and Boolean columns as integers. Rows are appended as blocks arrive and the file is
flushed on every ``flush()``, so a run that fails keeps every row recorded before.
:class:`FileSink` is the flush/close part any one-file sink shares (also the split
run's raw-row sink).
"""
from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import IO

import numpy as np


class FileSink:
    """Base of the recorder sinks that write one file, ``self._file`` (None until ``open``):
    ``flush`` pushes what was written to the OS, ``close`` closes the file (again: no-op)."""

    _file: IO | None = None

    def flush(self) -> None:
        if self._file is not None:
            self._file.flush()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


class CsvSink(FileSink):
    """Write recorder rows to ``path`` (created with its directory; overwritten)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file = None
        self._int_columns: list[int] = []

    def open(self, columns: Sequence[str], kinds: Sequence[str]) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "w", encoding="utf-8", newline="")
        csv.writer(self._file).writerow(columns)
        self._int_columns = [i for i, k in enumerate(kinds) if k in ("Integer", "Boolean")]
        self._file.flush()

    def write(self, block: np.ndarray) -> None:
        rows = block.tolist()
        if self._int_columns:
            for row in rows:
                for i in self._int_columns:
                    row[i] = int(row[i])
        self._file.write("".join(",".join(map(repr, row)) + "\n" for row in rows))


def read_csv(path: str | Path) -> tuple[list[str], np.ndarray]:
    """Read a file written by CsvSink: (column names, float64 array of shape (rows, columns))."""
    path = Path(path)
    with open(path, encoding="utf-8", newline="") as f:
        header = next(csv.reader(f))
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    if data.size == 0:
        data = np.zeros((0, len(header)))
    return header, data
