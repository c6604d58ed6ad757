"""Model-description helpers: variable lookup, start-value and connection checks.

Signal names are ``"<instance>.<variable>"``; the instance name is everything before
the first dot (FMU variable names may contain dots, instance names may not).
Connections are written ``"a.x -> b.y"`` (output or master variable to input).

These checks return a message instead of raising so that both the master
(``MasterConfigError``) and the scenario validator (``ScenarioError`` with a key path)
report the same wording.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from fnmatch import fnmatchcase

from fmpy.model_description import ModelDescription, ScalarVariable

from fmus.fmi3 import READ_ONLY_TYPES, Fmi3Element, check_fmi3_start
from fmus import fmu

#: FMI 2.0 scalar types a start value may have.
VALUE_TYPES: tuple[str, ...] = ("Real", "Integer", "Enumeration", "Boolean", "String")
#: Types that can travel on the master's signal buses (connections, tasks, recorders).
BUS_TYPES: tuple[str, ...] = fmu.VALUE_TYPES

_EXPECTED_PYTHON = {
    "Real": "a finite number (float or int)",
    "Integer": "an integer",
    "Enumeration": "an integer (enumeration item value)",
    "Boolean": "true or false",
    "String": "a string",
}


def bus_type(fmi_type: str) -> str:
    """Return the bus a variable of FMI type ``fmi_type`` travels on: the value type an
    :class:`fmus.fmu.Fmu` exchanges it as (Enumeration uses Integer; FMI 3.0 types: see fmus/fmi3.py)."""
    try:
        return fmu.VALUE_TYPE_OF[fmi_type]
    except KeyError:
        raise MasterTypeUnsupported(fmi_type) from None


class MasterTypeUnsupported(ValueError):
    """An FMI type (String, Binary) that cannot be connected, read by tasks or recorded."""

    def __init__(self, fmi_type: str) -> None:
        super().__init__(f"variables of type {fmi_type} cannot be connected, read by tasks or recorded "
                         f"(supported: {', '.join(BUS_TYPES)}, Enumeration; FMI 3.0: Float32/64, Int8..Int64, "
                         f"UInt8..UInt64, Boolean, and output Clock/Binary read and recorded)")


def split_signal(name: str) -> tuple[str, str]:
    """Split ``"inst.var.with.dots"`` into ``("inst", "var.with.dots")``; ValueError when malformed."""
    if not isinstance(name, str) or "." not in name:
        raise ValueError(f"signal name {name!r} is not of the form '<instance>.<variable>'")
    instance, variable = name.split(".", 1)
    if not instance or not variable or instance != instance.strip() or variable != variable.strip():
        raise ValueError(f"signal name {name!r} is not of the form '<instance>.<variable>'")
    return instance, variable


@dataclass(frozen=True)
class ConnectionSpec:
    """One connection ``source -> destination`` between signal names."""

    source: str
    destination: str

    def __str__(self) -> str:
        return f"{self.source} -> {self.destination}"


def parse_connection(text: str) -> ConnectionSpec:
    """Parse ``"a.x -> b.y"`` (whitespace around the arrow optional); ValueError when malformed."""
    if not isinstance(text, str) or text.count("->") != 1:
        raise ValueError(f"connection {text!r} is not of the form 'a.x -> b.y'")
    left, right = (part.strip() for part in text.split("->"))
    try:
        split_signal(left)
        split_signal(right)
    except ValueError:
        raise ValueError(f"connection {text!r} is not of the form 'a.x -> b.y'") from None
    return ConnectionSpec(left, right)


def is_pattern(signal: str) -> bool:
    """True when ``signal`` contains a wildcard (``*`` or ``?``)."""
    return "*" in signal or "?" in signal


def matches_pattern(name: str, pattern: str) -> bool:
    """Shell-style match with ``*`` and ``?`` only; brackets are literal (``"q[*]"`` matches ``"q[3]"``)."""
    escaped = pattern.replace("[", "\x00").replace("]", "[]]").replace("\x00", "[[]")
    return fnmatchcase(name, escaped)


def variables_by_name(model_description: ModelDescription) -> dict[str, ScalarVariable]:
    """Map variable name -> ScalarVariable for one model description."""
    return {v.name: v for v in model_description.modelVariables}


def settable_start(variable: ScalarVariable) -> bool:
    """True when FMI 2.0 allows setting ``variable`` after instantiation (before initialization)."""
    return variable.causality == "input" or (
        variable.variability != "constant" and variable.initial in ("exact", "approx"))


def check_start_value(variable: ScalarVariable, value: object) -> str | None:
    """Return None when ``value`` may be set as the start value of ``variable``, else what was expected.

    Real takes int or float (not bool, not NaN/Inf); Integer/Enumeration take int (not
    bool); Boolean takes bool; String takes str. The variable must be settable before
    initialization (an input, or a non-constant variable with initial exact/approx).
    FMI 3.0 elements: the value must fit the element's type (``fmi3.check_fmi3_start``).
    """
    if isinstance(variable, Fmi3Element):
        return check_fmi3_start(variable, value)
    if not settable_start(variable):
        return (f"a variable whose start value can be set (causality {variable.causality}, "
                f"variability {variable.variability}, initial {variable.initial} cannot be set)")
    expected = _EXPECTED_PYTHON.get(variable.type, variable.type)
    if variable.type == "Real":
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    elif variable.type in ("Integer", "Enumeration"):
        ok = isinstance(value, int) and not isinstance(value, bool) and -2**31 <= value < 2**31
    elif variable.type == "Boolean":
        ok = isinstance(value, bool)
    elif variable.type == "String":
        ok = isinstance(value, str)
    else:
        return f"a supported type (variable has type {variable.type})"
    return None if ok else f"{expected} for {variable.type} variable '{variable.name}'"


def declared_range(variable: ScalarVariable, model_description=None) -> tuple[float | None, float | None]:
    """The ``min``/``max`` the modelDescription declares for ``variable`` (on the variable, else on its
    declared type), as numbers; None where nothing is declared."""
    def number(text):
        if text is None:
            return None
        try:
            return float(text)
        except (TypeError, ValueError):
            return None

    low, high = number(getattr(variable, "min", None)), number(getattr(variable, "max", None))
    declared = getattr(variable, "declaredType", None)
    if declared is not None:
        if low is None:
            low = number(getattr(declared, "min", None))
        if high is None:
            high = number(getattr(declared, "max", None))
    return low, high


def check_declared_range(variable: ScalarVariable, value: object, model_description=None) -> str | None:
    """None when the numeric ``value`` lies in the variable's declared [min, max], else what was expected."""
    if variable.type not in ("Real", "Integer", "Enumeration") or isinstance(value, bool) \
            or not isinstance(value, (int, float)):
        return None
    low, high = declared_range(variable, model_description)
    if (low is not None and value < low) or (high is not None and value > high):
        bounds = " and ".join(p for p in (f">= {low:g}" if low is not None else "",
                                          f"<= {high:g}" if high is not None else "") if p)
        unit = getattr(variable, "unit", None) or getattr(getattr(variable, "declaredType", None), "unit", None)
        return (f"a value {bounds}{' ' + unit if unit else ''} (the range its modelDescription declares for "
                f"'{variable.name}')")
    return None


def check_connection_ends(source: ScalarVariable | None, destination: ScalarVariable,
                          source_type: str | None = None) -> str | None:
    """Return None when ``source`` may feed ``destination``, else what was expected.

    ``source`` is an FMU variable (causality output) or None for a master variable whose
    type is ``source_type``. The destination must be an input; types must match
    (Enumeration and Integer both travel as Integer).
    """
    src_type = source.type if source is not None else source_type
    for end, what in ((source, "source"), (destination, "destination")):  # the type first: it cannot be fixed
        if end is not None and end.type in READ_ONLY_TYPES:
            return (f"a Float, Int, UInt, Boolean or Enumeration variable as {what} ('{end.name}' is an FMI 3.0 "
                    f"{end.type}: clocks and binaries are read and recorded, not connected)")
        if end is not None and isinstance(end, Fmi3Element) and end.valueReference < 0:
            return f"{MasterTypeUnsupported(end.type)} ('{end.name}' is an FMI 3.0 {end.type}, the {what})"
    if destination.causality != "input":
        return f"an input as destination ('{destination.name}' has causality {destination.causality})"
    if source is not None and source.causality != "output":
        return f"an output as source ('{source.name}' has causality {source.causality})"
    try:
        if bus_type(src_type) != bus_type(destination.type):
            return (f"matching types (source is {src_type}, destination '{destination.name}' "
                    f"is {destination.type})")
    except MasterTypeUnsupported as exc:
        return str(exc)
    return None
