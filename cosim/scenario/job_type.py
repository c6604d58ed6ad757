"""What a job type is: the value of ``[scenario] job``, its runner, its schema and its check.

A job module (one of :data:`cosim.scenario.registry.JOB_MODULES`) defines its job as the
module attribute ``JOB = JobType(...)``; the registry reads it after importing the module.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from cosim.scenario.context import RunContext
    from cosim.scenario.loader import Scenario
    from cosim.scenario.schema import Table, Where

#: runner(scenario, context) -> extra summary.json fields (or None)
JobRunner = Callable[["Scenario", "RunContext"], "dict[str, Any] | None"]


@dataclass(frozen=True)
class JobType:
    """A registered job type.

    Attributes:
        name: the value of ``[scenario] job``.
        runner: runs a validated scenario; returns extra summary fields.
        schema: Table spec of the WHOLE document (including the ``scenario`` table,
            e.g. ``Table({"scenario": SCENARIO_FIELD, ...})``).
        check: optional semantic check ``check(document, where)`` after the schema
            (files, model descriptions, connections), raising ScenarioError.
        description: one line for ``--help``.
    """

    name: str
    runner: JobRunner
    schema: "Table"
    check: "Callable[[dict, Where], None] | None" = None
    description: str = ""


__all__ = ["JobRunner", "JobType"]
