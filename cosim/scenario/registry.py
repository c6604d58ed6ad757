"""Job types: what ``python -m cosim run`` does with a scenario, chosen by ``[scenario] job``.

A job module calls ``register_job`` at import time; the modules are listed in
``JOB_MODULES`` (add yours with a one-line edit) and imported on first lookup.
"""
from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from cosim.scenario.context import RunContext
    from cosim.scenario.loader import Scenario
    from cosim.scenario.schema import Table, Where

#: Modules that register job types when imported.
JOB_MODULES: tuple[str, ...] = (
    "cosim.scenario.fmus_job",
    "cosim.jobs.calibration",
    "cosim.jobs.iso9283",
    "cosim.jobs.identification",
    "cosim.jobs.fieldbus_fault",
    "cosim.jobs.planners",
    "cosim.jobs.compare",
)

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


_JOBS: dict[str, JobType] = {}
_loaded = False


def register_job(name: str, runner: JobRunner, schema: "Table",
                 check: "Callable[[dict, Where], None] | None" = None, description: str = "") -> JobType:
    """Register (or replace) the job type ``name``; returns it."""
    job = JobType(name, runner, schema, check, description)
    _JOBS[name] = job
    return job


def _load() -> None:
    global _loaded
    if not _loaded:
        _loaded = True
        for module in JOB_MODULES:
            importlib.import_module(module)


def get_job(name: str) -> JobType | None:
    """The job type registered as ``name`` (None when unknown)."""
    _load()
    return _JOBS.get(name)


def job_names() -> list[str]:
    """Names of all registered job types."""
    _load()
    return sorted(_JOBS)
