"""Last words of a run: the final status a supervising process writes when the run's process dies.

``python -m cosim run/serve/sweep`` runs the command in a child process watched by a small
supervisor (``cosim/commands/supervisor.py``). Before it forks, the supervisor creates this
table in anonymous shared memory; the run's process (the child) keeps in it, for every status
file it holds at ``"running"`` (``summary.json``, a sweep's ``sweep.json``), the file's path and
the status it would leave if it died at this moment: its running summary plus where it is (the
mode, the simulated time of the last progress). :class:`~cosim.results.summary.SummaryWriter`
publishes on every write and progress note (about every 0.2 s of wall time) and retracts the
entry when it writes a final status. Nothing goes to disk for this, and the table survives
whatever ends the child (SIGKILL, the out-of-memory killer, ``_exit()`` in an FMU): the
supervisor reads it after ``waitpid`` and writes ``failed`` into every file still ``running``.

Each slot holds two halves; a write fills the half not in use and then flips one byte, so a
child killed in the middle of a write leaves the previous complete entry. Only the process
that adopted the table (the run's process) publishes: a process forked from it (a worker)
does not overwrite the run's entries.
"""
from __future__ import annotations

import json
import math
import mmap
import os
import struct
import time
from pathlib import Path
from typing import Any

SLOTS = 16
"""Status files one run can hold at "running" at once."""
HALF_BYTES = 1 << 17
"""Largest entry (JSON) kept per slot; a bigger summary is trimmed (its longest lists first)."""
_HEADER = struct.Struct("<BBxxII4x")  # used, current half, length of half 0, length of half 1
_CLOCK = struct.Struct("<dd")  # after the header: sim_time_s, stopped_at_s of the latest progress
_HEAD_BYTES = _HEADER.size + _CLOCK.size
_FAREWELL = struct.Struct("<Bxxxi")  # the command returned (1), its exit code
_SLOT_BYTES = _HEAD_BYTES + 2 * HALF_BYTES

_table: "Table | None" = None
_owner: int | None = None
_slots: dict[str, int] = {}


class Table:
    """The shared table (anonymous shared memory: visible to the process that created it and to
    every process forked after)."""

    def __init__(self, slots: int = SLOTS) -> None:
        self.slots = int(slots)
        # MAP_SHARED | MAP_ANONYMOUS, zero-filled; after the slots, the command's farewell (flag, exit code)
        self.memory = mmap.mmap(-1, self.slots * _SLOT_BYTES + _FAREWELL.size)

    def _header(self, slot: int) -> tuple[int, int, int, int]:
        return _HEADER.unpack_from(self.memory, slot * _SLOT_BYTES)

    def write(self, slot: int, blob: bytes) -> None:
        """Put ``blob`` into the unused half of ``slot``, then make it the current one."""
        used, current, len0, len1 = self._header(slot)
        half = 1 - current if used else 0
        base = slot * _SLOT_BYTES + _HEAD_BYTES + half * HALF_BYTES
        self.memory[base:base + len(blob)] = blob
        lengths = [len0, len1]
        lengths[half] = len(blob)
        _HEADER.pack_into(self.memory, slot * _SLOT_BYTES, 1, half, *lengths)

    def clock(self, slot: int, sim_time_s: float, stopped_at_s: float) -> None:
        """The latest progress of ``slot`` (two doubles: cheap enough for every heartbeat)."""
        _CLOCK.pack_into(self.memory, slot * _SLOT_BYTES + _HEADER.size, sim_time_s, stopped_at_s)

    def say_farewell(self, code: int) -> None:
        _FAREWELL.pack_into(self.memory, self.slots * _SLOT_BYTES, 1, int(code))

    def farewell(self) -> int | None:
        """The exit code the command returned, if it returned (None: it never got there)."""
        said, code = _FAREWELL.unpack_from(self.memory, self.slots * _SLOT_BYTES)
        return code if said else None

    def clear(self, slot: int) -> None:
        self.memory[slot * _SLOT_BYTES] = 0

    def entries(self) -> list[dict[str, Any]]:
        """Every published entry (``path``, ``data``, ``also``, ``monotonic``)."""
        found = []
        for slot in range(self.slots):
            used, current, len0, len1 = self._header(slot)
            if not used:
                continue
            length = (len0, len1)[current]
            base = slot * _SLOT_BYTES + _HEAD_BYTES + current * HALF_BYTES
            try:
                entry = json.loads(bytes(self.memory[base:base + length]).decode("utf-8"))
            except ValueError:  # cannot happen with the two halves; never let it stop the others
                continue
            sim, at = _CLOCK.unpack_from(self.memory, slot * _SLOT_BYTES + _HEADER.size)
            data = entry.get("data")
            if isinstance(data, dict) and math.isfinite(sim):
                data["sim_time_s"] = sim
                data["stopped_at_s"] = at if math.isfinite(at) else data.get("stopped_at_s")
            found.append(entry)
        return found


def create(slots: int = SLOTS) -> Table:
    """Create the table (the supervisor, before it forks the run's process)."""
    global _table, _owner
    _table, _owner = Table(slots), None
    _slots.clear()
    return _table


def adopt() -> None:
    """Make this process (the run's process, just forked) the one that publishes into the table."""
    global _owner
    _owner = os.getpid()
    _slots.clear()


def active() -> bool:
    """Whether this process publishes (it runs under a supervisor)."""
    return _table is not None and _owner == os.getpid()


_ESSENTIAL = ("scenario", "job", "status", "started_at", "sim_time_s", "wall_time_s", "mode", "stopped_at_s")


def _encoded(entry: dict[str, Any]) -> bytes:
    """The entry as JSON of at most HALF_BYTES: long fields are left out first, then all but the essentials."""
    def dumps(value: Any) -> bytes:
        return json.dumps(value, allow_nan=False, default=str).encode("utf-8")

    blob = dumps(entry)
    if len(blob) <= HALF_BYTES:
        return blob
    data = {key: value if len(dumps(value)) <= 2000 else "(left out of the supervisor's copy: too long)"
            for key, value in entry["data"].items()}
    blob = dumps(dict(entry, data=data))
    if len(blob) <= HALF_BYTES:
        return blob
    return dumps(dict(entry, data={key: data[key] for key in _ESSENTIAL if key in data}))[:HALF_BYTES]


def _key(path: str | Path) -> str:
    text = os.fspath(path)
    return text if os.path.isabs(text) else os.path.abspath(text)


def publish(path: str | Path, data: dict[str, Any], also: tuple[str, ...] = ()) -> None:
    """Keep ``data`` (JSON-safe) as what ``path`` should say if this process died now.

    ``also``: glob patterns (relative to ``path``'s folder) of further status files that other
    processes write for this run (a sweep's variants): those still ``"running"`` are failed too.
    No-op without a supervisor.
    """
    if not active():
        return
    key = _key(path)
    slot = _slots.get(key)
    if slot is None:
        taken = set(_slots.values())
        free = [s for s in range(_table.slots) if s not in taken]
        if not free:
            return
        slot = _slots[key] = free[0]
    entry = {"path": key, "data": data, "also": list(also), "monotonic": time.monotonic()}
    _table.write(slot, _encoded(entry))
    sim, at = data.get("sim_time_s"), data.get("stopped_at_s")
    _table.clock(slot, float(sim) if isinstance(sim, (int, float)) else math.nan,
                 float(at) if isinstance(at, (int, float)) else math.nan)


def note_time(path: str | Path, sim_time_s: float, stopped_at_s: float) -> None:
    """The latest progress of the published ``path`` (simulated seconds in all, and the running
    part's own time): two doubles written in place, for every heartbeat. No-op without an entry."""
    if _table is None or _owner != os.getpid():
        return
    slot = _slots.get(_key(path))
    if slot is not None:
        _table.clock(slot, sim_time_s, stopped_at_s)


def farewell(code: int) -> None:
    """The command returned ``code`` normally (what is left ``running`` now is an oversight, not a death)."""
    if active():
        _table.say_farewell(code)


def retract(path: str | Path) -> None:
    """``path`` holds its final status: nothing to write for it any more."""
    if not active():
        return
    slot = _slots.pop(_key(path), None)
    if slot is not None:
        _table.clear(slot)


__all__ = ["HALF_BYTES", "SLOTS", "Table", "active", "adopt", "create", "farewell", "note_time", "publish", "retract"]
