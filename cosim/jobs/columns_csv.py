"""Write named columns of equal length to a CSV file (header ``name,...``; SI units).

Floats are written with ``repr`` (shortest round-trip decimal) so a reader gets the
exact numbers back; NaN is written as ``nan``. Readable with
``cosim.results.read_csv`` and ``numpy.loadtxt(path, delimiter=",", skiprows=1)``.
"""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np


def write_columns_csv(path: str | Path, columns: Mapping[str, np.ndarray]) -> Path:
    """Write ``columns`` (name -> (n,) array) to ``path``; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=float) for n in names]) if names else np.zeros((0, 0))
    with open(path, "w", encoding="utf-8", newline="") as f:
        f.write(",".join(names) + "\n")
        rows = data.tolist()
        for start in range(0, len(rows), 4096):
            f.write("".join(",".join(map(repr, row)) + "\n" for row in rows[start:start + 4096]))
    return path
