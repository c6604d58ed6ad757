"""The schema of the ``[execution]`` and ``[realtime]`` tables of a scenario (the tables
themselves are documented, and turned into run options, in :mod:`cosim.execution.config`).

It lives with the other table schemas so that ``cosim.scenario`` needs nothing from
``cosim.execution.timing`` (imports inside ``cosim/`` point from the jobs and execution modes to
the scenario layer, not back).
"""
from __future__ import annotations

import functools
from typing import Any

from cosim.scenario.schema import Boolean, Field, Integer, Number, String, Table, Where

EXECUTION_MODES = ("in_process", "split")
OVERRUN_POLICIES = ("hold", "skip", "lost_frame")
SCHEDULING = ("fifo", "normal")
DEFAULT_SPIN_S = 100e-6
DEFAULT_RECEIVE_TIMEOUT_S = 2.0


@functools.lru_cache(maxsize=1)
def _tables() -> tuple[Any, Any]:
    """The [execution] and [realtime] table specs (built once, on first use)."""

    class Tolerance(String):
        """'auto' or a time (s)."""

        @property
        def expected(self) -> str:  # type: ignore[override]
            return "'auto' or a time in s >= 0 (e.g. '10 us')"

        def check(self, value: Any, where: Where) -> Any:
            if value == "auto":
                return "auto"
            if isinstance(value, bool):
                raise where.error(self.expected, value)
            try:
                return Number(unit="s", min=0, max=1.0).check(value, where)
            except ValueError:
                raise where.error(self.expected, value) from None

    class Cpu(String):
        """'auto', 'none' or a CPU index."""

        @property
        def expected(self) -> str:  # type: ignore[override]
            return "'auto' (the highest-numbered usable CPU), 'none' (not pinned) or a CPU index >= 0"

        def check(self, value: Any, where: Where) -> Any:
            if value in ("auto", "none"):
                return value
            if isinstance(value, int) and not isinstance(value, bool) and value >= 0:
                return value
            raise where.error(self.expected, value)

    execution = Table({
        "mode": Field(String(choices=EXECUTION_MODES), default="in_process",
                      doc="'in_process' (one process) or 'split' (controller | drives + plant, python-can between)"),
        "realtime": Field(Boolean(), default=False, doc="pace the run at the controller cycle (wall clock)"),
        "receive_timeout": Field(Number(unit="s", gt=0, max=600), default=DEFAULT_RECEIVE_TIMEOUT_S,
                                 doc="split mode: wall seconds a side waits for the other side's frames"),
    }, doc="the [execution] table")
    realtime = Table({
        "overrun_policy": Field(String(choices=OVERRUN_POLICIES), default="hold",
                                doc="what a late cycle's telegrams carry: 'hold', 'skip' or 'lost_frame'"),
        "spin": Field(Number(unit="s", min=0, max=0.1), default=DEFAULT_SPIN_S,
                      doc="busy-wait before each wall deadline: a time in s in [0, 0.1]"),
        "scheduling": Field(String(choices=SCHEDULING), default="fifo",
                            doc="'fifo': ask for SCHED_FIFO (falls back to normal, reported) or 'normal'"),
        "fifo_priority": Field(Integer(min=1, max=99), default=10, doc="the SCHED_FIFO priority asked for"),
        "cpu": Field(Cpu(), default="auto", doc="the CPU the paced loop is pinned to"),
        "tolerance": Field(Tolerance(), default="auto",
                           doc="lateness above which a cycle is an overrun; 'auto': the cycle time minus the "
                               "isochronous phase"),
        "histogram_bins": Field(Integer(min=5, max=1000), default=60, doc="bins of the lateness histogram"),
    }, doc="the [realtime] table")
    return execution, realtime


def execution_fields() -> dict[str, Any]:
    """``{"execution": Field, "realtime": Field}`` to merge into a job's document schema
    (cosim.scenario.cosim_tables.COSIM_FIELDS does)."""

    execution, realtime = _tables()
    return {"execution": Field(execution, default={}, doc="how the run is executed: one process or split, paced or not"),
            "realtime": Field(realtime, default={}, doc="pacing of a wall-clock run: overruns, scheduling, statistics")}


def execution_tables(doc: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """The ``[execution]`` and ``[realtime]`` tables of a validated document with every default
    filled (an absent table validates as ``{}`` without its fields' defaults)."""
    tables = []
    for key, spec in zip(("execution", "realtime"), _tables()):
        table = doc.get(key) or {}
        tables.append(spec.check(dict(table), Where(None) / key))
    return tables[0], tables[1]


__all__ = ["DEFAULT_RECEIVE_TIMEOUT_S", "DEFAULT_SPIN_S", "EXECUTION_MODES", "OVERRUN_POLICIES", "SCHEDULING",
           "execution_fields", "execution_tables"]
