"""A final ``summary.json`` even when native code crashes the run's process (crashguard.c).

:class:`~cosim.results.summary.SummaryWriter` calls :func:`arm` after every write of a running
summary with the ``failed`` summary to leave if the process died now from SIGSEGV, SIGBUS,
SIGFPE, SIGILL or SIGABRT (an in-process FMU's NULL dereference or ``abort()``); the C handler
writes it (async-signal-safe) and lets the signal end the process. What it records is the
last progress the run reported (summary.json is rewritten every 2 s of wall time), and the
time series up to their last flush (about 1 s of wall time). ``_exit()`` cannot be caught:
only running the FMU out of process (docs/robustness.md) reports that. Without compiled code
nothing is installed: ``COSIM_NATIVE=off`` silently, no compiler or a failed build with a note
said once (``COSIM_NATIVE=require`` makes that an error, :mod:`native`).
"""
from __future__ import annotations

import ctypes
from pathlib import Path

_SOURCE = Path(__file__).with_name("crashguard.c")
_library: ctypes.CDLL | None | bool = None


def _load() -> ctypes.CDLL | None:
    global _library
    if _library is None:
        import native

        # COSIM_NATIVE=require: a failed build is an error; auto: said once, the run goes on
        # without the guard (the supervisor still records a crash); off: silently without it
        library = native.optional("crash guard",
                                  lambda: native.load_ctypes(native.build("cosim_crashguard", [_SOURCE])),
                                  instead="the run goes on without it (the supervisor still reports a crash)")
        if library is not None:
            library.crashguard_install.argtypes = [ctypes.c_char_p]
            library.crashguard_arm.argtypes = [ctypes.c_char_p, ctypes.c_size_t]
            library.crashguard_disarm.argtypes = []
        _library = library if library is not None else False
    return _library or None


def install(path: str | Path) -> bool:
    """Watch for fatal signals on behalf of the summary at ``path``; False when unavailable."""
    library = _load()
    return library is not None and library.crashguard_install(str(path).encode()) == 0


def arm(summary_text: str) -> None:
    """The text to write if the process dies now (``\\x01`` stands for the signal's name)."""
    library = _load()
    if library is not None:
        data = summary_text.encode("utf-8")
        library.crashguard_arm(data, len(data))


def disarm() -> None:
    """Nothing to write any more (the run wrote its final status)."""
    library = _load()
    if library is not None:
        library.crashguard_disarm()
