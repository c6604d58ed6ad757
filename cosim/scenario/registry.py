"""Job types: what ``python -m cosim run`` does with a scenario, chosen by ``[scenario] job``.

The job modules are listed in ``JOB_MODULES`` (add yours with a one-line edit) and imported on
first lookup; each defines its job type as the module attribute ``JOB`` (a
:class:`~cosim.scenario.job_type.JobType`), which the registry reads, so a job module never calls
back into the registry while it is imported. Code outside ``JOB_MODULES`` (a script, a test) adds
a job type with ``register_job``.
"""
from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import TYPE_CHECKING

from cosim.scenario.job_type import JobRunner, JobType

if TYPE_CHECKING:
    from cosim.scenario.schema import Table, Where

#: Modules that define a job type as their attribute ``JOB``.
JOB_MODULES: tuple[str, ...] = (
    "cosim.scenario.fmus_job",
    "cosim.jobs.calibration",
    "cosim.jobs.iso9283",
    "cosim.jobs.identification",
    "cosim.jobs.fieldbus_fault",
    "cosim.jobs.planners",
    "cosim.jobs.compare",
)

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
            job = getattr(importlib.import_module(module), "JOB", None)
            if job is not None:  # a module without JOB registered itself (register_job) while imported
                _JOBS[job.name] = job


def get_job(name: str) -> JobType | None:
    """The job type registered as ``name`` (None when unknown)."""
    _load()
    return _JOBS.get(name)


def job_names() -> list[str]:
    """Names of all registered job types."""
    _load()
    return sorted(_JOBS)


__all__ = ["JOB_MODULES", "JobRunner", "JobType", "get_job", "job_names", "register_job"]
