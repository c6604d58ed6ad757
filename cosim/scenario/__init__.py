"""Scenario files: loading, validation (reusable schema helper), job registry, run context."""
from cosim.scenario.context import RunContext
from cosim.scenario.cosim_tables import COSIM_FIELDS, add_record, build_master, check_cosim_tables
from cosim.scenario.errors import ScenarioError
from cosim.scenario.loader import SCENARIO_FIELD, SCENARIO_TABLE, Scenario, load_document, load_scenario
from cosim.scenario.registry import JOB_MODULES, JobType, get_job, job_names, register_job

__all__ = [
    "COSIM_FIELDS", "JOB_MODULES", "JobType", "RunContext", "SCENARIO_FIELD", "SCENARIO_TABLE", "Scenario",
    "ScenarioError", "add_record", "build_master", "check_cosim_tables", "get_job", "job_names", "load_document",
    "load_scenario", "register_job",
]
