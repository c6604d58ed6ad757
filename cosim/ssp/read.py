"""Read an SSP 1.0 archive into what the master runs: FMU instances with start values and connections.

Checked, in this order, each failure an ``SspError`` naming the file, the archive member
and element, and what was expected: a ZIP archive; ``SystemStructure.ssd`` in it;
well-formed XML; valid against the SSP 1.0 schema (fmpy's XSDs); every component's
``source`` an FMU in the archive that the master runs (FMI 2.0/3.0 co-simulation); every
connector and connection end a variable of its component (or a system connector);
every parameter set (``.ssv``) valid and naming settable variables of its component.
Supported subset: one flat system of FMU components, parameter sets given by ``source``
(``.ssv`` in the archive); nested systems, signal dictionaries, parameter mappings,
inline parameter values and unit/linear transformations are refused with an error.
"""
from __future__ import annotations

import atexit
import shutil
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lxml import etree

from fmus.fmu import load_model_description, variables_of
from cosim.master.errors import MasterConfigError
from cosim.master.variables import check_start_value
from cosim.ssp.errors import SspError
from cosim.ssp.schema import NS, SSD_XSD, SSV_XSD, problems
from cosim.ssp.write import ANNOTATION_TYPE, OSP_NS, RX_NS

SSD_MEMBER = "SystemStructure.ssd"
_extracted: list[str] = []


@atexit.register
def _cleanup() -> None:
    for d in _extracted:
        shutil.rmtree(d, ignore_errors=True)


@dataclass
class SspSystem:
    """What an .ssp holds, ready for the master.

    Attributes:
        path: the archive.
        name: the system's name.
        fmus: ``[[fmus]]``-style tables: name, path (extracted FMU), parameters, step (s or None),
            ssp_source (the FMU's path inside the archive, the component's ``source``).
        connections: ``"a.x -> b.y"`` between components.
        system_inputs: inputs the Python side drives: master variable -> (bus type, who drives
            it), with the connections they feed (``inputs_connections``: ``"bus.x -> drive1.y"``).
            Read from this project's annotation on the FMU inputs (what ``export_ssp`` writes),
            or from system input connectors and their connections (another SSP 1.0 writer's way).
        stop_time, macro_step: from the DefaultExperiment (this project's annotation, else the
            OSP fixed-step algorithm's base step), or None.
    """

    path: Path
    name: str
    fmus: list[dict[str, Any]]
    connections: list[str]
    system_inputs: dict[str, tuple[str, str]] = field(default_factory=dict)
    inputs_connections: list[str] = field(default_factory=list)
    stop_time: float | None = None
    macro_step: float | None = None


def _element_label(member: str, el: etree._Element) -> str:
    tag = etree.QName(el).localname
    prefix = next((p for p, uri in NS.items() if uri == etree.QName(el).namespace), "")
    name = el.get("name")
    return f"{member}: <{prefix + ':' if prefix else ''}{tag}{f' name={name!r}' if name else ''}> (line {el.sourceline})"


def _parse(path: Path, zf: zipfile.ZipFile, member: str, xsd: str) -> etree._Element:
    try:
        data = zf.read(member)
    except KeyError:
        raise SspError(path, member, f"an archive member {member!r}", problem="missing") from None
    try:
        root = etree.fromstring(data)
    except etree.XMLSyntaxError as exc:
        raise SspError(path, f"{member} line {exc.lineno}", "well-formed XML", problem=str(exc)) from None
    found = problems(root, xsd)
    if found:
        raise SspError(path, f"{member} {found[0].split(':', 1)[0]}",
                       f"a document valid against the SSP 1.0 schema ({xsd})",
                       problem=found[0].split(":", 1)[1].strip())
    return root


def _info(el: etree._Element) -> dict[str, str]:
    for a in el.findall("ssc:Annotations/ssc:Annotation", NS) + el.findall("ssd:Annotations/ssc:Annotation", NS):
        if a.get("type") == ANNOTATION_TYPE:
            info = a.find(f"{{{RX_NS}}}Info")
            if info is not None:
                return dict(info.attrib)
    return {}


def _value(path: Path, label: str, p: etree._Element) -> object:
    for kind in ("Real", "Integer", "Boolean"):
        v = p.find(f"ssv:{kind}", NS)
        if v is not None:
            text = v.get("value")
            if kind == "Real":
                return float(text)
            if kind == "Integer":
                return int(text)
            return text.strip() in ("true", "1")
    raise SspError(path, label, "a Real, Integer or Boolean parameter value", problem="other type given")


def load_ssp(path: str | Path, extract_to: str | Path | None = None) -> SspSystem:
    """Read and check the .ssp archive ``path``; FMUs are extracted to ``extract_to`` (default: a
    temporary folder removed at exit). Raises SspError."""
    path = Path(path)
    if not path.is_file():
        raise SspError(path, "archive", "an existing .ssp file", problem="no such file")
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError) as exc:
        raise SspError(path, "archive", "a ZIP archive (an .ssp file)", problem=str(exc)) from None
    with zf:
        root = _parse(path, zf, SSD_MEMBER, SSD_XSD)
        system = root.find("ssd:System", NS)
        if system.find("ssd:Elements/ssd:System", NS) is not None:
            raise SspError(path, _element_label(SSD_MEMBER, system.find("ssd:Elements/ssd:System", NS)),
                           "FMU components only", problem="nested systems are not supported")
        for unsupported in ("ssd:Elements/ssd:SignalDictionaryReference", "ssd:SignalDictionaries"):
            el = system.find(unsupported, NS)
            if el is not None:
                raise SspError(path, _element_label(SSD_MEMBER, el), "FMU components and connections only",
                               problem="signal dictionaries are not supported")
        target = Path(extract_to) if extract_to is not None else Path(tempfile.mkdtemp(prefix="ssp-"))
        if extract_to is None:
            _extracted.append(str(target))
        fmus: list[dict[str, Any]] = []
        variables: dict[str, dict[str, Any]] = {}
        driven_inputs: list[tuple[str, str, str, str]] = []  # (master variable, type, who, "comp.input")
        component_names = {comp.get("name") for comp in system.findall("ssd:Elements/ssd:Component", NS)}
        for comp in system.findall("ssd:Elements/ssd:Component", NS):
            label = _element_label(SSD_MEMBER, comp)
            name, source = comp.get("name"), comp.get("source")
            kind = comp.get("type", "application/x-fmu-sharedlibrary")
            if kind != "application/x-fmu-sharedlibrary":
                raise SspError(path, label, "type 'application/x-fmu-sharedlibrary' (an FMU)", problem=f"type {kind!r}")
            if comp.get("implementation", "any") == "ModelExchange":
                raise SspError(path, label, "implementation 'CoSimulation' or 'any'",
                               problem="the master runs co-simulation FMUs only")
            if name in variables or "." in name:
                raise SspError(path, label, "a unique component name without dots", problem=f"name {name!r}")
            if source.startswith(("http:", "https:", "file:", "/")) or source not in zf.namelist():
                raise SspError(path, f"{label} source", "the path of an FMU inside the archive (e.g. resources/x.fmu)",
                               problem=f"{source!r} is not in the archive")
            fmu_path = target / source
            if not fmu_path.exists():
                fmu_path.parent.mkdir(parents=True, exist_ok=True)
                with zf.open(source) as src, open(fmu_path, "wb") as dst:
                    shutil.copyfileobj(src, dst)
            try:
                variables[name] = variables_of(load_model_description(fmu_path))
            except MasterConfigError as exc:
                raise SspError(path, f"{label} source", "an FMI 2.0 or FMI 3.0 co-simulation FMU",
                               problem=getattr(exc, "problem", str(exc))) from None
            for c in comp.findall("ssd:Connectors/ssd:Connector", NS):
                if c.get("name") not in variables[name]:
                    raise SspError(path, _element_label(SSD_MEMBER, c), f"a variable of component '{name}' ({source})",
                                   problem=f"{source} has no variable {c.get('name')!r}")
                signal = _info(c).get("masterVariable")
                if signal is not None:  # an input the Python side drives (this project's annotation)
                    owner = signal.split(".", 1)[0]
                    if c.get("kind") != "input" or "." not in signal or owner in component_names:
                        raise SspError(path, _element_label(SSD_MEMBER, c), "masterVariable = 'owner.name' (not a "
                                       "component) on an input connector", problem=f"{signal!r} on kind {c.get('kind')!r}")
                    typ = next((t for t in ("Real", "Integer", "Boolean") if c.find(f"ssc:{t}", NS) is not None), "Real")
                    driven_inputs.append((signal, typ, _info(c).get("drivenBy", ""), f"{name}.{c.get('name')}"))
            parameters: dict[str, object] = {}
            for binding in comp.findall("ssd:ParameterBindings/ssd:ParameterBinding", NS):
                blabel = _element_label(SSD_MEMBER, binding)
                if binding.get("source") is None or binding.find("ssd:ParameterMapping", NS) is not None:
                    raise SspError(path, blabel, "a ParameterBinding with source = an .ssv file in the archive "
                                   "(inline values and parameter mappings are not read)")
                ssv_member = binding.get("source")
                ssv = _parse(path, zf, ssv_member, SSV_XSD)
                prefix = binding.get("prefix", "")
                for p in ssv.findall("ssv:Parameters/ssv:Parameter", NS):
                    plabel = _element_label(ssv_member, p)
                    var_name = p.get("name")[len(prefix):] if p.get("name").startswith(prefix) else p.get("name")
                    if var_name not in variables[name]:
                        raise SspError(path, plabel, f"a variable of component '{name}' ({source})",
                                       problem=f"no variable {var_name!r}")
                    value = _value(path, plabel, p)
                    problem = check_start_value(variables[name][var_name], value)
                    if problem:
                        raise SspError(path, plabel, problem, problem=f"value {value!r}")
                    parameters[var_name] = value
            info = _info(comp)
            fmus.append({"name": name, "path": fmu_path, "parameters": parameters, "debug_logging": False,
                         "ssp_source": source,
                         **({"step": float(info["step"])} if "step" in info else {})})
        system_inputs: dict[str, tuple[str, str]] = {}
        for c in system.findall("ssd:Connectors/ssd:Connector", NS):
            typ = next((t for t in ("Real", "Integer", "Boolean") if c.find(f"ssc:{t}", NS) is not None), "Real")
            system_inputs[c.get("name")] = (typ, _info(c).get("drivenBy", ""))
        connections, inputs_connections = [], []
        for signal, typ, by, destination in driven_inputs:
            system_inputs.setdefault(signal, (typ, by))
            inputs_connections.append(f"{signal} -> {destination}")
        for conn in system.findall("ssd:Connections/ssd:Connection", NS):
            label = _element_label(SSD_MEMBER, conn)
            start_el, start_c = conn.get("startElement"), conn.get("startConnector")
            end_el, end_c = conn.get("endElement"), conn.get("endConnector")
            if conn.find("ssc:LinearTransformation", NS) is not None or conn.find("ssc:BooleanMappingTransformation",
                                                                                    NS) is not None:
                raise SspError(path, label, "a connection without transformation", problem="transformations are not supported")
            if end_el is None or end_el not in variables or end_c not in variables[end_el]:
                raise SspError(path, label, "endElement/endConnector naming a component input",
                               problem=f"{end_el}.{end_c} is not a variable of a component")
            if start_el is None:
                if start_c not in system_inputs:
                    raise SspError(path, label, "startConnector naming a system connector",
                                   problem=f"no system connector {start_c!r}")
                inputs_connections.append(f"{start_c} -> {end_el}.{end_c}")
                continue
            if start_el not in variables or start_c not in variables[start_el]:
                raise SspError(path, label, "startElement/startConnector naming a component output",
                               problem=f"{start_el}.{start_c} is not a variable of a component")
            connections.append(f"{start_el}.{start_c} -> {end_el}.{end_c}")
        experiment = root.find("ssd:DefaultExperiment", NS)
        stop = None if experiment is None or experiment.get("stopTime") is None else float(experiment.get("stopTime"))
        info = {} if experiment is None else _info(experiment)
        macro_step = float(info["macroStep"]) if "macroStep" in info else None
        if macro_step is None and experiment is not None:
            fixed = experiment.find(f"ssd:Annotations/ssc:Annotation/{{{OSP_NS}}}Algorithm/{{{OSP_NS}}}FixedStepAlgorithm",
                                    NS)
            if fixed is not None and fixed.get("baseStepSize") is not None:
                macro_step = float(fixed.get("baseStepSize"))
        return SspSystem(path, system.get("name"), fmus, connections, system_inputs, inputs_connections, stop,
                         macro_step)
