"""What a job gets to run with: output folder, summary.json, progress bar, time-series sinks.

The ``run`` command creates a ``RunContext`` (which writes summary.json with
``status: "running"``), calls the job's runner, and finishes the summary with
``"ok"`` or ``"failed"``. Inside the runner, for each Master::

    ctx.attach(master, total_s=stop_time, label="standard")   # before master.initialize()
    master.initialize(stop_time)
    ctx.execute(master)                                       # runs it with progress + summary updates
"""
from __future__ import annotations

import math
import time
from pathlib import Path

from cosim.master import Master
from cosim.results.progress import ProgressBar
from cosim.results.summary import SummaryWriter
from cosim.results.timeseries import SUFFIXES, default_format, sink_for, write_columns
from cosim.scenario.heartbeat import PROGRESS_INTERVAL_S, SUMMARY_INTERVAL_S, Heartbeat  # noqa: F401
from cosim.scenario.loader import Scenario

#: The heartbeat task runs about this many times per attached run.
HEARTBEATS_PER_RUN = 1000


def user_fmu_in_process(doc: dict) -> bool:
    """Whether a scenario document runs an FMU that is not the project's own in the run's process: an
    ``[[fmus]]`` table with ``path`` or ``source`` not run out of process, a ``[controller] fmu``, or a
    ``compare`` controller FMU."""
    from cosim.scenario.cosim_tables import out_of_process

    sim = doc.get("simulation") or {}
    for fmu in doc.get("fmus") or []:
        if isinstance(fmu, dict) and "builtin" not in fmu and not out_of_process(fmu, sim):
            return True
    if (doc.get("controller") or {}).get("fmu"):
        return True
    entries = (doc.get("compare") or {}).get("controllers") or []
    return any(isinstance(e, dict) and (e.get("fmu") or e.get("fmu_source")) for e in entries)


class RunContext:
    """Output folder, summary and progress of one ``cosim run``.

    Attributes:
        scenario: the validated scenario.
        out_dir: results folder (created).
        quiet: no progress bar.
        summary: the SummaryWriter of ``out_dir/summary.json``.
        sim_time_s: simulated seconds completed so far over all executed masters.
        label: label of the master being executed (shown in the bar, reported on failure).
        execution: how robot cells run (:class:`cosim.execution.cell_execution.CellExecution`:
            split, paced) or None (one process, unpaced).
        timeseries_format: ``"parquet"`` (default, ``$COSIM_TIMESERIES``) or ``"csv"``: the
            format of every time series the run writes (:meth:`series_name`).
        write_through: the scenario runs an FMU of the user's in this process (:func:`user_fmu_in_process`):
            at every heartbeat (1000 per run) the recorders write what they hold, so a crash of that
            FMU leaves the rows up to the last simulated time the summary reports.

    ``wall_origin``/``wall_time_from``: where summary.json's wall time starts
    (:class:`cosim.results.summary.SummaryWriter`; default: now, ``"run call"``).
    """

    def __init__(self, scenario: Scenario, out_dir: str | Path, quiet: bool = False, execution=None,
                 timeseries_format: str | None = None, wall_origin: float | None = None,
                 wall_time_from: str = "run call") -> None:
        self.scenario = scenario
        self.write_through = user_fmu_in_process(getattr(scenario, "data", None) or {})
        self.timeseries_format = timeseries_format or default_format()
        if self.timeseries_format not in SUFFIXES:
            raise ValueError(f"timeseries format: expected one of {', '.join(SUFFIXES)}, got {self.timeseries_format!r}")
        self.execution = execution  # cosim.execution.timing.CellExecution (--realtime/--split) or None
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.quiet = quiet
        self.summary = SummaryWriter(self.out_dir / "summary.json", scenario.name, scenario.job.name,
                                     wall_origin=wall_origin, wall_time_from=wall_time_from)
        self.sim_time_s = 0.0
        self.label = ""
        self._bar: ProgressBar | None = None
        self._base = 0.0
        self._totals: dict[int, float] = {}
        self._running: Master | None = None
        self._last_time_s: float | None = None
        self.verdicts: dict[str, dict] = {}
        """label -> the verdict of each cell run of the job (:meth:`note_verdict`)."""

    def note_verdict(self, label: str, entry: dict) -> None:
        """Record the verdict of the cell run ``label`` from its summary record ``entry`` (its
        ``verdict``, ``first_violation``, ``warnings``; cosim/cell/verdict.py). The job's final
        status is the most severe of them; ``cosim run`` prints one line per run from them."""
        verdict = entry.get("verdict") or ("failed" if entry.get("status") == "failed" else "ok")
        self.verdicts[label] = {"verdict": verdict, "first_violation": entry.get("first_violation"),
                                "violations_total": entry.get("violations_total", len(entry.get("violations") or ())),
                                "warnings": list(entry.get("warnings") or ())}

    def note_position(self, label: str, time_s: float, covered_s: float = 0.0) -> None:
        """Record where a run that does not go through :meth:`execute` (the split cell) stopped:
        its ``label``, simulated time (s) and the simulated seconds it covered, for the final status."""
        self.label = label
        self._last_time_s = float(time_s)
        self.summary.note_where(mode=label, at_s=time_s)
        self.sim_time_s += float(covered_s)

    def begin(self, label: str) -> None:
        """Name the part about to be built and run (a mode, an entry): an error before its master
        starts is reported in ``label``, with no simulated time of an earlier part."""
        self.label = label
        self._last_time_s = None

    @property
    def stopped_at_s(self) -> float | None:
        """Simulated time (s) of the master being executed, else where the last one stopped (None before any)."""
        if self._running is not None:
            return self._running.time
        return self._last_time_s

    def path(self, name: str) -> Path:
        """``out_dir / name``."""
        return self.out_dir / name

    def series_name(self, name: str) -> str:
        """The file name of the time series ``name`` (``"tcp_standard"`` or ``"tcp_standard.csv"``)
        in this run's format: ``tcp_standard.parquet`` by default, ``.csv`` on request."""
        stem = name[:-len(Path(name).suffix)] if Path(name).suffix in (".csv", ".parquet") else name
        return stem + SUFFIXES[self.timeseries_format]

    def series_sink(self, name: str, units: dict[str, str] | None = None):
        """A streaming recorder sink writing ``out_dir / series_name(name)`` (Parquet or CSV)."""
        return sink_for(self.path(self.series_name(name)), units)

    csv_sink = series_sink
    """Former name of :meth:`series_sink` (writes the run's format, Parquet by default)."""

    def write_series(self, name: str, columns, units: dict[str, str] | None = None) -> str:
        """Write named columns of equal length as the time series ``name``; return the file name."""
        file = self.series_name(name)
        write_columns(self.path(file), columns, units)
        return file

    def attach(self, master: Master, total_s: float, label: str = "") -> None:
        """Add the heartbeat task (progress bar, summary.json sim_time_s) to ``master`` (before initialize)."""
        period = master.base_step * max(1, math.floor(total_s / HEARTBEATS_PER_RUN / master.base_step))
        self.label = label
        self.summary.note_where(mode=label, at_s=master.start_time)
        master.add_task(Heartbeat(self, master), period, priority=1_000_000, name="cosim.heartbeat")
        self._totals[id(master)] = total_s

    def execute(self, master: Master, until: float | None = None) -> float:
        """Run an initialized master to ``until`` (default its stop_time) with progress; return the time reached.

        ``sim_time_s`` grows by the simulated time covered. SimulationError propagates
        (the run command writes the failed summary).
        """
        start = master.time
        total = self._totals.get(id(master), (until if until is not None else master.stop_time or 0.0) - start)
        self._base = self.sim_time_s
        label = f"{self.scenario.name}{' ' + self.label if self.label else ''}"
        self._bar = ProgressBar(total, label, enabled=not self.quiet)
        self._running = master
        try:
            reached = master.run(until)
        finally:
            self._running = None
            self._last_time_s = master.time
            self.sim_time_s = self._base + (master.time - start)
            self._bar.update(master.time - master.start_time, force=True)
            self._bar.close()
            self._bar = None
        self.summary.progress(self.sim_time_s, at_s=master.time)
        return reached
