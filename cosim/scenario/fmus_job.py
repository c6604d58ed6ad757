"""Job ``fmus``: run the scenario's FMUs and connections on the master, record, nothing else.

The generic job: any FMI 2.0 or FMI 3.0 co-simulation FMUs, no controller. An FMU that
ends the simulation itself ends the run normally; ``summary.json`` then says who and when
(``ended_by``). Its document is the
``[scenario]`` table plus the standard co-simulation tables (cosim_tables.py).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from cosim.scenario.context import RunContext
from cosim.scenario.cosim_tables import COSIM_FIELDS, add_record, build_master, check_cosim_tables, out_of_process
from cosim.scenario.loader import SCENARIO_FIELD, Scenario
from cosim.scenario.job_type import JobType
from cosim.scenario.schema import Table

SCHEMA = Table({"scenario": SCENARIO_FIELD, **COSIM_FIELDS}, doc="a scenario document")


def run_fmus_job(scenario: Scenario, ctx: RunContext) -> dict[str, Any]:
    """Co-simulate the FMUs from t = 0 to stop_time, recording [record] into the results folder."""
    doc = scenario.data
    stop_time = doc["simulation"]["stop_time"]
    master = build_master(doc)
    recorder = add_record(master, doc, ctx)
    ctx.attach(master, stop_time)
    with master:
        master.initialize(stop_time)
        if doc.get("system"):  # FMUs from an SSP archive: the archive, and each FMU's path inside it
            ctx.summary.update(system=str(Path(doc["system"]).resolve()))
        ctx.summary.update(engine=master.engine.name,
                           fmus={f["name"]: f.get("ssp_source") or str(f["path"]) for f in doc["fmus"]},
                           out_of_process=[f["name"] for f in doc["fmus"] if out_of_process(f, doc["simulation"])],
                           timeseries=None if recorder is None else recorder.sink.path.name)
        ctx.execute(master)
    fields: dict[str, Any] = {"rows_recorded": 0 if recorder is None else recorder.rows_written}
    if master.ended_by is not None:
        fields["ended_by"] = master.ended_by
    return fields


JOB = JobType("fmus", run_fmus_job, SCHEMA, check_cosim_tables,
              "co-simulate the listed FMUs (FMI 2.0/3.0) and connections and record signals (no controller)")
