"""The CAN log as a columnar Parquet table: every frame on the bus, smaller than BLF and
cheaper to write, and nothing lost - :func:`fieldbus.blf.to_blf` turns it into the very BLF file
(byte for byte) python-can's ``BLFWriter`` writes for the same frames.

File format (``can_<mode>.parquet``; readable with any Parquet reader, this module not needed)
-----------------------------------------------------------------------------------------------
One row per frame, every value as it is (standard Parquet types; integers delta-binary-packed,
zstd): pandas, pyarrow, polars or DuckDB read each frame right without this module. Rows are
stored in row groups of at most :data:`ROW_GROUP_ROWS` frames; inside a row group they are
sorted by arbitration id (stably; the row group's ``sorting_columns`` say so), so each
telegram's fields form long smooth runs that delta-encode to a few bits. ``seq`` is the
frame's position in the log: sort by it for the frames in log (time) order; ``cycle`` is the
cell's cycle of the frame (null where the writer did not know it). Columns:

=========================  =======  ============================================================
``seq``                    int64    position of the frame in the whole log (0, 1, ...: time order)
``t_ns``                   int64    the frame's time in ns since ``start_s`` (BLF's object time)
``cycle``                  int64    the cell's POWERLINK cycle in which the frame was on the bus (0, 1,
                                    ...: the cycle that sent or took it; the SYNC's ``sync_counter``
                                    is the byte on the wire, e.g. an external controller's counter)
``id``                     uint16   arbitration id (11-bit, standard frames)
``error``                  bool     error frame
``length``                 uint8    data bytes (0..20; more than 8: a CAN FD frame)
``data``                   binary   the payload, only for frames no layout below decodes (else null;
                                    e.g. RPDO1s of 32-64 bytes carrying a set-point look-ahead)
telegram fields            int      the payload decoded by the layout of the frame's id and length
                                    (null in rows of other telegrams), fieldbus.telegrams:
=========================  =======  ============================================================

==========================  ======  =======================================================================
frames                      length  fields (little endian, in payload order)
==========================  ======  =======================================================================
SYNC ``0x080``              1       ``sync_counter`` u8
EMCY ``0x081..0x0FF``       8       ``error_code`` u16, ``error_register`` u8, ``counter_id`` u8,
                                    ``counter_value`` u16, ``counter_threshold`` u16
TPDO1 ``0x181..0x1FF``      8       ``statusword`` u16, ``position_actual`` i32, ``torque_actual`` i16
RPDO1 ``0x201..0x27F``      20      ``controlword`` u16, ``target_position`` i32, ``torque_offset`` i16,
                                    ``modes_of_operation`` i8, ``reserved`` u8, ``target_torque`` i16,
                                    ``target_velocity`` i32, ``velocity_offset`` i32
RPDO1 classic               8       ``controlword``, ``target_position``, ``torque_offset``
TPDO2 ``0x281..0x2FF``      7       ``velocity_actual`` i32, ``error_code`` u16,
                                    ``modes_of_operation_display`` i8
==========================  ======  =======================================================================

Error frames and frames of any other id or length keep their payload in ``data``.

Time: the frame's time in seconds is ``start_s + t_ns / 1e9`` with ``start_s`` from the file's key-value metadata. ``t_ns`` is what
a BLF file stores (``int((t - start_s) * 1e9)``, python-can's conversion, ``start_s`` = the first
frame's time truncated to ms) and ``stop_s`` (metadata) the last frame's time, which BLF keeps
in its header. Metadata ``format`` = :data:`FORMAT`.

While a run goes, the frames stream in log order to ``<file>.partial`` (an uncompressed Arrow
IPC stream, :data:`PARTIAL_FORMAT`: one column ``record`` holding the recorder's whole records,
:data:`RECORD_DTYPE`): every complete batch stays readable after a crash (:func:`read_frames`
reads it). Each row group is encoded once, as it fills, into ``<file>.tmp`` (a Parquet file
without its footer); ``close()`` writes the last group and the footer, renames the file into
place and removes the stream.
"""
from __future__ import annotations

import functools
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import can

FORMAT = "rx130l-cosim CAN log 3"
FORMAT_2 = "rx130l-cosim CAN log 2"
"""Files of the previous version (still read): no ``cycle`` column."""
FORMAT_1 = "rx130l-cosim CAN log 1"
"""Files of earlier versions (still read): ``seq`` the position within the row group, ``dt_ns`` the
difference to the previous frame's ``t_ns`` instead of ``t_ns``."""
ROW_GROUP_ROWS = 1 << 17
"""Frames per row group (about 6900 cycles of 19 frames): memory while converting and reading
is one group (~6 MB); smaller groups cost more (4750: +60 %, 65536: +8 %)."""
PARTIAL_SUFFIX = ".partial"
COMPRESSION_LEVEL = 1
"""zstd level of the Parquet file (6: 1.4-1.9 % smaller for ~10-20 ms more CPU per 600 000 frames)."""
PARTIAL_COMPRESSION = None
"""Compression of the partial stream (None: uncompressed, the cheapest to write; it only lives while a run goes)."""
MAX_DATA = 20


def record_dtype(data_bytes: int = MAX_DATA) -> np.dtype:
    """The recorder's records (``fieldbus.recorder.record_struct``): time s, id, error flag,
    length, data (20 bytes; 64 where PReqs carry a set-point look-ahead)."""
    return np.dtype([("t", "<f8"), ("id", "<u2"), ("error", "u1"), ("length", "u1"), ("data", "u1", (data_bytes,))])


def frame_dtype(data_bytes: int = MAX_DATA) -> np.dtype:
    """Frames as :func:`read_frames` returns them: BLF time (ns since ``start_s``), id, error, length, data."""
    return np.dtype([("t_ns", "<i8"), ("id", "<u2"), ("error", "u1"), ("length", "u1"), ("data", "u1", (data_bytes,))])


RECORD_DTYPE = record_dtype()
FRAME_DTYPE = frame_dtype()

# (first id, last id, length) -> fields; from fieldbus.telegrams' structs
_RPDO1 = [("controlword", "<u2"), ("target_position", "<i4"), ("torque_offset", "<i2"), ("modes_of_operation", "i1"),
          ("reserved", "u1"), ("target_torque", "<i2"), ("target_velocity", "<i4"), ("velocity_offset", "<i4")]
LAYOUTS: tuple[tuple[int, int, int, np.dtype], ...] = tuple((lo, hi, n, np.dtype(fields)) for lo, hi, n, fields in (
    (0x080, 0x080, 1, [("sync_counter", "u1")]),
    (0x081, 0x0FF, 8, [("error_code", "<u2"), ("error_register", "u1"), ("counter_id", "u1"),
                       ("counter_value", "<u2"), ("counter_threshold", "<u2")]),
    (0x181, 0x1FF, 8, [("statusword", "<u2"), ("position_actual", "<i4"), ("torque_actual", "<i2")]),
    (0x201, 0x27F, 20, _RPDO1),
    (0x201, 0x27F, 8, _RPDO1[:3]),
    (0x281, 0x2FF, 7, [("velocity_actual", "<i4"), ("error_code", "<u2"), ("modes_of_operation_display", "i1")]),
))
FIELDS: dict[str, np.dtype] = {}
for _lo, _hi, _n, _dt in LAYOUTS:
    for _name in _dt.names:
        FIELDS.setdefault(_name, _dt[_name].newbyteorder("="))
INT_COLUMNS = ("seq", "t_ns", "cycle", "id", "length", *FIELDS)
CYCLE_DESCRIPTION = ("the cell's POWERLINK cycle (0, 1, ...) in which the frame was on the bus; the SYNC's "
                     "sync_counter is the counter byte on the wire (in a served run the controller's)")


def blf_start(t0: float) -> float:
    """python-can's BLF start time for a log whose first frame is at ``t0`` s (truncated to ms)."""
    return int(float(t0) * 1000) / 1000


def blf_nanoseconds(t: np.ndarray, start: float) -> np.ndarray:
    """python-can's BLF object time: ``int((t - start) * 1e9)``, at least 0 (int64)."""
    return np.maximum(np.trunc((np.asarray(t, dtype=float) - start) * 1e9), 0.0).astype(np.int64)


@functools.lru_cache(maxsize=None)
def _schema():
    import pyarrow as pa

    fields = [pa.field("seq", pa.int64()), pa.field("t_ns", pa.int64(), metadata={b"unit": b"ns"}),
              pa.field("cycle", pa.int64(), metadata={b"description": CYCLE_DESCRIPTION.encode()}),
              pa.field("id", pa.uint16()), pa.field("error", pa.bool_()), pa.field("length", pa.uint8()),
              pa.field("data", pa.binary())]
    fields += [pa.field(name, pa.from_numpy_dtype(dtype)) for name, dtype in FIELDS.items()]
    return pa.schema(fields)


PARTIAL_FORMAT = FORMAT_1 + " partial 3"
"""``format`` of the partial stream: a column ``record`` of whole recorder records and ``cycle``
(int64, the cell's cycle; -1: not known). Read too: ``partial 2`` (``record`` only) and the stream
of ``FORMAT_1 + " partial"`` (the columns ``t``, ``id``, ``error``, ``length``, ``data``)."""


def _partial_schema(data_bytes: int = MAX_DATA):
    import pyarrow as pa

    layout = f"<f8 t (s), <u2 id, u1 error, u1 length, {data_bytes} bytes data (the first length of them)"
    return pa.schema([pa.field("record", pa.binary(record_dtype(data_bytes).itemsize),
                               metadata={b"layout": layout.encode()}),
                      pa.field("cycle", pa.int64(), metadata={b"description": CYCLE_DESCRIPTION.encode()})],
                     metadata={b"format": PARTIAL_FORMAT.encode(), b"data_bytes": str(data_bytes).encode()})


def _layout_masks(ids: np.ndarray, error: np.ndarray, length: np.ndarray):
    """(mask, layout dtype) per layout for frames of that id range and length (no error frames)."""
    for lo, hi, n, dtype in LAYOUTS:
        mask = (ids >= lo) & (ids <= hi) & (length == n) & (error == 0)
        if mask.any():
            yield mask, dtype


class CanLogWriter:
    """Writes recorder records (:data:`RECORD_DTYPE`, in log order) to the columnar CAN log
    ``path``: streamed to ``<path>.partial`` as they come (what a crash leaves readable), and
    encoded into the Parquet file's row groups as they fill (``<path>.tmp``, no footer yet);
    :meth:`close` writes the last row group and the footer, renames the file into place and
    removes the stream. The same interface as :class:`fieldbus.blf.BlfRecordWriter`
    (``write_records``, ``close``)."""

    def __init__(self, path: str | Path, row_group_rows: int = ROW_GROUP_ROWS, data_bytes: int = MAX_DATA) -> None:
        import pyarrow as pa

        self.path = Path(path)
        self.data_bytes = int(data_bytes)
        self.partial = self.path.with_name(self.path.name + PARTIAL_SUFFIX)
        self.row_group_rows = int(row_group_rows)
        self.object_count = 0
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.path.unlink(missing_ok=True)
        self._schema = _partial_schema(self.data_bytes)
        # buffered: one write(2) per batch (flush below) instead of one per Arrow buffer
        self._file = pa.BufferedOutputStream(pa.OSFile(str(self.partial), "wb"), buffer_size=1 << 20)
        self._stream = pa.ipc.new_stream(self._file, self._schema,
                                         options=pa.ipc.IpcWriteOptions(compression=PARTIAL_COMPRESSION))
        self._file.flush()
        self._groups = _RowGroups(self.path, self.data_bytes)

    def write_records(self, records: bytes | np.ndarray, cycles: np.ndarray | None = None) -> int:
        """Append frames given as recorder records (in log order) and each one's cell cycle
        (``cycles``, int64; None or -1: not known, null in the file); returns their number."""
        import pyarrow as pa

        rec = (np.frombuffer(records, dtype=record_dtype(self.data_bytes)) if not isinstance(records, np.ndarray)
               else records)
        if rec.size == 0:
            return 0
        rec = np.ascontiguousarray(rec)
        cycles = _cycles_or_unknown(cycles, rec.size)
        whole = pa.FixedSizeBinaryArray.from_buffers(self._schema.field(0).type, rec.size,
                                                     [None, pa.py_buffer(rec.view(np.uint8))])
        self._stream.write_batch(pa.RecordBatch.from_arrays([whole, pa.array(cycles)], schema=self._schema))
        self._file.flush()
        self._groups.add(rec, self.row_group_rows, cycles)
        self.object_count += rec.size
        return rec.size

    def close(self) -> None:
        """Write the last row group and the footer, rename the file into place (atomic) and
        remove the stream (again: no-op). Should that fail, the stream stays (readable, and
        :func:`partial_to_parquet` turns it into the Parquet file)."""
        if self._stream is None:
            return
        try:
            self._stream.close()
        finally:
            self._file.close()
            self._stream = self._file = None
        self._groups.finish()
        self.partial.unlink(missing_ok=True)


def _cycles_or_unknown(cycles: np.ndarray | None, n: int) -> np.ndarray:
    """``cycles`` as n int64 values (-1 each where None)."""
    if cycles is None:
        return np.full(n, -1, dtype=np.int64)
    cycles = np.ascontiguousarray(cycles, dtype=np.int64)
    if cycles.size != n:
        raise ValueError(f"{cycles.size} cycle numbers for {n} frames")
    return cycles


class _RowGroups:
    """Recorder records (log order) encoded into the row groups of the columnar CAN log ``path``
    as they fill (written to ``<path>.tmp``); :meth:`finish` adds the metadata and renames."""

    def __init__(self, path: Path, data_bytes: int = MAX_DATA) -> None:
        self.path = Path(path)
        self.tmp = self.path.with_name(self.path.name + ".tmp")
        self.data_bytes = int(data_bytes)
        self.start: float | None = None
        self.stop: float | None = None
        self.frames = 0  # frames encoded so far: the next one's seq
        self._buffer = np.empty(0, dtype=record_dtype(self.data_bytes))
        self._cycles = np.empty(0, dtype=np.int64)
        self._rows = 0
        self._writer = None
        self._scratch: dict = {}

    def add(self, rec: np.ndarray, row_group_rows: int, cycles: np.ndarray | None = None) -> None:
        """Take ``rec`` and their ``cycles`` (copied; None: not known); encode and write every row
        group of ``row_group_rows`` that fills."""
        if rec.size == 0:
            return
        cycles = _cycles_or_unknown(cycles, rec.size)
        width = rec.dtype["data"].shape[0]
        if width != self.data_bytes:
            raise ValueError(f"records of {width} data bytes for a CAN log of {self.data_bytes}")
        if self.start is None:
            self.start = blf_start(rec["t"][0])
        self.stop = float(rec["t"][-1])
        if self._buffer.size != row_group_rows:
            self._encode()  # (a new group size: what is buffered forms its own group)
            self._buffer = np.empty(row_group_rows, dtype=rec.dtype)
            self._cycles = np.empty(row_group_rows, dtype=np.int64)
        size = rec.dtype.itemsize  # whole records as bytes: a memcpy (numpy's structured copy is ~8x slower)
        buffer, raw = self._buffer.view(np.uint8), np.ascontiguousarray(rec).view(np.uint8)
        while raw.size:
            take = min(raw.size // size, row_group_rows - self._rows)
            buffer[self._rows * size:(self._rows + take) * size] = raw[:take * size]
            self._cycles[self._rows:self._rows + take] = cycles[:take]
            self._rows += take
            raw = raw[take * size:]
            cycles = cycles[take:]
            if self._rows == row_group_rows:
                self._encode()

    def _encode(self) -> None:
        if not self._rows:
            return
        table = _encode_records(self._buffer[:self._rows], self.start, self.frames, self._scratch,
                                self._cycles[:self._rows])
        self.frames += self._rows
        if self._writer is None:
            self._writer = _parquet_writer(self.tmp, table.schema)
        self._writer.write_table(table, row_group_size=self._rows)
        self._rows = 0

    def finish(self) -> None:
        """The last row group, the metadata (format, start_s, stop_s, data_bytes), the footer;
        then the file renamed into place."""
        try:
            self._encode()
            if self._writer is None:
                self._writer = _parquet_writer(self.tmp, _schema())
            self._writer.add_key_value_metadata({
                "format": FORMAT, "start_s": repr(self.start if self.start is not None else 0.0),
                "stop_s": repr(self.stop if self.stop is not None else 0.0), "data_bytes": str(self.data_bytes)})
        finally:
            if self._writer is not None:
                self._writer.close()
                self._writer = None
        os.replace(self.tmp, self.path)


def _partial_records(partial: Path) -> Iterator[tuple[np.ndarray, np.ndarray | None]]:
    """The complete batches of a partial stream as record arrays and their cell cycles (None:
    a stream without them; -1: not known); a torn last batch is skipped."""
    import pyarrow as pa

    with pa.OSFile(str(partial), "rb") as source:
        try:
            reader = pa.ipc.open_stream(source)
            while True:
                batch = reader.read_next_batch()
                if not batch.num_rows:
                    continue
                if batch.schema.names[0] == "record":
                    whole = batch.column(0)
                    size = whole.type.byte_width
                    raw = np.frombuffer(whole.buffers()[1], dtype=np.uint8)
                    cycles = (batch.column(1).to_numpy(zero_copy_only=False).astype(np.int64)
                              if batch.num_columns > 1 else None)
                    yield raw[whole.offset * size:(whole.offset + len(whole)) * size].view(
                        record_dtype(size - RECORD_DTYPE.itemsize + MAX_DATA)), cycles
                    continue
                data = batch.column("data")  # the first partial stream: the record's fields as columns
                width = data.type.byte_width
                rec = np.empty(batch.num_rows, dtype=record_dtype(width))
                for name in ("t", "id", "error", "length"):
                    rec[name] = batch.column(name).to_numpy()
                raw = np.frombuffer(data.buffers()[1], dtype=np.uint8)
                rec["data"] = raw[data.offset * width:(data.offset + len(data)) * width].reshape(-1, width)
                yield rec, None
        except (StopIteration, pa.ArrowInvalid, OSError):
            return


@functools.lru_cache(maxsize=64)
def _nulls(n: int, dtype: str):
    """A column of ``n`` nulls (pyarrow arrays are immutable: one per size and type)."""
    import pyarrow as pa

    return pa.nulls(n, type=pa.binary() if dtype == "binary" else pa.from_numpy_dtype(np.dtype(dtype)))


@functools.lru_cache(maxsize=None)
def _layout_views(itemsize: int) -> tuple[tuple[np.ndarray, np.ndarray, tuple[tuple[int, np.dtype], ...]], ...]:
    """Per layout (first ids, last ids and) its fields as a view of whole records of
    ``itemsize`` bytes (the payload starts at the record's ``data``)."""
    base = RECORD_DTYPE.fields["data"][1]  # the same for every data width (data is the last field)
    views = tuple((size, np.dtype({"names": list(dtype.names),
                                   "formats": [dtype.fields[name][0] for name in dtype.names],
                                   "offsets": [base + dtype.fields[name][1] for name in dtype.names],
                                   "itemsize": itemsize})) for _lo, _hi, size, dtype in LAYOUTS)
    return (np.array([lo for lo, *_ in LAYOUTS], dtype=np.uint16), np.array([hi for _lo, hi, *_ in LAYOUTS], dtype=np.uint16),
            views)


def _column(values: np.ndarray, present: np.ndarray, count: int):
    """A pyarrow array of ``values`` (null where not ``present``; ``count`` present)."""
    import pyarrow as pa

    n = values.size
    bitmap = np.packbits(present, bitorder="little")
    return pa.Array.from_buffers(pa.from_numpy_dtype(values.dtype), n, [pa.py_buffer(bitmap), pa.py_buffer(values)],
                                 null_count=n - count)


def _field_arrays(scratch: dict | None, name: str, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Zeroed values and presence of field ``name`` for ``n`` rows, from ``scratch`` when it
    has them (refilled: fresh pages cost more than a memset)."""
    if scratch is None:
        return np.zeros(n, dtype=FIELDS[name]), np.zeros(n, dtype=bool)
    arrays = scratch.get(name)
    if arrays is None or arrays[0].size != n:
        arrays = scratch[name] = np.zeros(n, dtype=FIELDS[name]), np.zeros(n, dtype=bool)
    else:
        arrays[0].fill(0)
        arrays[1].fill(False)
    return arrays


def _encode_records(rec: np.ndarray, start: float, first_seq: int, scratch: dict | None = None,
                    cycles: np.ndarray | None = None):
    """One row group (a pyarrow Table) of recorder records ``rec`` (log order, contiguous, the
    first one frame ``first_seq`` of the log) and their cell ``cycles`` (-1 or None: not known,
    null): the rows sorted by id (stably). ``scratch``: the
    field columns' arrays are reused from it (and kept in it) - the table must then be written
    before the next call."""
    import pyarrow as pa

    n = rec.size
    width = rec.dtype["data"].shape[0]
    ns = blf_nanoseconds(rec["t"], start)
    order = np.argsort(rec["id"], kind="stable")  # radix sort (16-bit keys)
    # the records in id order, taken whole (a memcpy each; numpy's structured take is ~8x slower)
    srec = np.ascontiguousarray(rec).view(np.dtype((np.void, rec.dtype.itemsize)))[order].view(rec.dtype)
    sid = np.ascontiguousarray(srec["id"])
    serr = np.ascontiguousarray(srec["error"])
    slen = np.ascontiguousarray(srec["length"])
    cycles = _cycles_or_unknown(cycles, n)[order]
    unknown = cycles < 0
    columns = {"seq": pa.array(order.astype(np.int64) + np.int64(first_seq)), "t_ns": pa.array(ns[order]),
               "cycle": pa.array(cycles, mask=unknown) if unknown.any() else pa.array(cycles), "id": pa.array(sid),
               "error": pa.array(serr != 0), "length": pa.array(slen)}
    spans: dict[str, list] = {}  # field -> (first row, end row, values, rows picked in between or None: all)
    picked: list = []
    decoded = 0
    los, his, views = _layout_views(rec.dtype.itemsize)
    # rows sorted by id: each layout's id range is one slice, its length and error flag pick the rows
    firsts, lasts = sid.searchsorted(los, side="left").tolist(), sid.searchsorted(his, side="right").tolist()
    for a, b, (size, view) in zip(firsts, lasts, views):
        if a >= b:
            continue
        pick = (slen[a:b] == size) & (serr[a:b] == 0)
        every = bool(pick.all())
        sub = srec[a:b].view(view) if every else srec[a:b][pick].view(view)
        if not sub.size:
            continue
        decoded += sub.size
        picked.append((a, b, None if every else pick))
        for name in view.names:
            spans.setdefault(name, []).append((a, b, sub[name], None if every else pick))
    if decoded == n:
        columns["data"] = _nulls(n, "binary")
    else:
        undecoded = np.ones(n, dtype=bool)
        for a, b, pick in picked:
            undecoded[a:b] &= False if pick is None else ~pick
        raw: list[bytes | None] = [None] * n
        data = srec["data"]
        for i in np.flatnonzero(undecoded).tolist():
            raw[i] = bytes(data[i, :min(int(slen[i]), width)])
        columns["data"] = pa.array(raw, type=pa.binary())
    for name, dtype in FIELDS.items():
        columns[name] = _field_column(spans.get(name), n, dtype, scratch, name)
    return pa.table(columns, schema=_schema())


def _field_column(spans: list | None, n: int, dtype: np.dtype, scratch: dict | None, name: str):
    """Field ``name``'s column of ``n`` rows from its ``spans`` (see :func:`_encode_records`).
    Where the rows of each span are all the field's (the usual case) the column is chunked:
    nulls, values without nulls, nulls - the Parquet writer takes such chunks about 20 %
    faster than one array with a validity bitmap (the same file)."""
    import pyarrow as pa

    if not spans:
        return _nulls(n, dtype.str)
    kind = pa.from_numpy_dtype(dtype)
    if all(pick is None for _a, _b, _values, pick in spans) and \
            all(spans[k][0] >= spans[k - 1][1] for k in range(1, len(spans))):
        chunks, row = [], 0
        for a, b, values, _pick in spans:
            if a > row:
                chunks.append(pa.nulls(a - row, type=kind))
            chunks.append(pa.array(np.ascontiguousarray(values, dtype=dtype)))
            row = b
        if row < n:
            chunks.append(pa.nulls(n - row, type=kind))
        return pa.chunked_array(chunks, type=kind)
    values, present = _field_arrays(scratch, name, n)
    for a, b, part, pick in spans:
        if pick is None:
            values[a:b] = part
            present[a:b] = True
        else:
            values[a:b][pick] = part
            present[a:b] |= pick
    return _column(values, present, int(np.count_nonzero(present)))


def partial_to_parquet(partial: Path, path: Path, row_group_rows: int = ROW_GROUP_ROWS) -> None:
    """Rewrite the partial stream ``partial`` (e.g. left by a killed run) as the columnar CAN log
    ``path`` (bounded memory) and remove the stream."""
    groups = None
    for rec, cycles in _partial_records(partial):
        if groups is None:
            groups = _RowGroups(path, rec.dtype["data"].shape[0])
        groups.add(rec, row_group_rows, cycles)
    (groups or _RowGroups(path)).finish()
    partial.unlink(missing_ok=True)


def _parquet_writer(path: Path, schema):
    import pyarrow.parquet as pq

    ints = [f.name for f in schema if f.name in INT_COLUMNS]
    return pq.ParquetWriter(path, schema, compression="zstd", compression_level=COMPRESSION_LEVEL,
                            use_dictionary=False, write_statistics=False,
                            column_encoding={name: "DELTA_BINARY_PACKED" for name in ints},
                            sorting_columns=[pq.SortingColumn(schema.get_field_index("id"))])


def _frames_of(rec: np.ndarray, start: float) -> np.ndarray:
    width = rec.dtype["data"].shape[0]
    frames = np.zeros(rec.size, dtype=frame_dtype(width))
    frames["t_ns"] = blf_nanoseconds(rec["t"], start)
    for name in ("id", "error", "length"):
        frames[name] = rec[name]
    keep = np.arange(width) < np.minimum(rec["length"], width)[:, None]
    frames["data"] = np.where(keep, rec["data"], 0)
    return frames


@dataclass
class CanLog:
    """A CAN log read back: ``frames`` (:data:`FRAME_DTYPE`, log order), the BLF start and stop
    times (s); ``complete`` is False for a run's partial stream (the run is going or died);
    ``cycles`` each frame's cell cycle (int64, -1 where not known; None: a log from before the
    ``cycle`` column)."""

    frames: np.ndarray
    start_s: float
    stop_s: float
    complete: bool = True
    cycles: np.ndarray | None = None

    @property
    def timestamps(self) -> np.ndarray:
        """Each frame's time in s as python-can's BLF reader gives it (``start_s + t_ns * 1e-9``)."""
        return self.frames["t_ns"] / 1e9 + self.start_s

    def __len__(self) -> int:
        return int(self.frames.size)


def resolve(path: str | Path) -> Path:
    """``path``, or its ``.partial`` stream when only that exists (a run going or killed)."""
    path = Path(path)
    partial = path.with_name(path.name + PARTIAL_SUFFIX)
    return partial if not path.exists() and partial.exists() else path


def read_frames(path: str | Path) -> CanLog:
    """Every frame of a columnar CAN log (or of its partial stream) in log order."""
    path = resolve(path)
    if path.name.endswith(PARTIAL_SUFFIX):
        batches = list(_partial_records(path))
        if not batches:
            return CanLog(np.zeros(0, dtype=FRAME_DTYPE), 0.0, 0.0, complete=False)
        rec = np.concatenate([r for r, _c in batches])
        cycles = (None if all(c is None for _r, c in batches)
                  else np.concatenate([_cycles_or_unknown(c, r.size) for r, c in batches]))
        start = blf_start(rec["t"][0])
        return CanLog(_frames_of(rec, start), start, float(rec["t"][-1]), complete=False, cycles=cycles)
    frames, start, stop, cycles = _read_parquet(path)
    return CanLog(frames, start, stop, cycles=cycles)


def _read_parquet(path: Path) -> tuple[np.ndarray, float, float, np.ndarray | None]:
    import pyarrow.parquet as pq

    pf = pq.ParquetFile(path)
    meta = {k.decode(): v.decode() for k, v in (pf.metadata.metadata or {}).items()}
    if meta.get("format") not in (FORMAT, FORMAT_2, FORMAT_1):
        raise ValueError(f"{path}: not a CAN log of this format (metadata format = {meta.get('format')!r}, "
                         f"expected {FORMAT!r})")
    version_1 = meta["format"] == FORMAT_1
    parts = []
    cycle_parts = []
    has_cycles = "cycle" in pf.schema_arrow.names
    previous = 0
    first = 0
    width = int(meta.get("data_bytes", MAX_DATA))
    for g in range(pf.metadata.num_row_groups):
        table = pf.read_row_group(g)
        n = table.num_rows
        seq = table.column("seq").to_numpy().astype(np.int64)
        if not version_1:
            seq = seq - first  # the position in the log: the row group's frames follow the earlier groups'
            first += n
        grouped = np.zeros(n, dtype=frame_dtype(width))
        grouped["id"] = table.column("id").to_numpy()
        grouped["error"] = table.column("error").to_numpy(zero_copy_only=False)
        grouped["length"] = table.column("length").to_numpy()
        decoded = np.zeros(n, dtype=bool)
        for mask, dtype in _layout_masks(grouped["id"], grouped["error"], grouped["length"]):
            sub = np.zeros(int(mask.sum()), dtype=dtype)
            for name in dtype.names:
                sub[name] = table.column(name).filter(mask).to_numpy()
            grouped["data"][mask, :dtype.itemsize] = sub.view(np.uint8).reshape(-1, dtype.itemsize)
            decoded |= mask
        if not decoded.all():
            raw = table.column("data").to_pylist()
            for i in np.flatnonzero(~decoded):
                payload = raw[i] or b""
                grouped["data"][i, :len(payload)] = np.frombuffer(payload, dtype=np.uint8)
        frames = np.empty(n, dtype=frame_dtype(width))
        frames[seq] = grouped
        if version_1:  # t_ns as differences
            dt = np.empty(n, dtype=np.int64)
            dt[seq] = table.column("dt_ns").to_numpy()
            frames["t_ns"] = previous + np.cumsum(dt)
            if n:
                previous = int(frames["t_ns"][-1])
        else:
            frames["t_ns"][seq] = table.column("t_ns").to_numpy()
        if has_cycles:
            cycles = np.empty(n, dtype=np.int64)
            cycles[seq] = table.column("cycle").fill_null(-1).to_numpy()
            cycle_parts.append(cycles)
        parts.append(frames)
    frames = np.concatenate(parts) if parts else np.zeros(0, dtype=frame_dtype(width))
    cycles = (np.concatenate(cycle_parts) if cycle_parts else np.zeros(0, dtype=np.int64)) if has_cycles else None
    return frames, float(meta["start_s"]), float(meta["stop_s"]), cycles


def iter_messages(path: str | Path) -> Iterator["can.Message"]:
    """The frames as ``can.Message`` objects, equal to those ``can.BLFReader`` reads from the
    BLF file :func:`fieldbus.blf.to_blf` writes (timestamp, id, flags, dlc, data, channel 0). As there, a
    start time before 1990 (a simulated clock) counts as 0: the timestamps are ``t_ns / 1e9``
    (:attr:`CanLog.timestamps` keeps ``start_s``)."""
    import can
    from can.io.blf import systemtime_to_timestamp, timestamp_to_systemtime
    from can.util import dlc2len, len2dlc

    log = read_frames(path)
    start = systemtime_to_timestamp(timestamp_to_systemtime(log.start_s))  # what the BLF header keeps
    stamps = (log.frames["t_ns"] / 1e9 + start).tolist()
    for k, frame in enumerate(log.frames.tolist()):
        _, arbitration_id, error, length, data = frame
        payload = bytes(data[:length])
        if error:
            dlc = len2dlc(length)
            yield can.Message(timestamp=stamps[k], is_error_frame=True, is_extended_id=False,
                              arbitration_id=arbitration_id, dlc=dlc, data=bytes(data[:min(dlc, 8)]), channel=0)
        elif length > 8:
            yield can.Message(timestamp=stamps[k], arbitration_id=arbitration_id, is_extended_id=False,
                              is_fd=True, dlc=dlc2len(len2dlc(length)), data=payload, channel=0)
        else:
            yield can.Message(timestamp=stamps[k], arbitration_id=arbitration_id, is_extended_id=False,
                              dlc=length, data=payload, channel=0)


class CanLogReader:
    """Iterate a columnar CAN log as ``can.Message`` objects, the way ``can.BLFReader`` reads a
    BLF file (usable as a context manager, like python-can's readers)."""

    def __init__(self, file: str | Path) -> None:
        self.file = Path(file)

    def __iter__(self) -> Iterator["can.Message"]:
        return iter_messages(self.file)

    def __enter__(self) -> "CanLogReader":
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def stop(self) -> None:
        return None


def is_columnar(path: str | Path) -> bool:
    """True for a columnar CAN log's path (``.parquet``, or its ``.parquet.partial`` stream)."""
    name = Path(path).name.lower()
    return name.endswith(".parquet") or name.endswith(".parquet" + PARTIAL_SUFFIX)


def open_log(path: str | Path):
    """A reader of ``can.Message`` for any CAN log a run writes: :class:`CanLogReader` for the
    columnar log (also while only its partial stream exists), ``can.LogReader`` for BLF, ASC
    and python-can's other formats."""
    if is_columnar(path):
        return CanLogReader(path)
    import can

    return can.LogReader(str(path))


__all__ = ["CYCLE_DESCRIPTION", "CanLog", "CanLogReader", "CanLogWriter", "FIELDS", "FORMAT", "FRAME_DTYPE", "LAYOUTS", "RECORD_DTYPE",
           "frame_dtype", "record_dtype",
           "PARTIAL_FORMAT", "ROW_GROUP_ROWS", "blf_nanoseconds", "blf_start", "is_columnar", "iter_messages", "open_log",
           "partial_to_parquet", "read_frames", "resolve"]
