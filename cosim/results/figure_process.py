"""A process that draws a run's figures, forked at the start of ``python -m cosim run``.

The main job's command spends its first second importing the cell (one core busy, the
other idle) and its last half second drawing figures. Matplotlib's import and first
drawing (fonts, text layout, the log-scale tick machinery, the PNG writer: about 0.5 CPU-s)
need none of the cell: :func:`start` forks this process while the command is still light
(before the scenario is loaded), and it imports matplotlib and warms it up on the idle core
while the command imports the cell. It then waits for one request, a call of a
``"module:function"`` with picklable arguments (plain arrays, not the run's objects: it
never imports the cell), made by the job when its modes are done (:meth:`FigureProcess.call`).
The job's own process does not import matplotlib at all.

Nothing depends on it: when it was not started (a library call, ``--realtime``/``--split``,
one usable core, ``$COSIM_FIGURE_PROCESS=0``), has died, or its call fails, the job draws
the figures itself, the same files.

Stopping: it ignores SIGINT (Ctrl-C reaches the whole process group; the command ends it);
SIGTERM ends it (and a drawing process it forked); it ends by itself when the command's
process is gone (checked twice a second) and when its request is answered. The command
ends it in any case when it finishes (:func:`stop`).
"""
from __future__ import annotations

import os
import signal
import sys
from typing import Any

#: Environment variable: ``0`` never starts the process (the job then draws in its own process).
ENV = "COSIM_FIGURE_PROCESS"
#: Seconds between checks that the command's process is still there.
PARENT_CHECK_S = 0.5
#: The process's name (``ps``, ``/proc/PID/comm``).
PROCESS_NAME = "cosim-figures"

_current: "FigureProcess | None" = None


def _resolve(target: str) -> Any:
    import importlib

    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)


def _name_process(name: str) -> None:
    """Set the process's name as ``ps``/``/proc/PID/comm`` show it (Linux; elsewhere nothing)."""
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        libc.prctl(15, ctypes.c_char_p(name.encode()[:15]), 0, 0, 0)  # PR_SET_NAME
    except (OSError, AttributeError):
        pass


def _on_term(signum: int, frame: Any) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    raise SystemExit(128 + signum)  # unwinds a drawing in progress (it kills its own child)


def _serve(connection: Any, other_end: Any, warm_up: str | None, parent: int) -> None:
    """The process's body: warm up, then answer one request (or none) and end."""
    other_end.close()
    _name_process(PROCESS_NAME)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, _on_term)
    if warm_up:
        try:
            _resolve(warm_up)()
        except Exception:  # noqa: BLE001 - only a head start: the request does the work anyway
            pass
    while True:
        try:
            if not connection.poll(PARENT_CHECK_S):
                if os.getppid() != parent:
                    return
                continue
            request = connection.recv()
        except (EOFError, OSError):
            return
        if request is None:
            return
        target, args = request
        try:
            reply = (True, _resolve(target)(*args))
        except Exception as exc:  # noqa: BLE001 - the caller does the work itself
            reply = (False, f"{type(exc).__name__}: {exc}")
        try:
            connection.send(reply)
        except (OSError, ValueError):
            return


class FigureProcess:
    """The forked figure process (see the module docstring); ``warm_up``: ``"module:function"``
    it calls first."""

    def __init__(self, warm_up: str | None) -> None:
        import multiprocessing

        context = multiprocessing.get_context("fork")
        self._connection, child_end = context.Pipe(duplex=True)
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        self._process = context.Process(target=_serve, args=(child_end, self._connection, warm_up, os.getpid()),
                                        name=PROCESS_NAME, daemon=True)
        self._process.start()
        child_end.close()
        self._owner = os.getpid()

    @property
    def pid(self) -> int | None:
        return self._process.pid

    def call(self, target: str, *args: Any) -> tuple[bool, Any]:
        """``target(*args)`` in the figure process (``"module:function"``): ``(True, value)``,
        or ``(False, why)`` when it could not (it died, failed, or its answer was lost): the
        caller then does the work itself. The process ends after its answer. A
        KeyboardInterrupt (Ctrl-C, SIGTERM through the command) ends it and propagates."""
        if os.getpid() != self._owner:
            return False, "not the process that started it"
        try:
            self._connection.send((target, args))
            while not self._connection.poll(PARENT_CHECK_S):
                if not self._process.is_alive():
                    raise EOFError(f"the figure process ended ({self._process.exitcode})")
            answer = self._connection.recv()
        except KeyboardInterrupt:
            self.stop()
            raise
        except Exception as exc:  # noqa: BLE001 - EOF, a broken pipe, an unpicklable argument
            self.stop()
            return False, f"{type(exc).__name__}: {exc}"
        self.stop()
        return answer

    def stop(self) -> None:
        """End the process (a request in progress is abandoned) and wait for it."""
        global _current
        if _current is self:
            _current = None
        if os.getpid() != self._owner:
            return
        try:
            self._connection.send(None)
        except (OSError, ValueError):
            pass
        self._process.join(timeout=0.5)
        if self._process.is_alive():
            self._process.terminate()
            self._process.join(timeout=5.0)
            if self._process.is_alive():
                self._process.kill()
                self._process.join(timeout=5.0)
        try:
            self._connection.close()
        except OSError:
            pass

    def _forget(self) -> None:
        """In a process forked from the owner (a mode worker): let go of the pipe, touch nothing."""
        try:
            self._connection.close()
        except OSError:
            pass


def _after_fork_in_child() -> None:
    global _current
    if _current is not None:
        _current._forget()
        _current = None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


def usable_cores() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def start(warm_up: str | None) -> FigureProcess | None:
    """Fork the figure process now (see the module docstring) unless ``$COSIM_FIGURE_PROCESS``
    is ``0``, there is one usable core, this process runs other threads or one is running
    already; returns it (also :func:`current`)."""
    global _current
    import threading

    if (os.environ.get(ENV, "").strip() == "0" or not hasattr(os, "fork") or usable_cores() < 2
            or threading.active_count() > 1 or _current is not None):
        return None
    try:
        _current = FigureProcess(warm_up)
    except OSError:
        _current = None
    return _current


def current() -> FigureProcess | None:
    """The figure process started by this process and not yet used or stopped (else None)."""
    if _current is not None and os.getpid() == _current._owner:
        return _current
    return None


def stop() -> None:
    """End the figure process if one is running (the command does this when it finishes)."""
    if _current is not None:
        _current.stop()
