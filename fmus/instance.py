"""The one FMI 2.0 co-simulation instance layer of the project.

Everything that loads and talks to an FMI 2.0 co-simulation FMU goes through
:class:`FmuInstance`: the archive extracted once per process (all instances of one FMU
share a library copy), ``fmi2Instantiate`` through fmpy with the FMU's log messages
routed to *their* instance (fmpy's native formatting proxy keeps a single, process-wide
Python callback, so messages are told apart by ``componentEnvironment``), and the raw
``fmi2*`` function pointers bound once so that callers step the FMU without per-call
allocation. Two users build on it:

- :class:`fmus.fast_fmu.FastFmu2Slave`: one FMU in a hand-written loop, with named,
  prepared I/O arrays (drive tuning benches, FMU tests);
- ``cosim.master.component.FmuComponent``: one FMU in the co-simulation master, whose
  compiled kernel calls the bound function addresses directly.
"""
from __future__ import annotations

import atexit
import ctypes
import itertools
import shutil
import tempfile
from collections.abc import Callable
from ctypes import CFUNCTYPE, c_double, c_int, c_size_t, c_void_p
from pathlib import Path

from fmpy import extract, read_model_description
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions,
                       fmi2CallbackLoggerTYPE)
from fmpy.model_description import ModelDescription

STATUS = ("OK", "Warning", "Discard", "Error", "Fatal", "Pending")
SET_T = CFUNCTYPE(c_int, c_void_p, c_void_p, c_size_t, c_void_p)
STEP_T = CFUNCTYPE(c_int, c_void_p, c_double, c_double, c_int)
#: FMI 2.0 functions bound as raw addresses (``fn_address["DoStep"]`` is fmi2DoStep).
BOUND = ("DoStep", "SetReal", "SetInteger", "SetBoolean", "GetReal", "GetInteger", "GetBoolean")

LogSink = Callable[[int, str, str], None]  # (status, category, text)

_EXTRACTED: dict[tuple[str, int], str] = {}
_SINKS: dict[int, LogSink] = {}
_environments = itertools.count(1)
_libc = ctypes.CDLL(None)
_libc.calloc.restype = ctypes.c_void_p
_libc.calloc.argtypes = [ctypes.c_size_t, ctypes.c_size_t]
_libc.free.argtypes = [ctypes.c_void_p]


def status_label(status: int) -> str:
    """``3 -> "Error"``."""
    return STATUS[status] if 0 <= status < len(STATUS) else f"status {status}"


def _route_log(environment, instance_name, status, category, message) -> None:
    sinks = _SINKS
    if sinks is None:  # interpreter shutdown: the module's globals are already gone
        return
    sink = sinks.get(environment or 0)
    text = message.decode("utf-8", "replace") if message else ""
    if sink is None:
        print(f"[{status_label(status).upper()}] {text}")
        return
    sink(int(status), category.decode("utf-8", "replace") if category else "", text)


_LOGGER = fmi2CallbackLoggerTYPE(_route_log)


def extracted_dir(fmu_path: Path) -> str:
    """The FMU archive extracted once per process (removed at exit)."""
    key = (str(fmu_path.resolve()), fmu_path.stat().st_mtime_ns)
    if key not in _EXTRACTED:
        directory = tempfile.mkdtemp(prefix=f"{fmu_path.stem}-")
        extract(str(fmu_path), directory)
        _EXTRACTED[key] = directory
    return _EXTRACTED[key]


@atexit.register
def _remove_extracted() -> None:
    for directory in _EXTRACTED.values():
        shutil.rmtree(directory, ignore_errors=True)


class FmuInstantiateError(RuntimeError):
    """fmi2Instantiate failed; ``messages`` are what the FMU logged."""


class FmuInstance:
    """One instantiated FMI 2.0 co-simulation FMU with its raw functions bound.

    Args:
        path: the .fmu file.
        instance_name: passed to fmi2Instantiate.
        log: called with (status, category, text) for each message the FMU logs.
        logging_on: ``loggingOn`` of fmi2Instantiate.
        model_description: the file's model description when already read.

    Attributes: ``model_description``, ``variables`` (name -> ScalarVariable), ``dll``,
    ``component`` (the fmi2Component), ``fn_address`` (name in :data:`BOUND` -> address),
    ``do_step_fn``, ``set_fn``/``get_fn`` (bus type Real/Integer/Boolean -> ctypes function).
    """

    def __init__(self, path: str | Path, instance_name: str, log: LogSink, *, logging_on: bool = False,
                 model_description: ModelDescription | None = None) -> None:
        self.path = Path(path)
        self.model_description = model_description or read_model_description(str(self.path))
        self.variables = {v.name: v for v in self.model_description.modelVariables}
        self.instance_name = instance_name
        self.component = None
        self._environment = next(_environments)
        _SINKS[self._environment] = log
        cb = fmi2CallbackFunctions()
        cb.logger = _LOGGER
        cb.componentEnvironment = self._environment
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(_libc.calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(_libc.free)
        try:
            from fmpy.logging import addLoggerProxy
            addLoggerProxy(ctypes.byref(cb))
        except Exception:  # pragma: no cover - platform without fmpy's logging proxy
            pass
        self._callbacks = cb
        md = self.model_description
        self.slave = FMU2Slave(guid=md.guid, unzipDirectory=extracted_dir(self.path),
                               modelIdentifier=md.coSimulation.modelIdentifier, instanceName=instance_name)
        try:
            self.slave.instantiate(callbacks=cb, loggingOn=logging_on)
        except Exception as exc:
            _SINKS.pop(self._environment, None)
            try:
                self.slave.freeLibrary()
            except Exception:  # pragma: no cover
                pass
            raise FmuInstantiateError(f"fmi2Instantiate failed: {exc}") from exc
        self.component = self.slave.component
        self.dll = self.slave.dll
        self.fn_address = {name: ctypes.cast(getattr(self.dll, "fmi2" + name), c_void_p).value for name in BOUND}
        self.do_step_fn = STEP_T(self.fn_address["DoStep"])
        self.set_fn = {t: SET_T(self.fn_address["Set" + t]) for t in ("Real", "Integer", "Boolean")}
        self.get_fn = {t: SET_T(self.fn_address["Get" + t]) for t in ("Real", "Integer", "Boolean")}

    def raw(self, name: str):
        """The library's function ``fmi2<name>`` (ctypes, arguments as the FMI 2.0 C API)."""
        return getattr(self.dll, "fmi2" + name)

    def free(self, terminate: bool = True) -> list[str]:
        """fmi2Terminate (when ``terminate``) and fmi2FreeInstance; never raises; returns what failed."""
        problems = []
        if self.component is None:
            return problems
        if terminate:
            try:
                status = self.dll.fmi2Terminate(self.component)
                if status > 1:
                    problems.append(f"fmi2Terminate returned fmi2{status_label(status)}")
            except Exception as exc:  # pragma: no cover
                problems.append(f"fmi2Terminate failed: {exc}")
        try:
            self.slave.freeInstance()
        except Exception as exc:  # pragma: no cover
            problems.append(f"fmi2FreeInstance failed: {exc}")
        self.component = None
        _SINKS.pop(self._environment, None)
        return problems

    def forget(self) -> None:
        """Drop the instance without calling it (after fmi2Fatal no function may be called)."""
        self.component = None
        _SINKS.pop(self._environment, None)


__all__ = ["BOUND", "FmuInstance", "FmuInstantiateError", "SET_T", "STEP_T", "extracted_dir", "status_label"]
