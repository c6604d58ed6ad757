"""A fast path to FMI 2.0 co-simulation FMUs for fixed-step master loops.

fmpy's ``FMU2Slave.setReal/getReal`` build ctypes arrays on every call and route each
call through a logging wrapper. :class:`FastFmu2Slave` uses fmpy only to load and
instantiate the FMU; afterwards it calls ``fmi2SetReal``/``fmi2GetReal``/``fmi2DoStep``
of the loaded library directly, with value-reference arrays and numpy value buffers
prepared once. Every call still checks the returned status and raises
:class:`FmuCallError` with the FMU's own logged message.

Typical use (six drives and a plant in a loop)::

    drive = FastFmu2Slave(paths["servo_drive"], "drive1", drive_start_values(1),
                          real_inputs=["target_position", "torque_offset", "q_meas", "qd_meas"],
                          real_outputs=["tau_out", "position_actual"],
                          integer_inputs=["controlword"], integer_outputs=["statusword"])
    drive.set_inputs(np.array([...]))   # in the order of real_inputs (or write drive.inputs[:],
                                        # then drive.push_inputs(): saves the copy)
    drive.set_integer_inputs([0x0F])
    drive.do_step(t, h)
    tau, pos = drive.get_outputs()      # a view of a reused buffer: copy to keep
"""
from __future__ import annotations

import atexit
import ctypes
import shutil
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, fmi2CallbackAllocateMemoryTYPE, \
    fmi2CallbackFreeMemoryTYPE
from fmpy.logging import addLoggerProxy

_STATUS = ("OK", "Warning", "Discard", "Error", "Fatal", "Pending")
_EXTRACTED: dict[tuple[str, int], str] = {}
_MESSAGES: dict[int, list[tuple[str, str]]] = {}  # componentEnvironment -> messages of that instance
_next_environment = 1
_libc = ctypes.CDLL(None)
_libc.calloc.restype = ctypes.c_void_p
_libc.calloc.argtypes = [ctypes.c_size_t, ctypes.c_size_t]
_libc.free.argtypes = [ctypes.c_void_p]


class FmuCallError(ValueError):
    """An FMU call returned fmi2Error/fmi2Fatal (or a name/value given to it was wrong)."""


def _route_log(environment, instance_name, status, category, message) -> None:
    """The one Python logger behind fmpy's native formatting proxy (which keeps a single,
    process-wide Python callback): messages go to their instance by componentEnvironment;
    others are printed the way fmpy prints them."""
    label = _STATUS[status] if 0 <= status < len(_STATUS) else str(status)
    text = message.decode("utf-8", "replace") if message else ""
    target = _MESSAGES.get(environment or 0)
    if target is None:
        print(f"[{label.upper()}] {text}")
    else:
        target.append((label, text))


_LOGGER = fmi2CallbackLoggerTYPE(_route_log)


def _extracted_dir(fmu_path: Path) -> str:
    """Extract each FMU file once per process (all instances share one library copy)."""
    key = (str(fmu_path.resolve()), fmu_path.stat().st_mtime_ns)
    if key not in _EXTRACTED:
        directory = tempfile.mkdtemp(prefix=f"{fmu_path.stem}-")
        extract(str(fmu_path), directory)
        atexit.register(shutil.rmtree, directory, True)
        _EXTRACTED[key] = directory
    return _EXTRACTED[key]


class FastFmu2Slave:
    """One instance of an FMI 2.0 co-simulation FMU with prepared I/O arrays.

    ``start_values`` maps variable names to values set in initialization mode (Real or
    Integer by the model description). ``real_inputs``/``real_outputs``/
    ``integer_inputs``/``integer_outputs`` fix the order of the arrays exchanged by
    :meth:`set_inputs`, :meth:`get_outputs`, :meth:`set_integer_inputs` and
    :meth:`get_integer_outputs`. The instance is initialised (ready for :meth:`do_step`
    at ``start_time``) when the constructor returns.
    """

    def __init__(self, fmu_path: str | Path, instance_name: str,
                 start_values: Mapping[str, float | int] | None = None, *,
                 real_inputs: Sequence[str] = (), real_outputs: Sequence[str] = (),
                 integer_inputs: Sequence[str] = (), integer_outputs: Sequence[str] = (),
                 start_time: float = 0.0, logging_on: bool = False) -> None:
        path = Path(fmu_path)
        if not path.is_file():
            raise FmuCallError(f"fmu_path = {str(path)!r} does not exist, expected an .fmu file")
        self.path = path
        self.model_description = read_model_description(str(path))
        self.variables = {v.name: v for v in self.model_description.modelVariables}
        global _next_environment
        self.messages: list[tuple[str, str]] = []  # (status, message) logged by the FMU
        self._environment = _next_environment
        _next_environment += 1
        _MESSAGES[self._environment] = self.messages
        self._callbacks = fmi2CallbackFunctions()
        self._callbacks.logger = _LOGGER
        self._callbacks.componentEnvironment = self._environment
        self._callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(_libc.calloc)
        self._callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(_libc.free)
        addLoggerProxy(ctypes.byref(self._callbacks))

        self._fmu = FMU2Slave(guid=self.model_description.guid, unzipDirectory=_extracted_dir(path),
                              modelIdentifier=self.model_description.coSimulation.modelIdentifier,
                              instanceName=instance_name)
        self._component = None
        try:
            self._fmu.instantiate(callbacks=self._callbacks, loggingOn=logging_on)
        except Exception as exc:
            self._fmu.freeLibrary()
            last = self.messages[-1][1] if self.messages else str(exc)
            raise FmuCallError(f"{path.name} ({instance_name}): fmi2Instantiate failed: {last}") from None
        self._component = self._fmu.component
        dll = self._fmu.dll
        self._do_step_fn = dll.fmi2DoStep
        self._set_real_fn = dll.fmi2SetReal
        self._get_real_fn = dll.fmi2GetReal
        self._set_int_fn = dll.fmi2SetInteger
        self._get_int_fn = dll.fmi2GetInteger

        self._real_in = self._prepare(real_inputs, "Real", np.float64, ctypes.c_double)
        self._real_out = self._prepare(real_outputs, "Real", np.float64, ctypes.c_double)
        self._int_in = self._prepare(integer_inputs, "Integer", np.int32, ctypes.c_int)
        self._int_out = self._prepare(integer_outputs, "Integer", np.int32, ctypes.c_int)

        try:
            self._check(dll.fmi2SetupExperiment(self._component, 0, 0.0, start_time, 0, 0.0), "fmi2SetupExperiment")
            self._check(dll.fmi2EnterInitializationMode(self._component), "fmi2EnterInitializationMode")
            for name, value in (start_values or {}).items():
                self.set_value(name, value)
            self._check(dll.fmi2ExitInitializationMode(self._component), "fmi2ExitInitializationMode")
        except FmuCallError:
            self.close()
            raise
        self.time = start_time

    # -- helpers ------------------------------------------------------------------
    def _variable(self, name: str, type_: str):
        variable = self.variables.get(name)
        if variable is None:
            raise FmuCallError(f"{self.path.name}: no variable named {name!r}")
        if variable.type != type_:
            raise FmuCallError(f"{self.path.name}: variable {name!r} is {variable.type}, expected {type_}")
        return variable

    def _prepare(self, names: Sequence[str], type_: str, dtype, ctype):
        vrs = [self._variable(n, type_).valueReference for n in names]
        vr_array = (ctypes.c_uint * max(len(vrs), 1))(*vrs)
        buffer = np.zeros(len(vrs), dtype=dtype)
        return vr_array, len(vrs), buffer, buffer.ctypes.data_as(ctypes.POINTER(ctype))

    def _check(self, status: int, function: str) -> None:
        if status > 1:  # worse than fmi2Warning
            last = self.messages[-1][1] if self.messages else "no message logged"
            raise FmuCallError(f"{self.path.name} ({self._fmu.instanceName}): {function} returned "
                               f"{_STATUS[status] if status < len(_STATUS) else status}: {last}")

    # -- the fast path ---------------------------------------------------------------
    @property
    def inputs(self) -> np.ndarray:
        """The Real input buffer (order of ``real_inputs``): write into it, then :meth:`push_inputs`."""
        return self._real_in[2]

    def push_inputs(self) -> None:
        """Send the current contents of :attr:`inputs` to the FMU (no copy: the fastest set)."""
        vr, n, _, pointer = self._real_in
        self._check(self._set_real_fn(self._component, vr, n, pointer), "fmi2SetReal")

    def set_inputs(self, values: np.ndarray | Sequence[float]) -> None:
        """Set the Real inputs (order of ``real_inputs``): copy into :attr:`inputs`, then push."""
        vr, n, buffer, pointer = self._real_in
        buffer[:] = values
        self._check(self._set_real_fn(self._component, vr, n, pointer), "fmi2SetReal")

    def get_outputs(self) -> np.ndarray:
        """The Real outputs (order of ``real_outputs``): a reused buffer, copy it to keep it."""
        vr, n, buffer, pointer = self._real_out
        self._check(self._get_real_fn(self._component, vr, n, pointer), "fmi2GetReal")
        return buffer

    def set_integer_inputs(self, values: np.ndarray | Sequence[int]) -> None:
        """Set the Integer inputs (order of ``integer_inputs``)."""
        vr, n, buffer, pointer = self._int_in
        buffer[:] = values
        self._check(self._set_int_fn(self._component, vr, n, pointer), "fmi2SetInteger")

    def get_integer_outputs(self) -> np.ndarray:
        """The Integer outputs (order of ``integer_outputs``): a reused buffer."""
        vr, n, buffer, pointer = self._int_out
        self._check(self._get_int_fn(self._component, vr, n, pointer), "fmi2GetInteger")
        return buffer

    def do_step(self, t: float, h: float) -> None:
        """Advance from communication point ``t`` by ``h`` seconds."""
        self._check(self._do_step_fn(self._component, t, h, 1), "fmi2DoStep")
        self.time = t + h

    # -- by name (slower, for set-up and inspection) ----------------------------------
    def set_value(self, name: str, value: float | int) -> None:
        """Set one variable by name (Real or Integer)."""
        variable = self.variables.get(name)
        if variable is None:
            raise FmuCallError(f"{self.path.name}: no variable named {name!r}")
        vr = (ctypes.c_uint * 1)(variable.valueReference)
        if variable.type == "Integer":
            if isinstance(value, bool) or int(value) != value:
                raise FmuCallError(f"{self.path.name}: {name} = {value!r}, expected an integer")
            self._check(self._set_int_fn(self._component, vr, 1, (ctypes.c_int * 1)(int(value))), "fmi2SetInteger")
        elif variable.type == "Real":
            self._check(self._set_real_fn(self._component, vr, 1, (ctypes.c_double * 1)(float(value))), "fmi2SetReal")
        else:
            raise FmuCallError(f"{self.path.name}: variable {name!r} has unsupported type {variable.type}")

    def get_value(self, name: str) -> float | int:
        """Get one variable by name (Real or Integer)."""
        variable = self.variables.get(name)
        if variable is None:
            raise FmuCallError(f"{self.path.name}: no variable named {name!r}")
        vr = (ctypes.c_uint * 1)(variable.valueReference)
        if variable.type == "Integer":
            out = (ctypes.c_int * 1)()
            self._check(self._get_int_fn(self._component, vr, 1, out), "fmi2GetInteger")
            return int(out[0])
        out_real = (ctypes.c_double * 1)()
        self._check(self._get_real_fn(self._component, vr, 1, out_real), "fmi2GetReal")
        return float(out_real[0])

    # -- life cycle ----------------------------------------------------------------------
    def close(self) -> None:
        """Terminate and free the instance (idempotent)."""
        if self._component is not None:
            self._fmu.dll.fmi2Terminate(self._component)  # status ignored: the instance is freed anyway
            self._fmu.freeInstance()
            self._component = None
            _MESSAGES.pop(self._environment, None)

    def __enter__(self) -> "FastFmu2Slave":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
