"""A run's process is watched by a small supervisor that writes the final status if it dies.

``python -m cosim run|serve|sweep`` forks once, right after the command line is parsed (before
any heavy import): the child runs the command as before, the parent only waits for it
(docs/reference/verdicts.md, "What stops a run"). Whatever ends the child, a status file it
left at ``"running"`` gets a final one:

* the child ends normally (it wrote its status): the parent exits with the child's code;
* the child is killed by a signal (SIGKILL by a user or the kernel's out-of-memory killer,
  SIGSEGV without the crash guard, ...) or exits without writing its status (``_exit()`` or
  ``exit()`` called by native code, e.g. an FMU running in process): the parent writes
  ``status: "failed"`` with ``reason`` (how the process ended and that it wrote no status),
  ``signal`` or ``exit_code``, and where the run was (``mode``, ``stopped_at_s``: the last
  progress the child published, at most about 0.2 s of wall time old; cosim/results/lastwords.py)
  into every such file (``summary.json``; a sweep's ``sweep.json`` and its variants), and then
  ends the way the child did: killed by the same signal (exit status 128 + n in a shell), or
  exit code 3 (failed run) after an exit without a status.

Signals: the child runs in its own process group, so a signal meant for the run reaches it
exactly once: the parent forwards SIGINT, SIGTERM, SIGHUP, SIGQUIT, SIGUSR1, SIGUSR2 and
SIGWINCH to the child (Ctrl-C in a terminal goes to the parent's process group only; ``kill
PID`` and ``kill -- -PGID`` reach the parent), and Ctrl-Z (SIGTSTP) stops the child's group and
then the parent, SIGCONT continues both. If the parent itself is killed, the child gets SIGHUP
(``PR_SET_PDEATHSIG``) and ends ``interrupted``. The third SIGINT/SIGTERM/SIGHUP is not forwarded: the
parent kills the child's process group (a child stuck in native code, e.g. an FMU hanging in
``fmi2DoStep`` in process, runs no Python signal handler) and writes ``interrupted`` (exit 130). The child's own children (CAN-log writer,
drive process, out-of-process FMUs, Dask workers) are in the child's group: after the child died
without a status they get ``GRACE_S`` to finish (they see their pipes close) and are then killed.

``COSIM_SUPERVISE=0`` in the environment runs the command in the one process (no fork).
"""
from __future__ import annotations

import json
import os
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

SUPERVISED_COMMANDS = ("run", "serve", "sweep")
"""Commands that keep a status file at "running" while they go."""
ENV_SUPERVISE = "COSIM_SUPERVISE"
GRACE_S = 5.0
"""Wall time the dead child's own children get to finish before they are killed, s."""
FORWARDED = ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT", "SIGUSR1", "SIGUSR2", "SIGWINCH")
INTERRUPTS = ("SIGINT", "SIGTERM", "SIGHUP")
INSIST = 3
"""The third interrupt (SIGINT/SIGTERM/SIGHUP) kills the run's process group instead of being forwarded."""
EXIT_INTERRUPTED = 130
EXIT_FAILED = 3
_PR_SET_PDEATHSIG = 1


def wanted(command: str | None) -> bool:
    """Whether ``command`` runs supervised here (not turned off, fork available)."""
    return (command in SUPERVISED_COMMANDS and hasattr(os, "fork")
            and os.environ.get(ENV_SUPERVISE, "1").strip().lower() not in ("0", "no", "false", "off"))


def supervise(run: Callable[[], int]) -> int:
    """Run ``run()`` in a forked child and wait for it (see the module docstring).

    In the child, returns what ``run()`` returns (the caller exits with it). In the parent,
    returns the exit code, or ends the process by the signal that ended the child."""
    from cosim.results import lastwords

    table = lastwords.create()
    oom_before = _oom_kills()
    parent = os.getpid()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    pid = os.fork()
    if pid == 0:
        _become_child(parent)
        code = run()
        lastwords.farewell(code)
        return code
    return _parent(pid, table, oom_before)


# ------------------------------------------------------------------------------------------ child
def _become_child(parent: int) -> None:
    from cosim.results import lastwords

    try:
        os.setpgid(0, 0)
    except OSError:
        pass
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signal.SIGHUP), 0, 0, 0)
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:  # the supervisor died before the death signal was set
        os.kill(os.getpid(), signal.SIGHUP)
    lastwords.adopt()


# ----------------------------------------------------------------------------------------- parent
class _Forwarder:
    """The parent's signal handlers: forward to the child, stop and continue with it."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.received: list[str] = []
        self.forced: str | None = None

    def forward(self, signum: int, frame) -> None:
        name = signal.Signals(signum).name
        self.received.append(name)
        interrupts = [n for n in self.received if n in INTERRUPTS]
        try:
            if name in INTERRUPTS and len(interrupts) >= INSIST:
                # the user insists: the run may be stuck in native code (an FMU hanging in process), where no
                # Python handler runs; end its whole group now, the final status is written below
                self.forced = name
                os.killpg(self.pid, signal.SIGKILL)
            else:
                os.kill(self.pid, signum)
        except ProcessLookupError:
            pass

    def stop(self, signum: int, frame) -> None:  # Ctrl-Z: stop the child's group, then this process
        try:
            os.killpg(self.pid, signal.SIGSTOP)
        except ProcessLookupError:
            pass
        signal.signal(signal.SIGTSTP, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGTSTP)  # stops here; SIGCONT continues below
        signal.signal(signal.SIGTSTP, self.stop)

    def resume(self, signum: int, frame) -> None:
        try:
            os.killpg(self.pid, signal.SIGCONT)
        except ProcessLookupError:
            pass

    def install(self) -> None:
        for name in FORWARDED:
            signal.signal(getattr(signal, name), self.forward)
        signal.signal(signal.SIGTSTP, self.stop)
        signal.signal(signal.SIGCONT, self.resume)


def _parent(pid: int, table, oom_before: int | None) -> int:
    try:
        os.setpgid(pid, pid)
    except OSError:  # the child did it first, or is gone already
        pass
    forwarder = _Forwarder(pid)
    forwarder.install()
    while True:
        try:
            _, status = os.waitpid(pid, 0)
            break
        except ChildProcessError:
            status = 0
            break
    entries = table.entries()  # the child is gone: nothing changes the table any more
    if os.WIFSIGNALED(status):
        signum = os.WTERMSIG(status)
        code = 128 + signum
    else:
        signum, code = None, os.waitstatus_to_exitcode(status)
    left_running = [e for e in entries if _still_running(Path(e["path"]))]
    if left_running or signum is not None:
        _wait_for_group(pid)
    returned = table.farewell()
    if left_running and signum is None and returned == code:  # the command returned: an oversight, not a death
        how = {"ended": f"ended (exit code {code})", "fields": {"exit_code": code}, "status": "failed",
               "cause": "the command returned without finishing this file"}
        _write_last_words(left_running, how)
        return code
    if forwarder.forced and signum == signal.SIGKILL:  # killed on the user's insistence: an interrupt
        how = {"ended": f"did not end after {INSIST} interrupts and was killed", "status": "interrupted",
               "fields": {"signal": forwarder.forced},
               "cause": "stuck in native code, e.g. an FMU hanging in fmi2DoStep in process: run it out of process "
                        "with a step_timeout, docs/reference/verdicts.md"}
        written = [str(path) for path in _write_last_words(left_running, how)]
        print(f"interrupted by {forwarder.forced}: the run's process {how['ended']}"
              f"{_where(left_running[0]['data']) if left_running else ''}"
              f"{'; ' + ', '.join(written) + ': interrupted' if written else ''}", file=sys.stderr, flush=True)
        return EXIT_INTERRUPTED
    if left_running:
        how = _how_it_ended(signum, code, oom_before, forwarder.received)
        written = [str(path) for path in _write_last_words(left_running, how)]
        where = _where(left_running[0]["data"])
        print(f"error: the run's process {how['ended']} without writing its final status{where}; "
              f"{', '.join(written)}: {how['status']} (docs/reference/verdicts.md)", file=sys.stderr, flush=True)
        if signum is None:
            code = EXIT_FAILED
    if signum is not None:
        _die_by(signum)
    return code


def _still_running(path: Path) -> bool:
    try:
        return json.loads(path.read_text(encoding="utf-8")).get("status") == "running"
    except FileNotFoundError:
        return False
    except (OSError, ValueError):  # torn or unreadable: it holds no final status
        return True


def _group_members(pgid: int) -> list[int]:
    """Live (not zombie) processes of the process group ``pgid``, from /proc."""
    found = []
    try:
        entries = os.listdir("/proc")
    except OSError:
        return found
    for name in entries:
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat", "rb") as handle:
                fields = handle.read().rsplit(b")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if len(fields) > 3 and fields[0] != b"Z" and int(fields[3]) == pgid:
            found.append(int(name))
    return found


def _wait_for_group(pgid: int, grace_s: float = GRACE_S) -> None:
    """Give the dead child's children ``grace_s`` to finish (their pipes are closed), then kill them."""
    deadline = time.monotonic() + grace_s
    while _group_members(pgid) and time.monotonic() < deadline:
        time.sleep(0.05)
    if _group_members(pgid):
        try:
            os.killpg(pgid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass


def _oom_kills() -> int | None:
    """The out-of-memory kill count of this process's memory cgroup (v2 ``memory.events``, v1
    ``memory.oom_control``), or None when the system does not say."""
    try:
        with open("/proc/self/cgroup", encoding="ascii") as handle:
            lines = handle.read().splitlines()
    except OSError:
        return None
    candidates = []
    for line in lines:
        _, controllers, path = (line.split(":", 2) + ["", ""])[:3]
        if controllers == "":
            candidates.append(f"/sys/fs/cgroup{path.rstrip('/')}/memory.events")
        elif "memory" in controllers.split(","):
            candidates += [f"/sys/fs/cgroup/memory{path.rstrip('/')}/memory.oom_control",
                           "/sys/fs/cgroup/memory/memory.oom_control"]
    for candidate in candidates:
        try:
            with open(candidate, encoding="ascii") as handle:
                for row in handle:
                    key, _, value = row.partition(" ")
                    if key == "oom_kill":
                        return int(value)
        except (OSError, ValueError):
            continue
    return None


def _how_it_ended(signum: int | None, code: int, oom_before: int | None, received: list[str]) -> dict[str, Any]:
    """The words and fields for the final status."""
    if signum is None:
        return {"ended": f"exited with code {code}", "fields": {"exit_code": code}, "status": "failed",
                "cause": "native code called exit() or _exit(), e.g. an FMU running in process: run FMUs you do "
                         "not trust out of process, docs/reference/verdicts.md"}
    name = _signal_name(signum)
    fields: dict[str, Any] = {"signal": name, "exit_code": 128 + signum}
    if signum == signal.SIGKILL:
        oom_after = _oom_kills()
        if oom_before is not None and oom_after is not None and oom_after > oom_before:
            cause = (f"the kernel's out-of-memory killer (the oom_kill count of this memory cgroup rose from "
                     f"{oom_before} to {oom_after}); lower the run's memory (docs/reference/verdicts.md) or free memory")
            fields["out_of_memory"] = True
        else:
            cause = "sent by another process or the kernel's out-of-memory killer (check dmesg)"
    elif signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        cause = "a repeated interrupt ended it before it had written its status" if received else \
            "sent to the run's process directly"
    else:
        cause = "a crash in native code (an in-process FMU or a compiled helper)"
    status = "interrupted" if signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP) else "failed"
    return {"ended": f"was killed by {name}", "fields": fields, "status": status, "cause": cause}


def _signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def _where(data: dict[str, Any], job: bool = False) -> str:
    parts = []
    if job and data.get("job"):
        parts.append(f"job {data['job']}")
    if data.get("mode"):
        parts.append(f"mode {data['mode']}")
    if data.get("stopped_at_s") is not None:
        parts.append(f"t = {data['stopped_at_s']:.6g} s")
    return f" ({', '.join(parts)})" if parts else ""


def _final(data: dict[str, Any], how: dict[str, Any], entry: dict[str, Any], reason: str) -> dict[str, Any]:
    final = dict(data)
    final.update(how["fields"])
    final["status"] = how["status"]
    final["reason"] = reason
    final.setdefault("stopped_at_s", final.get("sim_time_s"))
    if final.get("mode"):
        final["failed_in" if how["status"] == "failed" else "interrupted_in"] = final["mode"]
    wall = final.get("wall_time_s")
    if isinstance(wall, (int, float)) and isinstance(entry.get("monotonic"), (int, float)):
        final["wall_time_s"] = wall + max(0.0, time.monotonic() - entry["monotonic"])
        sim = final.get("sim_time_s")
        if isinstance(sim, (int, float)) and final["wall_time_s"] > 0:
            final["realtime_factor"] = sim / final["wall_time_s"]
    final["ended_at"] = time.strftime("%Y-%m-%dT%H:%M:%S+00:00", time.gmtime())
    final["status_written_by"] = "supervisor"
    return final


def _write_json(path: Path, data: dict[str, Any]) -> bool:
    from cosim.results.summary import write_final_json  # light: json, os, time

    return write_final_json(path, data, default=str)


def _write_last_words(entries: list[dict[str, Any]], how: dict[str, Any]) -> list[Path]:
    """Write the final status into each published file still ``running`` and into the files its
    ``also`` patterns match that are still ``running``; return the files written."""
    written = []
    for entry in entries:
        path = Path(entry["path"])
        data = entry.get("data") or {}
        reason = (f"the run's process {how['ended']} without writing its final status ({how['cause']}); "
                  f"last progress recorded: {_where(data, job=True)[2:-1] or 'none'}")
        if _write_json(path, _final(data, how, entry, reason)):
            written.append(path)
        for pattern in entry.get("also", ()):
            for other in sorted(path.parent.glob(pattern)):
                try:
                    found = json.loads(other.read_text(encoding="utf-8"))
                except (OSError, ValueError):
                    continue
                if found.get("status") != "running":
                    continue
                found.setdefault("stopped_at_s", found.get("sim_time_s"))
                outer = (f"the process that ran this ({path.name}) {how['ended']} while this was running "
                         f"({how['cause']}); last progress recorded: {_where(found, job=True)[2:-1] or 'none'}")
                if _write_json(other, _final(found, how, {}, outer)):
                    written.append(other)
        path.with_name(path.name + ".tmp").unlink(missing_ok=True)
    return written


def _die_by(signum: int) -> None:
    """End this process by ``signum`` as the child was (no second core dump)."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    try:
        import resource

        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    except (ImportError, OSError, ValueError):
        pass
    try:
        signal.signal(signum, signal.SIG_DFL)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, [signum])
    except (OSError, ValueError):
        pass
    os.kill(os.getpid(), signum)
    os._exit(128 + signum)  # a signal whose default is not to end the process


__all__ = ["ENV_SUPERVISE", "GRACE_S", "SUPERVISED_COMMANDS", "supervise", "wanted"]
