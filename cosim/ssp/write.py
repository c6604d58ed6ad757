"""Write a co-simulation (FMUs, connections, parameter values) as an SSP 1.0 archive."""
from __future__ import annotations

import math
import os
import secrets
import time
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from lxml import etree

from fmus.fmu import load_model_description, variables_of
from cosim.master.variables import bus_type, parse_connection
from cosim.ssp.errors import SspError
from cosim.ssp.schema import NS, SSD_XSD, SSV_XSD, problems

SSD, SSC, SSV = NS["ssd"], NS["ssc"], NS["ssv"]
#: Namespace of this project's annotations (master settings, who drives an input).
RX_NS = "urn:rx130l-cosim:ssp"
ANNOTATION_TYPE = "org.rx130l-cosim"
#: The Open Simulation Platform's annotations, read by libcosim and Ecos: the fixed-step
#: algorithm's base step on the DefaultExperiment, an FMU's own step on its component.
OSP_NS = "http://opensimulationplatform.com/SSP/OSPAnnotations"
OSP_ANNOTATION_TYPE = "com.opensimulationplatform"
#: The name of every component's parameter set: tools that apply one named set to all
#: components (Ecos: ``init(parameter_set=...)``; libcosim: the first set is the default) get all.
PARAMETER_SET = "initialValues"
_SSC_TYPE = {"Real": "Real", "Integer": "Integer", "Boolean": "Boolean"}


def driven_by(signal: str) -> str:
    """Who drives the master variable ``signal`` in the jobs (for the SSD annotation)."""
    owner = signal.split(".", 1)[0]
    if owner == "bus":
        return ("the Python controller (controller/, every controller period), through the emulated "
                "POWERLINK bus carrying CiA 402 telegrams (fieldbus/, cosim.cell.link.FieldbusLink); "
                "not an FMU")
    if owner == "tracker":
        return "the Python laser tracker model (cosim.tracking.laser_tracker); not an FMU"
    return f"a Python task of the job (master variable owner '{owner}'); not an FMU"


def _q(ns: str, tag: str) -> str:
    return f"{{{ns}}}{tag}"


def _annotations(parent: etree._Element, *entries: tuple[str, etree._Element]) -> None:
    """``<ssd:Annotations>`` under ``parent`` with one ``<ssc:Annotation type=...>`` per (type, element)."""
    annotations = etree.SubElement(parent, _q(SSD, "Annotations"))
    for kind, element in entries:
        etree.SubElement(annotations, _q(SSC, "Annotation"), type=kind).append(element)


def _info(attrs: Mapping[str, object]) -> tuple[str, etree._Element]:
    """This project's annotation: ``<rx:Info>`` with ``attrs``."""
    return ANNOTATION_TYPE, etree.Element(_q(RX_NS, "Info"), {k: str(v) for k, v in attrs.items()})


def _type_element(parent: etree._Element, fmi_type: str, unit: str | None = None) -> None:
    ssc_type = _SSC_TYPE[bus_type(fmi_type)]
    attrs = {"unit": unit} if ssc_type == "Real" and unit else {}
    etree.SubElement(parent, _q(SSC, ssc_type), attrs)


def _value_text(value: object, fmi_type: str) -> tuple[str, str]:
    kind = bus_type(fmi_type)
    if kind == "Real":
        v = float(value)
        if not math.isfinite(v):
            raise ValueError(f"parameter value {value!r} is not finite")
        return "Real", repr(v)
    if kind == "Boolean":
        return "Boolean", "true" if value else "false"
    return "Integer", str(int(value))


def _parameter_set(values: Mapping[str, object], variables: Mapping[str, Any]) -> etree._Element:
    root = etree.Element(_q(SSV, "ParameterSet"), nsmap={"ssv": SSV, "ssc": SSC}, version="1.0", name=PARAMETER_SET)
    params = etree.SubElement(root, _q(SSV, "Parameters"))
    for var_name, value in values.items():
        kind, text = _value_text(value, variables[var_name].type)
        p = etree.SubElement(params, _q(SSV, "Parameter"), name=var_name)
        etree.SubElement(p, _q(SSV, kind), value=text)
    return root


def _unit(variable) -> str | None:
    unit = getattr(variable, "unit", None)
    if unit is None and getattr(variable, "declaredType", None) is not None:
        unit = getattr(variable.declaredType, "unit", None)
    return unit


def export_document(fmus: list[dict[str, Any]], connections: list[str], out: str | Path, *, name: str,
                    stop_time: float, macro_step: float, coupling: str = "jacobi",
                    master_variables: Mapping[str, str] | None = None, description: str = "") -> Path:
    """Write ``out`` (.ssp) from resolved ``[[fmus]]`` tables (name, path, parameters, step) and connections.

    ``master_variables`` (name -> bus type) are the connection sources the Python side writes.
    Their connections are not SSD connections (libcosim and Ecos accept a connection only
    between two components): the FMU input each one feeds carries an annotation naming the
    master variable and who drives it, and keeps its start value in a tool that runs the
    archive alone. Every XML document is validated against the SSP 1.0 schema before the
    archive is written; the archive gets the mode the process's umask gives a new file.
    """
    out = Path(out)
    master_variables = dict(master_variables or {})
    files: dict[str, Path] = {}
    descriptions: dict[str, dict[str, Any]] = {}
    for fmu in fmus:
        path = Path(fmu["path"])
        member = f"resources/{path.name}"
        if member in files and files[member].resolve() != path.resolve():
            member = f"resources/{fmu['name']}_{path.name}"
        files.setdefault(member, path)
        fmu["_member"] = next(m for m, p in files.items() if p.resolve() == path.resolve())
        descriptions[fmu["name"]] = variables_of(load_model_description(path))
    specs = [parse_connection(c) for c in connections]
    driven = {s.destination: s.source for s in specs if s.source in master_variables}

    root = etree.Element(_q(SSD, "SystemStructureDescription"),
                         nsmap={"ssd": SSD, "ssc": SSC, "ssv": SSV, "osp": OSP_NS, "rx": RX_NS}, version="1.0",
                         name=name)
    system = etree.SubElement(root, _q(SSD, "System"), name=name)
    if description:
        system.set("description", description)
    elements = etree.SubElement(system, _q(SSD, "Elements"))
    ssv_docs: dict[str, etree._Element] = {}
    for fmu in fmus:
        variables = descriptions[fmu["name"]]
        comp = etree.SubElement(elements, _q(SSD, "Component"), name=fmu["name"], source=fmu["_member"],
                                type="application/x-fmu-sharedlibrary", implementation="CoSimulation")
        connectors = etree.SubElement(comp, _q(SSD, "Connectors"))
        for v in variables.values():
            if v.causality not in ("input", "output") or v.type in ("String", "Clock", "Binary"):
                continue
            c = etree.SubElement(connectors, _q(SSD, "Connector"), name=v.name, kind=v.causality)
            _type_element(c, v.type, _unit(v))
            signal = driven.get(f"{fmu['name']}.{v.name}")
            if signal is not None:
                _annotations(c, _info({"masterVariable": signal, "drivenBy": driven_by(signal)}))
        params = dict(fmu.get("parameters") or {})
        if params:
            member = f"resources/{fmu['name']}.ssv"
            bindings = etree.SubElement(comp, _q(SSD, "ParameterBindings"))
            etree.SubElement(bindings, _q(SSD, "ParameterBinding"), type="application/x-ssp-parameter-set",
                             source=member)
            ssv_docs[member] = _parameter_set(params, variables)
        info = {"fmu": Path(fmu["path"]).name}
        entries = []
        if fmu.get("step") is not None:
            info["step"] = repr(float(fmu["step"]))
            entries.append((OSP_ANNOTATION_TYPE, etree.Element(_q(OSP_NS, "StepSizeHint"), value=info["step"])))
        _annotations(comp, _info(info), *entries)
    between = [s for s in specs if s.source not in master_variables]
    if between:
        conns = etree.SubElement(system, _q(SSD, "Connections"))
        for s in between:
            src_inst, src_var = s.source.split(".", 1)
            dst_inst, dst_var = s.destination.split(".", 1)
            etree.SubElement(conns, _q(SSD, "Connection"), startElement=src_inst, startConnector=src_var,
                             endElement=dst_inst, endConnector=dst_var)
    experiment = etree.SubElement(root, _q(SSD, "DefaultExperiment"), startTime="0", stopTime=repr(float(stop_time)))
    algorithm = etree.Element(_q(OSP_NS, "Algorithm"))
    etree.SubElement(algorithm, _q(OSP_NS, "FixedStepAlgorithm"), baseStepSize=repr(float(macro_step)))
    _annotations(experiment, _info({"macroStep": repr(float(macro_step)), "coupling": coupling}),
                 (OSP_ANNOTATION_TYPE, algorithm))

    for doc, xsd, member in [(root, SSD_XSD, "SystemStructure.ssd")] + [(d, SSV_XSD, m) for m, d in ssv_docs.items()]:
        found = problems(doc, xsd)
        if found:  # a bug of this writer, not of the user's input
            raise SspError(out, member, "a document valid against the SSP 1.0 schema", "; ".join(found[:5]))
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{secrets.token_hex(6)}.tmp")
    try:
        # a new file with the mode the umask gives (0644 under 022), written whole, then renamed over ``out``
        with os.fdopen(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), "wb") as f, \
                zipfile.ZipFile(f, "w", zipfile.ZIP_DEFLATED) as zf:
            _write_member(zf, "SystemStructure.ssd", root)
            for member, doc in ssv_docs.items():
                _write_member(zf, member, doc)
            for member, path in files.items():
                zf.write(path, member)
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    for fmu in fmus:
        fmu.pop("_member", None)
    return out


def _write_member(zf: zipfile.ZipFile, member: str, doc: etree._Element) -> None:
    """``doc`` as the archive member ``member``, readable by all once extracted (rw-r--r--)."""
    info = zipfile.ZipInfo(member, date_time=time.localtime()[:6])
    info.compress_type = zipfile.ZIP_DEFLATED
    info.external_attr = 0o100644 << 16
    zf.writestr(info, etree.tostring(doc, xml_declaration=True, encoding="UTF-8", pretty_print=True))
