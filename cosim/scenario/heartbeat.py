"""The heartbeat of a run: the master task :meth:`cosim.scenario.context.RunContext.attach` adds
(progress bar, summary.json ``sim_time_s``, what a crash would leave). An observer of the run
in its own module: the master calls it, it reads the run's context and writes the summary
and the progress bar, and never calls back into the master's run loop (except to make the
recorders durable when an FMU of the user's runs in this process).
"""
from __future__ import annotations

import time
from typing import Any

#: Wall-time intervals between progress-bar and summary.json updates, s.
PROGRESS_INTERVAL_S = 0.2
SUMMARY_INTERVAL_S = 2.0


class Heartbeat:
    """The heartbeat task of ``master`` in the run of ``ctx`` (a RunContext): called with the
    simulated time ``t`` at every heartbeat tick."""

    def __init__(self, ctx: Any, master: Any) -> None:
        self.ctx = ctx
        self.master = master
        self.write_through = ctx.write_through
        self.bar_at = 0.0
        self.summary_at = time.perf_counter()
        self.guard_at = 0.0

    def __call__(self, t: float) -> None:
        now = time.perf_counter()
        ctx, master = self.ctx, self.master
        if self.write_through:  # an FMU of the user's in this process: a crash keeps the rows up to here
            master.flush_recorders()
        ctx.summary.note_time(ctx._base + t - master.start_time, t)  # for the supervisor: two numbers
        if ctx._bar is not None and now - self.bar_at > PROGRESS_INTERVAL_S:
            ctx._bar.update(t - master.start_time)
            self.bar_at = now
        if now - self.summary_at > SUMMARY_INTERVAL_S:
            ctx.summary.progress(ctx._base + t - master.start_time, at_s=t)
            self.summary_at = now
        elif now - self.guard_at > PROGRESS_INTERVAL_S:  # what a crash would leave (crashguard)
            ctx.summary.note_progress(ctx._base + t - master.start_time, at_s=t)
            self.guard_at = now
