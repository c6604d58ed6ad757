"""A scenario as an SSP 1.0 archive (``python -m cosim export-ssp``, docs/how-to/ssp.md).

The archive itself (SSD, SSV, the FMUs) is written by :mod:`cosim.ssp`, which knows FMUs,
connections and master variables only; this module loads the scenario and, for a robot
cell, gives it the FMUs, parameter values and connections the cell sets (true robot, drive
parameters of each axis, the generated wiring), so it sits on the cell's floor.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from fmus.fmu import load_model_description, variables_of
from cosim.cell import wiring
from cosim.cell.parts import make_true_robot
from cosim.master.variables import bus_type, parse_connection
from cosim.scenario import load_scenario
from cosim.ssp.write import export_document


def _cell_parameters(doc: dict[str, Any]) -> list[dict[str, Any]] | None:
    """For a robot-cell job: the [[fmus]] with the start values the cell gives its plant and drives
    (the seeded true robot's parameters and payload, each axis's drive parameters), the plant's start
    pose left at the scenario's/FMU's values (the cell computes it from the path at run time)."""
    if "true_robot" not in doc:
        return None
    names = {f["name"] for f in doc["fmus"]}
    if wiring.PLANT not in names or not set(wiring.DRIVES) <= names:
        return None
    plant = next(f for f in doc["fmus"] if f["name"] == wiring.PLANT)
    md = variables_of(load_model_description(plant["path"]))
    q0 = [plant["parameters"].get(f"q0[{i}]", float(md[f"q0[{i}]"].start)) for i in range(1, 7)]
    fmus = wiring.cell_fmus(doc["fmus"], make_true_robot(doc["true_robot"]), q0)
    for fmu in fmus:
        if fmu["name"] == wiring.PLANT:  # keep only what the scenario itself says about the start pose
            for key in [k for k in fmu["parameters"] if k.startswith(("q0[", "qd0[")) and k not in plant["parameters"]]:
                del fmu["parameters"][key]
    return fmus


def export_ssp(scenario: str | Path, out: str | Path) -> Path:
    """Export a scenario file's FMUs, connections and parameter values as ``out`` (.ssp).

    Works for every job built on the ``[[fmus]]`` tables; for robot-cell jobs (a
    ``[true_robot]`` table, FMUs ``plant`` and ``drive1..6``) the parameter values are the
    ones the cell sets (true robot, drive parameters of each axis). Raises ScenarioError
    for an invalid scenario.
    """
    loaded = load_scenario(scenario)
    doc = loaded.data
    cell_fmus = _cell_parameters(doc)
    fmus = cell_fmus or [dict(f) for f in doc["fmus"]]
    connections = list(doc.get("connections", []))
    if cell_fmus is not None:  # a robot cell: its generated wiring plus the scenario's own connections
        connections = wiring.merged_connections(connections, wiring.drive_variables_of(fmus))
    master_variables: dict[str, str] = {}
    descriptions = {f["name"]: variables_of(load_model_description(f["path"])) for f in fmus}
    for text in connections:
        spec = parse_connection(text)
        owner = spec.source.split(".", 1)[0]
        if owner not in descriptions:
            dst_inst, dst_var = spec.destination.split(".", 1)
            master_variables[spec.source] = bus_type(descriptions[dst_inst][dst_var].type)
    sim = doc["simulation"]
    return export_document(fmus, connections, out, name=loaded.name,
                           stop_time=sim["stop_time"], macro_step=sim["macro_step"], coupling=sim["coupling"],
                           master_variables=master_variables,
                           description=doc["scenario"].get("description", ""))


__all__ = ["export_ssp"]
