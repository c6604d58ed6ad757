"""The plain data one cell run yields (:class:`CellRun`), whatever its execution mode
(:func:`cosim.execution.run_cell`): the recording, the fieldbus summary, the failure, the
timings and what the mode measured. Judged by :func:`cosim.cell.verdict.judge`, evaluated by
:mod:`cosim.cell.evaluation`."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from cosim.master import MemorySink, SimulationError
from cosim.results.timeseries import SeriesFile


@dataclass
class CellRun:
    """What one cell run produced: the recorder file and its rows (also in memory), the
    simulated time reached (s), the fieldbus summary, the wall time of the run (s), the
    stepping engine, the SimulationError that ended it (None: ran to the end), the CPU
    time of this process over the same span as the wall time (s, process_time); for paced
    runs the :class:`cosim.execution.timing.pacer.Pacer` (lateness per cycle) and the scheduling
    granted; for split runs what the two processes reported (``split``); for a user's
    controller its compute time per cycle as the cell measured it (``controller_timing``,
    a :class:`controller.TimingSummary`; None for the built-in controller, which times itself)
    and what the controller contract itself cost per cycle (``port_overhead``, µs:
    :meth:`controller.port.ControllerPort.overhead`)."""

    label: str
    record_path: Any
    rows_recorded: int
    reached_s: float
    fieldbus: dict[str, Any]
    loop_wall_time_s: float
    engine: str
    recording: MemorySink | SeriesFile
    failure: SimulationError | None = None
    loop_cpu_time_s: float = float("nan")
    pacer: Any = None
    scheduling: str = "normal"
    split: dict[str, Any] | None = field(default=None)
    controller_timing: Any = None
    port_overhead: dict[str, float] | None = None
    controller_record: Any = None
    """The controller's log as the run went (``controller_<name>`` in the results folder, Parquet or
    CSV): the built-in controller's own log (None when it stayed in memory: paced and split runs),
    or for a user's controller the cell's :class:`controller.port.CommandLog`."""
    protection_events: list[dict] = field(default_factory=list)
    """The drives' and the plant's protection events (limit reached, end stop hit; the record of
    docs/reference/verdicts.md), one per onset: :func:`cosim.cell.protection.protection_events`, filled by
    :func:`cosim.execution.run_cell` in every mode; judged by :func:`cosim.cell.verdict.judge`."""
    drives_checked: bool = False
    """Whether the run watched the drives' states (``drives_enabled_at_s`` is meaningful)."""
    drives_enabled_at_s: float | None = None
    """Simulated time the six drives first all reported Operation enabled (None: never)."""
    controller_close_error: str | None = None
    """What the controller's ``close()`` raised (one line), None when it closed cleanly."""
