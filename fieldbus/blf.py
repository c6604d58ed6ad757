"""The CAN log as a BLF file, encoded with numpy a batch at a time: the same bytes python-can's
``can.io.blf.BLFWriter`` writes for the same frames, at a small part of its cost.

python-can's writer packs every frame with ``struct`` into a ``CAN_MESSAGE`` (classic frame),
``CAN_FD_MESSAGE`` (more than 8 data bytes) or ``CAN_ERROR_EXT`` object (a 32-byte object
header with the time since the log's start in ns, then the frame), joins them into a stream
that is cut into 128 KiB pieces, each deflated with zlib into a ``LOG_CONTAINER`` object, and
writes a file header with sizes, the object count and the start/stop times at the end. At
about 4 µs per frame, for the 19 frames of each 400 µs POWERLINK cycle that is more than the
whole closed loop costs. :class:`BlfRecordWriter` builds the objects of a whole batch of
frames with array operations and cuts and deflates the stream the same way, so the file is
byte for byte the one ``BLFWriter`` makes (``tests/fieldbus/test_blf.py`` compares them) and
``can.LogReader``, ``python -m can.player`` and Vector's tools read it.

The frames come as the :class:`fieldbus.recorder.FrameRecorder`'s 32-byte records
(timestamp, id, error flag, length, 20 data bytes), the way the recorder hands them over; the
frames python-can writes for them are those :class:`fieldbus.telegrams.FastMessage` makes:
standard 11-bit id, received (no ``DIR`` flag), channel 1, no bit-rate switch. :func:`to_blf`
writes a columnar CAN log (:mod:`fieldbus.canlog`, which this module builds on) as that BLF file.
"""
from __future__ import annotations

import contextlib
import signal
import zlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from can.io.blf import (CAN_ERROR_EXT, CAN_FD_MESSAGE, CAN_MESSAGE, EDL, FILE_HEADER_SIZE, FILE_HEADER_STRUCT,
                        LOG_CONTAINER, LOG_CONTAINER_STRUCT, NO_COMPRESSION, OBJ_HEADER_BASE_STRUCT, TIME_ONE_NANS,
                        ZLIB_DEFLATE, BLFWriter, timestamp_to_systemtime)
from can.util import len2dlc

from fieldbus.canlog import (MAX_DATA, RECORD_DTYPE, blf_nanoseconds, blf_start,  # noqa: E402,F401
                             read_frames, record_dtype)  # (the recorder's records; python-can's BLF times)
#: python-can's defaults: uncompressed bytes per container, zlib level, application id, channel.
CONTAINER_SIZE = BLFWriter.max_container_size
DEFAULT_COMPRESSION = -1
CHANNEL = 1

_HEADER = [("signature", "S4"), ("header_size", "<u2"), ("header_version", "<u2"), ("object_size", "<u4"),
           ("object_type", "<u4"), ("flags", "<u4"), ("client_index", "<u2"), ("object_version", "<u2"),
           ("timestamp", "<u8")]
#: One whole object (32-byte header + frame) per kind, laid out as python-can's structs pack them.
_CAN = np.dtype(_HEADER + [("channel", "<u2"), ("msg_flags", "u1"), ("dlc", "u1"), ("id", "<u4"),
                           ("data", "u1", (8,))])                                     # CAN_MSG_STRUCT
_FD = np.dtype(_HEADER + [("channel", "<u2"), ("msg_flags", "u1"), ("dlc", "u1"), ("id", "<u4"),
                          ("frame_length", "<u4"), ("bit_count", "u1"), ("fd_flags", "u1"),
                          ("valid_bytes", "u1"), ("reserved", "V5"), ("data", "u1", (64,))])  # CAN_FD_MSG_STRUCT
_ERROR = np.dtype(_HEADER + [("channel", "<u2"), ("length", "<u2"), ("err_flags", "<u4"), ("ecc", "u1"),
                             ("position", "u1"), ("dlc", "u1"), ("reserved1", "V1"), ("frame_length", "<u4"),
                             ("id", "<u4"), ("ext_flags", "<u2"), ("reserved2", "V2"),
                             ("data", "u1", (8,))])                                   # CAN_ERROR_EXT_STRUCT
_HEADER_SIZE = 32
_DLC = np.array([len2dlc(n) for n in range(64 + 1)], dtype=np.uint8)


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM wait (they are delivered when the block ends); as is where unavailable."""
    mask = getattr(signal, "pthread_sigmask", None)
    if mask is None:
        yield
        return
    previous = mask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        yield
    finally:
        mask(signal.SIG_SETMASK, previous)


def _objects(kind: np.dtype, object_type: int, ids: np.ndarray, nanoseconds: np.ndarray) -> np.ndarray:
    """The objects of frames with ``ids`` (all of one kind) as rows of bytes, the header filled in."""
    out = np.zeros(ids.size, dtype=kind)
    out["signature"] = b"LOBJ"
    out["header_size"] = _HEADER_SIZE
    out["header_version"] = 1
    out["object_size"] = kind.itemsize
    out["object_type"] = object_type
    out["flags"] = TIME_ONE_NANS
    out["timestamp"] = nanoseconds
    out["channel"] = CHANNEL
    out["id"] = ids
    return out


class BlfRecordWriter:
    """Writes recorder records to a BLF file (``.blf``), the bytes python-can's ``BLFWriter``
    would write for the same frames, and with its defaults (128 KiB containers, zlib's default
    level, application id 5, channel 1).

    Args:
        path: the file (created or replaced).
        compression_level: zlib level of the containers, -1 (zlib's default, python-can's) to 9;
            0 stores them uncompressed.
    """

    def __init__(self, path: str | Path, compression_level: int = DEFAULT_COMPRESSION) -> None:
        self.path = Path(path)
        self.compression_level = compression_level
        self._file = open(self.path, "wb")  # noqa: SIM115 - closed by close()
        self._pending = bytearray()
        self.object_count = 0
        self.uncompressed_size = FILE_HEADER_SIZE
        self.start_timestamp: float | None = None
        self.stop_timestamp: float | None = None
        self._write_header(FILE_HEADER_SIZE)

    # ------------------------------------------------------------------ frames
    def write_records(self, records: bytes | np.ndarray) -> int:
        """Append frames given as recorder records, in the order given; returns their number."""
        rec = np.frombuffer(records, dtype=RECORD_DTYPE) if not isinstance(records, np.ndarray) else records
        count = rec.size
        if count == 0:
            return 0
        t = rec["t"]
        if self.start_timestamp is None:  # python-can: the first frame's time, truncated to ms
            self.start_timestamp = blf_start(t[0])
        self.stop_timestamp = float(t[-1])
        return self.write_frames(blf_nanoseconds(t, self.start_timestamp), rec["id"], rec["error"], rec["length"],
                                 rec["data"])

    def write_frames(self, nanoseconds: np.ndarray, ids: np.ndarray, error: np.ndarray, length: np.ndarray,
                     data: np.ndarray) -> int:
        """Append frames given as columns: BLF object time (ns since :attr:`start_timestamp`,
        which the caller sets, and :attr:`stop_timestamp`, before the first frame), arbitration
        id, error flag, data length and (n, 20 or 64) data bytes; returns their number."""
        count = int(np.size(ids))
        if count == 0:
            return 0
        nanoseconds = np.asarray(nanoseconds, dtype=np.uint64)
        ids = np.asarray(ids)
        data = np.asarray(data, dtype=np.uint8)
        width = data.shape[1]  # 20 data bytes, 64 with a set-point look-ahead
        length = np.minimum(np.asarray(length), width)
        error = np.asarray(error) != 0
        fd = ~error & (length > 8)
        classic = ~error & ~fd
        sizes = np.where(error, _ERROR.itemsize, np.where(fd, _FD.itemsize, _CAN.itemsize))
        offsets = np.zeros(count, dtype=np.int64)
        np.cumsum(sizes[:-1], out=offsets[1:])
        stream = np.empty(int(offsets[-1] + sizes[-1]), dtype=np.uint8)
        for mask, kind, object_type in ((classic, _CAN, CAN_MESSAGE), (fd, _FD, CAN_FD_MESSAGE),
                                        (error, _ERROR, CAN_ERROR_EXT)):
            if not mask.any():
                continue
            n = length[mask]
            objects = _objects(kind, object_type, ids[mask], nanoseconds[mask])
            keep = np.arange(width) < n[:, None]  # data beyond the frame's length are zero
            payload = np.where(keep, data[mask], 0).astype(np.uint8)
            room = objects["data"].shape[1]
            objects["data"][:, :min(room, width)] = payload[:, :room]
            if kind is _CAN:
                objects["dlc"] = n  # CAN_MSG_STRUCT: msg.dlc
            elif kind is _FD:
                objects["dlc"] = _DLC[n]
                objects["fd_flags"] = EDL
                objects["valid_bytes"] = n
            else:
                objects["dlc"] = _DLC[n]  # CAN_ERROR_EXT_STRUCT: len2dlc(msg.dlc)
            rows = objects.view(np.uint8).reshape(n.size, kind.itemsize)
            index = offsets[mask][:, None] + np.arange(kind.itemsize)
            stream[index] = rows
        self._pending += stream.tobytes()
        self.object_count += count
        while len(self._pending) >= CONTAINER_SIZE:
            self._write_container(CONTAINER_SIZE)
        return count

    # ------------------------------------------------------------------ file
    def _write_container(self, size: int) -> None:
        """Deflate the first ``size`` pending bytes into one LOG_CONTAINER (python-can's ``_flush``),
        written in one piece with SIGINT/SIGTERM held back: a Ctrl-C can neither leave half a
        container in the file nor write one twice (the file stays readable up to the stop)."""
        with _signals_held():
            with memoryview(self._pending)[:size] as chunk:
                if self.compression_level:
                    data = zlib.compress(chunk, self.compression_level)
                    method = ZLIB_DEFLATE
                else:
                    data = bytes(chunk)
                    method = NO_COMPRESSION
            object_size = OBJ_HEADER_BASE_STRUCT.size + LOG_CONTAINER_STRUCT.size + len(data)
            self._file.write(b"".join([
                OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", OBJ_HEADER_BASE_STRUCT.size, 1, object_size, LOG_CONTAINER),
                LOG_CONTAINER_STRUCT.pack(method, size), data, b"\x00" * (object_size % 4)]))  # python-can's padding
            self.uncompressed_size += OBJ_HEADER_BASE_STRUCT.size + LOG_CONTAINER_STRUCT.size + size
            del self._pending[:size]

    def _write_header(self, file_size: int) -> None:
        header = [b"LOGG", FILE_HEADER_SIZE, BLFWriter.application_id, 0, 0, 0, 2, 6, 8, 1,
                  file_size, self.uncompressed_size, self.object_count, 0]
        header.extend(timestamp_to_systemtime(self.start_timestamp))
        header.extend(timestamp_to_systemtime(self.stop_timestamp))
        self._file.write(FILE_HEADER_STRUCT.pack(*header))
        self._file.write(b"\x00" * (FILE_HEADER_SIZE - FILE_HEADER_STRUCT.size))

    def close(self) -> None:
        """Write the last container and the final header; close the file (again: no-op)."""
        if self._file.closed:
            return
        try:
            if self._pending:
                self._write_container(len(self._pending))
            size = self._file.tell()
            self._file.seek(0)
            self._write_header(size)
        finally:
            self._file.close()


def to_blf(path: str | Path, out: str | Path, chunk: int = 1 << 16) -> Path:
    """Write the CAN log ``path`` (columnar, or its partial stream) as the BLF file ``out``: the
    bytes python-can's ``BLFWriter`` writes for the same frames. Returns ``out``."""
    log = read_frames(path)
    out = Path(out)
    writer = BlfRecordWriter(out)
    try:
        if log.frames.size:
            writer.start_timestamp = log.start_s
            writer.stop_timestamp = log.stop_s
            for begin in range(0, log.frames.size, chunk):
                f = log.frames[begin:begin + chunk]
                writer.write_frames(f["t_ns"].astype(np.uint64), f["id"], f["error"], f["length"], f["data"])
    finally:
        writer.close()
    return out
