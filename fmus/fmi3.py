"""FMI 3.0 co-simulation FMUs behind :class:`fmus.fmu.Fmu`: flattened variables and the C adapter binding.

An :class:`~fmus.fmu.Fmu` exchanges three value types, the ones the master's buses carry
(Real = float64, Integer = 32-bit int, Boolean). An FMI 3.0 variable is flattened into
bus elements, one per scalar or array element: ``u`` (scalar), ``u[2]`` (1-D, 1-based
like FMI 2.0 structured names), ``M[1,2]`` (n-D, row-major). Each element travels on the bus of its type (conversion rules, docs/explanation/fmus.md
"FMI 3.0 in the master"):

=================================  ============  ===============================================
FMI 3.0 type                       bus           conversion
=================================  ============  ===============================================
Float64                            Real          exact
Float32                            Real          widened exactly; set: rounded to nearest float32
Int8, UInt8, Int16, UInt16, Int32  Integer       exact; set: a value outside the type's range
                                                 stops the run naming the variable
UInt32, Int64, UInt64, Enumeration Integer       exact within 32-bit int; a value outside stops
                                                 the run (the bus is 32-bit)
Boolean                            Boolean       exact
Clock (output)                     Boolean       1 when the clock ticked at the event that ended
                                                 the last step (read and recorded only)
Binary (output)                    Integer       its size in bytes (read and recorded only; the
                                                 bytes via ``Fmu.get_binary``)
String, input Clock/Binary         —             cannot be connected, read by tasks or recorded
=================================  ============  ===============================================

Connections join elements of the same bus, so an FMI 2.0 Real feeds a Float32 input and
an FMI 3.0 Int16 output feeds an FMI 2.0 Integer input.
"""
from __future__ import annotations

import ctypes
import itertools
from ctypes import POINTER, Structure, c_char, c_double, c_int, c_longlong, c_size_t, c_uint, c_void_p
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from fmpy.model_description import ModelDescription

import native
from fmus.errors import FmuConfigError

#: FMI 3.0 types with their adapter code, shadow dtype and master bus.
TYPE_CODE = {"Float32": 0, "Float64": 1, "Int8": 2, "UInt8": 3, "Int16": 4, "UInt16": 5, "Int32": 6,
             "UInt32": 7, "Int64": 8, "UInt64": 9, "Boolean": 10, "Binary": 11, "Clock": 12,
             "Enumeration": 8}
SHADOW_DTYPE = {0: np.float32, 1: np.float64, 2: np.int8, 3: np.uint8, 4: np.int16, 5: np.uint16, 6: np.int32,
                7: np.uint32, 8: np.int64, 9: np.uint64, 10: np.bool_, 11: np.uintp, 12: np.bool_}
FMI3_BUS = {"Float32": "Real", "Float64": "Real", "Int8": "Integer", "UInt8": "Integer", "Int16": "Integer",
            "UInt16": "Integer", "Int32": "Integer", "UInt32": "Integer", "Int64": "Integer", "UInt64": "Integer",
            "Enumeration": "Integer", "Boolean": "Boolean", "Clock": "Boolean", "Binary": "Integer"}
INTEGER_RANGE = {"Int8": (-2**7, 2**7 - 1), "UInt8": (0, 2**8 - 1), "Int16": (-2**15, 2**15 - 1),
                 "UInt16": (0, 2**16 - 1), "Int32": (-2**31, 2**31 - 1), "UInt32": (0, 2**32 - 1),
                 "Int64": (-2**63, 2**63 - 1), "UInt64": (0, 2**64 - 1), "Enumeration": (-2**63, 2**63 - 1)}
#: Types whose variables are only read (outputs or locals): they cannot be set or feed an input.
READ_ONLY_TYPES = ("Clock", "Binary")
_BINDINGS = ("Float32", "Float64", "Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64",
             "Boolean")


@dataclass(frozen=True)
class Fmi3Element:
    """One bus element of an FMI 3.0 variable (a scalar, or one element of an array).

    Quacks like fmpy's FMI 2.0 ``ScalarVariable`` for the master's checks: ``valueReference``
    is the element's index in the adapter's table, ``fmi_value_reference`` the FMU's own.
    """

    name: str
    type: str
    causality: str
    variability: str
    initial: str | None
    valueReference: int
    fmi_value_reference: int
    element: int
    count: int
    variable: str
    start: object
    description: str | None = None


def _dimensions(variable, by_vr: dict[int, object]) -> list[int]:
    dims = []
    for d in variable.dimensions:
        if d.start is not None:
            dims.append(int(d.start))
        else:
            ref = by_vr.get(d.valueReference)
            if ref is None or ref.start is None:
                raise FmuConfigError(f"variable '{variable.name}': array dimension refers to value reference "
                                        f"{d.valueReference}, which has no start value")
            dims.append(int(str(ref.start).split()[0]))
    return dims


def _parse_start(text, fmi_type: str, count: int, name: str) -> list | None:
    if text is None:
        return None
    items = str(text).split() if fmi_type not in ("Binary",) else [str(text)]
    if fmi_type in ("Float32", "Float64"):
        values = [float(x) for x in items]
    elif fmi_type == "Boolean":
        values = [x in ("true", "1") for x in items]
    elif fmi_type in INTEGER_RANGE:
        values = [int(x) for x in items]
    else:
        return None
    if len(values) == 1 and count > 1:
        values = values * count
    if len(values) != count:
        raise FmuConfigError(f"variable '{name}': start has {len(values)} values for {count} elements")
    return values


def flatten(md: ModelDescription) -> list[Fmi3Element]:
    """The elements of an FMI 3.0 model description (the independent variable left out).

    Elements the adapter exchanges come first, numbered 0, 1, ... (``valueReference``);
    String elements follow with ``valueReference`` -1: they are known by name (so a
    connection or recording of one is refused for its type) but never exchanged.
    """
    by_vr = {v.valueReference: v for v in md.modelVariables}
    out: list[Fmi3Element] = []
    strings: list[Fmi3Element] = []
    for v in md.modelVariables:
        if v.causality == "independent":
            continue
        if v.type not in TYPE_CODE:
            dims = _dimensions(v, by_vr)
            names = ([f"{v.name}[{','.join(map(str, i))}]" for i in itertools.product(*(range(1, n + 1) for n in dims))]
                     if dims else [v.name])
            strings += [Fmi3Element(n, v.type, v.causality, v.variability, v.initial, -1, v.valueReference, k,
                                    len(names), v.name, None, v.description) for k, n in enumerate(names)]
            continue
        dims = _dimensions(v, by_vr)
        count = int(np.prod(dims)) if dims else 1
        starts = _parse_start(v.start, v.type, count, v.name)
        if dims:
            indices = list(itertools.product(*(range(1, n + 1) for n in dims)))
            names = [f"{v.name}[{','.join(map(str, i))}]" for i in indices]
        else:
            names = [v.name]
        for k, name in enumerate(names):
            out.append(Fmi3Element(name, v.type, v.causality, v.variability, v.initial, len(out), v.valueReference,
                                   k, count, v.name, None if starts is None else starts[k], v.description))
    return out + strings


def check_fmi3_start(variable: Fmi3Element, value: object) -> str | None:
    """None when ``value`` may be the start value of FMI 3.0 element ``variable``, else what was expected."""
    if variable.causality == "structuralParameter":
        return (f"a variable whose start value can be set ('{variable.name}' is a structural parameter, "
                f"set only in configuration mode, which the master does not use)")
    if variable.type in READ_ONLY_TYPES or variable.type not in TYPE_CODE:
        return (f"a Float, Int, UInt or Boolean variable ('{variable.name}' is an FMI 3.0 {variable.type}, "
                f"whose start value the master does not set)")
    if not (variable.causality == "input" or (variable.variability != "constant"
                                              and variable.initial in ("exact", "approx"))):
        return (f"a variable whose start value can be set (causality {variable.causality}, variability "
                f"{variable.variability}, initial {variable.initial} cannot be set)")
    if variable.type in ("Float32", "Float64"):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value)
        if ok and variable.type == "Float32" and abs(value) > float(np.finfo(np.float32).max):
            ok = False
        return None if ok else f"a finite number for {variable.type} variable '{variable.name}'"
    if variable.type == "Boolean":
        return None if isinstance(value, bool) else f"true or false for Boolean variable '{variable.name}'"
    lo, hi = INTEGER_RANGE[variable.type]
    if isinstance(value, int) and not isinstance(value, bool) and lo <= value <= hi:
        return None
    return f"an integer in [{lo}, {hi}] for {variable.type} variable '{variable.name}'"


class A3Entry(Structure):
    """Mirror of ``a3_entry`` in fmi3_adapter.c."""

    _fields_ = [("vr", c_uint), ("type", c_int), ("count", c_longlong), ("element", c_longlong),
                ("shadow", c_longlong)]


class A3Ctx(Structure):
    """Mirror of ``a3_ctx`` in fmi3_adapter.c."""

    _fields_ = [
        ("instance", c_void_p), ("set", c_void_p * 11), ("get", c_void_p * 11), ("get_binary", c_void_p),
        ("get_clock", c_void_p), ("do_step", c_void_p), ("enter_event_mode", c_void_p),
        ("update_discrete_states", c_void_p), ("enter_step_mode", c_void_p),
        ("entries", POINTER(A3Entry)), ("n_entries", c_longlong), ("shadow", c_void_p),
        ("clock_vrs", c_void_p), ("clock_shadow", c_void_p), ("n_clocks", c_longlong),
        ("event_mode_used", c_int), ("stop_at", c_void_p),
        ("terminated", c_int), ("end_status", c_int), ("last_successful_time", c_double),
        ("events", c_longlong), ("failed_entry", c_longlong), ("message", c_char * 256),
    ]


#: The adapter's C source, built and cached by the project's native layer (:mod:`native`).
ADAPTER_SOURCE = Path(__file__).with_name("fmi3_adapter.c")
CFLAGS = ("-O2", "-shared", "-fPIC", "-std=c99")


@lru_cache(maxsize=1)
def load_fmi3_adapter() -> ctypes.CDLL | None:
    """Return the compiled FMI 3.0 adapter library (fmi3_adapter.c), or None if it cannot be built."""
    return native.load_library(ADAPTER_SOURCE, CFLAGS, what="FMI 3.0 adapter")


class Fmi3Binding:
    """The adapter context of one FMI 3.0 instance: element table, shadow copies, function pointers.

    ``fn_address`` has the same keys as an FMI 2.0 component's ("DoStep", "SetReal", ...)
    so that both engines step FMI 2.0 and 3.0 FMUs alike.
    """

    def __init__(self, elements: list[Fmi3Element], dll: ctypes.CDLL, instance: int, event_mode_used: bool,
                 stop_at_address: int | None) -> None:
        elements = [e for e in elements if e.valueReference >= 0]  # Strings are never exchanged
        lib = load_fmi3_adapter()
        if lib is None:
            raise FmuConfigError("FMI 3.0 FMUs need the compiled FMI 3.0 adapter "
                                 "(fmus/fmi3_adapter.c), which could not be built: is a C compiler "
                                 "installed (set CC)?")
        self.lib = lib
        self.elements = elements
        offsets: dict[tuple[int, str], int] = {}
        size = 0
        for e in elements:
            key = (e.fmi_value_reference, e.type)
            if key not in offsets:
                offsets[key] = size
                item = np.dtype(SHADOW_DTYPE[TYPE_CODE[e.type]]).itemsize
                size += -(-(item * e.count) // 8) * 8
        self.offsets = offsets
        self.shadow = np.zeros(max(size, 8), dtype=np.uint8)
        self.entries = (A3Entry * max(len(elements), 1))()
        for i, e in enumerate(elements):
            self.entries[i] = A3Entry(e.fmi_value_reference, TYPE_CODE[e.type], e.count, e.element,
                                      offsets[(e.fmi_value_reference, e.type)])
            if e.start is not None and e.type not in READ_ONLY_TYPES:
                self.write_shadow(e, e.start)
        clocks = [e for e in elements if e.type == "Clock" and e.causality == "output"]
        self.clock_vrs = np.array([e.fmi_value_reference for e in clocks] or [0], dtype=np.uint32)
        self.clock_shadow = np.array([offsets[(e.fmi_value_reference, e.type)] for e in clocks] or [0],
                                     dtype=np.int64)
        self.stop_at_fallback = np.array([np.inf])
        ctx = A3Ctx()
        ctx.instance = instance
        for k, t in enumerate(_BINDINGS):
            ctx.set[k] = ctypes.cast(getattr(dll, "fmi3Set" + t), c_void_p).value
            ctx.get[k] = ctypes.cast(getattr(dll, "fmi3Get" + t), c_void_p).value
        for field, name in (("get_binary", "GetBinary"), ("get_clock", "GetClock"), ("do_step", "DoStep"),
                            ("enter_event_mode", "EnterEventMode"),
                            ("update_discrete_states", "UpdateDiscreteStates"), ("enter_step_mode", "EnterStepMode")):
            setattr(ctx, field, ctypes.cast(getattr(dll, "fmi3" + name), c_void_p).value)
        ctx.entries = ctypes.cast(self.entries, POINTER(A3Entry))
        ctx.n_entries = len(elements)
        ctx.shadow = self.shadow.ctypes.data
        ctx.clock_vrs = self.clock_vrs.ctypes.data
        ctx.clock_shadow = self.clock_shadow.ctypes.data
        ctx.n_clocks = len(clocks)
        ctx.event_mode_used = int(event_mode_used)
        ctx.stop_at = stop_at_address or self.stop_at_fallback.ctypes.data
        ctx.failed_entry = -1
        self.ctx = ctx
        self.address = ctypes.addressof(ctx)
        self.fn_address = {name: ctypes.cast(getattr(lib, "a3_" + fn), c_void_p).value for name, fn in (
            ("DoStep", "do_step"), ("SetReal", "set_real"), ("SetInteger", "set_integer"),
            ("SetBoolean", "set_boolean"), ("GetReal", "get_real"), ("GetInteger", "get_integer"),
            ("GetBoolean", "get_boolean"))}
        self._flush = lib.a3_flush
        self._flush.argtypes = [c_void_p, c_void_p, c_size_t]
        self._event_iteration = lib.a3_event_iteration
        self._event_iteration.argtypes = [c_void_p, c_double, c_int]

    def write_shadow(self, element: Fmi3Element, value: object) -> None:
        """Write ``value`` into the element's shadow copy (in its own type)."""
        dtype = np.dtype(SHADOW_DTYPE[TYPE_CODE[element.type]])
        offset = self.offsets[(element.fmi_value_reference, element.type)] + element.element * dtype.itemsize
        self.shadow[offset:offset + dtype.itemsize] = np.array([value], dtype=dtype).view(np.uint8)

    def set_start_values(self, values: dict[Fmi3Element, object]) -> int:
        """Set ``values`` (checked beforehand) with one FMI 3.0 setter call per variable; return the status."""
        for element, value in values.items():
            self.write_shadow(element, value)
        refs = np.array(sorted(e.valueReference for e in values), dtype=np.uint32)
        return int(self._flush(self.address, refs.ctypes.data, len(refs))) if len(refs) else 0

    def event_iteration(self, time: float, enter: bool) -> int:
        """Event mode: read clocks, iterate fmi3UpdateDiscreteStates, fmi3EnterStepMode."""
        return int(self._event_iteration(self.address, time, int(enter)))

    @property
    def message(self) -> str:
        text = self.ctx.message.decode("utf-8", "replace")
        if self.ctx.failed_entry >= 0:
            name = self.elements[self.ctx.failed_entry].name
            text = f"variable '{name}'" + (f": {text}" if text else "")
        return text

    def clear_message(self) -> None:
        self.ctx.message = b""
        self.ctx.failed_entry = -1

    @property
    def terminated(self) -> bool:
        return bool(self.ctx.terminated)


__all__ = ["FMI3_BUS", "Fmi3Binding", "Fmi3Element", "INTEGER_RANGE", "READ_ONLY_TYPES", "TYPE_CODE",
           "check_fmi3_start", "flatten", "load_fmi3_adapter"]
