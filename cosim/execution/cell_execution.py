"""The execution one ``cosim run`` chose: its mode and options, and what its runs measured.

``python -m cosim run`` puts a :class:`CellExecution` on ``RunContext.execution`` when the run
is not the plain simulated one; :func:`cosim.execution.run_cell` runs every cell of the job in
its :attr:`~CellExecution.mode` with its options and tells it when a run starts and when it has
ended (it observes, it runs nothing). The execution writes two summary fields: ``execution``
(the options) and, for paced runs, ``realtime``::

    "realtime": {"cycles", "overruns", "overrun_fraction",
                 "lateness": {"p50_us", "p99_us", "max_us", "mean_us"},   # all runs of the job
                 "histogram": "jitter.png", "policy", "scheduling", "tolerance_us", "spin_us",
                 "load_average_before", "load_average_after",
                 "runs": {<label>: {same statistics, "histogram": "jitter_<label>.png",
                                    "series": "lateness_<label>.parquet" (every cycle), ...}}}
"""
from __future__ import annotations

from typing import Any

from cosim.execution.config import ExecutionOptions
from cosim.execution.timing.pacer import LatenessLog
from cosim.execution.timing.stats import (LATENESS_UNITS, combine, lateness_columns, lateness_summary, load_average,
                                          write_histogram)

#: Jobs whose runs go through cosim.execution.run_cell (and so honour --realtime/--split).
CELL_JOBS = frozenset({"iso9283", "fieldbus_fault", "identification", "planners", "compare"})


class CellExecution:
    """The execution options of one ``cosim run`` and what its paced runs measured."""

    def __init__(self, options: ExecutionOptions) -> None:
        self.options = options
        self.logs: dict[str, LatenessLog] = {}
        self.runs: dict[str, dict[str, Any]] = {}
        self.period_s: float | None = None
        self.tolerance_s: float | None = None
        self.split_runs: dict[str, dict[str, Any]] = {}
        self._load_before: dict[str, Any] = {}

    @property
    def active(self) -> bool:
        return self.options.active

    @property
    def mode(self) -> str:
        """The execution mode of the cells (:data:`cosim.execution.MODES`)."""
        return self.options.cell_mode

    def started(self, cell) -> None:
        """A run of ``cell`` starts (:func:`cosim.execution.run_cell`): the load average before it."""
        self._load_before[cell.label] = load_average()

    def finished(self, cell, run, ctx) -> None:
        """The run of ``cell`` has ended (``run`` its :class:`cosim.cell.run.CellRun`): the summary's
        ``execution`` and, for a paced run, its lateness report (``realtime``)."""
        opts = self.options
        load_before = self._load_before.pop(cell.label, None)
        if opts.split:
            self.split_runs[cell.label] = run.split
        fields: dict[str, Any] = {"execution": {**opts.as_dict(), **({"split": self.split_runs} if opts.split else {})}}
        if run.pacer is not None:
            fields["realtime"] = self._report(ctx, cell.label, run.pacer, run.scheduling, load_before)
        ctx.summary.update(**fields)

    def _report(self, ctx, label: str, pacer, granted: str, load_before) -> dict[str, Any]:
        s = self.options.settings
        period = pacer.period_ns * 1e-9
        tolerance = pacer.tolerance_ns * 1e-9
        self.period_s, self.tolerance_s = period, tolerance
        log = pacer.log
        self.logs[label] = log
        run = lateness_summary(log, pacer.thresholds)
        run["series"] = ctx.write_series(f"lateness_{label}", lateness_columns(log, period, tolerance), LATENESS_UNITS)
        run["histogram"] = write_histogram(ctx.path(f"jitter_{label}.png"), log, period_s=period,
                                           tolerance_s=tolerance, bins=s.histogram_bins,
                                           title=f"{label}: {log.count} paced cycles, "
                                                 f"{int(log.overrun[:log.count].sum())} overruns").name
        run["scheduling"] = granted
        run["load_average_before"] = load_before
        run["load_average_after"] = load_average()
        self.runs[label] = run
        total = combine(list(self.logs.values()))
        out = lateness_summary(total, pacer.thresholds)
        out["histogram"] = write_histogram(ctx.path("jitter.png"), total, period_s=period, tolerance_s=tolerance,
                                           bins=s.histogram_bins).name
        out.update(policy=s.overrun_policy, period_us=period * 1e6, tolerance_us=tolerance * 1e6,
                   spin_us=s.spin_s * 1e6, scheduling=granted, mode=self.options.mode,
                   load_average_before=next(iter(self.runs.values()))["load_average_before"],
                   load_average_after=run["load_average_after"], runs=self.runs)
        return out
