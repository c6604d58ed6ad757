"""A final ``summary.json`` even when native code crashes the run's process (crashguard.c).

:class:`~cosim.results.summary.SummaryWriter` calls :func:`arm` after every write of a running
summary with the ``failed`` summary to leave if the process died now from SIGSEGV, SIGBUS,
SIGFPE, SIGILL or SIGABRT (an in-process FMU's NULL dereference or ``abort()``); the C handler
writes it (async-signal-safe) and lets the signal end the process. Where the run was comes
from two doubles the run writes at every heartbeat of the master (:func:`note`, 1000 per run):
the handler writes them in place of the marker bytes of the prepared text (``\x02`` simulated
seconds in all, ``\x03`` the running part's time). The time series hold what was flushed: a
run with FMUs of the user's in its process writes them through at every heartbeat
(:class:`cosim.scenario.context.RunContext`). ``_exit()`` cannot be caught:
only running the FMU out of process (docs/reference/verdicts.md) reports that. Without compiled code
nothing is installed: ``COSIM_NATIVE=off`` silently, no compiler or a failed build with a note
said once (``COSIM_NATIVE=require`` makes that an error, :mod:`native`).
"""
from __future__ import annotations

import ctypes
from pathlib import Path
from typing import Any

_SOURCE = Path(__file__).with_name("crashguard.c")
_library: ctypes.CDLL | None | bool = None
_progress: Any = None  # the library's two progress doubles (sim_time_s, stopped_at_s)


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
            library.crashguard_progress.restype = ctypes.POINTER(ctypes.c_double)
            global _progress
            _progress = library.crashguard_progress()
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


def note(sim_time_s: float, stopped_at_s: float) -> None:
    """Where the run is now (simulated seconds in all, the running part's own time), for the handler:
    two doubles written in place, cheap enough for every heartbeat. No-op before :func:`install`."""
    progress = _progress
    if progress is not None:
        progress[0] = sim_time_s
        progress[1] = stopped_at_s


def disarm() -> None:
    """Nothing to write any more (the run wrote its final status)."""
    library = _load()
    if library is not None:
        library.crashguard_disarm()
