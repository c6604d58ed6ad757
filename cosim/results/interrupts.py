"""Interrupts of a command: SIGINT, SIGTERM and SIGHUP end it cleanly (docs/reference/verdicts.md).

``install_signal_handlers`` (``cosim.cli.main``) makes the first such signal raise
:class:`~cosim.results.exits.Interrupted` (a KeyboardInterrupt) in the main thread; while the
final status of a run is written (:func:`defer_signals`) further signals are only counted,
and a third one ends the process by the signal's default action. A run's end
(:mod:`cosim.api`) reads :func:`interrupt_raised` to report an interrupt that code not ours
turned into an error. A floor under the commands and the runs that use it, above none of them.
"""
from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Iterator

from cosim.results.exits import Interrupted

INTERRUPTS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""Signals that end a command cleanly (final status ``interrupted``, exit 130)."""


class _SignalState:
    """How SIGINT/SIGTERM are handled: ``armed`` raises Interrupted once; while a command
    writes its final status (``defer_signals``) they are only counted."""

    armed = True
    deferred: list[int] = []
    raised: int | None = None  # the signal the handler raised Interrupted for (once per command)


def _on_signal(signum: int, frame) -> None:
    if _SignalState.armed:
        _SignalState.armed = False
        _SignalState.raised = signum
        raise Interrupted(signum)
    _SignalState.deferred.append(signum)
    if len(_SignalState.deferred) >= 3:  # the user insists: give up the clean shutdown
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)


@contextlib.contextmanager
def defer_signals() -> Iterator[None]:
    """Within the block, SIGINT/SIGTERM do not raise (the final status is being written)."""
    armed = _SignalState.armed
    _SignalState.armed = False
    try:
        yield
    finally:
        _SignalState.armed = armed


def interrupt_raised() -> Interrupted | None:
    """The :class:`~cosim.results.exits.Interrupted` the signal handler raised during this command
    (None: no signal came). Code that is not ours may have swallowed it: a Python-implemented
    FMU (pythonfmu) runs its model in this interpreter, so Ctrl-C can raise inside the FMU's
    ``do_step``, which reports that as fmi2Error/fmi2Fatal; the run then fails naming an
    innocent FMU unless the caller asks here and reports the interrupt instead."""
    return Interrupted(_SignalState.raised) if _SignalState.raised is not None else None


def install_signal_handlers() -> dict[int, object]:
    """SIGINT, SIGTERM and SIGHUP raise :class:`~cosim.results.exits.Interrupted` (a KeyboardInterrupt) once;
    returns the previous handlers (for :func:`restore_signal_handlers`)."""
    _SignalState.armed = True
    _SignalState.deferred = []
    _SignalState.raised = None
    previous: dict[int, object] = {}
    for signum in INTERRUPTS:
        try:
            previous[signum] = signal.signal(signum, _on_signal)
        except (ValueError, OSError):  # not the main thread: leave the defaults
            pass
    return previous


def restore_signal_handlers(previous: dict[int, object]) -> None:
    """Put back the handlers :func:`install_signal_handlers` replaced."""
    _SignalState.raised = None
    for signum, handler in previous.items():
        try:
            signal.signal(signum, handler if handler is not None else signal.SIG_DFL)
        except (ValueError, OSError, TypeError):
            pass


__all__ = ["INTERRUPTS", "defer_signals", "install_signal_handlers", "interrupt_raised",
           "restore_signal_handlers"]
