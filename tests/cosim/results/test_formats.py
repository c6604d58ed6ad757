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


@pytest.mark.parametrize("rows", [0, 10, 9000, 40000])
def test_compact_sink_plans_as_one_pass_over_the_whole_stream(tmp_path, rows):
    """The compact plan a sink gathers while it writes (same columns, exact counts, delta coding
    on the first rows) is the one a pass over the whole stream gives, and every value comes back."""
    from cosim.results.timeseries import _schema, encoding_plan

    rng = np.random.default_rng(rows)
    t = np.arange(rows) * 4e-4
    counts = np.cumsum(rng.integers(-3, 4, rows)).astype(float)
    data = np.column_stack([t, np.sin(t), np.sin(t), counts * 2.5e-6, rng.normal(size=rows),
                            rng.integers(0, 3, rows).astype(float), np.rint(np.cos(3 * t) * 1e3) * 1e-3 + 0.0,
                            -np.zeros(rows)])  # -0.0 is no integer count: not scaled, its sign comes back
    if rows > 20000:  # equal / exact counts up to the last row: decided on every row, not on the first ones
        data[-1, 2] += 0.5
        data[-1, 6] += 1e-7
    names, kinds = ["time", "a", "a_copy", "obs", "noise", "n", "c", "z"], ["Real"] * 5 + ["Integer", "Real", "Real"]
    scales = {"obs": 2.5e-6, "c": 1e-3, "z": 1.0}
    sink = ParquetSink(tmp_path / "s.parquet", buffer_rows=1024, flush_interval_s=3600.0, scales=scales,
                       float_delta=True)
    sink.open(names, kinds)
    for start in range(0, rows, 700):
        sink.write(data[start:start + 700])
    sink.close()
    import pyarrow as pa

    schema = _schema(names, [k == "Integer" for k in kinds], {})
    batches = [pa.RecordBatch.from_arrays([pa.array(data[s:s + 1024, i].astype(np.int64) if kinds[i] == "Integer"
                                                    else np.ascontiguousarray(data[s:s + 1024, i]))
                                           for i in range(len(names))], schema=schema)
               for s in range(0, rows, 1024)]
    plan = encoding_plan(batches, schema, scales, True)
    stored = pq.read_schema(tmp_path / "s.parquet")
    for name in names:
        how = plan.get(name)
        if how is not None and how[0] == "same":
            assert name not in stored.names
            continue
        meta = (stored.field(name).metadata or {}).get(b"cosim.encoding")
        assert meta == (None if how is None else b"scaled" if how[0] == "scaled" else f"delta{how[1]}".encode()), name
    if rows:
        assert (plan.get("a_copy", ("",))[0] == "same") == (rows <= 20000)
        assert plan["obs"][0] == "scaled" and (plan.get("c", ("",))[0] == "scaled") == (rows <= 20000)
        assert plan.get("z", ("",))[0] != "scaled"
    back_names, back = read_series(tmp_path / "s.parquet")
    assert back_names == names and np.array_equal(back.view(np.int64), data.view(np.int64))


def test_the_same_rows_make_the_same_file_however_the_stream_was_cut(tmp_path):
    """Row groups of ROW_GROUP_ROWS rows whatever the batches (wall-clock flushes cut the stream
    differently in every run): the same rows give the same bytes."""
    from cosim.results.timeseries import ROW_GROUP_ROWS

    rows = 2 * ROW_GROUP_ROWS + 1234
    t = np.arange(rows) * 1e-3
    data = np.column_stack([t, np.sin(t), np.cos(7 * t)])
    files = []
    for k, cut in enumerate((1000, 777, 5000)):
        sink = ParquetSink(tmp_path / f"s{k}.parquet", buffer_rows=4096, flush_interval_s=3600.0, float_delta=True)
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
    assert str(schema.field("phase").type) == "int64" and str(schema.field("x").type) == "double"
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
