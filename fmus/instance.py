"""FMI 2.0 plumbing under :class:`fmus.fmu.Fmu`, the project's one FMU class.

The archive is extracted once per process (all instances of one FMU share a library
copy); ``fmi2Instantiate`` goes through fmpy with the FMU's log messages routed to
*their* instance (fmpy's native formatting proxy keeps a single, process-wide Python
callback, so messages are told apart by ``componentEnvironment``); the per-step
functions are bound once as raw addresses (:func:`bound_addresses`) so that callers step
the FMU without per-call allocation.
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

from fmpy import extract
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


def status_name(status: int, api: str = "fmi2") -> str:
    """``3 -> "fmi2Error"`` (``api="fmi3"``: ``"fmi3Error"``; ``api=""``: ``"Error"``)."""
    return api + STATUS[status] if 0 <= status < len(STATUS) else f"status {status}"


def _route_log(environment, instance_name, status, category, message) -> None:
    sinks = _SINKS
    if sinks is None:  # interpreter shutdown: the module's globals are already gone
        return
    sink = sinks.get(environment or 0)
    text = message.decode("utf-8", "replace") if message else ""
    if sink is None:
        print(f"[{status_name(status, '').upper()}] {text}")
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


def instantiate_fmi2(path: Path, md: ModelDescription, instance_name: str, log: LogSink,
                     logging_on: bool = False) -> tuple[FMU2Slave, int]:
    """fmi2Instantiate ``path`` (model description ``md``) as ``instance_name``; ``log`` receives
    (status, category, text) for each message the FMU logs. Returns the fmpy slave and the log
    routing key to give to :func:`release_log` when the instance is freed.
    FmuInstantiateError when instantiation fails (the FMU's messages went to ``log``)."""
    environment = next(_environments)
    _SINKS[environment] = log
    cb = fmi2CallbackFunctions()
    cb.logger = _LOGGER
    cb.componentEnvironment = environment
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(_libc.calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(_libc.free)
    try:
        from fmpy.logging import addLoggerProxy
        addLoggerProxy(ctypes.byref(cb))
    except Exception:  # pragma: no cover - platform without fmpy's logging proxy
        pass
    slave = FMU2Slave(guid=md.guid, unzipDirectory=extracted_dir(path),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName=instance_name)
    try:
        slave.instantiate(callbacks=cb, loggingOn=logging_on)
    except Exception as exc:
        _SINKS.pop(environment, None)
        try:
            slave.freeLibrary()
        except Exception:  # pragma: no cover
            pass
        raise FmuInstantiateError(f"fmi2Instantiate failed: {exc}") from exc
    slave._cosim_callbacks = cb  # the callback structure must outlive the instance
    return slave, environment


def release_log(environment: int | None) -> None:
    """Stop routing the messages of the instance registered under ``environment``."""
    if environment is not None:
        _SINKS.pop(environment, None)


def bound_addresses(dll, prefix: str = "fmi2") -> dict[str, int]:
    """Name in :data:`BOUND` -> address of ``<prefix><name>`` in ``dll``."""
    return {name: ctypes.cast(getattr(dll, prefix + name), c_void_p).value for name in BOUND}


__all__ = ["BOUND", "FmuInstantiateError", "LogSink", "SET_T", "STEP_T", "bound_addresses", "extracted_dir",
           "instantiate_fmi2", "release_log", "status_name"]
