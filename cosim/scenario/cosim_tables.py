"""The standard co-simulation tables of a scenario, their checks, and building a Master from them.

Tables (all quantities SI numbers or unit strings, see units.py)::

    [simulation]  stop_time, macro_step, coupling = "jacobi"|"gauss_seidel", order = [...], engine
    [[fmus]]      name, path = "x.fmu" | builtin = "rx130l_plant"|"servo_drive" | source = "folder", step,
                  debug_logging
    [fmus.parameters]  <variable> = <start value>
    connections = ["a.x -> b.y", ...]
    system = "cell.ssp"   (instead of [[fmus]]: the FMUs, connections and parameters of an SSP 1.0 archive)
    [record]      period, signals = ["plant.q[1]", "drive1.*", ...], file = "timeseries.csv"
    [output]      dir

Any job built on the master reuses these: put ``COSIM_FIELDS`` in its document schema,
call ``check_cosim_tables(doc, where, master_variables)`` in its check, and
``build_master(doc)`` / ``add_record(master, doc, ctx)`` in its runner.
"""
from __future__ import annotations

import math

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from cosim.master import Master, MasterConfigError, Recorder, load_model_description
from fmus.fmu import SUPPORTED_FMUS, variables_of
from cosim.master.master import COUPLINGS, ENGINES
from cosim.master.variables import (MasterTypeUnsupported, bus_type, check_connection_ends, check_declared_range,
                                    check_start_value, is_pattern, matches_pattern, parse_connection, split_signal)
from cosim.results.timeseries import sink_for
from cosim.scenario.execution_tables import execution_fields
from cosim.scenario.schema import (AnyValue, Boolean, Field, FilePath, Integer, List, Number, String, Table, Where)

if TYPE_CHECKING:
    from cosim.scenario.context import RunContext

INSTANCE_PATTERN = r"[A-Za-z_][A-Za-z0-9_]*"


def builtin_fmu_names() -> tuple[str, ...]:
    """Names accepted by ``builtin = ...`` (the project's FMUs built by fmus.build)."""
    try:
        from fmus.build import RECIPES
    except ImportError:
        return ()
    return tuple(sorted(RECIPES))


def resolve_builtin(name: str) -> Path:
    """Path of the project's FMU ``name``, built (if needed: its inputs' hash changed) by
    ``fmus.build.build_fmu``."""
    from fmus.build import build_fmu

    return Path(build_fmu(name)[0])


def resolve_source(folder: str, where: Where) -> Path:
    """The FMU built from the C source folder ``folder`` (``fmus.source_fmu``; relative to the
    scenario file's folder); ScenarioError at ``where`` when it is not a source folder or does not build."""
    from fmus.source_fmu import SourceFmuError, build_source_fmu

    path = Path(folder).expanduser()
    if not path.is_absolute():
        path = where.base_dir / path
    try:
        return build_source_fmu(path)
    except SourceFmuError as exc:
        raise where.error("a folder with modelDescription.xml and the FMU's C files that compiles to a valid "
                          "FMI 2.0 co-simulation FMU", folder, problem=str(exc)) from None


def _multiple_check(value: float, base: float) -> bool:
    ratio = value / base
    if not math.isfinite(ratio):  # e.g. macro_step = 5e-324: no whole number of steps
        return False
    return round(ratio) >= 1 and abs(ratio - round(ratio)) <= 1e-9 * max(1.0, ratio)


#: Default upper bound on the base steps of one run (stop_time / macro_step). At the ~1-2 us per base
#: step of the fastest loops (one small FMU, compiled kernel; benchmarks/) 1e9 steps are already
#: 20-30 min of wall time, and hours with the robot cell; a larger count is a typo (stop_time = 1e300,
#: macro_step = 5e-324) more often than a plan. Raise it per scenario with [simulation] max_base_steps.
MAX_BASE_STEPS = 1_000_000_000

#: [simulation] isolation: which FMUs run in a child process by default (docs/reference/verdicts.md).
ISOLATIONS = ("none", "third_party", "all")

SIMULATION_TABLE = Table({
    "stop_time": Field(Number(unit="s", gt=0), required=True, doc="the simulated duration: a number in s > 0"),
    "macro_step": Field(Number(unit="s", gt=0), required=True, doc="the base macro step: a number in s > 0"),
    "coupling": Field(String(choices=COUPLINGS), default="jacobi",
                      doc="'jacobi': FMUs due together see each other's outputs of the step start; "
                          "'gauss_seidel': later FMUs see earlier ones' new outputs"),
    "order": Field(List(String(pattern=INSTANCE_PATTERN, pattern_doc="naming an FMU instance"), unique=True),
                   doc="the stepping order of the FMU instances (default: the order of [[fmus]])"),
    "engine": Field(String(choices=ENGINES), default="auto",
                    doc="the master's loop: 'native' (compiled kernel), 'python', or 'auto' (native when a C "
                        "compiler is available)"),
    "max_base_steps": Field(Integer(min=1), default=MAX_BASE_STEPS,
                            doc="the largest stop_time / macro_step accepted (a guard against typos)"),
    "isolation": Field(String(choices=ISOLATIONS), default="none",
                       doc="which FMUs run out of process: 'none', 'third_party' (every FMU given by path or source, not builtin), 'all'"),
}, doc="the [simulation] table")

FMU_TABLE = Table({
    "name": Field(String(pattern=INSTANCE_PATTERN, pattern_doc="of letters, digits and '_' (an identifier)"),
                  required=True, doc="a string of letters, digits and '_' (an identifier): the FMU instance's name in connections and signals"),
    "path": Field(FilePath(must_exist=True, suffix=".fmu"), doc="an FMU file (one of path, builtin, source)"),
    "builtin": Field(String(), doc="the name of one of the project's FMUs"),
    "source": Field(String(), doc="a folder with modelDescription.xml and C files (relative to the scenario "
                                  "file's folder): the FMU is built from it with the system C compiler"),
    "step": Field(Number(unit="s", gt=0), doc="this FMU's communication step, a whole multiple of macro_step "
                                           "(default: macro_step)"),
    "parameters": Field(Table({}, extra=AnyValue(), doc="a table of <variable> = <start value>"), default={}),
    "debug_logging": Field(Boolean(), default=False, doc="instantiate the FMU with loggingOn and print its log"),
    "out_of_process": Field(Boolean(), doc="run this FMU in a child process (default from [simulation] isolation)"),
    "step_timeout": Field(Number(unit="s", gt=0),
                          doc="longest wall time of one step of an out-of-process FMU before it counts as hung"),
}, one_of=[("path", "builtin", "source")], doc="an [[fmus]] table")

RECORD_TABLE = Table({
    "period": Field(Number(unit="s", gt=0), required=True, doc="the sampling period: a number in s > 0"),
    "signals": Field(List(String(), min_len=1), required=True,
                     doc="a list of signal names '<instance>.<variable>' (globs like 'drive1.*' allowed)"),
    "file": Field(String(pattern=r"[A-Za-z0-9_-][A-Za-z0-9_.-]*", pattern_doc="a file name in the results folder: "
                         "'NAME' (the run's format: NAME.parquet, or NAME.csv with --timeseries csv), "
                         "'NAME.parquet' or 'NAME.csv'"),
                  default="timeseries", doc="the time-series file (Parquet by default)"),
}, doc="the [record] table")

OUTPUT_TABLE = Table({
    "dir": Field(String(), doc="the results folder (relative to the working directory)"),
}, doc="the [output] table")

#: Fields of the standard co-simulation tables, to merge into a job's document schema.
COSIM_FIELDS: dict[str, Field] = {
    "simulation": Field(SIMULATION_TABLE, required=True, doc="a [simulation] table with stop_time and macro_step"),
    "fmus": Field(List(FMU_TABLE, min_len=1), default=[], doc="at least one [[fmus]] table"),
    "system": Field(FilePath(must_exist=True, suffix=".ssp"),
                    doc="an .ssp file (SSP 1.0) whose FMUs, connections and parameter values replace [[fmus]]"),
    "connections": Field(List(String()), default=[], doc="connections \"fmu.output -> fmu.input\""),
    "record": Field(RECORD_TABLE, doc="which signals are recorded, how often, into which file"),
    "output": Field(OUTPUT_TABLE, default={}, doc="where the results go"),
    **execution_fields(),  # [execution], [realtime]: cosim/scenario/execution_tables.py
}


def _isolate_if_only_once(fmu: dict, md, where: Where, sim: dict, in_process_once: dict[str, str]) -> None:
    """An FMU whose modelDescription says ``canBeInstantiatedOnlyOncePerProcess="true"`` keeps global state:
    a second instance in the master's process would share it (silently wrong results). Every further
    in-process instance of it runs out of process automatically (its own process, docs/reference/verdicts.md);
    ``out_of_process = false`` on one, or an FMI 3.0 FMU (in process only), is refused."""
    if not getattr(md.coSimulation, "canBeInstantiatedOnlyOncePerProcess", False):
        return
    key = str(Path(fmu["path"]).resolve())
    if out_of_process(fmu, sim):
        return
    first = in_process_once.get(key)
    if first is None:
        in_process_once[key] = fmu["name"]
        return
    problem = (f"{Path(fmu['path']).name} declares canBeInstantiatedOnlyOncePerProcess and instance {first!r} of it "
               f"runs in the master's process already")
    if fmu.get("out_of_process") is False:
        raise (where / "out_of_process").error("true or unset (this instance then runs in its own process)", False,
                                               problem=problem)
    if str(md.fmiVersion) != "2.0":
        raise (where / "name").error("one instance of this FMI 3.0 FMU (it runs in process only)", fmu["name"],
                                     problem=problem)
    fmu["_only_once_per_process"] = True


def _check_platform(fmu: dict, md, where: Where) -> None:
    """An FMU given by path must carry a binary for this platform (fmpy would fail only when the run
    instantiates it, as an internal error)."""
    if "path" not in fmu:
        return
    from fmpy import platform, platform_tuple, supported_platforms

    try:
        platforms = supported_platforms(str(fmu["path"]))
    except Exception:  # noqa: BLE001 - an unreadable archive was reported by load_model_description already
        return
    if platform in platforms or platform_tuple in platforms:
        return
    has = [p for p in platforms if p != "c-code"]
    raise (where / "path").error(
        f"an FMU with a binary for this platform (binaries/{platform if str(md.fmiVersion) == '2.0' else platform_tuple}/)",
        str(fmu["path"]), problem=f"it has binaries for {', '.join(has) if has else 'no platform'}"
        + (" and C sources (give it as [[fmus]] source = <folder with the sources> to build it here)"
           if "c-code" in platforms else ""))


def check_cosim_tables(doc: dict, where: Where, master_variables: Mapping[str, str] | None = None) -> None:
    """Check the co-simulation tables of a validated document against the FMUs themselves.

    Resolves ``builtin`` FMUs to files (``doc["fmus"][i]["path"]``), then checks: FMI 2.0 or
    3.0 co-simulation FMU, unique instance names, steps and periods multiples of macro_step,
    stop_time a multiple of macro_step, every parameter exists and has the right type,
    every connection joins an existing output (or master variable) to an existing input
    of the same type once, every recorded signal exists. ``master_variables`` (name ->
    "Real"/"Integer"/"Boolean") are the variables a job's tasks will declare.
    Raises ScenarioError at the offending key.
    """
    master_variables = dict(master_variables or {})
    expand_system(doc, where, master_variables)
    sim = doc["simulation"]
    base = sim["macro_step"]
    steps = sim["stop_time"] / base
    limit = sim.get("max_base_steps", MAX_BASE_STEPS)
    if not math.isfinite(steps):
        raise (where / "simulation" / "macro_step").error(
            f"a step giving a finite number of base steps in stop_time = {sim['stop_time']:g} s", sim["macro_step"],
            problem="stop_time / macro_step overflows")
    if steps > limit * (1 + 1e-9):
        raise (where / "simulation" / "stop_time").error(
            f"at most [simulation] max_base_steps = {limit:g} base steps, i.e. stop_time <= {limit * base:.6g} s "
            f"with macro_step = {base:g} s (raise max_base_steps to run longer)", sim["stop_time"],
            problem=f"{steps:.3g} base steps")
    if not _multiple_check(sim["stop_time"], base):
        raise (where / "simulation" / "stop_time").error(
            f"a positive integer multiple of macro_step = {base!r} s", sim["stop_time"])
    descriptions = {}
    in_process_once: dict[str, str] = {}  # FMUs that may be instantiated once per process -> their in-process instance
    builtins: dict[str, Path] = {}  # each project FMU checked (hashed over its sources) once per document
    for i, fmu in enumerate(doc["fmus"]):
        w = where / "fmus"
        if fmu["name"] in descriptions or fmu["name"] in {v.split(".", 1)[0] for v in master_variables}:
            raise (w[i] / "name").error("a unique instance name", fmu["name"], problem="already used")
        if "builtin" in fmu:
            names = builtin_fmu_names()
            if fmu["builtin"] not in names:
                raise (w[i] / "builtin").error(f"one of the project's FMUs {list(names)}", fmu["builtin"])
            if fmu["builtin"] not in builtins:
                builtins[fmu["builtin"]] = resolve_builtin(fmu["builtin"])
            fmu["path"] = builtins[fmu["builtin"]]
        if "source" in fmu:
            fmu["path"] = resolve_source(fmu["source"], w[i] / "source")
        try:
            md = load_model_description(fmu["path"])
        except MasterConfigError as exc:
            raise (w[i] / next(k for k in ("builtin", "source", "path") if k in fmu)).error(
                SUPPORTED_FMUS, str(fmu["path"]), problem=getattr(exc, "problem", str(exc))) from None
        _check_platform(fmu, md, w[i])
        descriptions[fmu["name"]] = variables_of(md)
        _isolate_if_only_once(fmu, md, w[i], sim, in_process_once)
        isolated = out_of_process(fmu, sim)
        if "step_timeout" in fmu and not isolated:
            raise (w[i] / "step_timeout").error("out_of_process = true (or [simulation] isolation covering this FMU): "
                                                "only an FMU in its own process can be timed out", fmu["step_timeout"])
        if isolated and str(md.fmiVersion) != "2.0":
            raise (w[i] / "out_of_process").error("false for an FMI 3.0 FMU (out-of-process execution supports "
                                                  "FMI 2.0 FMUs)", True, problem=f"FMI {md.fmiVersion} FMU")
        if "step" in fmu and not _multiple_check(fmu["step"], base):
            raise (w[i] / "step").error(f"a positive integer multiple of macro_step = {base!r} s", fmu["step"])
        variables = descriptions[fmu["name"]]
        for key, value in fmu["parameters"].items():
            kw = w[i] / "parameters" / key
            if key not in variables:
                settable = [v.name for v in variables.values() if v.causality == "parameter"]
                raise kw.error(f"a variable of {Path(fmu['path']).name} (parameters: {_short(settable)})",
                               problem="unknown key")
            problem = check_start_value(variables[key], value) or check_declared_range(variables[key], value, md)
            if problem:
                raise kw.error(problem, value)
    if sim.get("order") is not None:
        if sorted(sim["order"]) != sorted(descriptions):
            raise (where / "simulation" / "order").error(
                f"each FMU instance exactly once: {sorted(descriptions)}", sim["order"])

    def fmu_variable(signal: str, w: Where):
        try:
            inst, var = split_signal(signal)
        except ValueError:
            raise w.error("a signal name '<instance>.<variable>'", signal) from None
        if inst not in descriptions:
            raise w.error(f"a signal of an FMU instance {sorted(descriptions)}"
                          + (f" or a master variable {sorted(master_variables)}" if master_variables else ""),
                          signal, problem=f"unknown instance {inst!r}")
        if var not in descriptions[inst]:
            raise w.error(f"a variable of FMU '{inst}' (outputs: "
                          f"{_short([v.name for v in descriptions[inst].values() if v.causality == 'output'])}; "
                          f"inputs: {_short([v.name for v in descriptions[inst].values() if v.causality == 'input'])})",
                          signal, problem=f"unknown variable {var!r}")
        return descriptions[inst][var]

    destinations: dict[str, int] = {}
    for i, text in enumerate(doc["connections"]):
        w = (where / "connections")[i]
        try:
            spec = parse_connection(text)
        except ValueError:
            raise w.error("a connection 'instance.output -> instance.input'", text) from None
        if spec.source in master_variables:
            dst = fmu_variable(spec.destination, w)
            problem = check_connection_ends(None, dst, master_variables[spec.source])
        else:
            src = fmu_variable(spec.source, w)
            dst = fmu_variable(spec.destination, w)
            problem = check_connection_ends(src, dst)
        if problem:
            raise w.error(problem, text)
        if spec.destination in destinations:
            raise w.error(f"an input not already connected (connections[{destinations[spec.destination]}] "
                          f"drives {spec.destination})", text, problem="second source for one input")
        destinations[spec.destination] = i
    record = doc.get("record")
    if record is not None:
        if not _multiple_check(record["period"], base):
            raise (where / "record" / "period").error(f"a positive integer multiple of macro_step = {base!r} s",
                                                      record["period"])
        for i, signal in enumerate(record["signals"]):
            w = (where / "record" / "signals")[i]
            if is_pattern(signal):
                outs = [f"{n}.{v}" for n, vs in descriptions.items() for v, var in vs.items()
                        if var.causality == "output" and var.type != "String"] + list(master_variables)
                if not any(matches_pattern(o, signal) for o in outs):
                    raise w.error("a pattern matching at least one FMU output or master variable", signal)
                continue
            if signal in master_variables:
                continue
            var = fmu_variable(signal, w)
            try:
                bus_type(var.type)
            except MasterTypeUnsupported as exc:
                raise w.error("a Real, Integer, Boolean or Enumeration variable", signal, problem=str(exc)) from None


def expand_system(doc: dict, where: Where, master_variables: Mapping[str, str] | None = None) -> None:
    """Replace ``system = "x.ssp"`` by its ``[[fmus]]`` tables and connections (idempotent).

    The archive's connections between components come first, then its system inputs'
    connections whose source is one of ``master_variables`` (a job that drives them), then
    the scenario's own ``connections``. System inputs no job variable drives stay
    unconnected: those FMU inputs keep their start values. Raises ScenarioError at
    ``system`` (naming the archive member and element) for a bad archive.
    """
    if doc.get("_system_expanded") or "system" not in doc:
        if not doc.get("fmus") and "system" not in doc:
            raise (where / "fmus").error("at least one [[fmus]] table, or system = 'file.ssp'",
                                         problem="no FMU given")
        return
    if doc.get("fmus"):
        raise (where / "system").error("either system = 'file.ssp' or [[fmus]] tables, not both", str(doc["system"]),
                                       problem="both given")
    from cosim.ssp import SspError, load_ssp

    try:
        system = load_ssp(doc["system"])
    except SspError as exc:
        raise (where / "system").error(exc.expected, str(doc["system"]),
                                       problem=f"{exc.element}: {exc.problem}" if exc.problem else exc.element) from None
    driven = [c for c in system.inputs_connections if parse_connection(c).source in (master_variables or {})]
    doc["fmus"] = system.fmus
    doc["connections"] = system.connections + driven + list(doc.get("connections", []))
    doc["_system_expanded"] = True


def _short(names: list[str], limit: int = 12) -> str:
    return ", ".join(names[:limit]) + (f", ... ({len(names)} in all)" if len(names) > limit else "") or "none"


def out_of_process(fmu: dict, sim: dict) -> bool:
    """Whether the [[fmus]] table ``fmu`` runs in a child process: its own ``out_of_process``, else a
    further instance of an FMU that can be instantiated only once per process (set by validation), else
    ``[simulation] isolation`` ('all'; 'third_party': FMUs given by ``path`` or ``source``, not ``builtin``)."""
    if fmu.get("out_of_process") is not None:
        return bool(fmu["out_of_process"])
    if fmu.get("_only_once_per_process"):  # a second instance of an FMU that allows one per process
        return True
    isolation = sim.get("isolation", "none")
    return isolation == "all" or (isolation == "third_party" and "builtin" not in fmu)


def build_master(doc: dict, master_variables: Mapping[str, tuple[str, object]] | None = None) -> Master:
    """A Master with the document's FMUs and connections (not initialized).

    ``master_variables`` (name -> (type, start)) are declared before the connections so
    that connections may read them; tasks and recorders are for the caller to add.
    """
    sim = doc["simulation"]
    master = Master(sim["macro_step"], coupling=sim["coupling"], engine=sim["engine"])
    for fmu in doc["fmus"]:
        isolated = out_of_process(fmu, sim)
        master.add_fmu(fmu["name"], fmu["path"], step=fmu.get("step"), start_values=fmu["parameters"],
                       out_of_process=isolated, step_timeout=fmu.get("step_timeout") if isolated else None,
                       debug_logging=fmu["debug_logging"])
    for name, (type_, start) in (master_variables or {}).items():
        master.add_variable(name, type_, start)
    for text in doc["connections"]:
        master.connect(text)
    if sim.get("order") is not None:
        master.set_order(sim["order"])
    return master


def add_record(master: Master, doc: dict, ctx: "RunContext", file: str | None = None,
               extra_signals: list[str] | None = None) -> Recorder | None:
    """Add the ``[record]`` table's recorder streaming into the results folder (Parquet unless
    ``[record] file`` ends in ``.csv`` or the run asks for CSV; None without [record]).

    ``file`` overrides ``[record] file`` (e.g. one file per mode of a job);
    ``extra_signals`` are recorded after the table's signals (e.g. a job's master variables).
    """
    record = doc.get("record")
    if record is None:
        return None
    signals = list(record["signals"]) + [s for s in (extra_signals or []) if s not in record["signals"]]
    name = file or record["file"]
    units = {"time": "s"}
    for signal in master.expand_signals(signals):
        try:
            units[signal] = master.unit(signal)
        except Exception:  # a glob or a master variable: no declared unit
            continue
    if Path(name).suffix in (".csv", ".parquet"):
        sink = sink_for(ctx.path(name), units)  # the scenario chose the format
    else:
        sink = ctx.series_sink(name, units)
    return master.add_recorder(signals, record["period"], sink, name="record")


__all__ = ["COSIM_FIELDS", "FMU_TABLE", "OUTPUT_TABLE", "RECORD_TABLE", "SIMULATION_TABLE", "add_record",
           "build_master", "builtin_fmu_names", "check_cosim_tables", "expand_system", "resolve_builtin",
           "resolve_source"]
