"""Time series written while a run goes: Parquet by default, CSV on request.

Two sinks implement ``cosim.master.recorder.Sink`` (``open(columns, kinds)``,
``write(block)``, ``flush()``, ``close()``; column 0 is ``time`` in s):

* :class:`ParquetSink` (default): one column per signal, ``float64`` for Real signals
  and ``int64`` for Integer/Boolean ones (exact), zstd-compressed; float64 columns
  byte-stream-split, columns with few distinct values dictionary-encoded
  (:func:`column_encodings`) - standard Parquet types and encodings only, so pandas, pyarrow,
  polars and DuckDB read every value bit for bit; the unit of each column in its field
  metadata (``b"unit"``). Rows are buffered in one
  preallocated block of at most ``buffer_rows`` rows (bounded memory, whatever the run's
  length) and streamed as an Arrow batch to ``<file>.partial`` when the block is full or,
  on ``flush()``, when ``flush_interval_s`` of wall time passed: readable while the run
  goes and after a crash (every complete batch). ``close()`` (every run end, error and
  signal included, closes its sinks) turns the stream into the Parquet file;
* :class:`CsvSink`: header ``time,<signal>,...``, Reals with ``repr`` (shortest
  round-trip decimal), Integer/Boolean columns as integers, flushed on every ``flush()``.

Files written by earlier versions in their compact layout (``cosim.encoding`` field metadata:
``scaled``/``delta<k>`` columns; ``cosim.derived`` schema metadata: columns left out) are still
read back bit for bit by :func:`read_series` and the other readers here (:func:`decode_column`,
:func:`derived_spec`); nothing writes that layout any more.

:func:`write_columns` writes named columns of equal length at once (format by suffix),
:func:`read_series` reads either format back (column names, float64 array),
:func:`read_units` the units. ``COSIM_TIMESERIES=csv`` in the environment (or ``cosim run
--timeseries csv``) makes runs write CSV instead of Parquet.
"""
from __future__ import annotations

import csv
import os
import time
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from robot.textfiles import open_text

FORMATS = ("parquet", "csv")
SUFFIXES = {"parquet": ".parquet", "csv": ".csv"}
ENV_FORMAT = "COSIM_TIMESERIES"
DEFAULT_BUFFER_ROWS = 8192
"""Rows buffered per Parquet sink before a row group is written (8192 x 40 columns = 2.6 MB)."""
DEFAULT_FLUSH_INTERVAL_S = 1.0
"""Longest wall time (s) rows wait in a Parquet sink's buffer before they are streamed to disk
(``$COSIM_FLUSH_INTERVAL_S`` overrides it)."""
ENV_FLUSH_INTERVAL = "COSIM_FLUSH_INTERVAL_S"


def default_flush_interval() -> float:
    """``$COSIM_FLUSH_INTERVAL_S`` (a number of seconds >= 0) or :data:`DEFAULT_FLUSH_INTERVAL_S`."""
    text = os.environ.get(ENV_FLUSH_INTERVAL, "").strip()
    if not text:
        return DEFAULT_FLUSH_INTERVAL_S
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not (value >= 0.0 and value < float("inf")):
        raise ValueError(f"{ENV_FLUSH_INTERVAL}={text!r}: expected a number of seconds >= 0")
    return value
COMPRESSION = "zstd"
COMPRESSION_LEVEL = 3
"""zstd level of the final Parquet files (the streams while a run goes are not compressed). On the
main job's controller log: level 1 4.22 MB, 3 3.99 MB, 6 3.74 MB for 0.15 CPU-s more per file
(measured by CPU time at load 11): level 3, the cheaper write."""


def default_format() -> str:
    """``$COSIM_TIMESERIES`` (``parquet`` or ``csv``), else ``parquet``."""
    value = os.environ.get(ENV_FORMAT, "").strip().lower() or "parquet"
    if value not in FORMATS:
        raise ValueError(f"{ENV_FORMAT}={os.environ[ENV_FORMAT]!r}: expected one of {', '.join(FORMATS)}")
    return value


class FileSink:
    """Base of the recorder sinks that write one file, ``self._file`` (None until ``open``):
    ``flush`` pushes what was written to the OS, ``close`` closes the file (again: no-op)."""

    _file: IO | None = None

    def flush(self) -> None:
        if self._file is not None:
            self._file.flush()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


class CsvSink(FileSink):
    """Write recorder rows to ``path`` (created with its directory; overwritten)."""

    def __init__(self, path: str | Path, units: Mapping[str, str] | None = None) -> None:
        self.path = Path(path)
        self.units = dict(units or {})  # CSV has no place for them (docs list the units)
        self._file = None
        self._int_columns: list[int] = []

    def open(self, columns: Sequence[str], kinds: Sequence[str]) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "w", encoding="utf-8", newline="")
        csv.writer(self._file).writerow(columns)
        self._int_columns = [i for i, k in enumerate(kinds) if k in ("Integer", "Boolean")]
        self._file.flush()

    def write(self, block: np.ndarray) -> None:
        rows = block.tolist()
        if self._int_columns:
            for row in rows:
                for i in self._int_columns:
                    row[i] = int(row[i])
        self._file.write("".join(",".join(map(repr, row)) + "\n" for row in rows))


_POOL_SET = False
os.environ.setdefault("ARROW_DEFAULT_MEMORY_POOL", "system")  # when pyarrow is not imported yet


def _memory_pool() -> None:
    """Arrow allocates from the C library's allocator (once per process; unless
    ``$ARROW_DEFAULT_MEMORY_POOL`` chooses): with its default mimalloc pool the resident memory
    of a long cell run grew with the rows rewritten and read back (a 60 s cell run: +22 MB
    rewriting the recording, +26 MB the controller log; with malloc +9 and +3 MB), although
    Arrow itself held under 4 MB."""
    global _POOL_SET
    if _POOL_SET:
        return
    _POOL_SET = True
    if os.environ.get("ARROW_DEFAULT_MEMORY_POOL", "system") != "system":
        return  # the user's choice
    import pyarrow as pa

    pa.set_memory_pool(pa.system_memory_pool())


_LIBC: list = []


def release_memory() -> None:
    """Give the C heap's free memory back to the system (glibc ``malloc_trim``; elsewhere a
    no-op). Called between the chunks of long rewrites and evaluations: glibc serves large
    blocks freed and allocated again from its heap and keeps them, so the resident memory of
    a long run's evaluation otherwise grew with the number of chunks (+20 MB at 300 s)."""
    if not _LIBC:
        import ctypes
        import ctypes.util

        try:
            libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
            trim = libc.malloc_trim
            trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
            # a fixed mmap threshold (M_MMAP_THRESHOLD = -3): blocks above 256 KiB always go to
            # mmap and back to the system when freed (glibc otherwise raises the threshold after
            # each freed large block and keeps the next ones in its heap)
            libc.mallopt.argtypes, libc.mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
            libc.mallopt(-3, 256 * 1024)
        except (OSError, AttributeError):
            trim = None
        _LIBC.append(trim)
    if _LIBC[0] is not None:
        _LIBC[0](0)


def _schema(columns: Sequence[str], integer: Sequence[bool], units: Mapping[str, str]):
    import pyarrow as pa

    _memory_pool()

    fields = []
    for name, is_int in zip(columns, integer):
        unit = units.get(name, "s" if name in ("time", "t") else "")
        fields.append(pa.field(name, pa.int64() if is_int else pa.float64(),
                               metadata={b"unit": unit.encode()} if unit else None))
    return pa.schema(fields, metadata={b"writer": b"rx130l-cosim"})


DICTIONARY_SAMPLE_ROWS = 4096
"""Rows (the first of a file) on which each column's encoding is chosen (:func:`column_encodings`)."""
DICTIONARY_MAX_SHARE = 1 / 8
"""A column is dictionary-encoded when its first :data:`DICTIONARY_SAMPLE_ROWS` rows hold at most
this share of distinct values (phases, iteration counts, segment numbers, a drive's constant
following-error flag); the other float64 columns are byte-stream-split."""


def column_encodings(names: Sequence[str], sample: np.ndarray | None, integer: Sequence[bool]) -> tuple[list[str], list[str]]:
    """``(dictionary columns, byte-stream-split columns)`` for a time series whose first rows are
    ``sample`` (float64, one column per name; None: no rows): dictionary where few distinct
    values repeat, byte-stream split for the other float64 columns, plain for the other
    integer ones. Standard Parquet encodings only: every reader decodes them."""
    dictionary = []
    if sample is not None and len(sample):
        rows = sample[:DICTIONARY_SAMPLE_ROWS]
        for i, name in enumerate(names):
            if len(np.unique(rows[:, i])) <= DICTIONARY_MAX_SHARE * len(rows):
                dictionary.append(name)
    split = [n for n, is_int in zip(names, integer) if not is_int and n not in dictionary]
    return dictionary, split


def _writer(path: Path, schema, sample: np.ndarray | None = None):
    """The Parquet writer of a time series: zstd, float64 columns byte-stream-split or (few
    distinct values in ``sample``, the first rows) dictionary-encoded; no statistics."""
    import pyarrow.parquet as pq

    integer = [str(f.type) != "double" for f in schema]
    dictionary, split = column_encodings(schema.names, sample, integer)
    return pq.ParquetWriter(path, schema, compression=COMPRESSION, compression_level=COMPRESSION_LEVEL,
                            use_dictionary=dictionary or False, use_byte_stream_split=split or False,
                            write_statistics=False)


PARTIAL_SUFFIX = ".partial"
"""While a run goes, a Parquet sink streams to ``<file>.parquet.partial`` (Arrow IPC stream,
uncompressed: :data:`PARTIAL_COMPRESSION`): readable at any moment up to the last complete
batch, also after a crash."""
PARTIAL_COMPRESSION = None
"""Compression of the partial streams. zstd (level 1) made the main job's controller log stream
8.4 MB instead of 10.6 MB but cost 21 ms to write and 12 ms to read back per mode (none: 7 and
2 ms; lz4: 9.1 MB, 12 and 5 ms): the stream lives only until the run ends, the Parquet file
holds the rows compressed (zstd 3, about 4 MB)."""
ROW_GROUP_ROWS = 16384
"""Rows per Parquet row group: a reader holds one group at a time (16384 x 40 float64 columns =
5 MB); 0.2 % larger files than 65536-row groups on the main job, and memory that stays flat
however long the file (64k-row groups cost a growing 9 MB more when closing a 600 s series)."""


class ParquetSink:
    """Stream recorder rows with bounded memory; ``units`` maps column names to units (``time``: s).

    While the run goes the rows go, batch by batch, to ``<path>.partial`` (an Arrow IPC
    stream: every complete batch is readable, by :func:`read_series` too, even after the
    process was killed); :meth:`close` turns it into the Parquet file ``path`` (row groups
    of :data:`ROW_GROUP_ROWS` rows, streamed, then an atomic rename) and removes the stream."""

    def __init__(self, path: str | Path, units: Mapping[str, str] | None = None,
                 buffer_rows: int = DEFAULT_BUFFER_ROWS, flush_interval_s: float | None = None) -> None:
        self.path = Path(path)
        self.partial = self.path.with_name(self.path.name + PARTIAL_SUFFIX)
        self.units = dict(units or {})
        self.buffer_rows = int(buffer_rows)
        self.flush_interval_s = float(flush_interval_s if flush_interval_s is not None else default_flush_interval())
        self.rows_written = 0
        self._file = None
        self._stream = None
        self._schema = None
        self._buffer: np.ndarray | None = None
        self._fill = 0
        self._int_columns: list[int] = []
        self._last = time.perf_counter()

    def open(self, columns: Sequence[str], kinds: Sequence[str]) -> None:
        import pyarrow as pa

        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.path.unlink(missing_ok=True)  # a reader must not mistake an old run's file for this one
        integer = [k in ("Integer", "Boolean") for k in kinds]
        self._int_columns = [i for i, flag in enumerate(integer) if flag]
        self._schema = _schema(columns, integer, self.units)
        self._file = pa.OSFile(str(self.partial), "wb")
        self._stream = pa.ipc.new_stream(self._file, self._schema,
                                         options=pa.ipc.IpcWriteOptions(compression=PARTIAL_COMPRESSION))
        # the schema (column names, units) on disk at once: readable even if the run dies now
        self._stream.write_batch(pa.RecordBatch.from_arrays([pa.array([], type=f.type) for f in self._schema],
                                                            schema=self._schema))
        self._file.flush()
        self._buffer = np.empty((self.buffer_rows, len(columns)))
        self._fill = 0

    def write(self, block: np.ndarray) -> None:
        block = np.asarray(block, dtype=float)
        start = 0
        while start < len(block):
            take = min(len(block) - start, self.buffer_rows - self._fill)
            self._buffer[self._fill:self._fill + take] = block[start:start + take]
            self._fill += take
            start += take
            if self._fill == self.buffer_rows:
                self._write_batch()

    def _write_batch(self) -> None:
        import pyarrow as pa

        if not self._fill or self._stream is None:
            return
        data = self._buffer[:self._fill]
        columns = np.ascontiguousarray(data.T)  # one transposing copy: each column contiguous
        ints = set(self._int_columns)
        arrays = [pa.array(columns[i].astype(np.int64) if i in ints else columns[i]) for i in range(len(columns))]
        self._stream.write_batch(pa.RecordBatch.from_arrays(arrays, schema=self._schema))
        self._file.flush()
        self.rows_written += self._fill
        self._fill = 0
        self._last = time.perf_counter()

    def flush(self) -> None:
        if self._fill and time.perf_counter() - self._last >= self.flush_interval_s:
            self._write_batch()

    def sync(self) -> None:
        """Write the rows held to the stream now, whatever the flush interval."""
        self._write_batch()

    def close(self) -> None:
        if self._stream is None:
            return
        try:
            self._write_batch()
        finally:
            self._stream.close()
            self._file.close()
            self._stream = self._file = None
            self._buffer = None
        _partial_to_parquet(self.partial, self.path, self._schema)


def _stream_batches(partial: Path):
    import pyarrow as pa

    with pa.OSFile(str(partial), "rb") as source:
        yield from pa.ipc.open_stream(source)


def _partial_to_parquet(partial: Path, path: Path, schema) -> None:
    """Rewrite the Arrow stream ``partial`` as the Parquet file ``path`` (bounded memory), in one
    pass, in row groups of :data:`ROW_GROUP_ROWS` rows (the last one shorter; the same file for
    the same rows, however the run's wall-clock flushes cut the stream); each column's encoding
    is chosen on the first rows (:func:`column_encodings`)."""
    import pyarrow as pa

    tmp = path.with_name(path.name + ".tmp")
    writer = None

    def write(table) -> None:
        nonlocal writer
        if writer is None:
            sample = None
            if table is not None and table.num_rows:
                head = table.slice(0, DICTIONARY_SAMPLE_ROWS)
                sample = np.column_stack([head.column(i).to_numpy().astype(float, copy=False)
                                          for i in range(head.num_columns)])
            writer = _writer(tmp, schema, sample)
        if table is not None:
            writer.write_table(table)

    try:
        pending, rows = [], 0
        for batch in _stream_batches(partial):
            pending.append(batch)
            rows += batch.num_rows
            if rows >= ROW_GROUP_ROWS:  # row groups of exactly ROW_GROUP_ROWS rows, whatever the batches
                table = pa.Table.from_batches(pending, schema=schema)
                start = 0
                while rows - start >= ROW_GROUP_ROWS:
                    write(table.slice(start, ROW_GROUP_ROWS))
                    start += ROW_GROUP_ROWS
                pending = table.slice(start).to_batches() if rows > start else []
                rows -= start
                release_memory()
        write(pa.Table.from_batches(pending, schema=schema) if pending else None)
    finally:
        if writer is not None:
            writer.close()
    os.replace(tmp, path)
    partial.unlink(missing_ok=True)


# ------------------------------------------- reading files of earlier versions (compact layout)
ENCODING_KEY = b"cosim.encoding"
SCALE_KEY = b"cosim.scale"
DERIVED_KEY = b"cosim.derived"


def _bits_undelta(stored: np.ndarray, order: int) -> np.ndarray:
    """Inverse of :func:`_bits_delta`: cumulative sums (wrapping), viewed as float64."""
    x = np.asarray(stored, dtype=np.int64)
    with np.errstate(over="ignore"):
        for _ in range(order):
            x = np.cumsum(x, dtype=np.int64)
    return x.view(np.float64)


def decode_column(field, values: np.ndarray) -> np.ndarray:
    """A stored column (one row group's values) as float64: plain columns as they are (every
    file written now), in files of earlier versions
    ``scaled`` ones ``counts * scale``, ``delta<k>`` ones by k cumulative sums of the int64
    values viewed as float64 bit patterns (the chain restarts in every row group)."""
    how = (field.metadata or {}).get(ENCODING_KEY)
    if how is None:
        return values.astype(float, copy=False)
    if how == b"scaled":
        return np.asarray(values, dtype=np.float64) * float(field.metadata[SCALE_KEY])
    if how.startswith(b"delta"):
        return _bits_undelta(values, int(how[5:]))
    raise ValueError(f"column {field.name!r}: unknown encoding {how!r}")


def is_encoded(schema) -> bool:
    """True when a Parquet schema has compact-encoded or derived columns (read them with this module)."""
    return bool((schema.metadata or {}).get(DERIVED_KEY)) or any(
        ENCODING_KEY in (f.metadata or {}) for f in schema)


def _read_partial(partial: Path) -> tuple[list[str], np.ndarray]:
    """The complete batches of an Arrow stream a sink is writing (or left after a crash)."""
    import pyarrow as pa

    batches, names = [], []
    with pa.OSFile(str(partial), "rb") as source:
        try:
            reader = pa.ipc.open_stream(source)
            names = list(reader.schema.names)
            while True:
                batches.append(reader.read_next_batch())
        except (StopIteration, pa.ArrowInvalid, OSError):
            pass
    rows = [np.column_stack([b.column(i).to_numpy().astype(float) for i in range(len(names))])
            for b in batches if b.num_rows]
    return names, (np.concatenate(rows) if rows else np.zeros((0, len(names))))


def sink_for(path: str | Path, units: Mapping[str, str] | None = None):
    """A :class:`ParquetSink` or :class:`CsvSink` by the suffix of ``path``."""
    path = Path(path)
    return CsvSink(path, units) if path.suffix == ".csv" else ParquetSink(path, units)


def write_columns(path: str | Path, columns: Mapping[str, np.ndarray], units: Mapping[str, str] | None = None) -> Path:
    """Write ``columns`` (name -> (n,) array) to ``path``: Parquet (``.parquet``, float64
    columns, encoded as :class:`ParquetSink` encodes them) or CSV (``.csv``, floats with ``repr``, NaN as
    ``nan``); ``units`` into the Parquet column metadata. Returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    names = list(columns)
    arrays = [np.asarray(columns[n], dtype=float) for n in names]
    if path.suffix == ".csv":
        data = np.column_stack(arrays) if names else np.zeros((0, 0))
        with open(path, "w", encoding="utf-8", newline="") as f:
            f.write(",".join(names) + "\n")
            rows = data.tolist()
            for start in range(0, len(rows), 4096):
                f.write("".join(",".join(map(repr, row)) + "\n" for row in rows[start:start + 4096]))
        return path
    import pyarrow as pa

    schema = _schema(names, [False] * len(names), dict(units or {}))
    table = pa.Table.from_arrays([pa.array(a) for a in arrays], schema=schema)
    sample = np.column_stack([a[:DICTIONARY_SAMPLE_ROWS] for a in arrays]) if names and len(arrays[0]) else None
    writer = _writer(path, schema, sample)
    try:
        writer.write_table(table, row_group_size=ROW_GROUP_ROWS)
    finally:
        writer.close()
    return path


def resolve_series(path: str | Path) -> Path:
    """``path`` if it exists; else the same stem with the other format's suffix (a test or
    script written for ``x.csv`` finds ``x.parquet``), or the stream ``x.parquet.partial`` of
    a run still going (or killed); else ``path``."""
    path = Path(path)
    if path.exists():
        return path
    for suffix in (".parquet", ".csv", ".parquet" + PARTIAL_SUFFIX):
        other = Path(f"{path.with_suffix('') if path.suffix in ('.csv', '.parquet') else path}{suffix}")
        if other.exists():
            return other
    return path


def read_series(path: str | Path) -> tuple[list[str], np.ndarray]:
    """Read a time-series file of either format (see :func:`resolve_series`): (column
    names, float64 array of shape (rows, columns))."""
    path = resolve_series(path)
    _memory_pool()
    if derived_spec(path) is not None:
        names = series_columns(path)
        blocks = [block for _, block in iter_series(path)]
        return names, (np.concatenate(blocks) if blocks else np.zeros((0, len(names))))
    if path.name.endswith(PARTIAL_SUFFIX):
        return _read_partial(path)
    if path.suffix == ".parquet":
        names = series_columns(path)
        blocks = [block for _, block in parquet_groups(path)]
        return names, (np.concatenate(blocks) if blocks else np.zeros((0, len(names))))
    with open_text(path) as f:
        header = next(csv.reader(f))
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    if data.size == 0:
        data = np.zeros((0, len(header)))
    return header, data


def parquet_groups(path: str | Path, columns: Sequence[str] | None = None, groups: Sequence[int] | None = None):
    """Yield ``(names, float64 block)`` per row group of a Parquet time series, its columns
    decoded (:func:`decode_column`) - ``columns`` (all when None) in the order given."""
    import pyarrow.parquet as pq

    pf = pq.ParquetFile(path)
    schema = pf.schema_arrow
    names = list(columns) if columns is not None else list(schema.names)
    for name in names:
        if schema.get_field_index(name) < 0:
            raise KeyError(f"{name!r}: no such column in {path}")
    for g in (range(pf.num_row_groups) if groups is None else groups):
        table = pf.read_row_group(g, columns=names, use_threads=False)
        if not table.num_rows:
            continue
        cols = [decode_column(schema.field(n), table.column(n).to_numpy()) for n in names]
        yield names, np.column_stack(cols)


def derived_spec(path: str | Path) -> dict[str, Any] | None:
    """The derived-columns description of a Parquet file or partial stream (None: none).

    A file may leave out columns that are exact copies of another time series' columns or
    exact functions of its own: schema metadata ``cosim.derived`` (JSON) lists ``columns``
    (every column, in order), ``source`` (a time series in the same folder, row for row
    aligned with this file), ``copy`` ({column: source column}), ``same`` ({column: a stored
    column of this file with the same values}), ``difference`` ({column:
    [a, b]}: ``a - b``) and ``distance_mm`` ({column: [[ax, ay, az], [bx, by, bz]]}:
    ``numpy.linalg.norm(A - B, axis=1) * 1e3``), evaluated in that order; ``units`` the
    derived columns' units. The values are bit for bit those the writer computed."""
    import json

    path = Path(path)
    meta = None
    if path.suffix == ".parquet" and path.exists():
        import pyarrow.parquet as pq

        meta = pq.read_schema(path).metadata
    elif path.name.endswith(PARTIAL_SUFFIX) and path.exists():
        import pyarrow as pa

        with pa.OSFile(str(path), "rb") as source:
            try:
                meta = pa.ipc.open_stream(source).schema.metadata
            except (pa.ArrowInvalid, OSError):
                return None
    raw = (meta or {}).get(DERIVED_KEY)
    return json.loads(raw) if raw else None


class _RowFeeder:
    """Rows of a chunk iterator handed out ``n`` at a time."""

    def __init__(self, chunks) -> None:
        self._chunks = (block for _, block in chunks)
        self._rest: np.ndarray | None = None

    def take(self, n: int) -> np.ndarray:
        parts, have = ([self._rest] if self._rest is not None else []), (len(self._rest) if self._rest is not None else 0)
        while have < n:
            block = next(self._chunks, None)
            if block is None:
                break
            parts.append(block)
            have += len(block)
        if not parts:
            self._rest = None
            return np.zeros((0, 0))
        data = np.concatenate(parts) if len(parts) > 1 else parts[0]
        self._rest = data[n:] if len(data) > n else None
        return data[:n]


def _derived_chunks(path: Path, spec: Mapping[str, Any], columns: Sequence[str] | None, rows: int):
    names = list(columns) if columns is not None else list(spec["columns"])
    copies, differences, distances = spec.get("copy", {}), spec.get("difference", {}), spec.get("distance_mm", {})
    same = spec.get("same", {})
    unknown = [n for n in names if n not in spec["columns"]]
    if unknown:
        raise KeyError(f"{unknown[0]!r}: no such column in {path}")
    stored = [c for c in spec["columns"] if c not in copies and c not in differences and c not in distances
              and c not in same]
    # only what the columns asked for are made of (every stored column used to be read)
    need = set(names)
    pending = list(names)
    while pending:
        c = pending.pop()
        deps = ([same[c]] if c in same else list(differences[c]) if c in differences
                else [*distances[c][0], *distances[c][1]] if c in distances else [])
        for d in deps:
            if d not in need:
                need.add(d)
                pending.append(d)
    stored = [c for c in stored if c in need] or stored[:1]  # one column at least: it counts the rows
    copies = {c: s for c, s in copies.items() if c in need}
    same = {c: o for c, o in same.items() if c in need}
    differences = {c: ab for c, ab in differences.items() if c in need}
    distances = {c: ab for c, ab in distances.items() if c in need}
    source_columns = list(dict.fromkeys(copies.values()))
    source = resolve_series(path.parent / spec["source"]) if source_columns else path
    if not source.exists():
        raise FileNotFoundError(f"{path}: its columns {', '.join(copies)} are the columns of {spec['source']}, which "
                                f"is not in {path.parent} (a file of an earlier version: keep the two files together)")
    feeder = _RowFeeder(iter_series(source, source_columns, rows)) if source_columns else None
    for _, block in _iter_stored(path, stored, rows):
        n = len(block)
        values = {c: block[:, i] for i, c in enumerate(stored)}
        if feeder is not None:
            src = feeder.take(n)
            if len(src) != n:
                raise ValueError(f"{path}: its source {source.name} has fewer rows than it (derived columns "
                                 f"{', '.join(copies)} cannot be rebuilt)")
            for c, s in copies.items():
                values[c] = src[:, source_columns.index(s)]
        for c, other in same.items():
            values[c] = values[other]
        for c, (a, b) in differences.items():
            values[c] = values[a] - values[b]
        for c, (a, b) in distances.items():
            values[c] = np.linalg.norm(np.column_stack([values[x] for x in a]) - np.column_stack([values[x] for x in b]),
                                       axis=1) * 1e3
        yield names, np.column_stack([values[c] for c in names])


READ_CHUNK_ROWS = 16384
"""Rows per chunk of :func:`iter_series` (16384 x 40 float64 columns = 5 MB)."""


def iter_series(path: str | Path, columns: Sequence[str] | None = None, rows: int = READ_CHUNK_ROWS):
    """Read a time series (either format, or a run's ``.partial`` stream) chunk by chunk:
    yields ``(names, block)`` with ``block`` a float64 array of at most about ``rows`` rows
    of ``columns`` (all when None, in the file's order otherwise in the order given).
    Memory is bounded by the chunk, whatever the file's length. Derived columns
    (:func:`derived_spec`) are rebuilt from their source file as they are read."""
    path = resolve_series(path)
    spec = derived_spec(path)
    if spec is not None:
        yield from _derived_chunks(path, spec, columns, rows)
        return
    yield from _iter_stored(path, columns, rows)


def _iter_stored(path: Path, columns: Sequence[str] | None, rows: int):
    """:func:`iter_series` of the columns stored in the file (``path`` resolved)."""
    if path.name.endswith(PARTIAL_SUFFIX) or path.suffix == ".parquet":
        import pyarrow as pa

        _memory_pool()

        if path.suffix == ".parquet":
            # one row group at a time (ParquetFile.iter_batches holds memory that grows with the file)
            for names, block in parquet_groups(path, columns):
                for start in range(0, len(block), rows):
                    yield names, block[start:start + rows]
            return
        else:
            names, batches = _partial_batches(path, columns)
        for batch in batches:
            if isinstance(batch, pa.RecordBatch) and batch.num_rows:
                cols = [batch.column(batch.schema.get_field_index(n)).to_numpy(zero_copy_only=False) for n in names]
                yield names, np.column_stack([c.astype(float, copy=False) for c in cols])
        return
    with open_text(path) as f:
        header = next(csv.reader([f.readline()]))
        take = [header.index(n) for n in columns] if columns is not None else list(range(len(header)))
        names = [header[i] for i in take]
        while True:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # "input contained no data" at the end
                block = np.loadtxt(f, delimiter=",", max_rows=rows, ndmin=2)
            if block.size == 0:
                return
            yield names, block[:, take]


def _partial_batches(partial: Path, columns: Sequence[str] | None):
    """(names, iterator of the complete batches) of an Arrow stream a sink writes or left behind."""
    import pyarrow as pa

    source = pa.OSFile(str(partial), "rb")
    try:
        reader = pa.ipc.open_stream(source)
    except (pa.ArrowInvalid, OSError):
        source.close()
        return (list(columns or [])), iter(())
    names = list(columns) if columns is not None else list(reader.schema.names)

    def batches():
        try:
            while True:
                yield reader.read_next_batch()
        except (StopIteration, pa.ArrowInvalid, OSError):
            return
        finally:
            source.close()
    return names, batches()


def series_columns(path: str | Path) -> list[str]:
    """Column names of a time series (either format, or a ``.partial`` stream) without its rows."""
    path = resolve_series(path)
    spec = derived_spec(path)
    if spec is not None:
        return list(spec["columns"])
    if path.suffix == ".parquet":
        import pyarrow.parquet as pq

        return list(pq.read_schema(path).names)
    if path.name.endswith(PARTIAL_SUFFIX):
        import pyarrow as pa

        with pa.OSFile(str(path), "rb") as source:
            try:
                return list(pa.ipc.open_stream(source).schema.names)
            except (pa.ArrowInvalid, OSError):
                return []
    with open_text(path) as f:
        return next(csv.reader([f.readline()]))


def series_rows(path: str | Path) -> int:
    """Rows of a time series (Parquet: from its footer; otherwise counted chunk by chunk)."""
    path = resolve_series(path)
    if path.suffix == ".parquet":
        import pyarrow.parquet as pq

        return int(pq.ParquetFile(path).metadata.num_rows)
    return sum(len(block) for _, block in iter_series(path, columns=None))


def last_row(path: str | Path, columns: Sequence[str] | None = None) -> np.ndarray | None:
    """The last row of a time series (``columns`` of it), None when it has no rows; reads the
    last row group of a Parquet file, else the chunks in turn."""
    path = resolve_series(path)
    if path.suffix == ".parquet" and derived_spec(path) is None:
        import pyarrow.parquet as pq

        groups = pq.ParquetFile(path).metadata.num_row_groups
        for g in range(groups - 1, -1, -1):
            for _, block in parquet_groups(path, columns, groups=[g]):
                if len(block):
                    return block[-1].copy()
        return None
    last = None
    for _, block in iter_series(path, columns):
        last = block[-1].copy()
    return last


def tail(path: str | Path, seconds: float, columns: Sequence[str] | None = None) -> tuple[list[str], np.ndarray]:
    """The rows of the last ``seconds`` of a time series (column 0 of ``columns`` is the time,
    s): ``time >= last time - seconds``, read chunk by chunk, holding at most one chunk more."""
    kept: list[np.ndarray] = []
    names: list[str] = list(columns or [])
    for names, block in iter_series(path, columns):
        kept.append(block)
        end = block[-1, 0]
        while len(kept) > 1 and kept[-2][-1, 0] < end - seconds:
            kept.pop(0)
    if not kept:
        return names, np.zeros((0, len(names)))
    data = np.concatenate(kept)
    return names, data[data[:, 0] >= data[-1, 0] - seconds]


class SeriesFile:
    """A written time series read back on first use (``columns``, ``data``, ``column(name)``):
    what a run streamed to disk, for the evaluation after the loop, without a copy held in
    memory during the loop. ``MemorySink``-compatible for readers."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._loaded: tuple[list[str], np.ndarray] | None = None

    def _load(self) -> tuple[list[str], np.ndarray]:
        if self._loaded is None:
            self._loaded = read_series(self.path) if resolve_series(self.path).exists() else ([], np.zeros((0, 0)))
        return self._loaded

    @property
    def columns(self) -> list[str]:
        """Column names (from the file's header or schema: the rows are not read)."""
        if self._loaded is None and resolve_series(self.path).exists():
            return series_columns(self.path)
        return self._load()[0]

    @property
    def data(self) -> np.ndarray:
        return self._load()[1]

    def column(self, name: str) -> np.ndarray:
        return self.data[:, self.columns.index(name)]

    def chunks(self, columns: Sequence[str] | None = None, rows: int = READ_CHUNK_ROWS):
        """:func:`iter_series` of the file (bounded memory; nothing kept)."""
        if self._loaded is not None:
            names, data = self._loaded
            take = [names.index(n) for n in columns] if columns is not None else list(range(len(names)))
            for start in range(0, len(data), rows):
                yield [names[i] for i in take], data[start:start + rows][:, take]
            return
        if resolve_series(self.path).exists():
            yield from iter_series(self.path, columns, rows)

    @property
    def rows(self) -> int:
        """Rows in the file (without reading them all when it is Parquet)."""
        if self._loaded is not None:
            return len(self._loaded[1])
        return series_rows(self.path) if resolve_series(self.path).exists() else 0


read_csv = read_series
"""Former name of :func:`read_series` (reads CSV and Parquet)."""


def read_units(path: str | Path) -> dict[str, str]:
    """Units of a Parquet time series' columns (``{}`` for CSV: see the docs)."""
    path = resolve_series(path)
    if path.suffix != ".parquet":
        return {}
    import pyarrow.parquet as pq

    schema = pq.read_schema(path)
    units = {f.name: (f.metadata or {}).get(b"unit", b"").decode() for f in schema}
    spec = derived_spec(path)
    if spec is not None:  # every column, in order; the derived ones' units from the description
        return {name: units.get(name, spec.get("units", {}).get(name, "")) for name in spec["columns"]}
    return units


__all__ = ["CsvSink", "DEFAULT_BUFFER_ROWS", "ENV_FORMAT", "FORMATS", "FileSink", "PARTIAL_SUFFIX", "ParquetSink", "SUFFIXES", "SeriesFile",
           "default_format", "iter_series", "last_row", "read_csv", "read_series", "read_units", "resolve_series",
           "series_columns", "series_rows", "sink_for", "tail", "write_columns"]
