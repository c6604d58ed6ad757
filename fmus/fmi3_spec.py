"""The FMI 3.0 rendering of an :class:`fmus.fmi2_spec.FmuSpec`: ``modelDescription.xml``
(fmiVersion 3.0, co-simulation) and the C header ``fmi3_variables.h`` that
``fmus/common/fmi3_wrapper.c`` compiles against.

Both builds of an FMU come from one spec and one model source, so they share every
value, range and causality. FMI 3.0 has native arrays: the FMI 2.0 scalars ``q[1]`` ..
``q[6]`` (one ``add_array``) become one Float64 variable ``q`` with ``<Dimension
start="6"/>``, whose elements the master (and any FMI 3.0 importer with structured
names) calls ``q[1]`` .. ``q[6]`` again. Real is Float64, Integer is Int32. Value
references: 0 is the independent variable ``time``, then 1, 2, ... in declaration
order (FMI 3.0 wants them unique over all types). An array whose elements carry
different units (none today) is written without a unit, its units listed in its
description.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

from fmus.fmi2_spec import OUTPUT, PARAMETER, FmuSpec, Variable, _fmt

FMI3_TYPE = {"Real": "Float64", "Integer": "Int32"}


@dataclass(frozen=True)
class Fmi3Variable:
    """One FMI 3.0 variable: a scalar or an array of consecutive FMI 2.0 scalars."""

    name: str
    value_reference: int
    elements: tuple[Variable, ...]
    first: int  # index of the first element among the spec's variables of its type

    @property
    def head(self) -> Variable:
        return self.elements[0]

    @property
    def is_array(self) -> bool:
        return self.head.array_length > 1


def fmi3_variables(spec: FmuSpec) -> list[Fmi3Variable]:
    """Group the spec's scalars into FMI 3.0 variables (arrays from ``add_array``)."""
    out: list[Fmi3Variable] = []
    counters = {"Real": 0, "Integer": 0}
    k = 0
    variables = spec.variables
    while k < len(variables):
        v = variables[k]
        n = v.array_length if v.index == 0 else 1
        group = tuple(variables[k:k + n])
        name = v.name.rsplit("[", 1)[0] if n > 1 else v.name
        out.append(Fmi3Variable(name, len(out) + 1, group, counters[v.type]))
        counters[v.type] += n
        k += n
    return out


def _known_references(spec: FmuSpec, var: Fmi3Variable, by_element: dict[str, int]) -> list[int]:
    names = {n for e in var.elements for n in e.depends_on}
    return sorted({by_element[n] for n in names})


def _variables_xml(spec: FmuSpec) -> str:
    lines = ['    <Float64 name="time" valueReference="0" causality="independent" variability="continuous" '
             'description="simulation time"/>']
    for var in fmi3_variables(spec):
        v = var.head
        units = {e.unit for e in var.elements}
        attrs = (f'name={quoteattr(var.name)} valueReference="{var.value_reference}" causality="{v.causality}" '
                 f'variability="{v.variability}"')
        if v.initial and v.causality == PARAMETER:
            attrs += f' initial="{v.initial}"'
        if var.is_array:
            texts = "; ".join(f"[{e.index + 1}] {e.description}" for e in var.elements)
            if len(units) > 1:
                texts += " (units: " + ", ".join(str(e.unit) for e in var.elements) + ")"
            attrs += f" description={quoteattr(texts)}"
        else:
            attrs += f" description={quoteattr(v.description)}"
        if v.start is not None and v.causality != OUTPUT:
            attrs += f' start="{" ".join(_fmt(e.start, e.type) for e in var.elements)}"'
        if len(units) == 1 and v.unit is not None:
            attrs += f' unit="{v.unit}"'
        if v.min is not None:
            attrs += f' min="{_fmt(v.min, v.type)}"'
        if v.max is not None:
            attrs += f' max="{_fmt(v.max, v.type)}"'
        tag = FMI3_TYPE[v.type]
        if var.is_array:
            lines.append(f'    <{tag} {attrs}><Dimension start="{v.array_length}"/></{tag}>')
        else:
            lines.append(f"    <{tag} {attrs}/>")
    return "\n".join(lines)


def instantiation_token(spec: FmuSpec) -> str:
    """Deterministic instantiationToken: a hash of the FMI 3.0 variables."""
    digest = hashlib.sha256(("fmi3" + _variables_xml(spec)).encode()).hexdigest()
    return "{%s-%s-%s-%s-%s}" % (digest[:8], digest[8:12], digest[12:16], digest[16:20], digest[20:32])


def model_description_xml3(spec: FmuSpec) -> str:
    """The complete FMI 3.0 ``modelDescription.xml`` text (co-simulation, no event mode)."""
    variables = fmi3_variables(spec)
    by_element = {e.name: var.value_reference for var in variables for e in var.elements}
    structure = []
    for var in variables:
        if var.head.causality == OUTPUT:
            structure.append(f'    <Output valueReference="{var.value_reference}" dependencies=""/>')
    for var in variables:
        if var.head.causality == OUTPUT:
            deps = " ".join(str(r) for r in _known_references(spec, var, by_element))
            structure.append(f'    <InitialUnknown valueReference="{var.value_reference}" dependencies="{deps}"/>')
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription
  fmiVersion="3.0"
  modelName="{spec.model_identifier}"
  instantiationToken="{instantiation_token(spec)}"
  description={quoteattr(spec.description)}
  generationTool="rx130l-cosim fmus.build"
  variableNamingConvention="structured">
  <CoSimulation
    modelIdentifier="{spec.model_identifier}"
    canHandleVariableCommunicationStepSize="true"
    canGetAndSetFMUState="true"
    canSerializeFMUState="true"
    hasEventMode="false"
    providesIntermediateUpdate="false"
    canReturnEarlyAfterIntermediateUpdate="false"/>
{spec.common_xml()}
  <ModelVariables>
{_variables_xml(spec)}
  </ModelVariables>
  <ModelStructure>
{chr(10).join(structure)}
  </ModelStructure>
</fmiModelDescription>
"""


def fmi3_header(spec: FmuSpec) -> str:
    """The ``fmi3_variables.h`` text: token, value reference -> (type, first element, count)."""
    variables = fmi3_variables(spec)
    n = max(len(variables), 1)
    types = [("0" if v.head.type == "Real" else "1") for v in variables] or ["0"]
    firsts = [str(v.first) for v in variables] or ["0"]
    counts = [str(len(v.elements)) for v in variables] or ["0"]
    return "\n".join([
        f"/* Generated by fmus/fmi3_spec.py for {spec.model_identifier}: do not edit. */",
        "#ifndef FMI3_VARIABLES_H",
        "#define FMI3_VARIABLES_H",
        f'#define MODEL_TOKEN3 "{instantiation_token(spec)}"',
        "#define VR3_TIME 0",
        f"#define N_VARS3 {len(variables)}",
        "/* variable with value reference j + 1: type (0 Float64 = Reals, 1 Int32 = Integers), first element, count */",
        f"static const int VAR3_TYPE[{n}] = {{{', '.join(types)}}};",
        f"static const int VAR3_FIRST[{n}] = {{{', '.join(firsts)}}};",
        f"static const int VAR3_COUNT[{n}] = {{{', '.join(counts)}}};",
        "#endif",
    ]) + "\n"


__all__ = ["Fmi3Variable", "fmi3_header", "fmi3_variables", "instantiation_token", "model_description_xml3"]
