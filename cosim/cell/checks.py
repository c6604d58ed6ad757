"""Checks of a robot-cell scenario document, shared by the jobs that run the cell.

A job that runs the cell (:func:`cosim.cell.runner.run_cell`: ``iso9283``,
``fieldbus_fault``, ``identification``, ``planners``) calls :func:`check_cell` from its
own ``check``: the cell's FMUs, their variables and parameters, its connections (the
generated ones plus the scenario's own), the ``[fieldbus]`` table and the periods (s) of
controller, tracker and recorder against the master's steps.
Every problem is a ``ScenarioError`` (a ValueError) at the key that holds it.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from cosim.cell import wiring
from cosim.scenario.cosim_tables import check_cosim_tables
from cosim.scenario.schema import Table, Where

PLANT_VARIABLES = frozenset({"tau[1]", "q[6]", "p[78]", "payload_mass"})
"""Variables the cell needs of the plant FMU (``rx130l_plant``)."""

DRIVE_VARIABLES = frozenset({"target_position", "torque_offset", "controlword", "statusword", "position_actual",
                             "torque_actual"})
"""Variables the cell needs of every drive FMU (``servo_drive``)."""


def fill_defaults(doc: dict[str, Any], schema: Table, keys: Iterable[str]) -> None:
    """Give every table ``keys`` of ``doc`` that is absent or empty its fields' defaults from
    ``schema`` (an absent table gets the schema default ``{}`` without them)."""
    for key in keys:
        if not doc.get(key):
            doc[key] = schema.fields[key].spec.check({}, Where(None) / key)


def is_integer_multiple(value: float, base: float) -> bool:
    """Whether ``value`` is a positive whole multiple of ``base`` (same unit), to 1e-9 relative."""
    ratio = value / base
    return round(ratio) >= 1 and abs(ratio - round(ratio)) <= 1e-9 * max(1.0, ratio)


def check_cell(doc: dict[str, Any], where: Where, job_set_drive_parameters: Mapping[str, str] | None = None) -> None:
    """Check what a robot cell needs of a scenario document (tables filled with their defaults).

    In order: the ``[[fmus]]`` ``plant`` and ``drive1`` .. ``drive6`` exist; the standard
    co-simulation tables (:func:`~cosim.scenario.cosim_tables.check_cosim_tables`, with the
    cell's master variables and its connections: :func:`~cosim.cell.wiring.merged_connections`);
    the FMUs have :data:`PLANT_VARIABLES` / :data:`DRIVE_VARIABLES`;
    no drive sets a parameter of ``job_set_drive_parameters`` (parameter name -> what is
    expected instead, for the message) and the plant none of
    :data:`~cosim.cell.wiring.JOB_SET_PLANT_PARAMETERS`; the ``[fieldbus]`` table is
    valid and its cycle time equals ``[controller] period`` (s); the controller and
    ``[tracker]`` periods are whole multiples of ``[simulation] macro_step`` and of the cell's
    FMU steps; the ``[record]`` period is a whole multiple of ``macro_step``.

    Raises ScenarioError (a ValueError) at the first key that is wrong.
    """
    from cosim.master import load_model_description
    from fieldbus import FieldbusConfig, FieldbusConfigError

    by_name = {fmu["name"]: (i, fmu) for i, fmu in enumerate(doc["fmus"])}
    needed = {wiring.PLANT: wiring.PLANT_FMU, **{d: wiring.DRIVE_FMU for d in wiring.DRIVES}}
    for name, builtin in needed.items():
        if name not in by_name:
            raise (where / "fmus").error(f"an [[fmus]] table with name = {name!r} (builtin = {builtin!r}): "
                                         f"the cell needs {sorted(needed)}", problem=f"FMU {name!r} missing")
    variables = {name: type_ for name, (type_, _) in wiring.cell_variables().items()}
    # the scenario's own connections first (their indices are the file's), then the generated ones
    check_cosim_tables({**doc, "connections": wiring.merged_connections(doc["connections"])}, where,
                       master_variables=variables)
    for name, builtin in needed.items():
        i, fmu = by_name[name]
        have = {v.name for v in load_model_description(fmu["path"]).modelVariables}
        want = PLANT_VARIABLES if name == wiring.PLANT else DRIVE_VARIABLES
        if not want <= have:
            raise (where / "fmus")[i].error(f"a {builtin} FMU (variables {sorted(want)})", str(fmu["path"]),
                                            problem=f"instance {name!r} lacks {sorted(want - have)}")
    for name in wiring.DRIVES:
        i, fmu = by_name[name]
        for key, expected in (job_set_drive_parameters or {}).items():
            if key in fmu["parameters"]:
                raise ((where / "fmus")[i] / "parameters" / key).error(expected, fmu["parameters"][key],
                                                                       problem="parameter set by the job")
    plant_i, plant = by_name[wiring.PLANT]
    for key in plant["parameters"]:
        if key.startswith(wiring.JOB_SET_PLANT_PARAMETERS):
            raise (where / "fmus")[plant_i].error(
                "no q0/qd0/p/payload parameters: the job sets them from [true_robot] and the path start",
                problem=f"parameter {key!r} is set by the job")
    try:
        fb = FieldbusConfig.from_dict(doc["fieldbus"], source=str(where.file) if where.file else "<scenario>")
    except FieldbusConfigError as exc:
        raise (where / "fieldbus" / exc.key).error(exc.expected, exc.given) from None
    ctrl, base = doc["controller"], doc["simulation"]["macro_step"]
    if abs(fb.cycle_time_s - ctrl["period"]) > 1e-12:
        raise (where / "controller" / "period").error(
            f"the fieldbus cycle time {fb.cycle_time_s * 1e6:g} us ([fieldbus] cycle_time_us)", ctrl["period"])
    for table, value in (("controller", ctrl["period"]), ("tracker", doc["tracker"]["period"])):
        if not is_integer_multiple(value, base):
            raise (where / table / "period").error(f"a positive integer multiple of macro_step = {base!r} s", value)
        for fmu in doc["fmus"]:
            step = fmu.get("step", base)
            if fmu["name"] in needed and not is_integer_multiple(value, step):
                raise (where / "fmus")[by_name[fmu["name"]][0]].error(
                    f"a step that divides the {table} period {value!r} s (it reads FMU outputs then)", step,
                    problem="FMU step does not divide the period")
    if doc.get("record") is not None and not is_integer_multiple(doc["record"]["period"], base):
        raise (where / "record" / "period").error(f"a positive integer multiple of macro_step = {base!r} s",
                                                  doc["record"]["period"])
