"""Job ``fmus``: run the scenario's FMUs and connections on the master, record, nothing else.

The generic job: any FMI 2.0 co-simulation FMUs, no controller. Its document is the
``[scenario]`` table plus the standard co-simulation tables (cosim_tables.py).
"""
from __future__ import annotations

from typing import Any

from cosim.scenario.context import RunContext
from cosim.scenario.cosim_tables import COSIM_FIELDS, add_record, build_master, check_cosim_tables
from cosim.scenario.loader import SCENARIO_FIELD, Scenario
from cosim.scenario.registry import register_job
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
        ctx.summary.update(engine=master.engine.name, fmus={f["name"]: str(f["path"]) for f in doc["fmus"]},
                           timeseries=None if recorder is None else recorder.sink.path.name)
        ctx.execute(master)
    return {"rows_recorded": 0 if recorder is None else recorder.rows_written}


register_job("fmus", run_fmus_job, SCHEMA, check_cosim_tables,
             "co-simulate the listed FMUs and connections and record signals (no controller)")
