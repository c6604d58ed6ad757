"""A fast path to FMI 2.0 co-simulation FMUs for hand-written fixed-step loops.

fmpy's ``FMU2Slave.setReal/getReal`` build ctypes arrays on every call and route each
call through a logging wrapper. :class:`FastFmu2Slave` loads and instantiates the FMU
through the project's one FMI 2.0 instance layer (:mod:`fmus.instance`, which the
co-simulation master's FmuComponent uses too); afterwards it calls ``fmi2SetReal``/``fmi2GetReal``/``fmi2DoStep``
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

import ctypes
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from fmus.instance import FmuInstance, FmuInstantiateError, status_label


class FmuCallError(ValueError):
    """An FMU call returned fmi2Error/fmi2Fatal (or a name/value given to it was wrong)."""


class FastFmu2Slave:
    """One instance of an FMI 2.0 co-simulation FMU with prepared I/O arrays.

    Built on :class:`fmus.instance.FmuInstance`, the project's one FMI 2.0 instance layer
    (also under the co-simulation master's ``FmuComponent``). ``start_values`` maps
    variable names to values set in initialization mode (Real or Integer by the model
    description). ``real_inputs``/``real_outputs``/``integer_inputs``/``integer_outputs``
    fix the order of the arrays exchanged by :meth:`set_inputs`, :meth:`get_outputs`,
    :meth:`set_integer_inputs` and :meth:`get_integer_outputs`. The instance is
    initialised (ready for :meth:`do_step` at ``start_time``) when the constructor returns.
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
        self.messages: list[tuple[str, str]] = []  # (status, message) logged by the FMU
        self._instance_name = instance_name
        self._component = None
        try:
            self._fmu = FmuInstance(path, instance_name, self._log, logging_on=logging_on)
        except FmuInstantiateError as exc:
            last = self.messages[-1][1] if self.messages else str(exc)
            raise FmuCallError(f"{path.name} ({instance_name}): fmi2Instantiate failed: {last}") from None
        self.model_description = self._fmu.model_description
        self.variables = self._fmu.variables
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

    def _log(self, status: int, category: str, text: str) -> None:
        self.messages.append((status_label(status), text))

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
            raise FmuCallError(f"{self.path.name} ({self._instance_name}): {function} returned "
                               f"{status_label(status)}: {last}")

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
            self._fmu.free(terminate=True)  # a failed fmi2Terminate is ignored: the instance is freed anyway
            self._component = None

    def __enter__(self) -> "FastFmu2Slave":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
