"""One FMI 2.0 co-simulation FMU instance as the master sees it.

Loading, instantiation and the lifecycle calls (setup, initialization, terminate,
free) go through fmpy. The per-step calls (fmi2Set*/fmi2Get*/fmi2DoStep) are bound
once as raw C function pointers so that the engines can call them with prepared
value-reference arrays and bus addresses, without per-step allocation.
The FMU's log messages go to a bounded per-instance buffer (``messages``) that a
``SimulationError`` quotes when the FMU fails.
"""
from __future__ import annotations

import atexit
import ctypes
import shutil
from collections import deque
from ctypes import CFUNCTYPE, c_double, c_int, c_size_t, c_void_p
from functools import lru_cache
from pathlib import Path

from fmpy import calloc, extract, free, read_model_description
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
from fmpy.model_description import ModelDescription, ScalarVariable

from cosim.master.errors import MasterConfigError, SimulationError

_STATUS = ("OK", "Warning", "Discard", "Error", "Fatal", "Pending")
SET_T = CFUNCTYPE(c_int, c_void_p, c_void_p, c_size_t, c_void_p)
STEP_T = CFUNCTYPE(c_int, c_void_p, c_double, c_double, c_int)

_extracted: dict[tuple[str, float], str] = {}


def status_name(status: int) -> str:
    """``3 -> "fmi2Error"``."""
    return "fmi2" + _STATUS[status] if 0 <= status < len(_STATUS) else f"status {status}"


@lru_cache(maxsize=64)
def _read_description(path: str, mtime: float) -> ModelDescription:
    return read_model_description(path, validate=False)


def load_model_description(path: str | Path) -> ModelDescription:
    """Read (and cache) the modelDescription of an FMU file; MasterConfigError if not FMI 2.0 CS."""
    path = Path(path)
    if not path.is_file():
        raise MasterConfigError(f"FMU file {str(path)!r} does not exist (expected a path to a .fmu file)")
    try:
        md = _read_description(str(path.resolve()), path.stat().st_mtime)
    except Exception as exc:  # fmpy raises plain Exceptions for broken archives
        raise MasterConfigError(f"FMU file {str(path)!r} cannot be read: {exc}") from exc
    if md.fmiVersion != "2.0" or md.coSimulation is None:
        raise MasterConfigError(f"FMU file {str(path)!r}: expected an FMI 2.0 co-simulation FMU, "
                                f"got fmiVersion {md.fmiVersion} with"
                                f"{'' if md.coSimulation else 'out'} a CoSimulation interface")
    return md


def _unzip_dir(path: Path) -> str:
    key = (str(path.resolve()), path.stat().st_mtime)
    if key not in _extracted:
        _extracted[key] = extract(str(path))
    return _extracted[key]


@atexit.register
def _remove_extracted() -> None:
    for directory in _extracted.values():
        shutil.rmtree(directory, ignore_errors=True)


class FmuComponent:
    """An FMU instance: model description, fmpy slave, raw FMI function pointers, log buffer.

    Args:
        name: instance name (no dots).
        path: the .fmu file.
        step_ticks: the FMU's communication step as a multiple of the master's base step.
        start_values: variable name -> start value (checked by the master beforehand).
        debug_logging: passed as ``loggingOn`` to fmi2Instantiate.
        log_capacity: how many log messages to keep.
    """

    def __init__(self, name: str, path: str | Path, step_ticks: int, start_values: dict[str, object],
                 debug_logging: bool = False, log_capacity: int = 50) -> None:
        self.name = name
        self.path = Path(path)
        self.model_description = load_model_description(self.path)
        self.variables = {v.name: v for v in self.model_description.modelVariables}
        self.step_ticks = int(step_ticks)
        self.start_values = dict(start_values)
        self.debug_logging = debug_logging
        self.messages: deque[str] = deque(maxlen=log_capacity)
        self.slave: FMU2Slave | None = None
        self.failed_fatally = False
        self._callbacks: fmi2CallbackFunctions | None = None

    # ----------------------------------------------------------------- lifecycle
    def _logger(self, env, instance_name, status, category, message) -> None:
        text = message.decode("utf-8", "replace") if message else ""
        cat = category.decode("utf-8", "replace") if category else ""
        self.messages.append(f"[{status_name(status)}] {cat + ': ' if cat else ''}{text}")

    def instantiate(self) -> None:
        """Load the binary and call fmi2Instantiate; bind the raw step functions."""
        md = self.model_description
        self.slave = FMU2Slave(guid=md.guid, unzipDirectory=_unzip_dir(self.path),
                               modelIdentifier=md.coSimulation.modelIdentifier, instanceName=self.name)
        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(self._logger)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        try:
            from fmpy.logging import addLoggerProxy
            addLoggerProxy(ctypes.byref(cb))
        except Exception:  # pragma: no cover - platform without fmpy's logging proxy
            pass
        self._callbacks = cb
        try:
            self.slave.instantiate(callbacks=cb, loggingOn=self.debug_logging)
        except Exception as exc:
            raise self.error(0.0, f"fmi2Instantiate failed: {exc}") from exc
        dll = self.slave.dll
        self.component = self.slave.component
        self.fn_address = {name: ctypes.cast(getattr(dll, "fmi2" + name), c_void_p).value
                           for name in ("DoStep", "SetReal", "SetInteger", "SetBoolean",
                                        "GetReal", "GetInteger", "GetBoolean")}
        self.do_step_fn = STEP_T(self.fn_address["DoStep"])
        self.set_fn = {t: SET_T(self.fn_address["Set" + t]) for t in ("Real", "Integer", "Boolean")}
        self.get_fn = {t: SET_T(self.fn_address["Get" + t]) for t in ("Real", "Integer", "Boolean")}

    def call(self, what: str, time: float, function, *args):
        """Run an fmpy lifecycle call; turn its failure into SimulationError with the log."""
        try:
            return function(*args)
        except Exception as exc:
            status = getattr(exc, "status", None)
            if status == 4:
                self.failed_fatally = True
            raise self.error(time, f"{what} failed: {exc}") from exc

    def apply_start_values(self, time: float) -> None:
        """Set every start value with the fmpy setter of its type."""
        for name, value in self.start_values.items():
            var = self.variables[name]
            vr = [var.valueReference]
            if var.type == "Real":
                self.call(f"setting start value {name}", time, self.slave.setReal, vr, [float(value)])
            elif var.type in ("Integer", "Enumeration"):
                self.call(f"setting start value {name}", time, self.slave.setInteger, vr, [int(value)])
            elif var.type == "Boolean":
                self.call(f"setting start value {name}", time, self.slave.setBoolean, vr, [bool(value)])
            else:
                self.call(f"setting start value {name}", time, self.slave.setString, vr, [str(value)])

    def error(self, time: float, reason: str) -> SimulationError:
        """SimulationError for this instance at ``time`` (s) quoting its log messages."""
        hint = "" if self.debug_logging else "the FMU logged nothing; debug_logging=True turns its logging on"
        return SimulationError(self.name, time, reason, self.messages, hint)

    def check(self, what: str, time: float, status: int) -> None:
        """Raise SimulationError when ``status`` is Discard/Error/Fatal/Pending."""
        if status > 1:
            if status == 4:
                self.failed_fatally = True
            raise self.error(time, f"{what} returned {status_name(status)}")

    def close(self, terminate: bool) -> None:
        """fmi2Terminate (when the instance is healthy) and fmi2FreeInstance; never raises."""
        if self.slave is None:
            return
        if self.failed_fatally:  # FMI 2.0: after fmi2Fatal no function may be called
            self.slave = None
            return
        try:
            if terminate:
                self.slave.terminate()
        except Exception as exc:
            self.messages.append(f"[master] fmi2Terminate failed: {exc}")
        try:
            self.slave.freeInstance()
        except Exception as exc:  # pragma: no cover
            self.messages.append(f"[master] fmi2FreeInstance failed: {exc}")
        self.slave = None

    def variable(self, name: str) -> ScalarVariable:
        """The ScalarVariable called ``name``; MasterConfigError naming the FMU when unknown."""
        try:
            return self.variables[name]
        except KeyError:
            raise MasterConfigError(f"FMU '{self.name}' ({self.path.name}) has no variable '{name}'") from None


