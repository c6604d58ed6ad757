"""How much a run will write and hold in memory, estimated from the validated scenario
before anything runs, and the budget it must fit in.

The estimate counts what grows with the simulated time: recorded rows (``[record]`` or
the robot cell's 1 ms tracker rate) times columns, the controller's per-cycle log, the TCP
evaluation series and the CAN log (about 14 frames of 11 bytes per 400 µs cycle,
BLF-compressed). Bytes per stored value: 7 in Parquet (zstd, byte-stream-split float64,
measured on the main job), 20 in CSV (shortest round-trip decimals), 8 in memory.

Memory: in process every series streams to disk with bounded buffers and the evaluation
reads the files back in chunks (``cosim.cell.evaluation``), so what a cell job holds is one
chunk of rows and the motion window's samples (the ISO path's duration, not the run's);
paced and split runs (``--realtime``, ``--split``) keep the recording and the controller
log in memory until the loop ends (no file I/O in a paced cycle): ``in_memory=True``.

Budget (``cosim run`` refuses a run that exceeds it, exit code 2, with the estimate in
the message): output at most ``--max-output`` / ``$COSIM_MAX_OUTPUT`` (default: the free
space of the results folder's file system minus 5 %), memory at most ``--max-memory`` /
``$COSIM_MAX_MEMORY`` (default: half the machine's physical memory); ``--ignore-budget``
runs anyway.
"""
from __future__ import annotations

import math
import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

BYTES_PER_VALUE = {"parquet": 7.0, "csv": 20.0}
MEMORY_BYTES_PER_VALUE = 8.0
CELL_DEFAULT_COLUMNS = 40
"""Columns the robot cell records besides the [record] signals (drives, plant, tracker)."""
CONTROLLER_LOG_COLUMNS = 42
TCP_COLUMNS = 33
CAN_BYTES_PER_CYCLE = 14 * 11
"""BLF CAN log bytes per cycle (19 frames; the main job: 172)."""
COLUMNAR_CAN_BYTES_PER_CYCLE = 64
"""Columnar CAN log (fieldbus.canlog) bytes per cycle (the main job: 46-51)."""
EVAL_CHUNK_ROWS = 8192
"""Rows the cell's evaluation reads at once (cosim.cell.evaluation.EVAL_CHUNK_ROWS)."""
ISO_PATH_S_AT_1_M_S = 12.3
"""Duration (s) of the ISO 9283 test path at 1 m/s (planners.iso9283): its window is held whole."""
GLOB_SIGNALS = 10
"""Signals assumed for one glob pattern in [record] signals (e.g. 'drive1.*')."""
_UNITS = {"": 1, "b": 1, "k": 1e3, "kb": 1e3, "m": 1e6, "mb": 1e6, "g": 1e9, "gb": 1e9, "t": 1e12, "tb": 1e12,
          "kib": 2 ** 10, "mib": 2 ** 20, "gib": 2 ** 30, "tib": 2 ** 40}


class BudgetError(ValueError):
    """The run's estimated output or memory exceeds the budget (message has both)."""


def parse_size(text: str | float | int, what: str = "size") -> float:
    """``"2 GB"``, ``"500MiB"``, ``"1e9"`` -> bytes; ValueError naming ``what`` otherwise."""
    if isinstance(text, (int, float)):
        value = float(text)
    else:
        match = re.fullmatch(r"\s*([0-9.eE+-]+)\s*([A-Za-z]*)\s*", str(text))
        unit = match.group(2).lower() if match else None
        if not match or unit not in _UNITS:
            raise ValueError(f"{what}: expected a size like '2 GB', '500 MiB' or a number of bytes, got {text!r}")
        try:
            value = float(match.group(1)) * _UNITS[unit]
        except ValueError:
            raise ValueError(f"{what}: expected a size like '2 GB', got {text!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise ValueError(f"{what}: expected a positive size, got {text!r}")
    return value


def human(n: float) -> str:
    """Bytes as a short decimal size (``'1.3 GB'``)."""
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n:.0f} B"


@dataclass
class Estimate:
    """Bytes the run writes and holds at most; ``parts`` says where they come from."""

    output_bytes: float = 0.0
    memory_bytes: float = 0.0
    parts: dict[str, float] = field(default_factory=dict)

    def add(self, name: str, output: float = 0.0, memory: float = 0.0) -> None:
        self.output_bytes += output
        self.memory_bytes += memory
        if output:
            self.parts[name] = self.parts.get(name, 0.0) + output

    def describe(self) -> str:
        parts = ", ".join(f"{k} {human(v)}" for k, v in self.parts.items() if v >= 1e3)
        return (f"about {human(self.output_bytes)} of output ({parts or 'small files'}) and "
                f"{human(self.memory_bytes)} of memory")


def _signal_count(signals: list[str]) -> int:
    return sum(GLOB_SIGNALS if any(c in s for c in "*?[") and not s.endswith("]") else 1 for s in signals)


def estimate_run(doc: dict[str, Any], timeseries_format: str = "parquet", in_memory: bool = False) -> Estimate:
    """Estimate the output and memory of the validated scenario ``doc`` (``in_memory``: a paced
    or split cell run, which holds its recording and controller log until the loop ends)."""
    est = Estimate()
    sim = doc.get("simulation") or {}
    stop = float(sim.get("stop_time") or 0.0)
    if not math.isfinite(stop) or stop <= 0:
        return est
    bpv = BYTES_PER_VALUE.get(timeseries_format, BYTES_PER_VALUE["csv"])
    record = doc.get("record") or {}
    controller = doc.get("controller")
    signals = _signal_count(list(record.get("signals") or []))
    if isinstance(controller, dict) and doc.get("fmus"):  # a robot-cell job
        modes = max(1, len(controller.get("modes") or [None]))
        period = float(controller.get("period") or 400e-6)
        record_period = float(record.get("period") or (doc.get("tracker") or {}).get("period") or 1e-3)
        rows = stop / record_period
        cycles = stop / period
        columns = signals + CELL_DEFAULT_COLUMNS
        est.add("time series", modes * rows * columns * bpv, 0.0)
        est.add("controller logs", modes * cycles * CONTROLLER_LOG_COLUMNS * bpv,
                cycles * CONTROLLER_LOG_COLUMNS * MEMORY_BYTES_PER_VALUE if in_memory else 0.0)
        est.add("TCP series", modes * rows * TCP_COLUMNS * bpv, 0.0)
        if (doc.get("results") or {}).get("can_log", False):
            blf = (doc.get("results") or {}).get("can_log_format", "parquet") == "blf"
            est.add("CAN logs", modes * cycles * (CAN_BYTES_PER_CYCLE if blf else COLUMNAR_CAN_BYTES_PER_CYCLE))
        speed = float((doc.get("path") or {}).get("speed") or 1.0)
        window_rows = min(rows, ISO_PATH_S_AT_1_M_S / max(speed, 1e-3) / record_period)
        chunk = rows if in_memory else min(rows, EVAL_CHUNK_ROWS)
        # the recording (or one chunk of it) with its TCP columns, and the motion window's samples
        est.memory_bytes += (chunk * (columns + TCP_COLUMNS) + window_rows * TCP_COLUMNS) * MEMORY_BYTES_PER_VALUE
    elif record:
        rows = stop / float(record.get("period") or 1.0)
        est.add("time series", rows * (1 + signals) * bpv)
    return est


def default_limits(out_dir: Path) -> tuple[float, float]:
    """(output, memory) budget in bytes without options: the free space of ``out_dir``'s
    file system minus 5 %, and half the physical memory."""
    probe = Path(out_dir)
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    try:  # an unwritable folder is reported by the results-folder check, not as a full disk
        free = shutil.disk_usage(probe).free * 0.95 if os.access(probe, os.W_OK) else math.inf
    except OSError:
        free = math.inf
    try:
        ram = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2
    except (ValueError, OSError, AttributeError):
        ram = math.inf
    return free, ram


def check_budget(estimate: Estimate, out_dir: Path, max_output: str | float | None = None,
                 max_memory: str | float | None = None) -> None:
    """BudgetError when ``estimate`` exceeds the budget (options, else the environment, else
    :func:`default_limits`)."""
    free, ram = default_limits(out_dir)
    out_what = "--max-output" if max_output is not None else "$COSIM_MAX_OUTPUT"
    mem_what = "--max-memory" if max_memory is not None else "$COSIM_MAX_MEMORY"
    max_output = max_output if max_output is not None else os.environ.get("COSIM_MAX_OUTPUT")
    max_memory = max_memory if max_memory is not None else os.environ.get("COSIM_MAX_MEMORY")
    out_limit = parse_size(max_output, out_what) if max_output not in (None, "") else free
    mem_limit = parse_size(max_memory, mem_what) if max_memory not in (None, "") else ram
    problems = []
    if estimate.output_bytes > out_limit:
        source = out_what if max_output not in (None, "") else f"free space in {out_dir}"
        problems.append(f"output {human(estimate.output_bytes)} > {human(out_limit)} ({source})")
    if estimate.memory_bytes > mem_limit:
        source = mem_what if max_memory not in (None, "") else "half the physical memory"
        problems.append(f"memory {human(estimate.memory_bytes)} > {human(mem_limit)} ({source})")
    if problems:
        raise BudgetError(f"the run would need {estimate.describe()}: {'; '.join(problems)}. Shorten "
                          f"[simulation] stop_time, record less, raise --max-output/--max-memory "
                          f"($COSIM_MAX_OUTPUT/$COSIM_MAX_MEMORY) or pass --ignore-budget")


__all__ = ["BudgetError", "Estimate", "check_budget", "default_limits", "estimate_run", "human", "parse_size"]
