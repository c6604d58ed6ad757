"""One FMI 2.0 or FMI 3.0 co-simulation FMU instance: the project's one FMU class.

Everything that loads and steps an FMU goes through :class:`Fmu`: the co-simulation
master (``cosim.master``: its engines and compiled kernel call the bound per-step
functions directly), its out-of-process proxy (``cosim.master.proxy``, a subclass whose
per-step functions forward to a child process), and hand-written loops (drive benches,
FMU tests), which use the named, prepared I/O arrays.

- Loading: the model description is read once per file (and checked: an FMI 2.0 or
  3.0 FMU with a co-simulation interface); ``variables`` maps names to variables (FMI
  3.0: one flattened element per scalar or array element, :mod:`fmus.fmi3`).
- Life cycle: :meth:`instantiate`, :meth:`enter_initialization` (start values),
  :meth:`exit_initialization`, :meth:`close`; :meth:`start` does the first three. The
  life-cycle calls go through fmpy; a failure raises :class:`~fmus.errors.SimulationError`
  quoting the FMU's log.
- Per step: ``do_step_fn``, ``set_fn``/``get_fn`` (value type Real/Integer/Boolean ->
  ctypes function of the form ``f(component, value_references, n, values)``) and their
  raw addresses ``fn_address`` are bound once: FMI 2.0 straight to the FMU's
  ``fmi2DoStep``/``fmi2Set*``/``fmi2Get*``, FMI 3.0 to the C adapter of :mod:`fmus.fmi3`,
  which offers the same call shapes. No per-call allocation (fmpy's ``setReal``/``getReal``
  build ctypes arrays and go through a logging wrapper on every call).
- Hand loops: ``real_inputs``/``real_outputs``/``integer_inputs``/``integer_outputs``
  (and the Boolean pair) fix the order of the arrays exchanged by :meth:`set_inputs`,
  :meth:`get_outputs`, :meth:`set_integer_inputs`, :meth:`get_integer_outputs`,
  :meth:`set_boolean_inputs`, :meth:`get_boolean_outputs`; :meth:`do_step` steps; every
  call checks the returned status. A user's controller FMU runs through this path too
  (``controller.fmu_controller.ControllerFmu``, opened by ``cosim.cell.user_controller``).
- Log: the FMU's messages go to a bounded buffer (``messages``) that a
  ``SimulationError`` quotes when the FMU fails.

Typical hand loop (six drives and a plant)::

    with Fmu(paths["servo_drive"], "drive1", drive_start_values(1),
             real_inputs=["target_position", "torque_offset", "q_meas", "qd_meas"],
             real_outputs=["tau_out", "position_actual"],
             integer_inputs=["controlword"]).start() as drive:
        drive.set_inputs(np.array([...]))   # in the order of real_inputs (or write drive.inputs[:],
                                            # then drive.push_inputs(): saves the copy)
        drive.set_integer_inputs([0x0F])
        drive.do_step(t, h)
        tau, pos = drive.get_outputs()      # a view of a reused buffer: copy to keep
"""
from __future__ import annotations

import ctypes
import weakref
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from functools import lru_cache
from pathlib import Path

import numpy as np
from fmpy import read_model_description
from fmpy.fmi3 import FMU3Slave
from fmpy.model_description import ModelDescription, ScalarVariable

from fmus.errors import FmuConfigError, SimulationError
from fmus.fmi3 import FMI3_BUS, Fmi3Binding, flatten
from fmus.instance import (SET_T, STEP_T, FmuInstantiateError, bound_addresses, extracted_dir, instantiate_fmi2,
                           release_log, status_name)

#: The value types the per-step functions exchange (the master's three buses).
VALUE_TYPES = ("Real", "Integer", "Boolean")
#: FMI type -> value type it is exchanged as (FMI 2.0 Enumeration as Integer; FMI 3.0: ``fmi3.FMI3_BUS``).
VALUE_TYPE_OF = {"Real": "Real", "Integer": "Integer", "Enumeration": "Integer", "Boolean": "Boolean", **FMI3_BUS}
#: Value type -> numpy dtype and ctypes type of its values (Boolean as fmi2Boolean, an int).
VALUE_DTYPE = {"Real": np.float64, "Integer": np.intc, "Boolean": np.intc}
VALUE_CTYPE = {"Real": ctypes.c_double, "Integer": ctypes.c_int, "Boolean": ctypes.c_int}
#: What an Fmu runs, in words (for error messages).
SUPPORTED_FMUS = "an FMI 2.0 or FMI 3.0 co-simulation FMU"


@lru_cache(maxsize=64)
def _read_description(path: str, mtime: float) -> ModelDescription:
    return read_model_description(path, validate=False)


def fmu_kind_problem(md: ModelDescription) -> str | None:
    """None when ``md`` is an FMU this class runs; otherwise what it is, in one sentence (no "expected")."""
    version = str(md.fmiVersion)
    if version not in ("2.0",) and not version.startswith("3."):
        return f"its modelDescription.xml declares fmiVersion {version!r}, which the master does not run"
    if md.coSimulation is not None:
        return None
    interfaces = [name for name, attr in (("model exchange", "modelExchange"),
                                          ("scheduled execution", "scheduledExecution"))
                  if getattr(md, attr, None) is not None]
    kind = " and ".join(interfaces) or "no"
    return (f"it is an FMI {version} FMU with {kind} interface{'s' if len(interfaces) > 1 else ''} only "
            f"(no <CoSimulation> element); the master steps FMUs through their co-simulation interface")


def load_model_description(path: str | Path) -> ModelDescription:
    """Read (and cache) the modelDescription of an FMU file; FmuConfigError naming the file
    when it is missing, unreadable, or not an FMI 2.0/3.0 co-simulation FMU."""
    path = Path(path)
    if not path.is_file():
        raise FmuConfigError(f"FMU file {str(path)!r} does not exist (expected a path to a .fmu file)")
    try:
        md = _read_description(str(path.resolve()), path.stat().st_mtime)
    except Exception as exc:  # fmpy raises plain Exceptions for broken archives
        raise FmuConfigError(f"FMU file {str(path)!r} cannot be read: {exc}") from exc
    problem = fmu_kind_problem(md)
    if problem:
        error = FmuConfigError(f"FMU file {str(path)!r}: {problem}; expected {SUPPORTED_FMUS}")
        error.problem = problem
        raise error
    return md


def variables_of(md: ModelDescription) -> dict:
    """Variable name -> variable as an Fmu exchanges it (FMI 3.0: flattened elements, ``fmi3.flatten``)."""
    if str(md.fmiVersion).startswith("3."):
        return {e.name: e for e in flatten(md)}
    return {v.name: v for v in md.modelVariables}


class Fmu:
    """One instance of an FMI 2.0 or FMI 3.0 co-simulation FMU (see the module docstring).

    Args:
        path: the .fmu file.
        name: instance name (passed to fmi2Instantiate / fmi3InstantiateCoSimulation).
        start_values: variable name -> value, set in initialization mode.
        real_inputs, real_outputs, integer_inputs, integer_outputs, boolean_inputs, boolean_outputs:
            variable names fixing the order of the hand-loop arrays (:meth:`set_inputs` ...;
            Booleans as fmi2Boolean ints, 0 or 1).
        debug_logging: ``loggingOn`` of the instantiation.
        log_capacity: how many log messages ``messages`` keeps.
        on_message: also called with each formatted log message as it is logged.

    The constructor reads the model description only; :meth:`start` (or the master)
    instantiates and initializes the FMU.
    """

    out_of_process = False

    def __init__(self, path: str | Path, name: str, start_values: Mapping[str, object] | None = None, *,
                 real_inputs: Sequence[str] = (), real_outputs: Sequence[str] = (),
                 integer_inputs: Sequence[str] = (), integer_outputs: Sequence[str] = (),
                 boolean_inputs: Sequence[str] = (), boolean_outputs: Sequence[str] = (),
                 debug_logging: bool = False, log_capacity: int = 50,
                 on_message: Callable[[str], None] | None = None) -> None:
        self.name = name
        self.path = Path(path)
        self.model_description = load_model_description(self.path)
        self.fmi3 = str(self.model_description.fmiVersion).startswith("3.")
        self.api = "fmi3" if self.fmi3 else "fmi2"
        self.variables = variables_of(self.model_description)
        self.start_values = dict(start_values or {})
        self.debug_logging = debug_logging
        self.messages: deque[str] = deque(maxlen=log_capacity)
        self._on_message = on_message
        self.binding: Fmi3Binding | None = None
        self.slave = None  # fmpy's FMU2Slave/FMU3Slave: the life-cycle calls
        self.component = None  # the handle the per-step functions take (FMI 3.0: the adapter context)
        self.failed_fatally = False
        self.time = 0.0  # communication point of the hand loop (do_step)
        self._environment: int | None = None  # FMI 2.0 in this process: the log routing key
        self._unbind("is not instantiated yet (start() or the master instantiates it)")
        self._io = {key: self._prepare(names, value_type) for key, names, value_type in (
            ("real_in", real_inputs, "Real"), ("real_out", real_outputs, "Real"),
            ("int_in", integer_inputs, "Integer"), ("int_out", integer_outputs, "Integer"),
            ("bool_in", boolean_inputs, "Boolean"), ("bool_out", boolean_outputs, "Boolean"))}

    # ----------------------------------------------------------------- variables
    def variable(self, name: str) -> ScalarVariable:
        """The variable called ``name``; FmuConfigError naming the FMU when unknown."""
        try:
            return self.variables[name]
        except KeyError:
            raise FmuConfigError(f"FMU '{self.name}' ({self.path.name}) has no variable '{name}'") from None

    @property
    def bus_variables(self) -> list:
        """The variables in modelDescription order (FMI 3.0: flattened elements)."""
        return list(self.variables.values())

    def _value_type(self, name: str) -> tuple[ScalarVariable, str]:
        variable = self.variable(name)
        value_type = VALUE_TYPE_OF.get(variable.type)
        if value_type is None or variable.valueReference < 0:
            raise FmuConfigError(f"FMU '{self.name}' ({self.path.name}): variable '{name}' has type "
                                 f"{variable.type}, expected one of {', '.join(VALUE_TYPES)}")
        return variable, value_type

    def _prepare(self, names: Sequence[str], value_type: str):
        """Value references and a reused buffer for one hand-loop array."""
        refs = []
        for name in names:
            variable, actual = self._value_type(name)
            if actual != value_type:
                raise FmuConfigError(f"FMU '{self.name}' ({self.path.name}): variable '{name}' is "
                                     f"{variable.type}, expected {value_type}")
            refs.append(variable.valueReference)
        vrs = np.array(refs or [0], dtype=np.uint32)
        buffer = np.zeros(max(len(refs), 1), dtype=VALUE_DTYPE[value_type])[:len(refs)]
        return value_type, vrs, len(refs), buffer, vrs.ctypes.data, buffer.ctypes.data

    # ----------------------------------------------------------------- lifecycle
    def _logger(self, status: int, category: str, text: str) -> None:
        self._log(f"[{status_name(status)}] {category + ': ' if category else ''}{text}")

    def _logger3(self, env, status, category, message) -> None:
        text = message.decode("utf-8", "replace") if message else ""
        cat = category.decode("utf-8", "replace") if category else ""
        self._log(f"[{status_name(status, 'fmi3')}] {cat + ': ' if cat else ''}{text}")

    def _log(self, text: str) -> None:
        self.messages.append(text)
        if self._on_message is not None:
            self._on_message(text)

    def _bind(self, fn_address: dict[str, int]) -> None:
        """Bind the per-step functions from their addresses ("DoStep", "SetReal", ... "GetBoolean")."""
        self.fn_address = dict(fn_address)
        self.do_step_fn = STEP_T(self.fn_address["DoStep"])
        self.set_fn = {t: SET_T(self.fn_address["Set" + t]) for t in VALUE_TYPES}
        self.get_fn = {t: SET_T(self.fn_address["Get" + t]) for t in VALUE_TYPES}

    def _unbind(self, state: str) -> None:
        """Per-step functions that raise FmuConfigError saying the instance ``state`` (before
        instantiation, after close: no call may reach the FMU's code with a dead handle)."""
        text = f"FMU '{self.name}' ({self.path.name}) {state}"  # no reference to self: no cycle

        def refuse(*_args):
            raise FmuConfigError(text)
        self.fn_address = {}
        self.do_step_fn = refuse
        self.set_fn = {t: refuse for t in VALUE_TYPES}
        self.get_fn = {t: refuse for t in VALUE_TYPES}

    def _instantiate3(self, stop_at_address: int | None) -> None:
        md = self.model_description
        self.slave = FMU3Slave(guid=md.guid, unzipDirectory=extracted_dir(self.path),
                               modelIdentifier=md.coSimulation.modelIdentifier, instanceName=self.name)
        event_mode = bool(getattr(md.coSimulation, "hasEventMode", False))
        try:
            self.slave.instantiate(loggingOn=self.debug_logging, eventModeUsed=event_mode, earlyReturnAllowed=False,
                                   logMessage=self._logger3)
        except Exception as exc:
            raise self.error(0.0, f"fmi3InstantiateCoSimulation failed: {exc}") from exc
        self.binding = Fmi3Binding(list(self.variables.values()), self.slave.dll, self.slave.component, event_mode,
                                   stop_at_address)
        self.event_mode_used = event_mode
        self.component = self.binding.address
        self._bind(self.binding.fn_address)

    def instantiate(self, stop_at_address: int | None = None) -> None:
        """Load the binary and instantiate it (fmi2Instantiate / fmi3InstantiateCoSimulation); bind the
        per-step functions. ``stop_at_address``: the engines' end-of-run time an FMI 3.0 FMU that ends
        the simulation itself writes (a float64)."""
        if self.fmi3:
            self._instantiate3(stop_at_address)
            return
        logger = weakref.WeakMethod(self._logger)  # the routing table must not keep a dropped instance alive

        def log(status: int, category: str, text: str) -> None:
            method = logger()
            if method is not None:
                method(status, category, text)
        try:
            self.slave, self._environment = instantiate_fmi2(self.path, self.model_description, self.name, log,
                                                             self.debug_logging)
        except FmuInstantiateError as exc:
            raise self.error(0.0, str(exc)) from exc
        self.component = self.slave.component
        self._bind(bound_addresses(self.slave.dll, "fmi2"))

    def call(self, what: str, time: float, function, *args):
        """Run an fmpy lifecycle call; turn its failure into SimulationError with the log."""
        try:
            return function(*args)
        except Exception as exc:
            status = getattr(exc, "status", None)
            if status == 4:
                self.failed_fatally = True
            raise self.error(time, f"{what} failed: {exc}") from exc

    def enter_initialization(self, start_time: float = 0.0, stop_time: float | None = None) -> None:
        """FMI 2.0: fmi2SetupExperiment, start values, fmi2EnterInitializationMode.
        FMI 3.0: start values, fmi3EnterInitializationMode(start_time, stop_time)."""
        if self.fmi3:
            self.apply_start_values(start_time)
            self.call("fmi3EnterInitializationMode", start_time, self.slave.enterInitializationMode, None,
                      start_time, stop_time)
            return
        self.call("fmi2SetupExperiment", start_time, self.slave.setupExperiment, None, start_time, stop_time)
        self.apply_start_values(start_time)
        self.call("fmi2EnterInitializationMode", start_time, self.slave.enterInitializationMode)

    def exit_initialization(self, start_time: float = 0.0) -> None:
        """fmi2ExitInitializationMode / fmi3ExitInitializationMode (FMI 3.0 with event mode: the event
        iteration that follows it, then step mode)."""
        self.call(f"{self.api}ExitInitializationMode", start_time, self.slave.exitInitializationMode)
        if self.fmi3 and self.event_mode_used:
            self.check("the event iteration after initialization", start_time,
                       self.binding.event_iteration(start_time, enter=False))
            if self.binding.terminated:
                raise self.error(start_time, "the FMU asked to terminate the simulation during initialization")
        self.time = start_time

    def start(self, start_time: float = 0.0, stop_time: float | None = None) -> "Fmu":
        """Instantiate and initialize (start values set) for a hand loop; return self, ready for
        :meth:`do_step` at ``start_time``. On failure the instance is freed and the error raised."""
        try:
            self.instantiate()
            self.enter_initialization(start_time, stop_time)
            self.exit_initialization(start_time)
        except BaseException:
            self.close()
            raise
        return self

    def get_binary(self, name: str) -> bytes:
        """The current value of FMI 3.0 Binary output ``name`` (one element)."""
        element = self.variable(name)
        if not self.fmi3 or element.type != "Binary":
            raise FmuConfigError(f"FMU '{self.name}': '{name}' is not an FMI 3.0 Binary variable")
        values = self.call(f"fmi3GetBinary({name})", 0.0, self.slave.getBinary, [element.fmi_value_reference],
                           element.count)
        return bytes(values[element.element])

    def apply_start_values(self, time: float) -> None:
        """Set every start value with the fmpy setter of its type (FMI 3.0: through the adapter)."""
        if self.fmi3:
            values = {self.variable(name): value for name, value in self.start_values.items()}
            self.check("setting start values", time, self.binding.set_start_values(values))
            return
        for name, value in self.start_values.items():
            var = self.variable(name)
            vr = [var.valueReference]
            if var.type == "Real":
                self.call(f"setting start value {name}", time, self.slave.setReal, vr, [float(value)])
            elif var.type in ("Integer", "Enumeration"):
                self.call(f"setting start value {name}", time, self.slave.setInteger, vr, [int(value)])
            elif var.type == "Boolean":
                self.call(f"setting start value {name}", time, self.slave.setBoolean, vr, [bool(value)])
            else:
                self.call(f"setting start value {name}", time, self.slave.setString, vr, [str(value)])

    def ended_itself(self, t: float, h: float) -> float | None:
        """After fmi2DoStep(t, h) returned fmi2Discard: the FMU's fmi2LastSuccessfulTime (s) when it
        reports fmi2Terminated (it ended the simulation, as fmpy.simulate_fmu accepts) and that time
        lies within the step, after its start: (t, t + h]; else None (an ordinary discard: the run
        fails). An FMU that did not get past the step's start is taken as failing: pythonfmu, for one,
        reports fmi2Terminated after any step its model refused."""
        if self.fmi3 or self.slave is None:
            return None
        try:
            if not self.slave.getBooleanStatus(3):  # fmi2Terminated
                return None
            last = float(self.slave.getRealStatus(2))  # fmi2LastSuccessfulTime
        except Exception:  # noqa: BLE001 - status not provided: an ordinary discard
            return None
        tolerance = 1e-9 * max(1.0, abs(t) + abs(h))
        return last if t + tolerance < last <= t + h + tolerance else None

    def error(self, time: float, reason: str) -> SimulationError:
        """SimulationError for this instance at ``time`` (s) quoting its log messages (and, for FMI 3.0,
        what the adapter found: a value out of range, an early return, the variable concerned)."""
        hint = "" if self.debug_logging else "the FMU logged nothing; debug_logging=True turns its logging on"
        if self.binding is not None and self.binding.message:
            reason = f"{reason} ({self.binding.message})"
            self.binding.clear_message()
        return SimulationError(self.name, time, reason, self.messages, hint)

    def check(self, what: str, time: float, status: int) -> None:
        """Raise SimulationError when ``status`` is Discard/Error/Fatal/Pending."""
        if status > 1:
            if status == 4:
                self.failed_fatally = True
            raise self.error(time, f"{what} returned {status_name(status, self.api)}")

    def close(self, terminate: bool = True) -> None:
        """fmi2Terminate/fmi3Terminate (when ``terminate`` and the instance is healthy) and
        fmi2FreeInstance/fmi3FreeInstance; idempotent, never raises (what failed goes to ``messages``)."""
        slave = self.slave
        if slave is None:
            return
        self.slave = None
        self.component = None
        self._unbind("is closed")
        try:
            if self.failed_fatally:  # after fmi2Fatal/fmi3Fatal no function may be called
                return
            if terminate:
                try:
                    slave.terminate()
                except Exception as exc:
                    self.messages.append(f"[close] {self.api}Terminate failed: {exc}")
            try:
                slave.freeInstance()
            except Exception as exc:  # pragma: no cover
                self.messages.append(f"[close] {self.api}FreeInstance failed: {exc}")
        finally:
            release_log(self._environment)
            self._environment = None

    def __enter__(self) -> "Fmu":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        if getattr(self, "_environment", None) is not None:  # an in-process FMI 2.0 instance nobody closed
            try:
                self.close()
            except Exception:  # noqa: BLE001 - interpreter shutdown
                pass

    # ----------------------------------------------------------------- hand loops
    def _exchange(self, key: str, fn: dict, what: str) -> np.ndarray:
        value_type, _, n, buffer, vr_address, address = self._io[key]
        status = fn[value_type](self.component, vr_address, n, address)
        if status > 1:
            self.check(f"{self.api}{what}{value_type}", self.time, status)
        return buffer

    @property
    def inputs(self) -> np.ndarray:
        """The Real input buffer (order of ``real_inputs``): write into it, then :meth:`push_inputs`."""
        return self._io["real_in"][3]

    def push_inputs(self) -> None:
        """Send the current contents of :attr:`inputs` to the FMU (no copy: the fastest set)."""
        self._exchange("real_in", self.set_fn, "Set")

    def set_inputs(self, values: np.ndarray | Sequence[float]) -> None:
        """Set the Real inputs (order of ``real_inputs``): copy into :attr:`inputs`, then push."""
        self._io["real_in"][3][:] = values
        self._exchange("real_in", self.set_fn, "Set")

    def get_outputs(self) -> np.ndarray:
        """The Real outputs (order of ``real_outputs``): a reused buffer, copy it to keep it."""
        return self._exchange("real_out", self.get_fn, "Get")

    def set_integer_inputs(self, values: np.ndarray | Sequence[int]) -> None:
        """Set the Integer inputs (order of ``integer_inputs``)."""
        self._io["int_in"][3][:] = values
        self._exchange("int_in", self.set_fn, "Set")

    def get_integer_outputs(self) -> np.ndarray:
        """The Integer outputs (order of ``integer_outputs``): a reused buffer."""
        return self._exchange("int_out", self.get_fn, "Get")

    def set_boolean_inputs(self, values: np.ndarray | Sequence[int]) -> None:
        """Set the Boolean inputs (order of ``boolean_inputs``; 0/1 or bools)."""
        self._io["bool_in"][3][:] = values
        self._exchange("bool_in", self.set_fn, "Set")

    def get_boolean_outputs(self) -> np.ndarray:
        """The Boolean outputs (order of ``boolean_outputs``) as 0/1 ints: a reused buffer."""
        return self._exchange("bool_out", self.get_fn, "Get")

    def do_step(self, t: float, h: float) -> None:
        """Advance from communication point ``t`` by ``h`` seconds (SimulationError when the step fails)."""
        status = self.do_step_fn(self.component, t, h, 1)
        if status > 1:
            self.check(f"{self.api}DoStep(t={t:.9g} s, h={h:.9g} s)", t, status)
        self.time = t + h

    def set_value(self, name: str, value: float | int | bool) -> None:
        """Set one variable by name (slower: for set-up and inspection)."""
        variable, value_type = self._value_type(name)
        if value_type == "Real":
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
                raise FmuConfigError(f"FMU '{self.name}': {name} = {value!r}, expected a number")
        elif value_type == "Integer" and (isinstance(value, bool) or int(value) != value):
            raise FmuConfigError(f"FMU '{self.name}': {name} = {value!r}, expected an integer")
        ctype = VALUE_CTYPE[value_type]
        vr = (ctypes.c_uint * 1)(variable.valueReference)
        converted = float(value) if value_type == "Real" else int(value)
        self.check(f"{self.api}Set{value_type}({name})", self.time,
                   self.set_fn[value_type](self.component, vr, 1, (ctype * 1)(converted)))

    def get_value(self, name: str) -> float | int | bool:
        """Get one variable by name (slower: for set-up and inspection)."""
        variable, value_type = self._value_type(name)
        ctype = VALUE_CTYPE[value_type]
        out = (ctype * 1)()
        vr = (ctypes.c_uint * 1)(variable.valueReference)
        self.check(f"{self.api}Get{value_type}({name})", self.time,
                   self.get_fn[value_type](self.component, vr, 1, out))
        return {"Real": float, "Integer": int, "Boolean": bool}[value_type](out[0])


__all__ = ["Fmu", "SUPPORTED_FMUS", "VALUE_CTYPE", "VALUE_DTYPE", "VALUE_TYPES", "VALUE_TYPE_OF", "fmu_kind_problem",
           "load_model_description", "status_name", "variables_of"]
