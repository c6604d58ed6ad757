"""Time series as Parquet (default) or CSV: streamed with a bounded buffer, lossless,
units in the column metadata, one reader for both; the output/memory budget refuses a
run before it starts with the estimate in the message."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from cosim.results.budget import BudgetError, check_budget, estimate_run, parse_size
from cosim.results.timeseries import (CsvSink, ParquetSink, SeriesFile, read_series, read_units, resolve_series,
                                      write_columns)
from cosim.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
ISO = ROOT / "scenarios" / "iso9283.toml"


def _rows(n: int) -> np.ndarray:
    rng = np.random.default_rng(3)
    data = np.column_stack([np.arange(n) * 1e-3, rng.normal(size=n), rng.integers(-5, 5, n).astype(float)])
    data[5, 1], data[6, 1], data[7, 1], data[8, 1] = np.nan, np.inf, -0.0, 1e-310
    return data


def test_parquet_sink_streams_with_a_bounded_buffer_readable_while_running(tmp_path):
    path = tmp_path / "s.parquet"
    path.write_bytes(b"an old run's file")
    sink = ParquetSink(path, units={"x": "rad"}, buffer_rows=100, flush_interval_s=3600.0)
    sink.open(["time", "x", "n"], ["Real", "Real", "Integer"])
    assert not path.exists()  # an old run's file is not mistaken for this run's
    assert read_series(path) == (["time", "x", "n"], pytest.approx(np.zeros((0, 3))))  # columns at once
    data = _rows(1050)
    for start in range(0, 1050, 64):
        sink.write(data[start:start + 64])
        assert sink._buffer.shape == (100, 3)  # memory does not grow with the run
    assert sink.rows_written == 1000  # ten full batches already on disk before close
    columns, so_far = read_series(path)  # while the run goes: the stream <file>.partial
    assert columns == ["time", "x", "n"] and np.array_equal(so_far, data[:1000], equal_nan=True)
    with open(sink.partial, "ab") as f:  # a crash in the middle of a batch: complete ones stay readable
        f.write(b"\x00garbage")
    assert read_series(path)[1].shape == (1000, 3)
    sink.partial.write_bytes(sink.partial.read_bytes()[:-len(b"\x00garbage")])
    sink.close()
    assert not sink.partial.exists() and pq.ParquetFile(path).metadata.num_rows == 1050
    columns, back = read_series(path)
    assert columns == ["time", "x", "n"]
    assert np.array_equal(back, data, equal_nan=True) and np.array_equal(np.signbit(back), np.signbit(data))
    assert str(pq.read_schema(path).field("n").type) == "int64"
    assert read_units(path) == {"time": "s", "x": "rad", "n": ""}


def test_flush_streams_buffered_rows_after_the_interval(tmp_path):
    sink = ParquetSink(tmp_path / "s.parquet", buffer_rows=1000, flush_interval_s=0.0)
    sink.open(["time", "x"], ["Real", "Real"])
    sink.write(_rows(10)[:, :2])
    sink.flush()
    assert sink.rows_written == 10
    sink.close()
    sink.close()  # idempotent
    assert read_series(tmp_path / "s.parquet")[1].shape == (10, 2)


STANDARD_ENCODINGS = {"PLAIN", "RLE", "RLE_DICTIONARY", "PLAIN_DICTIONARY", "BYTE_STREAM_SPLIT", "DELTA_BINARY_PACKED"}


@pytest.mark.parametrize("rows", [0, 10, 9000, 40000])
def test_standard_readers_read_every_value_a_sink_wrote(tmp_path, rows):
    """A sink's file holds its values in standard Parquet types and encodings: pandas, pyarrow,
    polars and DuckDB give back every value bit for bit (-0.0, NaN, a column of few values
    dictionary-encoded, the others byte-stream-split), as read_series does; units in the
    field metadata."""
    import duckdb
    import pandas as pd
    import polars as pl

    rng = np.random.default_rng(rows)
    t = np.arange(rows) * 4e-4
    data = np.column_stack([t, np.sin(t), np.cumsum(rng.integers(-3, 4, rows)) * 2.5e-6, rng.normal(size=rows),
                            rng.integers(0, 3, rows).astype(float), -np.zeros(rows), np.full(rows, np.nan)])
    names, kinds = ["time", "a", "obs", "noise", "n", "z", "nan"], ["Real"] * 4 + ["Integer", "Real", "Real"]
    sink = ParquetSink(tmp_path / "s.parquet", units={"a": "rad", "n": "1"}, buffer_rows=1024, flush_interval_s=3600.0)
    sink.open(names, kinds)
    for start in range(0, rows, 700):
        sink.write(data[start:start + 700])
    sink.close()
    path = tmp_path / "s.parquet"
    back_names, back = read_series(path)
    assert back_names == names and np.array_equal(back.view(np.int64), data.view(np.int64))
    frame = pd.read_parquet(path)
    table = pq.read_table(path)
    polars = pl.read_parquet(path)
    duck = duckdb.connect().execute(f"SELECT * FROM read_parquet('{path}')").fetchnumpy()
    assert list(frame.columns) == table.column_names == polars.columns == list(duck) == names
    for i, name in enumerate(names):
        want = data[:, i]
        for got in (frame[name].to_numpy(), table.column(name).to_numpy(), polars[name].to_numpy(),
                    np.asarray(duck[name])):
            assert got.dtype == (np.int64 if kinds[i] == "Integer" else np.float64), name
            assert np.array_equal(got.astype(np.float64).view(np.int64), want.view(np.int64)), name
    assert read_units(path)["a"] == "rad" and table.schema.field("a").metadata[b"unit"] == b"rad"
    meta = pq.ParquetFile(path).metadata
    encodings = {meta.schema.column(c).name: set(meta.row_group(g).column(c).encodings)
                 for g in range(meta.num_row_groups) for c in range(meta.num_columns)}
    assert all(e <= STANDARD_ENCODINGS for e in encodings.values()), encodings
    if rows >= 9000:
        assert "BYTE_STREAM_SPLIT" in encodings["a"] and "RLE_DICTIONARY" in encodings["z"]
        assert not any(b"cosim" in k for f in table.schema for k in (f.metadata or {}))


def test_the_same_rows_make_the_same_file_however_the_stream_was_cut(tmp_path):
    """Row groups of ROW_GROUP_ROWS rows whatever the batches (wall-clock flushes cut the stream
    differently in every run): the same rows give the same bytes."""
    from cosim.results.timeseries import ROW_GROUP_ROWS

    rows = 2 * ROW_GROUP_ROWS + 1234
    t = np.arange(rows) * 1e-3
    data = np.column_stack([t, np.sin(t), np.cos(7 * t)])
    files = []
    for k, cut in enumerate((1000, 777, 5000)):
        sink = ParquetSink(tmp_path / f"s{k}.parquet", buffer_rows=4096, flush_interval_s=3600.0)
        sink.open(["time", "a", "b"], ["Real"] * 3)
        for start in range(0, rows, cut):
            sink.write(data[start:start + cut])
            if (start // cut) % 3 == 0:
                sink._write_batch()  # what a flush after the wall-clock interval does
        sink.close()
        files.append((tmp_path / f"s{k}.parquet").read_bytes())
        assert pq.ParquetFile(tmp_path / f"s{k}.parquet").metadata.num_row_groups == 3
    assert files[0] == files[1] == files[2]


def test_write_columns_both_formats_are_exact(tmp_path):
    data = _rows(500)
    columns = {"t": data[:, 0], "x": data[:, 1], "phase": data[:, 2]}
    pq_path = write_columns(tmp_path / "c.parquet", columns, {"x": "m"})
    csv_path = write_columns(tmp_path / "c.csv", columns)
    for path in (pq_path, csv_path):
        names, back = read_series(path)
        assert names == ["t", "x", "phase"]
        assert np.array_equal(back, data, equal_nan=True) and np.array_equal(np.signbit(back), np.signbit(data))
    schema = pq.read_schema(pq_path)
    assert str(schema.field("phase").type) == str(schema.field("x").type) == "double"
    assert read_units(pq_path) == {"t": "s", "x": "m", "phase": ""}
    assert pq_path.stat().st_size < csv_path.stat().st_size


def test_one_reader_finds_either_format(tmp_path):
    write_columns(tmp_path / "only.parquet", {"t": np.arange(3.0)})
    assert resolve_series(tmp_path / "only.csv") == tmp_path / "only.parquet"
    assert resolve_series(tmp_path / "only") == tmp_path / "only.parquet"
    assert SeriesFile(tmp_path / "only.parquet").column("t").tolist() == [0.0, 1.0, 2.0]
    sink = CsvSink(tmp_path / "c.csv")
    sink.open(["time", "k"], ["Real", "Integer"])
    sink.write(np.array([[0.5, 3.0]]))
    sink.close()
    assert (tmp_path / "c.csv").read_text() == "time,k\n0.5,3\n"


def test_budget_estimate_and_refusal(tmp_path):
    doc = load_scenario(ISO).data
    est = estimate_run(doc)
    assert 30e6 < est.output_bytes < 100e6  # the main job writes 48 MB (Parquet)
    long_doc = {**doc, "simulation": {**doc["simulation"], "stop_time": 36000.0}}
    with pytest.raises(BudgetError, match=r"about 1\d\d GB of output .*memory: output .*--max-output"):
        check_budget(estimate_run(long_doc), tmp_path, max_output="100 GB", max_memory="1 GB")
    # in process everything streams: memory does not grow with the run's length ...
    streamed = estimate_run(long_doc).memory_bytes
    assert streamed == estimate_run({**doc, "simulation": {**doc["simulation"], "stop_time": 60.0}}).memory_bytes
    assert streamed < 50e6
    check_budget(estimate_run(long_doc), tmp_path, max_output="1 TB", max_memory="1 GB")
    # ... a paced or split run holds its recording and controller log until the loop ends
    with pytest.raises(BudgetError, match=r"memory \d+(\.\d+)? GB > 1 GB \(--max-memory\)"):
        check_budget(estimate_run(long_doc, in_memory=True), tmp_path, max_output="1 TB", max_memory="1 GB")
    check_budget(est, tmp_path, max_output="1 GB", max_memory="1 GB")  # fits
    assert estimate_run(doc, "csv").output_bytes > est.output_bytes
    assert parse_size("2 GB") == 2e9 and parse_size("1 MiB") == 2 ** 20
    with pytest.raises(ValueError, match="--max-output: expected a size"):
        parse_size("lots", "--max-output")


def test_cli_refuses_before_running_and_names_the_estimate(tmp_path):
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "cosim", "run", str(ISO), "--out", str(out), "--max-output", "10 MB"],
                          capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 2
    assert "iso9283.toml" in done.stderr and "MB of output" in done.stderr and "--ignore-budget" in done.stderr
    assert "Traceback" not in done.stderr and not (out / "summary.json").exists()
