"""``summary.json``: written when a run starts and rewritten atomically as it goes.

Fields every run has: ``scenario``, ``job``, ``status`` (``"running"``, ``"ok"``,
``"limit"``, ``"fault"``, ``"failed"`` or ``"interrupted"``: the most severe verdict of the
job's cell runs, cosim/cell/verdict.py), ``verdicts`` (per cell run: its verdict and first
violation), ``reason`` (also for ``limit``/``fault``), and ``stopped_at_s`` when failed or
interrupted (plus ``signal`` and ``failed_in``/``interrupted_in``, the mode or part that
was running), ``sim_time_s`` (simulated
seconds reached), ``wall_time_s``, ``realtime_factor`` (= sim_time_s / wall_time_s, >1 is
faster than real time), ``wall_time_from`` (where the wall clock starts: ``"process start"``
for ``python -m cosim run``, the whole command from the interpreter's start to the final
status, imports, set-up, writing and figures included; ``"run call"`` for a run started from
Python, :func:`cosim.run`), ``started_at`` (UTC, ISO 8601, the same origin). Jobs add their
own fields with ``update``. Non-finite floats are written as null (strict JSON).
"""
from __future__ import annotations

import json
import math
import os
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any


#: Stands for the signal's name in the crash summary (crashguard.c writes the name there).
_SIGNAL_MARK = "@@SIGNAL@@"
#: Stand for the latest progress in the crash summary (crashguard.c writes the numbers there).
_SIM_TIME_MARK, _AT_MARK = "@@SIM_TIME@@", "@@AT@@"


def replace_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (temporary file + rename); no ``.tmp`` is left when it
    fails (the error is raised)."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    except BaseException:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass
        raise


def write_final_json(path: Path, data: Any, **dumps: Any) -> bool:
    """Write a final status file however full the disk: atomically if possible, else in place (the
    old file's blocks are freed first, compact JSON); False when neither worked. Never raises
    OSError. ``dumps``: further :func:`json.dumps` arguments."""
    try:
        replace_text(path, json.dumps(data, indent=2, **dumps) + "\n")
        return True
    except OSError:
        pass
    try:
        with open(path, "w", encoding="utf-8") as handle:
            handle.write(json.dumps(data, indent=None, **dumps) + "\n")
        return True
    except OSError:
        return False


def process_started_perf_counter() -> float | None:
    """The :func:`time.perf_counter` reading at which this process (under the supervisor: the
    supervisor, where the command started) started (from its start time
    in ``/proc/self/stat``, in clock ticks since boot, against ``CLOCK_BOOTTIME``; resolution one
    clock tick, 10 ms), or None where that is not available (not Linux)."""
    from cosim.results import lastwords

    # under the supervisor (python -m cosim run), the command started with the supervisor, before the fork
    stat = f"/proc/{os.getppid()}/stat" if lastwords.active() else "/proc/self/stat"
    try:
        with open(stat, "rb") as handle:
            fields = handle.read().rsplit(b")", 1)[1].split()
        started = int(fields[19]) / os.sysconf("SC_CLK_TCK")  # field 22 of proc(5): starttime
        now_boot, now_perf = time.clock_gettime(time.CLOCK_BOOTTIME), time.perf_counter()
    except (OSError, ValueError, IndexError, AttributeError):
        return None
    age = now_boot - started
    if not 0.0 <= age < 30 * 86400:  # a clock that does not match: no claim
        return None
    return now_perf - age


def _json_safe(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if hasattr(value, "tolist"):  # numpy scalars and arrays
        return _json_safe(value.tolist())
    if isinstance(value, Path):
        return str(value)
    return value


class SummaryWriter:
    """Owns ``<out_dir>/summary.json`` for one run.

    Args:
        path: the summary.json path (its directory is created).
        scenario: scenario name.
        job: job type name.
        wall_origin: the :func:`time.perf_counter` reading the wall time counts from (default:
            now); :func:`process_started_perf_counter` for a whole command.
        wall_time_from: what ``wall_origin`` is, written as ``wall_time_from``.
    """

    def __init__(self, path: str | Path, scenario: str, job: str, wall_origin: float | None = None,
                 wall_time_from: str = "run call") -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        now = time.perf_counter()
        self._wall0 = now if wall_origin is None else min(float(wall_origin), now)
        self._guarded = False
        self.where: dict[str, Any] = {}
        self._key = str(self.path.absolute())
        started = datetime.fromtimestamp(time.time() - (now - self._wall0), timezone.utc)
        self.data: dict[str, Any] = {
            "scenario": scenario,
            "job": job,
            "status": "running",
            "started_at": started.isoformat(timespec="seconds"),
            "sim_time_s": 0.0,
            "wall_time_s": 0.0,
            "wall_time_from": wall_time_from,
            "realtime_factor": None,
        }
        self.write()

    @property
    def wall_time_s(self) -> float:
        """Wall time since the writer was created, s."""
        return time.perf_counter() - self._wall0

    def note_where(self, mode: str | None = None, at_s: float | None = None) -> None:
        """Where the run is, for a summary written on its behalf if its process dies (crash guard,
        supervisor): the ``mode`` (or part) running and its simulated time ``at_s`` (s). No file write."""
        if mode is not None:
            self.where["mode"] = mode or None
        if at_s is not None:
            self.where["stopped_at_s"] = round(float(at_s), 12)

    def note_time(self, sim_time_s: float, at_s: float) -> None:
        """The latest progress for the supervisor only (two numbers in shared memory: cheap enough for
        every heartbeat; cosim/results/lastwords.py). No file write."""
        from cosim.results import crashguard, lastwords

        lastwords.note_time(self._key, sim_time_s, at_s)
        self.where["stopped_at_s"] = at_s  # what the next prepared summary says (no rounding: every heartbeat)
        self.where["sim_time_s"] = sim_time_s
        if self._guarded:
            crashguard.note(sim_time_s, at_s)

    def dying_words(self) -> dict[str, Any]:
        """The running summary with where the run is (``mode``, ``stopped_at_s``): the base of the
        ``failed`` summary the crash guard or the supervisor writes if the process dies now."""
        data = dict(self.data)
        data.setdefault("mode", self.where.get("mode"))
        data["sim_time_s"] = round(float(self.where.get("sim_time_s", data["sim_time_s"])), 12)
        data["stopped_at_s"] = self.where.get("stopped_at_s", data.get("sim_time_s"))
        return data

    def _guard(self) -> None:
        """Prepare the summary a dying process leaves: the crash guard's (crashguard.py, fatal signals
        in this process) and the supervisor's (lastwords.py, any death); drop them once the run ended."""
        from cosim.results import crashguard, lastwords

        if self.data.get("status") != "running":
            crashguard.disarm()
            lastwords.retract(self._key)
            return
        words = self.dying_words()
        lastwords.publish(self._key, _json_safe(words))
        if not self._guarded:
            self._guarded = crashguard.install(self.path)
            if not self._guarded:
                return
        crashguard.note(words.get("sim_time_s") or 0.0, words["stopped_at_s"] or 0.0)
        mode = words.get("mode")
        # the handler writes the latest heartbeat's times (crashguard.note) where the marks stand
        crash = dict(words, status="failed", signal=_SIGNAL_MARK, sim_time_s=_SIM_TIME_MARK, stopped_at_s=_AT_MARK,
                     reason=f"the run's process died from {_SIGNAL_MARK} (a crash in native code: an in-process "
                            f"FMU or a compiled helper) at t = {_AT_MARK} s"
                            f"{f' in mode {mode}' if mode else ''} (the last simulated time reached, to the "
                            f"master's heartbeat). Run third-party FMUs out of process to isolate them "
                            f"(docs/reference/verdicts.md)")
        text = json.dumps(_json_safe(crash), indent=2, allow_nan=False) + "\n"
        text = text.replace(f'"{_SIM_TIME_MARK}"', "\x02").replace(f'"{_AT_MARK}"', "\x03")
        crashguard.arm(text.replace(_AT_MARK, "\x03").replace(_SIGNAL_MARK, "\x01"))

    def write(self) -> None:
        """Rewrite the file atomically (temporary file + rename); no ``.tmp`` is left when it fails."""
        self._guard()
        replace_text(self.path, json.dumps(_json_safe(self.data), indent=2, allow_nan=False) + "\n")

    def write_final(self) -> None:
        """Write the final status, however full the disk (:func:`write_final_json`); give up quietly
        when even that fails (the caller has already told the user). Never raises OSError."""
        self._guard()
        write_final_json(self.path, _json_safe(self.data), allow_nan=False)

    def progress(self, sim_time_s: float, at_s: float | None = None) -> None:
        """Record how far the run got (simulated s; ``at_s``: the running part's own time, see
        :meth:`note_where`) and the wall time so far; rewrite."""
        self.note_where(at_s=at_s)
        wall = self.wall_time_s
        self.data["sim_time_s"] = round(float(sim_time_s), 12)  # n * h0 carries float noise (0.49999999999999994)
        self.where["sim_time_s"] = self.data["sim_time_s"]
        self.data["wall_time_s"] = wall
        self.data["realtime_factor"] = sim_time_s / wall if wall > 0 else None
        self.write()

    def note_progress(self, sim_time_s: float, at_s: float | None = None) -> None:
        """Record the simulated time reached for the crash guard's and the supervisor's summary only
        (no file write; cheap enough for every progress-bar update)."""
        from cosim.results import lastwords

        self.data["sim_time_s"] = round(float(sim_time_s), 12)
        self.where["sim_time_s"] = self.data["sim_time_s"]
        self.data["wall_time_s"] = self.wall_time_s
        self.note_where(at_s=at_s)
        if self._guarded or lastwords.active():
            self._guard()

    def update(self, **fields: Any) -> None:
        """Add or replace job-specific fields; rewrite."""
        self.data.update(fields)
        self.write()

    def _finish(self, sim_time_s: float) -> None:
        wall = self.wall_time_s
        self.data["sim_time_s"] = round(float(sim_time_s), 12)
        self.data["wall_time_s"] = wall
        self.data["realtime_factor"] = sim_time_s / wall if wall > 0 else None
        self.data["ended_at"] = datetime.now(timezone.utc).isoformat(timespec="seconds")

    def finish_ok(self, sim_time_s: float, **fields: Any) -> None:
        """Final status ``"ok"`` (an OSError writing it propagates: the run then fails)."""
        self.data.update(fields)
        self.data["status"] = "ok"
        self.data.pop("reason", None)
        self._finish(sim_time_s)
        self.write()

    def finish_verdict(self, status: str, sim_time_s: float, reason: str | None = None, **fields: Any) -> None:
        """Final status of a run that completed: ``"ok"``, or the most severe verdict of its cell
        runs (``"limit"``, ``"fault"``, ``"failed"``) with ``reason`` (the run and its first
        violation). An OSError writing it propagates, as for :meth:`finish_ok`."""
        if status == "ok":
            self.finish_ok(sim_time_s, **fields)
            return
        self.data.update(fields)
        self.data["status"] = status
        self.data["reason"] = reason or status
        self._finish(sim_time_s)
        self.write()

    def finish_failed(self, reason: str, stopped_at_s: float | None, sim_time_s: float, **fields: Any) -> None:
        """Final status ``"failed"`` with the reason and the simulated time it stopped at (s); never raises OSError."""
        self.data.update(fields)
        self.data["status"] = "failed"
        self.data["reason"] = reason
        self.data["stopped_at_s"] = None if stopped_at_s is None else round(float(stopped_at_s), 12)
        self._finish(sim_time_s)
        self.write_final()

    def finish_interrupted(self, signal_name: str, stopped_at_s: float | None, sim_time_s: float,
                           **fields: Any) -> None:
        """Final status ``"interrupted"`` by ``signal_name`` (``"SIGINT"``, ``"SIGTERM"``) at ``stopped_at_s``
        (simulated s of the part that was running); never raises OSError."""
        self.data.update(fields)
        self.data["status"] = "interrupted"
        self.data["signal"] = signal_name
        self.data["reason"] = f"interrupted by {signal_name}"
        self.data["stopped_at_s"] = None if stopped_at_s is None else round(float(stopped_at_s), 12)
        self._finish(sim_time_s)
        self.write_final()
