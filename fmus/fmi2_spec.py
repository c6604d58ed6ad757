"""One description of an FMU's variables, rendered both as ``modelDescription.xml`` and
as the C header ``model_variables.h`` that the FMU's C code compiles against.

Because both files come from the same :class:`FmuSpec`, the value references, start
values, ranges and causalities in the XML and in the binary can never disagree.

Value-reference scheme: each type has its own numbering starting at 0 in declaration
order (Reals 0..n_real-1, Integers 0..n_integer-1). An array variable such as ``q[1]``..
``q[6]`` gets consecutive value references; the header defines ``VR_Q`` (first one)
and ``N_Q`` (length).
"""
from __future__ import annotations

import dataclasses
import hashlib
import math
import re
from dataclasses import dataclass, field
from xml.sax.saxutils import quoteattr

#: Base-unit exponents (kg, m, s, A, rad) of every unit the FMUs use.
UNITS: dict[str, dict[str, int]] = {
    "1": {},
    "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1},
    "rad/s2": {"rad": 1, "s": -2},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "N.m/A": {"kg": 1, "m": 2, "s": -2, "A": -1},
    "A": {"A": 1},
    "A.s/rad": {"A": 1, "s": 1, "rad": -1},
    "V": {"kg": 1, "m": 2, "s": -3, "A": -1},
    "V/A": {"kg": 1, "m": 2, "s": -3, "A": -2},
    "V.s/rad": {"kg": 1, "m": 2, "s": -2, "A": -1, "rad": -1},
    "Ohm": {"kg": 1, "m": 2, "s": -3, "A": -2},
    "H": {"kg": 1, "m": 2, "s": -2, "A": -2},
    "s": {"s": 1},
    "1/s": {"s": -1},
    "kg": {"kg": 1},
    "m": {"m": 1},
    "kg.m": {"kg": 1, "m": 1},
    "kg.m2": {"kg": 1, "m": 2},
    "N.m.s/rad": {"kg": 1, "m": 2, "s": -1, "rad": -1},
    "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1},
    "N.m/rad3": {"kg": 1, "m": 2, "s": -2, "rad": -3},
}

INPUT, OUTPUT, PARAMETER, LOCAL = "input", "output", "parameter", "local"
_KIND_CODE = {INPUT: "KIND_INPUT", OUTPUT: "KIND_OUTPUT", PARAMETER: "KIND_PARAMETER", LOCAL: "KIND_LOCAL"}


class SpecError(ValueError):
    """An FMU variable specification is inconsistent."""


@dataclass(frozen=True)
class Variable:
    """One scalar FMU variable.

    ``c_name`` is the upper-case C identifier of the variable (or of its array);
    ``index`` is its 0-based position inside that array (0 for scalars).
    """

    name: str
    c_name: str
    type: str  # "Real" | "Integer"
    causality: str  # input | output | parameter | local
    description: str
    unit: str | None = None
    start: float | int | None = None
    min: float | None = None
    max: float | None = None
    index: int = 0
    array_length: int = 1
    #: names of the knowns (inputs and parameters) an output depends on in Initialization
    #: Mode (ModelStructure/InitialUnknowns); () = none
    depends_on: tuple[str, ...] = ()
    #: a parameter that may be set between communication steps too (variability "tunable";
    #: the C code reads it at every step)
    tunable: bool = False

    @property
    def kind_code(self) -> str:
        """The C kind of the variable (KIND_TUNABLE: a tunable parameter)."""
        return "KIND_TUNABLE" if self.tunable and self.causality == PARAMETER else _KIND_CODE[self.causality]

    @property
    def variability(self) -> str:
        if self.causality == PARAMETER:
            return "tunable" if self.tunable else "fixed"
        return "continuous" if self.type == "Real" else "discrete"

    @property
    def initial(self) -> str | None:
        if self.causality == OUTPUT:
            return "calculated"
        if self.causality == PARAMETER:
            return "exact"
        return None


@dataclass
class FmuSpec:
    """All variables of one FMU plus its identity and C source files."""

    model_identifier: str
    description: str
    source_files: tuple[str, ...]
    default_step: float
    default_stop: float
    variables: list[Variable] = field(default_factory=list)

    # -- building the list -------------------------------------------------
    def add(self, name: str, type_: str, causality: str, description: str, *,
            unit: str | None = None, start: float | int | None = None,
            min: float | None = None, max: float | None = None, depends_on: tuple[str, ...] = (),
            tunable: bool = False) -> None:
        """Add one scalar variable named ``name`` (C name derived from it). ``depends_on``
        (outputs only): the inputs and parameters its value in Initialization Mode depends on."""
        c_name = re.sub(r"[^A-Za-z0-9]", "_", name).upper()
        self._append(Variable(name, c_name, type_, causality, description, unit, start, min, max,
                              depends_on=tuple(depends_on), tunable=tunable))

    def add_array(self, base: str, starts: list[float], causality: str, description: str, *,
                  unit: str | None = None, min: float | None = None, max: float | None = None,
                  descriptions: list[str] | None = None, units: list[str] | None = None,
                  type_: str = "Real") -> None:
        """Add ``base[1]``..``base[n]`` (Real, or ``type_``) with one start value (and optionally unit) per element."""
        n = len(starts)
        c_name = re.sub(r"[^A-Za-z0-9]", "_", base).upper()
        for k, start in enumerate(starts):
            text = descriptions[k] if descriptions else f"{description} (element {k + 1})"
            self._append(Variable(f"{base}[{k + 1}]", c_name, type_, causality, text,
                                  units[k] if units else unit, start, min, max, index=k, array_length=n))

    def set_depends_on(self, name: str, knowns: tuple[str, ...]) -> None:
        """Set ``depends_on`` of the output ``name`` after it was added (e.g. an array element)."""
        for k, v in enumerate(self.variables):
            if v.name == name:
                self.variables[k] = dataclasses.replace(v, depends_on=tuple(knowns))
                return
        raise SpecError(f"{self.model_identifier}: no variable named {name!r}")

    def _append(self, v: Variable) -> None:
        if v.type not in ("Real", "Integer"):
            raise SpecError(f"variable {v.name!r}: type {v.type!r}, expected 'Real' or 'Integer'")
        if v.causality not in _KIND_CODE:
            raise SpecError(f"variable {v.name!r}: causality {v.causality!r}, expected one of {sorted(_KIND_CODE)}")
        if v.unit is not None and v.unit not in UNITS:
            raise SpecError(f"variable {v.name!r}: unit {v.unit!r} is not in fmus.fmi2_spec.UNITS")
        if v.causality != OUTPUT and v.start is None:
            raise SpecError(f"variable {v.name!r}: a {v.causality} needs a start value")
        if v.start is not None and v.causality != OUTPUT:
            value = float(v.start)
            if not math.isfinite(value):
                raise SpecError(f"variable {v.name!r}: start value {v.start!r} is not finite")
            if (v.min is not None and value < v.min) or (v.max is not None and value > v.max):
                raise SpecError(f"variable {v.name!r}: start value {value!r} outside [{v.min}, {v.max}]")
        if any(w.name == v.name for w in self.variables):
            raise SpecError(f"variable {v.name!r} declared twice")
        self.variables.append(v)

    # -- queries --------------------------------------------------------------
    def of_type(self, type_: str) -> list[Variable]:
        return [v for v in self.variables if v.type == type_]

    def value_reference(self, name: str) -> int:
        """Value reference of variable ``name`` (numbered per type)."""
        for type_ in ("Real", "Integer"):
            for vr, v in enumerate(self.of_type(type_)):
                if v.name == name:
                    return vr
        raise SpecError(f"{self.model_identifier}: no variable named {name!r}")

    @property
    def guid(self) -> str:
        """Deterministic GUID: a hash of everything the binary depends on."""
        digest = hashlib.sha256(self._render_variables_xml().encode()).hexdigest()
        return "{%s-%s-%s-%s-%s}" % (digest[:8], digest[8:12], digest[12:16], digest[16:20], digest[20:32])

    # -- rendering --------------------------------------------------------------
    def _render_variables_xml(self) -> str:
        lines = []
        counters = {"Real": 0, "Integer": 0}
        for v in self.variables:
            vr = counters[v.type]
            counters[v.type] += 1
            attrs = f'name={quoteattr(v.name)} valueReference="{vr}" causality="{v.causality}" variability="{v.variability}"'
            if v.initial:
                attrs += f' initial="{v.initial}"'
            attrs += f" description={quoteattr(v.description)}"
            type_attrs = ""
            if v.start is not None and v.causality != OUTPUT:
                type_attrs += f' start="{_fmt(v.start, v.type)}"'
            if v.unit is not None:
                type_attrs += f' unit="{v.unit}"'
            if v.min is not None:
                type_attrs += f' min="{_fmt(v.min, v.type)}"'
            if v.max is not None:
                type_attrs += f' max="{_fmt(v.max, v.type)}"'
            lines.append(f"    <ScalarVariable {attrs}>\n      <{v.type}{type_attrs}/>\n    </ScalarVariable>")
        return "\n".join(lines)

    def common_xml(self) -> str:
        """The ``modelDescription.xml`` elements that read the same in FMI 2.0 and 3.0:
        ``UnitDefinitions``, ``LogCategories`` and ``DefaultExperiment`` (indented, one per line)."""
        used_units = sorted({v.unit for v in self.variables if v.unit is not None})
        unit_xml = []
        for unit in used_units:
            exps = " ".join(f'{k}="{e}"' for k, e in UNITS[unit].items())
            unit_xml.append(f'    <Unit name="{unit}"><BaseUnit {exps}/></Unit>' if exps
                            else f'    <Unit name="{unit}"/>')
        return f"""  <UnitDefinitions>
{chr(10).join(unit_xml)}
  </UnitDefinitions>
  <LogCategories>
    <Category name="logStatusError" description="errors: rejected calls and numerical failures"/>
    <Category name="logStatusWarning" description="warnings"/>
    <Category name="logEvents" description="CiA 402 state transitions and limits (debug logging only)"/>
  </LogCategories>
  <DefaultExperiment startTime="0" stopTime="{self.default_stop!r}" stepSize="{self.default_step!r}"/>"""

    def model_description_xml(self) -> str:
        """The complete ``modelDescription.xml`` text (FMI 2.0, co-simulation)."""
        index = {v.name: i + 1 for i, v in enumerate(self.variables)}
        outputs = [v for v in self.variables if v.causality == OUTPUT]
        for v in outputs:
            for name in v.depends_on:
                known = next((w for w in self.variables if w.name == name), None)
                if known is None or known.causality not in (INPUT, PARAMETER):
                    raise SpecError(f"variable {v.name!r}: depends_on names {name!r}, expected an input or "
                                    "parameter of this FMU")
        # co-simulation outputs change only in fmi2DoStep: no direct feed-through
        unknowns = "\n".join(f'      <Unknown index="{index[v.name]}" dependencies=""/>' for v in outputs)
        initial = "\n".join(
            f'      <Unknown index="{index[v.name]}" dependencies="{" ".join(str(i) for i in sorted(index[n] for n in v.depends_on))}"/>'
            for v in outputs)
        sources = "\n".join(f'      <File name="{f}"/>' for f in self.source_files)
        return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription
  fmiVersion="2.0"
  modelName="{self.model_identifier}"
  guid="{self.guid}"
  description={quoteattr(self.description)}
  generationTool="rx130l-cosim fmus.build"
  variableNamingConvention="structured"
  numberOfEventIndicators="0">
  <CoSimulation
    modelIdentifier="{self.model_identifier}"
    canHandleVariableCommunicationStepSize="true"
    canGetAndSetFMUstate="true"
    canSerializeFMUstate="true"
    canNotUseMemoryManagementFunctions="true">
    <SourceFiles>
{sources}
    </SourceFiles>
  </CoSimulation>
{self.common_xml()}
  <ModelVariables>
{self._render_variables_xml()}
  </ModelVariables>
  <ModelStructure>
    <Outputs>
{unknowns}
    </Outputs>
    <InitialUnknowns>
{initial}
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""

    def c_header(self) -> str:
        """The ``model_variables.h`` text: value references, start values, ranges, names."""
        out = [
            f"/* Generated by fmus/fmi2_spec.py for {self.model_identifier}: do not edit. */",
            "#ifndef MODEL_VARIABLES_H",
            "#define MODEL_VARIABLES_H",
            "#include <math.h>",
            f'#define MODEL_IDENTIFIER_STRING "{self.model_identifier}"',
            f'#define MODEL_GUID "{self.guid}"',
            "enum { KIND_INPUT, KIND_OUTPUT, KIND_PARAMETER, KIND_LOCAL, KIND_TUNABLE };",
        ]
        for type_, tag in (("Real", "REAL"), ("Integer", "INTEGER")):
            vs = self.of_type(type_)
            out.append(f"#define N_{tag}S {len(vs)}")
            for vr, v in enumerate(vs):
                if v.index == 0:
                    out.append(f"#define VR_{v.c_name} {vr}")
                    if v.array_length > 1:
                        out.append(f"#define N_{v.c_name} {v.array_length}")
            n = max(len(vs), 1)
            ctype = "double" if type_ == "Real" else "int"
            starts = [_c_value(v.start if v.causality != OUTPUT else 0, type_) for v in vs] or ["0"]
            mins = [_c_bound(v.min, -1, type_) for v in vs] or ["0"]
            maxs = [_c_bound(v.max, +1, type_) for v in vs] or ["0"]
            kinds = [v.kind_code for v in vs] or ["KIND_LOCAL"]
            names = [f'"{v.name}"' for v in vs] or ['""']
            out.append(f"static const {ctype} {tag}_START[{n}] = {{{', '.join(starts)}}};")
            out.append(f"static const double {tag}_MIN[{n}] = {{{', '.join(mins)}}};")
            out.append(f"static const double {tag}_MAX[{n}] = {{{', '.join(maxs)}}};")
            out.append(f"static const int {tag}_KIND[{n}] = {{{', '.join(kinds)}}};")
            out.append(f"static const char *const {tag}_NAME[{n}] = {{{', '.join(names)}}};")
        out.append("#endif")
        return "\n".join(out) + "\n"


def _fmt(value: float | int, type_: str) -> str:
    return str(int(value)) if type_ == "Integer" else repr(float(value))


def _c_value(value: float | int | None, type_: str) -> str:
    if type_ == "Integer":
        return str(int(value or 0))
    return repr(float(value or 0.0))


def _c_bound(value: float | None, sign: int, type_: str) -> str:
    if value is None:
        return "INFINITY" if sign > 0 else "-INFINITY"
    return repr(float(value))
