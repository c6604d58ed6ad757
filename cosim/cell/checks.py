"""Checks of a robot-cell scenario document, shared by the jobs that run the cell.

A job that runs the cell (:func:`cosim.execution.run_cell`: ``iso9283``,
``fieldbus_fault``, ``identification``, ``planners``) calls :func:`check_cell` from its
own ``check``: the cell's FMUs, their variables and parameters, its connections (the
generated ones plus the scenario's own), the ``[fieldbus]`` table and the periods (s) of
controller, tracker and recorder against the master's steps.
Every problem is a ``ScenarioError`` (a ValueError) at the key that holds it.
"""
from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping
from typing import Any

from cosim.cell import wiring
from cosim.cell.protection import check_protection_parameters
from cosim.scenario.cosim_tables import check_cosim_tables
from cosim.scenario.schema import Table, Where

PLANT_VARIABLES = frozenset({"tau[1]", "q[6]", "p[78]", "payload_mass"})
"""Variables the cell needs of the plant FMU (``rx130l_plant``)."""

DRIVE_VARIABLES = wiring.REQUIRED_DRIVE_VARIABLES
"""Variables the cell needs of every drive FMU: the required ones of the minimal drive
interface (``fmus.servo_drive.interface``, docs/explanation/fmus.md)."""


def fill_defaults(doc: dict[str, Any], schema: Table, keys: Iterable[str]) -> None:
    """Give every table ``keys`` of ``doc`` that is absent or empty its fields' defaults from
    ``schema`` (an absent table gets the schema default ``{}`` without them)."""
    for key in keys:
        if not doc.get(key):
            doc[key] = schema.fields[key].spec.check({}, Where(None) / key)


def is_integer_multiple(value: float, base: float) -> bool:
    """Whether ``value`` is a positive whole multiple of ``base`` (same unit), to 1e-9 relative."""
    ratio = value / base
    if not math.isfinite(ratio):  # e.g. macro_step = 5e-324: no whole number of steps
        return False
    return round(ratio) >= 1 and abs(ratio - round(ratio)) <= 1e-9 * max(1.0, ratio)


def check_cell(doc: dict[str, Any], where: Where, job_set_drive_parameters: Mapping[str, str] | None = None,
               run_length_s: float | None = None) -> None:
    """Check what a robot cell needs of a scenario document (tables filled with their defaults).

    In order: the ``[[fmus]]`` ``plant`` and ``drive1`` .. ``drive6`` exist; the standard
    co-simulation tables (:func:`~cosim.scenario.cosim_tables.check_cosim_tables`, with the
    cell's master variables and its connections: :func:`~cosim.cell.wiring.merged_connections`);
    the FMUs have :data:`PLANT_VARIABLES` / :data:`DRIVE_VARIABLES`;
    no drive sets a parameter of ``job_set_drive_parameters`` (parameter name -> what is
    expected instead, for the message) and the plant none of
    :data:`~cosim.cell.wiring.JOB_SET_PLANT_PARAMETERS`; the drives' and the plant's protection
    parameters are within what the drive and the arm allow
    (:func:`~cosim.cell.protection.check_protection_parameters`); the ``[fieldbus]`` table is
    valid and its cycle time equals ``[controller] period`` (s); the controller and
    ``[tracker]`` periods are whole multiples of ``[simulation] macro_step`` and of the cell's
    FMU steps; the ``[record]`` period is a whole multiple of ``macro_step``.

    The fieldbus table is also checked against the cell (:func:`check_cell_fieldbus`: one node
    per drive, a python-can interface that exists, options it takes, cycle 0 at t = 0, fault
    plans inside ``run_length_s`` when given).

    Raises ScenarioError (a ValueError) at the first key that is wrong.
    """
    from cosim.master import load_model_description
    from fmus.fmu import variables_of
    from fieldbus import FieldbusConfig, FieldbusConfigError

    by_name = {fmu["name"]: (i, fmu) for i, fmu in enumerate(doc["fmus"])}
    needed = {wiring.PLANT: wiring.PLANT_FMU, **{d: wiring.DRIVE_FMU for d in wiring.DRIVES}}
    for name, builtin in needed.items():
        if name not in by_name:
            raise (where / "fmus").error(f"an [[fmus]] table with name = {name!r} (builtin = {builtin!r}): "
                                         f"the cell needs {sorted(needed)}", problem=f"FMU {name!r} missing")
    variables = {name: type_ for name, (type_, _) in wiring.cell_variables().items()}
    # the scenario's own connections first (their indices are the file's), then the generated ones
    try:
        drive_variables = wiring.drive_variables_of(doc["fmus"])
    except Exception:  # noqa: BLE001 - an FMU file that cannot be read: check_cosim_tables names it
        drive_variables = None
    check_cosim_tables({**doc, "connections": wiring.merged_connections(doc["connections"], drive_variables)}, where,
                       master_variables=variables)
    for name, builtin in needed.items():
        i, fmu = by_name[name]
        have = set(variables_of(load_model_description(fmu["path"])))  # FMI 3.0: array elements q[1]..
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
                "no q0/qd0/p/payload/geometric_errors parameters: the job sets them from [true_robot] and the path start",
                problem=f"parameter {key!r} is set by the job")
    check_protection_parameters(doc, where)
    try:
        fb = FieldbusConfig.from_dict(doc["fieldbus"], source=str(where.file) if where.file else "<scenario>")
    except FieldbusConfigError as exc:
        at = where / "fieldbus"
        for part in re.findall(r"\[\d+\]|[^.\[\]]+", str(exc.key)):  # "faults.bursts[0].node" -> its keys
            at = at[int(part[1:-1])] if part.startswith("[") else at / part
        raise at.error(exc.expected, exc.given) from None
    check_cell_fieldbus(fb, doc["fieldbus"], where / "fieldbus", len(wiring.DRIVES), run_length_s)
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
    if doc.get("record") is not None and doc["record"].get("file", "timeseries") not in ("timeseries",
                                                                                      "timeseries.csv"):
        raise (where / "record" / "file").error(
            "no file name here: a robot-cell job writes one time series per mode (timeseries_<mode>.parquet, "
            "or .csv with --timeseries csv)",
            doc["record"]["file"], problem="key the job does not use")
    if doc.get("record") is not None and not is_integer_multiple(doc["record"]["period"], base):
        raise (where / "record" / "period").error(f"a positive integer multiple of macro_step = {base!r} s",
                                                  doc["record"]["period"])


def _interface_parameters(interface: str) -> set[str] | None:
    """Keyword arguments the python-can interface's bus class takes by name (None: cannot tell)."""
    import inspect

    import can

    try:
        from can.interface import _get_class_for_interface

        cls = _get_class_for_interface(interface)
    except Exception:  # noqa: BLE001 - an interface whose driver is missing: no check of its options
        return None
    names: set[str] = set()
    for klass in (cls, can.BusABC):
        for name, par in inspect.signature(klass.__init__).parameters.items():
            if name != "self" and par.kind not in (par.VAR_KEYWORD, par.VAR_POSITIONAL):
                names.add(name)
    return names


def check_cell_fieldbus(fb, table: Mapping[str, Any], where: Where, joints: int,
                        run_length_s: float | None = None) -> None:
    """What the cell needs of its validated fieldbus configuration ``fb`` (``table`` = the [fieldbus] table
    as given, ``where`` its position): ``nodes`` equal to the ``joints`` drives, a python-can
    interface that is installed, ``bus.options`` the interface takes (python-can passes unknown
    keyword arguments through silently), ``start_time_s`` = 0 (the cell's master starts at 0 s,
    cycle k is at k * cycle time) and, with ``run_length_s``, fault bursts and silent nodes that
    start within the run."""
    import can

    if fb.nodes != joints:
        raise (where / "nodes").error(f"{joints} (one controlled node per servo drive of the cell)", fb.nodes)
    interface = fb.bus.interface
    known = set(getattr(can.interfaces, "VALID_INTERFACES", ())) | {"simbus"}
    if interface not in known:
        raise (where / "bus" / "interface").error(f"a python-can interface installed here: {', '.join(sorted(known))}",
                                                  interface, problem="unknown interface")
    if fb.bus.options:
        accepted = _interface_parameters(interface)
        if accepted is not None:
            used = {"channel", "can_filters"}
            for key in fb.bus.options:
                if key not in accepted or key in used:
                    raise (where / "bus" / "options" / key).error(
                        f"a keyword argument the {interface!r} bus takes and the cell does not set itself "
                        f"({', '.join(sorted(accepted - used)) or 'none'})", fb.bus.options[key],
                        problem="option the interface would ignore")
    if fb.start_time_s != 0.0:
        raise (where / "start_time_s").error("0 (the cell's simulation starts at t = 0 s with fieldbus cycle 0)",
                                             table.get("start_time_s"), problem="not supported in a robot cell")
    if run_length_s is None:
        return
    cycles = int(run_length_s / fb.cycle_time_s + 1e-9)
    faults = table.get("faults") or {}
    for i, burst in enumerate(fb.faults.bursts):
        if burst.start_cycle >= cycles:
            raise (where / "faults" / "bursts")[i].error(
                f"start_cycle < {cycles} (the run has {cycles} cycles of {fb.cycle_time_s * 1e6:g} us in "
                f"stop_time = {run_length_s:g} s)", (faults.get("bursts") or [{}])[i].get("start_cycle"),
                problem="burst after the end of the run")
    for i, node in enumerate(fb.faults.silent_nodes):
        if node.from_cycle >= cycles:
            raise (where / "faults" / "silent_nodes")[i].error(
                f"from_cycle < {cycles} (the run has {cycles} cycles of {fb.cycle_time_s * 1e6:g} us in "
                f"stop_time = {run_length_s:g} s)", node.from_cycle, problem="silent node after the end of the run")
