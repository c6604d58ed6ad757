"""The sweep table: one row per variant, written as CSV.

Columns, in order: ``variant``, the axis keys (the values as the job validated them: SI
numbers, strings, lists as JSON), ``status`` (``ok``/``failed``), ``reason`` (why it
failed), ``wall_time_s`` (wall time of the variant's task), ``cpu_time_s`` (CPU time of the
worker process meanwhile: well below the wall time means the CPU was shared), ``worker`` (host:pid that ran
it), ``hash`` (the variant hash), ``folder`` (its results folder, relative to the
table), then the metrics: the numeric leaves of the variant's
summary.json (booleans as true/false) as key paths (``calibrated.e_x.max``,
``modes.standard.tcp_error_max_mm``, ``restart_values[2]``). By default every numeric
leaf is a metric except items of lists longer than ``MAX_LIST_ITEMS``; ``[sweep]
metrics`` chooses them instead (globs: ``calibrated.*.max``, ``modes.**``). A metric
named like a fixed or parameter column is prefixed ``summary.`` (``summary.wall_time_s``).
"""
from __future__ import annotations

import csv
import json
import math
import os
import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from cosim.scenario.keypath import format_key_path

#: Default metrics skip the items of longer lists (candidate indices, per-pose residuals, ...).
MAX_LIST_ITEMS = 16
FIXED_COLUMNS: tuple[str, ...] = ("variant", "status", "reason", "wall_time_s", "cpu_time_s", "worker", "hash",
                                  "folder")


def flatten_numeric(value: Any, max_list: int | None = MAX_LIST_ITEMS, prefix: tuple = ()) -> dict[str, Any]:
    """Numeric (and boolean) leaves of a JSON value by key path; lists longer than ``max_list`` skipped."""
    out: dict[str, Any] = {}
    if isinstance(value, bool) or (isinstance(value, (int, float)) and math.isfinite(value)):
        out[format_key_path(prefix)] = value
    elif isinstance(value, dict):
        for key, item in value.items():
            out.update(flatten_numeric(item, max_list, prefix + (str(key),)))
    elif isinstance(value, list) and (max_list is None or len(value) <= max_list):
        for i, item in enumerate(value):
            out.update(flatten_numeric(item, max_list, prefix + (i,)))
    return out


def select_metrics(summary: dict[str, Any], patterns: Sequence[str] | None) -> dict[str, Any]:
    """The metrics of one summary: every numeric leaf, or those matching ``patterns`` (in pattern order)."""
    if not patterns:
        return flatten_numeric(summary)
    leaves = flatten_numeric(summary, max_list=None)
    out: dict[str, Any] = {}
    for text in patterns:
        rx = metric_pattern(text)
        for key, value in leaves.items():
            if key not in out and rx.match(key):
                out[key] = value
    return out


def metric_pattern(text: str) -> re.Pattern[str]:
    """A compiled pattern for a metric glob (``*`` matches within one key, ``**`` across keys)."""
    out = ""
    i = 0
    while i < len(text):
        if text.startswith("**", i):
            out += ".*"
            i += 2
        elif text[i] == "*":
            out += r"[^.\[]*"
            i += 1
        else:
            out += re.escape(text[i])
            i += 1
    return re.compile(out + r"\Z")


def cell(value: Any) -> str:
    """A CSV cell: numbers round-trip, booleans true/false, lists/tables as JSON, None empty."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ""
    if isinstance(value, (list, dict)):
        return json.dumps(value, default=str)
    return str(value)


def metric_columns(rows: Iterable[dict[str, Any]]) -> list[str]:
    """Metric names in first-seen order over ``rows``."""
    seen: dict[str, None] = {}
    for row in rows:
        for key in row.get("metrics", {}):
            seen.setdefault(key, None)
    return list(seen)


def table_columns(parameters: Sequence[str], metrics: Sequence[str]) -> tuple[list[str], dict[str, str]]:
    """All column names and the map metric -> column (``summary.`` prefix on a clash)."""
    taken = set(FIXED_COLUMNS) | set(parameters)
    renamed = {m: (f"summary.{m}" if m in taken else m) for m in metrics}
    return ["variant", *parameters, *FIXED_COLUMNS[1:], *renamed.values()], renamed


def table_records(rows: Sequence[dict[str, Any]], parameters: Sequence[str]) -> tuple[list[str], list[dict]]:
    """Columns and flat records (column -> value) of ``rows`` (sorted by variant index)."""
    columns, renamed = table_columns(parameters, metric_columns(rows))
    records = []
    for row in sorted(rows, key=lambda r: r["index"]):
        rec = {"variant": row["variant"], **{p: row["values"].get(p) for p in parameters},
               **{k: row.get(k) for k in FIXED_COLUMNS[1:]}}
        rec.update({renamed[m]: v for m, v in row.get("metrics", {}).items()})
        records.append(rec)
    return columns, records


def write_table(path: str | Path, rows: Sequence[dict[str, Any]], parameters: Sequence[str]) -> Path:
    """Write the CSV table of ``rows`` atomically (temporary file + rename); return the path."""
    path = Path(path)
    columns, records = table_records(rows, parameters)
    for rec in records:
        if rec.get("folder"):
            rec["folder"] = os.path.relpath(rec["folder"], path.parent)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(columns)
        for rec in records:
            writer.writerow([cell(rec.get(c)) for c in columns])
    os.replace(tmp, path)
    return path


__all__ = ["FIXED_COLUMNS", "MAX_LIST_ITEMS", "cell", "flatten_numeric", "metric_columns", "metric_pattern",
           "select_metrics", "table_columns", "table_records", "write_table"]
