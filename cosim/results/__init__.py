"""Run results: summary.json, streamed time-series files (Parquet or CSV) and the progress bar.

The names below are imported on first use, so ``from cosim.results import lastwords`` (the
supervisor of ``python -m cosim run``, before it forks) does not import numpy or tqdm.
"""
from __future__ import annotations

import importlib
from typing import Any

_LAZY = {"ProgressBar": "cosim.results.progress", "SummaryWriter": "cosim.results.summary",
         "CsvSink": "cosim.results.timeseries", "ParquetSink": "cosim.results.timeseries",
         "read_csv": "cosim.results.timeseries", "read_series": "cosim.results.timeseries",
         "read_units": "cosim.results.timeseries", "write_columns": "cosim.results.timeseries",
         "iter_series": "cosim.results.timeseries", "derived_spec": "cosim.results.timeseries",
         "decode_column": "cosim.results.timeseries"}

__all__ = ["CsvSink", "ParquetSink", "ProgressBar", "SummaryWriter", "decode_column", "derived_spec", "iter_series",
           "read_csv", "read_series", "read_units", "write_columns"]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'cosim.results' has no attribute {name!r}")
