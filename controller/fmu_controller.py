"""A controller FMU in the cell: an FMI 2.0 co-simulation FMU stepped once per bus cycle
through the controller contract (:class:`controller.contract.CellController`).

A controller exported from Simulink, Modelica or C code becomes a cell controller by naming
its variables: ``inputs`` maps an FMU input to what the controller is given, ``outputs`` an
FMU output to what it returns (joint index in brackets, 1-based)::

    [controller]
    fmu = "pd_controller.fmu"
    [controller.fmu_inputs]            # FMU input = controller input field
    q1 = "position[1]"                 # also velocity[i], torque[i], statusword[i],
    qd1 = "velocity[1]"                # modes_of_operation_display[i], fresh[i], node_fault[i],
    q_ref1 = "reference_position[1]"   # reference_position/velocity/acceleration[i], time_s, cycle
    [controller.fmu_outputs]           # FMU output = controller output field
    tau1 = "torque_offset[1]"          # also target_position/velocity/torque[i], velocity_offset[i],
                                       # controlword[i], modes_of_operation[i]
    [controller.parameters]            # FMU parameters (start values)
    kp = 800.0

Each cycle: the mapped inputs are set, the FMU does one step from ``t_k`` over the bus
cycle ``T``, the mapped outputs are read. What the FMU does not map is done as by the
built-in controller (:class:`controller.tracking_clock.TrackingClock`): the CiA 402 enable
sequence and quick stop (``controlword``), mode 8 CSP (``modes_of_operation``), the
reference position as ``target_position``, zeros for the rest. The reference inputs are
the joint reference at the time the output acts (``t_k + lead``), the start pose while
enabling and settling (``settle_time_s``: the scenario's ``[controller] settle_time``).

Checked before the run (:func:`check_controller_fmu`): the FMU is FMI 2.0 co-simulation,
every mapped variable exists with the right causality (input / output / parameter) and
type, every mapped field is known.

The FMU instance itself is opened by whoever composes the cell (``controller/`` imports no FMU
code): :class:`FmuController` takes ``open_fmu``, a callable returning a started instance that
satisfies :class:`ControllerFmu` - ``cosim.cell.user_controller`` passes ``fmus.fmu.Fmu``,
whose per-step calls go straight to the FMU's ``fmi2Set*``/``fmi2DoStep``/``fmi2Get*`` with
preallocated value-reference and value arrays. Each cycle the mapped inputs are gathered into
those arrays with one indexed copy per source field (``benchmarks/bench_controller_fmu.py``).
"""
from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from controller.contract import OUTPUT_INTEGER, OUTPUT_REAL, ControllerInfo, ControllerInput, ControllerOutput
from controller.tracking_clock import TrackingClock

INPUT_JOINT_FIELDS = ("position", "velocity", "torque", "statusword", "modes_of_operation_display", "error_code",
                      "fresh", "node_fault", "reference_position", "reference_velocity", "reference_acceleration")
"""Per-joint fields an FMU input may be mapped to (``name[i]``, i = 1..6)."""
INPUT_SCALAR_FIELDS = ("time_s", "cycle", "previous_output_late", "previous_output_lost")
"""Scalar fields an FMU input may be mapped to."""
OUTPUT_FIELDS = OUTPUT_REAL + OUTPUT_INTEGER
"""Per-joint fields an FMU output may be mapped to."""

_FIELD = re.compile(r"^([a-z_]+)(?:\[(\d+)\])?$")
_NUMERIC = ("Real", "Integer", "Boolean", "Enumeration")


class ControllerFmuError(ValueError):
    """A controller FMU or its mapping is unusable: names the FMU, the key and what was expected."""

    def __init__(self, key: str, expected: str, given: Any, problem: str = "") -> None:
        self.key, self.expected, self.given, self.problem = key, expected, given, problem
        super().__init__(f"{key} = {given!r}: expected {expected}" + (f" ({problem})" if problem else ""))


def parse_field(text: Any, joint_fields: tuple[str, ...], scalar_fields: tuple[str, ...] = (),
                n_joints: int = 6) -> tuple[str, int | None]:
    """``"position[3]"`` -> ("position", 2); ``"time_s"`` -> ("time_s", None); ValueError otherwise."""
    m = _FIELD.match(text) if isinstance(text, str) else None
    if m is None:
        raise ValueError("not 'field[joint]'")
    name, index = m.group(1), m.group(2)
    if index is None:
        if name not in scalar_fields:
            raise ValueError(f"unknown field {name!r}" if name not in joint_fields else f"{name} needs a joint [1..{n_joints}]")
        return name, None
    if name not in joint_fields:
        raise ValueError(f"unknown field {name!r}")
    joint = int(index)
    if not 1 <= joint <= n_joints:
        raise ValueError(f"joint {joint} outside 1..{n_joints}")
    return name, joint - 1


def _variables(path: Path) -> tuple[Any, dict[str, Any]]:
    from fmpy import read_model_description

    md = read_model_description(str(path), validate=False)
    return md, {v.name: v for v in md.modelVariables}


def check_controller_fmu(path: Any, inputs: dict[str, str], outputs: dict[str, str], parameters: dict[str, Any],
                         where: Any = None) -> None:
    """Check a controller FMU and its mapping before the run. With ``where`` (a scenario
    position) the problem is a ScenarioError at the key; else a :class:`ControllerFmuError`."""
    def fail(key: str, expected: str, given: Any, problem: str = "") -> Exception:
        if where is None:
            return ControllerFmuError(key, expected, given, problem)
        w = where
        for part in key.split("."):
            w = w / part
        return w.error(expected, given, problem=problem or None)

    path = Path(path)
    try:
        md, variables = _variables(path)
    except Exception as exc:  # noqa: BLE001 - an unreadable FMU: say so at the key
        raise fail("fmu", "an FMI 2.0 co-simulation FMU", str(path), problem=f"cannot read it: {exc}") from None
    if md.fmiVersion != "2.0" or md.coSimulation is None:
        raise fail("fmu", "an FMI 2.0 co-simulation FMU", str(path),
                   problem=f"FMI {md.fmiVersion}, co-simulation: {md.coSimulation is not None}")
    names = sorted(variables)
    for table, mapping, causality, fields in (
            ("fmu_inputs", inputs, "input", (INPUT_JOINT_FIELDS, INPUT_SCALAR_FIELDS)),
            ("fmu_outputs", outputs, "output", (OUTPUT_FIELDS, ()))):
        for var, field in mapping.items():
            key = f"{table}.{var}"
            if var not in variables:
                raise fail(key, f"an {causality} variable of {path.name}", field,
                           problem=f"{path.name} has no variable {var!r} (its {causality}s: "
                                   f"{[n for n in names if variables[n].causality == causality]})")
            v = variables[var]
            if v.causality != causality or v.type not in _NUMERIC:
                raise fail(key, f"a numeric {causality} variable of {path.name}", field,
                           problem=f"{var!r} is a {v.causality} {v.type}")
            try:
                parse_field(field, *fields)
            except ValueError as exc:
                allowed = [f"{f}[i]" for f in fields[0]] + list(fields[1])
                raise fail(key, f"one of {allowed} (i = 1..6)", field, problem=str(exc)) from None
    for var, value in parameters.items():
        key = f"parameters.{var}"
        if var not in variables:
            raise fail(key, f"a parameter of {path.name}", value, problem=f"{path.name} has no variable {var!r}")
        v = variables[var]
        if v.causality != "parameter" or v.type not in _NUMERIC:
            raise fail(key, f"a numeric parameter of {path.name}", value,
                       problem=f"{var!r} is a {v.causality} {v.type}")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise fail(key, "a number", value)


@runtime_checkable
class ControllerFmu(Protocol):
    """A started FMU instance as :class:`FmuController` steps it (``fmus.fmu.Fmu`` is one).

    The value arrays are in the order of the names the instance was opened with
    (``real_inputs`` ... ``boolean_outputs``, see :data:`FmuOpener`); Booleans as 0/1 ints.
    The getters may return a reused buffer. A failing call raises."""

    @property
    def inputs(self) -> np.ndarray: ...  # the Real input array: written in place, then push_inputs()

    def push_inputs(self) -> None: ...

    def set_integer_inputs(self, values: np.ndarray) -> None: ...

    def set_boolean_inputs(self, values: np.ndarray) -> None: ...

    def get_outputs(self) -> np.ndarray: ...  # Real outputs

    def get_integer_outputs(self) -> np.ndarray: ...

    def get_boolean_outputs(self) -> np.ndarray: ...

    def do_step(self, t: float, h: float) -> None: ...

    def close(self) -> None: ...


FmuOpener = Callable[..., ControllerFmu]
"""``open_fmu(path, name, start_values, *, real_inputs, real_outputs, integer_inputs, integer_outputs,
boolean_inputs, boolean_outputs) -> ControllerFmu``: instantiate the FMU at ``path``, set the
``start_values`` (the parameters) and initialize it; the name lists fix the order of the arrays."""

_VALUE_TYPE = {"Real": "Real", "Integer": "Integer", "Enumeration": "Integer", "Boolean": "Boolean"}


class _Gather:
    """Copies mapped fields into one value array: per source field, ``dest[at] = source[joints]``."""

    def __init__(self, entries: Sequence[tuple[str, int | None]], references: dict[str, int]) -> None:
        self.n = len(entries)
        groups: dict[str, tuple[list[int], list[int]]] = {}
        self.scalars: list[tuple[int, str]] = []
        for at, (name, joint) in enumerate(entries):
            if joint is None:
                self.scalars.append((at, name))
            else:
                dest, joints = groups.setdefault(name, ([], []))
                dest.append(at)
                joints.append(joint)
        # (index into the reference triple or -1, input field name, destination indices, joints)
        self.groups = [(references.get(name, -1), name, np.array(dest), np.array(joints))
                       for name, (dest, joints) in groups.items()]

    def into(self, dest: np.ndarray, inputs: ControllerInput, reference: tuple) -> None:
        for which, name, at, joints in self.groups:
            dest[at] = (reference[which] if which >= 0 else getattr(inputs, name))[joints]
        for at, name in self.scalars:
            dest[at] = getattr(inputs, name)


class _Scatter:
    """Copies one value array into the mapped output fields: ``out.field[joints] = values[at]``."""

    def __init__(self, entries: Sequence[tuple[str, int]]) -> None:
        groups: dict[str, tuple[list[int], list[int]]] = {}
        for at, (name, joint) in enumerate(entries):
            src, joints = groups.setdefault(name, ([], []))
            src.append(at)
            joints.append(joint)
        self.groups = [(name, np.array(src), np.array(joints)) for name, (src, joints) in groups.items()]

    def into(self, out: ControllerOutput, values: np.ndarray) -> None:
        for name, at, joints in self.groups:
            getattr(out, name)[joints] = values[at]


class FmuController:
    """An FMI 2.0 co-simulation controller FMU behind the controller contract (module docstring).

    Args:
        path: the .fmu file. inputs / outputs: FMU variable -> field (``"position[1]"``).
        parameters: FMU parameter -> value (start values). settle_time_s: hold after enabling, s.
        open_fmu: opens the instance (:data:`FmuOpener`; the cell passes ``fmus.fmu.Fmu``'s).
    """

    _REFERENCES = {"reference_position": 0, "reference_velocity": 1, "reference_acceleration": 2}

    def __init__(self, path: Any, inputs: dict[str, str], outputs: dict[str, str],
                 parameters: dict[str, Any] | None = None, settle_time_s: float = 0.2, *,
                 open_fmu: FmuOpener) -> None:
        self.path = Path(path)
        self.inputs_map = dict(inputs)
        self.outputs_map = dict(outputs)
        self.parameters = dict(parameters or {})
        self.settle_time_s = settle_time_s
        self.open_fmu = open_fmu
        check_controller_fmu(self.path, self.inputs_map, self.outputs_map, self.parameters)
        self._fmu: ControllerFmu | None = None
        self.clock: TrackingClock | None = None
        self.time = 0.0

    # the optional attributes of the contract
    @property
    def motion_start_s(self) -> float | None:
        return self.clock.motion_start_s if self.clock is not None else None

    @property
    def stop_reason(self) -> str | None:
        return self.clock.stop_reason if self.clock is not None else None

    @property
    def stopped_at_s(self) -> float | None:
        return self.clock.stopped_at_s if self.clock is not None else None

    def setup(self, info: ControllerInfo) -> None:
        _, variables = _variables(self.path)
        self.info = info
        self.period_s = info.period_s
        self.clock = TrackingClock(info, settle_time_s=self.settle_time_s)
        self.out = ControllerOutput.zeros(info.n_joints)

        def split(mapping: dict[str, str], fields: tuple) -> dict[str, list[tuple[str, tuple]]]:
            """Value type -> [(FMU variable, (field, joint))] in mapping order."""
            out: dict[str, list] = {"Real": [], "Integer": [], "Boolean": []}
            for var, field in mapping.items():
                out[_VALUE_TYPE[variables[var].type]].append((var, parse_field(field, *fields)))
            return out

        ins = split(self.inputs_map, (INPUT_JOINT_FIELDS, INPUT_SCALAR_FIELDS))
        outs = split(self.outputs_map, (OUTPUT_FIELDS, ()))
        names = {f"{kind}_{way}": [var for var, _ in table[value_type]]
                 for way, table in (("inputs", ins), ("outputs", outs))
                 for kind, value_type in (("real", "Real"), ("integer", "Integer"), ("boolean", "Boolean"))}
        self._fmu = self.open_fmu(self.path, "controller", self.parameters, **names)
        self._gather = {t: _Gather([f for _, f in ins[t]], self._REFERENCES) for t in ins}
        self._scatter = {t: _Scatter([f for _, f in outs[t]]) for t in outs}
        self._int_in = np.zeros(len(ins["Integer"]), dtype=np.int64)
        self._bool_in = np.zeros(len(ins["Boolean"]), dtype=np.int64)
        self._bool_flags = np.zeros(len(ins["Boolean"]), dtype=bool)
        self._mapped_out = {parse_field(f, OUTPUT_FIELDS)[0] for f in self.outputs_map.values()}
        self.time = 0.0

    def step(self, inputs: ControllerInput) -> ControllerOutput:
        out = self.out
        tau = self.clock.update(inputs, out.controlword)
        reference = self.clock.reference(tau)
        fmu = self._fmu
        gather = self._gather
        if gather["Real"].n:
            gather["Real"].into(fmu.inputs, inputs, reference)
            fmu.push_inputs()
        if gather["Integer"].n:
            gather["Integer"].into(self._int_in, inputs, reference)
            fmu.set_integer_inputs(self._int_in)
        if gather["Boolean"].n:
            gather["Boolean"].into(self._bool_in, inputs, reference)
            fmu.set_boolean_inputs(np.not_equal(self._bool_in, 0, out=self._bool_flags))
        fmu.do_step(inputs.time_s, self.period_s)
        self.time = inputs.time_s + self.period_s
        # what the FMU does not map: as the built-in controller (CSP, reference position)
        if "target_position" not in self._mapped_out:
            out.target_position[:] = reference[0]
        scatter = self._scatter
        if scatter["Real"].groups:
            scatter["Real"].into(out, fmu.get_outputs())
        if scatter["Integer"].groups:
            scatter["Integer"].into(out, fmu.get_integer_outputs())
        if scatter["Boolean"].groups:
            scatter["Boolean"].into(out, fmu.get_boolean_outputs())
        if self.clock.stop_reason is not None:  # stopped: quick stop, hold where the drives are
            out.controlword[:] = 0x0002
            out.modes_of_operation[:] = 8
            out.target_position[:] = inputs.position
            out.torque_offset[:] = 0.0
        return out

    def close(self) -> None:
        fmu, self._fmu = self._fmu, None
        if fmu is not None:
            fmu.close()
