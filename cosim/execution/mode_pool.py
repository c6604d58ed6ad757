"""The built-in modes of a scenario run side by side, one worker process per mode.

The modes of the main job (``standard``, ``standard_speed_ff``, ``model_based``) are
independent closed-loop runs of the same cell on the same true robot: nothing one mode
computes enters another. :func:`run_modes` runs each in a worker process forked from this
one after the shared set-up (:func:`cosim.execution.mode_runs.prepare`), so the set-up, the
imports and the compiled helpers are inherited, not redone. Each worker runs
:func:`cosim.execution.mode_runs.run_mode` exactly as the one-process run does - the same cell,
controller, FMUs, evaluation and files (``timeseries_<mode>``, ``controller_<mode>``,
``tcp_<mode>``, ``can_<mode>.blf``, streamed to disk as the run goes) - so the results are
bit for bit those of a run in this process (``tests/test_iso9283_parallel.py``). The worker
sends its progress (simulated time) and at the end its summary entry and tracking result
back through a pipe; this process keeps summary.json and one progress bar for all modes.

How many: all modes at once when there are at most twice as many modes as usable cores
(``os.sched_getaffinity``: three equal runs on two cores then end after 1.5 run times, not
two), else one per core; on one core the modes run one after another in this process.
``$COSIM_MODE_PROCESSES`` = N asks for N worker processes (at most one per mode; 0 or 1:
one after another in this process). Paced (``--realtime``) and split (``--split``) runs
always run one mode at a time here, and so does a process that runs other threads (a sweep's
Dask worker, which is already one of several processes): only a single-threaded process is
forked. summary.json says ``mode_processes`` (0: in this process). A job that knows one mode takes
longer may give the others' workers a lower scheduling priority (``niceness``), so that all
end together.

Stopping:

* SIGINT/SIGTERM to this process (Ctrl-C reaches the whole process group): the workers
  ignore SIGINT; this process sends each running worker SIGTERM, in mode order, and waits
  for it: the worker stops its loop where it is, closes its time series and CAN log
  (everything recorded so far stays readable) and reports where it stopped. summary.json
  ends ``interrupted`` with ``mode`` (the first mode that did not finish), ``stopped_at_s``
  (its simulated time) and ``stopped_at_s_by_mode`` (every unfinished mode).
* A mode that fails (SimulationError) ends its own worker with a summary entry like a
  failed mode in one process; the other modes run on, and the job then fails naming it.
* A worker that dies (a crash in native code, SIGKILL, out of memory) is a failed mode:
  ``"the worker process of mode X died from SIGSEGV"`` at the last simulated time it
  reported; the other modes run on.
"""
from __future__ import annotations

import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from cosim.master import SimulationError

#: Environment variable capping the worker processes (0 or 1: the modes run in this process).
PROCESSES_ENV = "COSIM_MODE_PROCESSES"
#: Wall seconds a stopping worker gets to close its files before it is killed.
STOP_GRACE_S = 60.0
#: Wall seconds between progress messages of a worker (the summary heartbeat's own rate).
PROGRESS_INTERVAL_S = 0.2


@dataclass
class ModeOutcome:
    """One mode's result: the summary entry and tracking result (None when the mode produced
    none: it failed before its first sample, or its worker died) and the SimulationError that
    ended it (None: ran to its end)."""

    mode: str
    entry: dict[str, Any] | None
    result: Any
    failure: SimulationError | None


def usable_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def worker_count(modes: int, ctx: Any = None) -> int:
    """Worker processes for ``modes`` modes: 0 means one after another in this process."""
    execution = getattr(ctx, "execution", None)
    if modes <= 1 or (execution is not None and execution.active):
        return 0
    if threading.active_count() > 1:  # fork only a single-threaded process (a sweep's Dask worker is not one)
        return 0
    cores = usable_cores()
    text = os.environ.get(PROCESSES_ENV, "").strip()
    if text:  # as asked (even on one core), at most one per mode
        try:
            asked = int(text)
        except ValueError:
            raise ValueError(f"${PROCESSES_ENV} = {text!r}: expected a whole number of worker processes "
                             f"(0 or 1: run the modes in this process)") from None
        return min(asked, modes) if asked > 1 else 0
    if cores == 1:
        return 0
    return modes if modes <= 2 * cores else cores


def run_modes(ctx: Any, setup: Any, modes: Sequence[str], extra_signals: Sequence[str] = (),
              processes: int | None = None, while_waiting: Callable[[], Any] | None = None,
              niceness: Mapping[str, int] | None = None) -> Iterator[ModeOutcome]:
    """Run ``modes`` of ``setup`` (:func:`cosim.execution.mode_runs.prepare`) and yield their
    :class:`ModeOutcome` in the order of ``modes``. ``processes``: worker processes (default
    :func:`worker_count`; 0: one after another in this process, where a failed mode ends the
    sequence as before). A failure before a mode's first sample raises as
    :func:`cosim.execution.mode_runs.run_mode` does. ``while_waiting``: called once in a thread of
    this process once every worker has been forked (this process then only relays their
    progress), e.g. to import what comes after the modes; joined when the outcomes run out
    (before the caller's loop over them ends); an exception from it is ignored (the work is redone later). Not called when the
    modes run in this process or when there are more modes than workers (a later fork must not
    happen while another thread runs). ``niceness``: per mode, how much lower the scheduling
    priority of its worker is (``nice`` increment, 0 if not given): the modes known to take
    less CPU yield some of the cores to a longer one, so that all end about together instead
    of the longest running alone on one core at the end (results unchanged)."""
    from cosim.execution.mode_runs import run_mode

    modes = list(modes)
    count = worker_count(len(modes), ctx) if processes is None else processes
    if count <= 0 or len(modes) <= 1:
        count = 0
    ctx.summary.update(mode_processes=count)
    if count == 0:
        for mode in modes:
            entry, result, cell, _ = run_mode(ctx, setup, mode, extra_signals)
            yield ModeOutcome(mode, entry, result, cell.failure)
            if cell.failure is not None and entry.get("verdict", "failed") == "failed":
                return  # a failed run ends the sequence; a stop after a limit or a fault reaction does not
        return
    yield from _Pool(ctx, setup, modes, extra_signals, count, while_waiting, niceness).outcomes()


# ------------------------------------------------------------------------------------------ worker side
class _WorkerSummary:
    """Stands in for the run's SummaryWriter inside a worker: progress goes to the parent."""

    def __init__(self, connection: Any, mode: str) -> None:
        self._connection = connection
        self._mode = mode
        self._last = 0.0
        self.data: dict[str, Any] = {}

    def _send(self, sim_time_s: float, force: bool = False) -> None:
        now = time.perf_counter()
        if force or now - self._last >= PROGRESS_INTERVAL_S:
            self._last = now
            _send_whole(self._connection, ("progress", self._mode, float(sim_time_s)))

    def progress(self, sim_time_s: float, *args: Any, **kwargs: Any) -> None:
        self._send(sim_time_s, force=True)

    def note_progress(self, sim_time_s: float, *args: Any, **kwargs: Any) -> None:
        self._send(sim_time_s)

    def note_time(self, sim_time_s: float, *args: Any, **kwargs: Any) -> None:
        self._send(sim_time_s)

    def update(self, **fields: Any) -> None:
        self.data.update(fields)

    def write(self) -> None:
        """Nothing: summary.json belongs to the parent."""

    def __getattr__(self, name: str) -> Any:
        """Any other writer method (``note_where``, ...) does nothing here: the parent keeps
        summary.json and the supervisor's record of where the run is."""
        if name.startswith("_"):
            raise AttributeError(name)
        return lambda *args, **kwargs: None


def _send_whole(connection: Any, message: Any) -> None:
    """``connection.send`` with SIGTERM held back until the message is whole (a stop request in
    the middle would leave half a message in the pipe)."""
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM, signal.SIGINT})
    try:
        connection.send(message)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def _recv_whole(connection: Any) -> Any:
    """``connection.recv`` with SIGINT/SIGTERM held back until the message is read whole (a
    KeyboardInterrupt between its length and its bytes would leave the pipe unreadable)."""
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM, signal.SIGINT})
    try:
        return connection.recv()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def _quietly(work: Callable[[], Any]) -> None:
    """``work()``; an exception is ignored (only a head start: the caller does the work again)."""
    try:
        work()
    except Exception:  # noqa: BLE001
        pass


class _Stop(KeyboardInterrupt):
    """The parent asked this worker to stop (SIGTERM)."""


class _SignalledStop(KeyboardInterrupt):
    """A worker was stopped by a SIGTERM that reached it directly (SIGTERM to the process group)."""

    signal_name = "SIGTERM"


def _on_stop(signum: int, frame: Any) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # once: the clean-up that follows must not be cut short
    raise _Stop()


def _failure_state(failure: SimulationError | None) -> tuple | None:
    if failure is None:
        return None
    return failure.component, failure.time, failure.reason, failure.messages, failure.args


def _failure_from(state: tuple | None) -> SimulationError | None:
    if state is None:
        return None
    component, time_s, reason, messages, args = state
    failure = SimulationError(component, time_s, reason, messages)
    failure.args = args
    return failure


def _worker(connection: Any, ctx: Any, setup: Any, mode: str, extra_signals: Sequence[str]) -> None:
    """Run one mode in a forked worker; report ``done``, ``failed`` or ``stopped`` and exit."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C to the group: the parent stops us in order
    signal.signal(signal.SIGTERM, _on_stop)
    try:
        from cosim.results import crashguard

        crashguard.disarm()  # a crash here is reported by the parent, not by the parent's summary file
    except Exception:  # noqa: BLE001 - no guard in this build
        pass
    from cosim.execution.mode_runs import run_mode

    ctx.summary = _WorkerSummary(connection, mode)
    ctx.quiet = True
    ctx.sim_time_s = 0.0
    ctx.label = mode
    try:
        entry, result, cell, _ = run_mode(ctx, setup, mode, extra_signals)
        message = ("done", mode, entry, result, _failure_state(cell.failure), cell.reached_s)
    except _Stop:
        message = ("stopped", mode, ctx.stopped_at_s, ctx.sim_time_s)
    except SimulationError as exc:  # before the first sample: nothing to evaluate
        message = ("failed", mode, _failure_state(exc), ctx.sim_time_s)
    except BaseException as exc:  # noqa: BLE001 - reported to the parent, which fails the run
        message = ("error", mode, f"{type(exc).__name__}: {exc}", ctx.stopped_at_s, ctx.sim_time_s)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        _send_whole(connection, message)
    except (OSError, ValueError):
        pass
    connection.close()


# ------------------------------------------------------------------------------------------ parent side
class _Pool:
    """The parent's side: start the workers, relay progress, collect outcomes, stop them."""

    def __init__(self, ctx: Any, setup: Any, modes: list[str], extra_signals: Sequence[str], count: int,
                 while_waiting: Callable[[], Any] | None = None, niceness: Mapping[str, int] | None = None) -> None:
        self.ctx, self.setup, self.modes, self.extra_signals = ctx, setup, modes, tuple(extra_signals)
        self.while_waiting = while_waiting
        self.niceness = dict(niceness or {})
        self.count = count
        self.total_s = float(setup.doc["simulation"]["stop_time"]) * len(modes)
        self.progress: dict[str, float] = {}
        self.running: dict[str, tuple[Any, Any]] = {}  # mode -> (process, connection)
        self.outcomes_by_mode: dict[str, ModeOutcome] = {}
        self.stopped_at: dict[str, float | None] = {}
        self.base_s = float(ctx.sim_time_s)

    def _start(self, mode: str) -> None:
        context = multiprocessing.get_context("fork")
        receiver, sender = context.Pipe(duplex=False)
        sys.stdout.flush()
        sys.stderr.flush()
        process = context.Process(target=_worker, args=(sender, self.ctx, self.setup, mode, self.extra_signals),
                                  name=f"cosim-mode-{mode}", daemon=True)
        process.start()
        sender.close()
        increment = int(self.niceness.get(mode, 0))
        if increment > 0:  # lower its priority (allowed for our own process): a longer mode gets more CPU
            try:
                os.setpriority(os.PRIO_PROCESS, process.pid, os.getpriority(os.PRIO_PROCESS, 0) + increment)
            except (AttributeError, OSError):
                pass
        self.running[mode] = (process, receiver)
        self.progress.setdefault(mode, 0.0)

    def _covered(self) -> float:
        return self.base_s + sum(self.progress.values())

    def outcomes(self) -> Iterator[ModeOutcome]:
        from cosim.results.progress import ProgressBar

        ctx = self.ctx
        waiting = list(self.modes)
        label = f"{ctx.scenario.name} ({len(self.modes)} modes, {self.count} processes)"
        while waiting and len(self.running) < self.count:  # forked before the bar's thread exists
            self._start(waiting.pop(0))
        bar = ProgressBar(self.total_s, label, enabled=not ctx.quiet)
        last_summary = time.perf_counter()
        next_yield = 0
        helper = None
        try:
            if self.while_waiting is not None and not waiting:  # every worker forked: no fork while it runs
                helper = threading.Thread(target=_quietly, args=(self.while_waiting,), name="cosim-while-waiting",
                                          daemon=True)
                helper.start()
            while next_yield < len(self.modes):
                while waiting and len(self.running) < self.count:
                    self._start(waiting.pop(0))
                self._receive(timeout_s=PROGRESS_INTERVAL_S)
                covered = self._covered()
                bar.update(covered - self.base_s)
                self._note_where()
                now = time.perf_counter()
                if now - last_summary > 2.0:
                    ctx.summary.progress(covered)
                    last_summary = now
                else:
                    ctx.summary.note_progress(covered)
                while next_yield < len(self.modes) and self.modes[next_yield] in self.outcomes_by_mode:
                    outcome = self.outcomes_by_mode[self.modes[next_yield]]
                    next_yield += 1
                    ctx.sim_time_s = self._covered()
                    if outcome.failure is not None:
                        ctx.label = outcome.mode  # the failed mode is the one summary.json names
                    yield outcome
        except KeyboardInterrupt:
            self._stop_all()
            raise
        finally:
            bar.update(self._covered() - self.base_s, force=True)
            bar.close()
            self._stop_all(quiet=True)
            ctx.sim_time_s = self._covered()
            if helper is not None:  # done before the caller goes on (it may fork, e.g. for a figure)
                helper.join()

    def _note_where(self) -> None:
        """Tell the summary writer (for a crash guard or supervisor writing on this process's
        behalf) the first mode still running and its simulated time."""
        running = [m for m in self.modes if m in self.running]
        note_where = getattr(self.ctx.summary, "note_where", None)
        if running and note_where is not None:
            note_where(mode=running[0], at_s=self.progress.get(running[0], 0.0))

    def _receive(self, timeout_s: float) -> None:
        from multiprocessing.connection import wait

        if not self.running:
            return
        connections = {conn: mode for mode, (_, conn) in self.running.items()}
        for conn in wait(list(connections), timeout=timeout_s):
            mode = connections[conn]
            try:
                message = _recv_whole(conn)
            except (EOFError, OSError):
                self._died(mode)
                continue
            self._handle(mode, message)

    def _handle(self, mode: str, message: tuple) -> None:
        kind = message[0]
        if kind == "progress":
            self.progress[mode] = message[2]
            return
        process, conn = self.running.pop(mode)
        conn.close()
        process.join(timeout=STOP_GRACE_S)
        if kind == "done":
            _, _, entry, result, failure, reached = message
            self.progress[mode] = reached
            self.outcomes_by_mode[mode] = ModeOutcome(mode, entry, result, _failure_from(failure))
        elif kind == "failed":
            failure = _failure_from(message[2])
            self.progress[mode] = message[3]
            self.outcomes_by_mode[mode] = ModeOutcome(mode, None, None, failure)
            raise failure
        elif kind == "error":
            _, _, text, stopped, covered = message
            self.progress[mode] = covered
            self.ctx.label = mode
            raise RuntimeError(f"mode {mode}: {text}")
        elif kind == "stopped":  # stopped by a signal that reached it directly (SIGTERM to the group)
            self.stopped_at[mode] = message[2]
            self.progress[mode] = message[3] if message[3] else self.progress.get(mode, 0.0)
            raise _SignalledStop()

    def _died(self, mode: str) -> None:
        """A worker ended without a word: a failed mode at the last time it reported."""
        process, conn = self.running.pop(mode)
        conn.close()
        process.join(timeout=STOP_GRACE_S)
        code = process.exitcode
        how = (f"died from {signal.Signals(-code).name}" if code is not None and code < 0
               else f"exited with code {code} without a result")
        at = self.progress.get(mode, 0.0)
        failure = SimulationError(f"mode {mode}", at, f"the worker process of mode {mode} {how} (a crash in native "
                                  f"code, a kill or out of memory); its files hold what it wrote up to then")
        self.outcomes_by_mode[mode] = ModeOutcome(mode, None, None, failure)

    def _stop_all(self, quiet: bool = False) -> None:
        """Stop every running worker, in mode order: SIGTERM, then its report (where it stopped);
        summary.json's interrupted status names the first unfinished mode."""
        if not self.running:
            return
        stopped_at = dict(self.stopped_at)
        for mode in [m for m in self.modes if m in self.running]:
            process, conn = self.running[mode]
            if process.is_alive():
                try:
                    os.kill(process.pid, signal.SIGTERM)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + STOP_GRACE_S
            while time.monotonic() < deadline:
                try:
                    if not conn.poll(0.5):
                        if not process.is_alive():
                            break
                        continue
                    message = _recv_whole(conn)
                except (EOFError, OSError):
                    break
                if message[0] == "progress":
                    self.progress[mode] = message[2]
                    continue
                if message[0] == "stopped":
                    stopped_at[mode] = message[2]
                    self.progress[mode] = message[3] or self.progress.get(mode, 0.0)
                elif message[0] == "error":  # the stop met an error while the worker closed its files
                    stopped_at[mode] = message[3]
                    self.progress[mode] = message[4] or self.progress.get(mode, 0.0)
                    self.ctx.summary.data.setdefault("stop_errors", {})[mode] = message[2]
                elif message[0] == "done":
                    self.progress[mode] = message[5]
                break
            process.join(timeout=1.0)
            if process.is_alive():
                process.kill()
                process.join(timeout=5.0)
            conn.close()
            del self.running[mode]
            stopped_at.setdefault(mode, self.progress.get(mode))
        if quiet:
            return
        unfinished = [m for m in self.modes if m in stopped_at]
        if unfinished:
            first = unfinished[0]
            self.ctx.label = first
            self.ctx.note_position(first, stopped_at[first] if stopped_at[first] is not None else 0.0)
            self.ctx.summary.data["stopped_at_s_by_mode"] = {  # rounded as summary.json's stopped_at_s
                m: None if stopped_at[m] is None else round(float(stopped_at[m]), 12) for m in unfinished}
