"""Recording of every frame with python-can's own ``Logger`` in simulated time.

The hot loop packs each sent frame into a 32-byte record (timestamp, id, flags, dlc,
up to 20 data bytes: the CAN FD RPDO1 is the longest telegram) - the network reuses its message objects, so they are copied here. Every
``flush_every_cycles`` cycles the records are handed to a sink that sorts them by
timestamp (late frames may have been sent out of time order) and writes those older
than a watermark with ``can.Logger`` (``.blf``, ``.asc`` or any other format python-can
writes), so the file is in timestamp order and ``can.LogReader``,
``python -m can.player`` and ``python -m can.viewer`` read it.

With ``background=True`` the sink runs in a separate process fed through a pipe, so
creating messages and encoding BLF objects (about 4 µs per frame) does not cost the
simulation loop.
"""
from __future__ import annotations

import functools
import multiprocessing
import struct
from pathlib import Path
from typing import Any

import can
import numpy as np

from fieldbus.codec import load_codec
from fieldbus.errors import FieldbusConfigError
from fieldbus.lifecycle import Closeable
from fieldbus.telegrams import FastMessage

RECORD = struct.Struct("<dHBB20s")  # timestamp, id, is_error_frame, dlc, data (padded; at most 20 bytes)


def record_struct(data_bytes: int = 20) -> struct.Struct:
    """The record for frames of up to ``data_bytes`` (20; 64 where PReqs carry a set-point look-ahead)."""
    return RECORD if data_bytes == 20 else struct.Struct(f"<dHBB{data_bytes}s")


LOG_SUFFIXES = (".parquet", ".blf", ".asc", ".log", ".csv", ".trc", ".txt", ".mf4")


class _LogSink:
    """Sorts records and writes them with can.Logger up to a watermark time."""

    def __init__(self, path: str, data_bytes: int = 20) -> None:
        self.logger = can.Logger(path)
        self.pending: list[tuple[float, int, bool, bytes]] = []
        self.written = 0
        self._record = record_struct(data_bytes)

    @staticmethod
    def open(path: str, data_bytes: int = 20) -> "_LogSink | _BlfSink":
        """The sink for ``path``: the columnar CAN log (``.parquet``) through
        :class:`fieldbus.canlog.CanLogWriter`, BLF through :class:`fieldbus.blf.BlfRecordWriter`
        (the same bytes as python-can's writer, a batch at a time), any other format through
        can.Logger."""
        suffix = Path(path).suffix.lower()
        if suffix in (".parquet", ".blf"):
            return _BlfSink(path, data_bytes, columnar=suffix == ".parquet")
        return _LogSink(path, data_bytes)

    def feed(self, records: bytes, watermark_s: float | None, cycles: np.ndarray | None = None) -> None:
        # (python-can's formats have no place for the cell's cycle: ``cycles`` is not kept)
        self.pending.extend((t, i, bool(e), d[:n]) for t, i, e, n, d in self._record.iter_unpack(records))
        pending = self.pending
        pending.sort(key=lambda r: r[0])
        count = len(pending)
        if watermark_s is not None:
            while count and pending[count - 1][0] >= watermark_s:
                count -= 1
        write = self.logger.on_message_received
        for timestamp, arbitration_id, is_error, data in pending[:count]:
            # a standard data frame as can.Message(timestamp=..., arbitration_id=..., is_extended_id=False,
            # data=..., is_error_frame=..., is_fd=len(data) > 8) makes it, through the lean constructor
            # (half the cost)
            write(FastMessage(timestamp, arbitration_id, bytearray(data), is_error))
        del pending[:count]
        self.written += count

    def close(self) -> None:
        self.feed(b"", None)
        self.logger.stop()


class _BlfSink:
    """:class:`_LogSink` for ``.blf`` and columnar ``.parquet`` logs with array operations: the
    records are sorted by timestamp (stably, as ``list.sort``) and those older than the
    watermark written by :class:`fieldbus.blf.BlfRecordWriter` (the bytes ``can.Logger`` would
    write) or, ``columnar``, :class:`fieldbus.canlog.CanLogWriter` (the same frames)."""

    def __init__(self, path: str, data_bytes: int = 20, columnar: bool = False) -> None:
        from fieldbus.canlog import CanLogWriter, record_dtype

        self._dtype = record_dtype(data_bytes)
        self._void = np.dtype((np.void, self._dtype.itemsize))
        if columnar:
            self.writer = CanLogWriter(path, data_bytes=data_bytes)
        else:
            from fieldbus.blf import BlfRecordWriter

            self.writer = BlfRecordWriter(path)
        self.columnar = columnar
        self.pending = np.empty(0, dtype=self._void)
        self.pending_cycles = np.empty(0, dtype=np.int64)
        self.written = 0

    def feed(self, records: bytes, watermark_s: float | None, cycles: np.ndarray | None = None) -> None:
        """Take ``records`` and their cell ``cycles`` (int64, one per record; None: -1, not known)
        and write those older than ``watermark_s`` (all: None)."""
        void = self._void  # whole records: copies and takes at memcpy speed (numpy's structured ones are ~8x slower)
        new = np.frombuffer(records, dtype=void)
        pending = np.concatenate([self.pending, new]) if self.pending.size else new
        if self.columnar:  # the cycles travel with their records
            new_cycles = np.full(new.size, -1, dtype=np.int64) if cycles is None else np.asarray(cycles, dtype=np.int64)
            pending_cycles = (np.concatenate([self.pending_cycles, new_cycles]) if self.pending_cycles.size
                              else new_cycles)
        t = pending.view(self._dtype)["t"]
        if t.size > 1 and not (t[1:] >= t[:-1]).all():  # a cycle's frames interleave: sort (stably, as list.sort)
            order = np.argsort(t, kind="stable")
            pending = pending[order]
            if self.columnar:
                pending_cycles = pending_cycles[order]
            t = pending.view(self._dtype)["t"]
        count = pending.size if watermark_s is None else int(np.searchsorted(t, watermark_s, "left"))
        if self.columnar:
            self.written += _whole(self.writer.write_records, pending[:count].view(self._dtype), pending_cycles[:count])
            self.pending_cycles = pending_cycles[count:].copy()
        else:
            self.written += _whole(self.writer.write_records, pending[:count].view(self._dtype))
        self.pending = pending[count:].copy()

    def close(self) -> None:
        self.feed(b"", None)
        self.writer.close()


def _whole(function: Any, *args: Any) -> Any:
    """``function(*args)`` with SIGINT and SIGTERM held back until it returns (delivered right
    after): a KeyboardInterrupt between the writes of one BLF object would leave half of it in
    the file, and every object written after it (at close) unreadable."""
    import signal

    mask = getattr(signal, "pthread_sigmask", None)
    if mask is None:
        return function(*args)
    previous = mask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        return function(*args)
    finally:
        mask(signal.SIG_SETMASK, previous)


def _send_whole(connection: Any, message: Any) -> None:
    """``connection.send(message)`` with SIGINT and SIGTERM held back until it is complete: a
    KeyboardInterrupt in the middle of a large message would leave half of it in the pipe and
    the writer could not read another message. The signal is delivered right after."""
    import signal

    mask = getattr(signal, "pthread_sigmask", None)
    if mask is None:
        connection.send(message)
        return
    previous = mask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        connection.send(message)
    finally:
        mask(signal.SIG_SETMASK, previous)


def _writer_process(path: str, connection: Any, data_bytes: int = 20) -> None:
    """Child process: feed (records, watermark) batches to a sink until None arrives.

    It ignores SIGINT and SIGTERM: Ctrl-C in a terminal reaches the whole process group, and
    the writer must outlive the simulation loop to write what it was sent; the parent shuts it
    down (None), and a parent that dies closes the pipe (EOFError ends the loop)."""
    import signal

    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, signal.SIG_IGN)
    sink = _LogSink.open(path, data_bytes)
    connection.send("ready")  # imports done, file open: FrameRecorder.wait_ready
    try:
        while True:
            try:
                batch = connection.recv()
            except (EOFError, OSError):  # the parent is gone (or died mid-message): keep what was written
                break
            if batch is None:
                break
            sink.feed(*batch)
    finally:
        sink.close()
        try:
            connection.send(sink.written)
        except OSError:
            pass
        connection.close()


class FrameRecorder(Closeable):
    """Collects sent frames and writes them, time-ordered, with ``can.Logger``.

    Each frame's cell cycle is the ``cycle`` of the next :meth:`end_cycle` call after it was
    added (the cycle it was sent or taken in); the columnar log keeps it in its ``cycle`` column.

    Args:
        path: log file; the suffix selects the format (.blf, .asc, ...).
        flush_every_cycles: hand-over period in cycles.
        background: run the Logger in a child process.
    """

    def __init__(self, path: str | Path, flush_every_cycles: int = 250, background: bool = False,
                 data_bytes: int = 20) -> None:
        self.path = Path(path)
        if self.path.suffix.lower() not in LOG_SUFFIXES:
            raise FieldbusConfigError(str(self.path), "log_path", str(self.path),
                                      "a log file ending in .parquet (columnar), .blf or .asc (or another python-can Logger format: "
                                      + ", ".join(LOG_SUFFIXES) + ")")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.flush_every_cycles = flush_every_cycles
        self.background = background
        self._records = bytearray()  # the records since the last flush, in the order they were added
        # records hold frames of up to data_bytes (20: the plain RPDO1; 64 with a set-point look-ahead)
        self.data_bytes = data_bytes
        self._record_struct = record_struct(data_bytes)
        codec = load_codec() if data_bytes == 20 else None  # compiled packing: 20-byte records only
        self._pack_records = getattr(codec, "pack_records", None)
        append = getattr(codec, "pack_records_append", None)
        if append is not None:
            # add_many as one compiled call appending to the records (no Python frame, no bytes
            # object per call): the same bytes as the method below, which stays the reference
            self.add_many = functools.partial(append, self._records, self._add_packed)  # type: ignore[method-assign]
        self.frames_recorded = 0
        self.frames_written = 0
        # (bytes of records at an end_cycle, its cycle) since the last flush: the records' cell cycles
        self._cycle_ends: list[tuple[int, int]] = []
        self._next_cycle = 0  # the cycle of records added after the last end_cycle
        self._sink: _LogSink | _BlfSink | None = None
        if background:
            context = multiprocessing.get_context("spawn")
            receiver, self._conn = context.Pipe(duplex=True)
            self._process = context.Process(target=_writer_process, args=(str(self.path), receiver, data_bytes),
                                            name="fieldbus-recorder", daemon=True)
            self._process.start()
            receiver.close()
        else:
            self._sink = _LogSink.open(str(self.path), data_bytes)
        self._ready = not background

    def wait_ready(self, timeout_s: float = 60.0) -> bool:
        """Wait until a background writer has started (its interpreter and python-can are
        loaded): a real-time loop calls this before its first cycle, so the first hand-over
        does not stall on a writer that is still starting. True when ready."""
        if not self._ready and self._conn.poll(timeout_s):
            self._ready = self._conn.recv() == "ready"
        return self._ready

    def add_many(self, frames: list) -> None:
        """Record sent frames (copied: the senders reuse their message objects)."""
        if self._pack_records is not None:
            records = self._pack_records(frames)  # the same bytes, in one call
            if records is not None:
                self._records += records
                return
        self._add_packed(frames)

    def _add_packed(self, frames: list) -> None:
        """:meth:`add_many` in Python (``struct.error`` for a value that does not fit a record)."""
        pack = self._record_struct.pack
        self._records += (b"".join([pack(m.timestamp, m.arbitration_id, m.is_error_frame, len(m.data), m.data)
                                       for m in frames]))

    def end_cycle(self, cycle: int, watermark_s: float) -> None:
        """Called once per cycle, after the cycle's frames were added (they are this ``cycle``'s);
        hands over frames older than ``watermark_s`` periodically."""
        self._cycle_ends.append((len(self._records), cycle))
        if cycle % self.flush_every_cycles == 0:
            self.flush(watermark_s)

    def flush(self, watermark_s: float | None = None) -> None:
        """Hand all records over; those with timestamp < ``watermark_s`` (all if None)
        are written, later ones wait for the next flush."""
        records = bytes(self._records)
        self._records.clear()  # in place: the compiled add_many holds this bytearray
        size = self._record_struct.size
        cycles = self._take_cycles(len(records) // size, size)
        self.frames_recorded += len(records) // size
        if self._sink is not None:
            self._sink.feed(records, watermark_s, cycles)
            self.frames_written = self._sink.written
            return
        try:
            _send_whole(self._conn, (records, watermark_s, cycles))
        except (BrokenPipeError, OSError) as error:
            raise RuntimeError(f"fieldbus recorder process for {self.path} died: {error}") from error

    def _take_cycles(self, count: int, size: int) -> np.ndarray:
        """The cell cycle of each of the ``count`` records handed over now (int64)."""
        ends = self._cycle_ends
        if not ends:
            return np.full(count, self._next_cycle, dtype=np.int64)
        marks = np.array(ends, dtype=np.int64)
        self._cycle_ends = []
        self._next_cycle = int(marks[-1, 1]) + 1
        bounds = np.append(marks[:, 0] // size, count)
        values = np.append(marks[:, 1], self._next_cycle)
        return np.repeat(values, np.diff(bounds, prepend=0))

    def _release(self) -> None:
        """Write everything and close the file."""
        self.flush(None)
        if self._sink is not None:
            self._sink.close()
            self.frames_written = self._sink.written
            return
        _send_whole(self._conn, None)
        self.wait_ready(60.0)
        if self._conn.poll(60):
            self.frames_written = self._conn.recv()
        self._conn.close()
        self._process.join(timeout=30)
        if self._process.exitcode != 0:
            raise RuntimeError(f"fieldbus recorder process for {self.path} exited with {self._process.exitcode}")
