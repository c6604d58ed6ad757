"""Recording of every frame with python-can's own ``Logger`` in simulated time.

The hot loop only appends (timestamp, id, data, is_error_frame) tuples of the sent
frames to a list (the network reuses its message objects, so they are copied here). Every
``flush_every_cycles`` cycles the list is sorted by timestamp (late frames may have
been sent out of time order) and handed to ``can.Logger`` (``.blf``, ``.asc`` or any
other format python-can writes), up to a watermark time so that a frame still in
flight is written after the ones before it: the file is in timestamp order and
``can.LogReader``, ``python -m can.player`` and ``python -m can.viewer`` read it.

With ``background=True`` the Logger runs in a separate process fed through a pipe,
so encoding BLF objects does not cost the simulation loop (2-3 µs per frame).
"""
from __future__ import annotations

import multiprocessing
from operator import itemgetter
from pathlib import Path
from typing import Any

import can

from fieldbus.errors import FieldbusConfigError

_BY_TIME = itemgetter(0)


def _open_logger(path: str) -> can.io.generic.MessageWriter:
    return can.Logger(path)


def _write(logger: can.io.generic.MessageWriter, batch: list[tuple[float, int, bytes, bool]]) -> None:
    write = logger.on_message_received
    for timestamp, arbitration_id, data, is_error in batch:
        write(can.Message(timestamp=timestamp, arbitration_id=arbitration_id, is_extended_id=False,
                          data=data, is_error_frame=is_error))


def _writer_process(path: str, connection: Any) -> None:
    """Child process: receive batches of (timestamp, id, data, is_error) and log them."""
    logger = _open_logger(path)
    try:
        while True:
            batch = connection.recv()
            if batch is None:
                break
            _write(logger, batch)
    finally:
        logger.stop()
        connection.close()


class FrameRecorder:
    """Collects sent frames and writes them, time-ordered, with ``can.Logger``.

    Args:
        path: log file; the suffix selects the format (.blf, .asc, ...).
        flush_every_cycles: hand-over period in cycles.
        background: run the Logger in a child process.
    """

    def __init__(self, path: str | Path, flush_every_cycles: int = 250, background: bool = False) -> None:
        self.path = Path(path)
        suffix = self.path.suffix.lower()
        if suffix not in (".blf", ".asc", ".log", ".csv", ".trc", ".txt", ".mf4"):
            raise FieldbusConfigError(str(self.path), "recording.path", str(self.path),
                                      "a log file ending in .blf or .asc (or another python-can Logger format)")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.flush_every_cycles = flush_every_cycles
        self.background = background
        self.pending: list[tuple[float, int, bytes, bool]] = []
        self.frames_written = 0
        self._closed = False
        if background:
            context = multiprocessing.get_context("spawn")
            child_conn, self._conn = context.Pipe(duplex=False)  # (receiving end, sending end)
            self._process = context.Process(target=_writer_process, args=(str(self.path), child_conn),
                                            name="fieldbus-recorder", daemon=True)
            self._process.start()
            child_conn.close()
            self._logger = None
        else:
            self._logger = _open_logger(str(self.path))

    def add_many(self, frames: list) -> None:
        """Record sent frames (copied: the senders reuse their message objects)."""
        self.pending.extend([(m.timestamp, m.arbitration_id, bytes(m.data), m.is_error_frame) for m in frames])

    def end_cycle(self, cycle: int, watermark_s: float) -> None:
        """Called once per cycle; flushes frames older than ``watermark_s`` periodically."""
        if cycle % self.flush_every_cycles == 0:
            self.flush(watermark_s)

    def flush(self, watermark_s: float | None = None) -> None:
        """Write all pending frames with timestamp < ``watermark_s`` (all if None)."""
        pending = self.pending
        if not pending:
            return
        pending.sort(key=_BY_TIME)
        if watermark_s is None:
            count = len(pending)
        else:
            count = len(pending)
            while count and pending[count - 1][0] >= watermark_s:
                count -= 1
        if not count:
            return
        batch = pending[:count]
        del pending[:count]
        if self._logger is not None:
            _write(self._logger, batch)
        else:
            try:
                self._conn.send(batch)
            except (BrokenPipeError, OSError) as error:
                raise RuntimeError(f"fieldbus recorder process for {self.path} died: {error}") from error
        self.frames_written += count

    def close(self) -> None:
        """Write everything and close the file (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self.flush(None)
        if self._logger is not None:
            self._logger.stop()
        else:
            self._conn.send(None)
            self._conn.close()
            self._process.join(timeout=30)
            if self._process.exitcode != 0:
                raise RuntimeError(f"fieldbus recorder process for {self.path} exited with {self._process.exitcode}")
