"""Size, write and read time of the main job's output under other encodings (lossless only).

Takes a results folder of the main job (``--results DIR``; default: runs
``scenarios/iso9283.toml`` into a temporary folder with ``can_log_format = "blf"``, through ``bench_output.run_job``) and rewrites every time series
(``timeseries_*``, ``controller_*``, ``tcp_*`` Parquet files) with each candidate set of
pyarrow writer options, checking that every value reads back bit for bit, and prints the
total size, the write time and the read time per candidate; then the CAN logs: BLF as
written (python-can, zlib level 6), and the same frames as a columnar Parquet table
(timestamp in integer ns, delta-encoded; identifier, length and each data byte as columns).

Run: python benchmarks/bench_output_size.py [--results results/iso9283]
"""
from __future__ import annotations

import argparse
import io
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from bench_output import run_job


def candidates(table) -> dict[str, dict]:
    """Writer options tried (name -> pyarrow.parquet.write_table keywords); the first is the
    job's own choice (cosim.results.timeseries.column_encodings on the first rows)."""
    from cosim.results.timeseries import COMPRESSION_LEVEL, DICTIONARY_SAMPLE_ROWS, column_encodings

    schema = table.schema
    floats = [f.name for f in schema if str(f.type) == "double"]
    head = table.slice(0, DICTIONARY_SAMPLE_ROWS)
    sample = np.column_stack([head.column(i).to_numpy().astype(float) for i in range(head.num_columns)])
    dictionary, split = column_encodings(schema.names, sample, [str(f.type) != "double" for f in schema])
    base = dict(use_dictionary=False, write_statistics=False)
    return {
        "as written (bss/dictionary, zstd 3)": dict(compression="zstd", compression_level=COMPRESSION_LEVEL,
                                                    write_statistics=False, use_dictionary=dictionary or False,
                                                    use_byte_stream_split=split or False, row_group_size=16384),
        "bss, zstd 1": dict(base, compression="zstd", compression_level=1, use_byte_stream_split=floats,
                            row_group_size=16384),
        "plain, zstd 3": dict(base, compression="zstd", compression_level=3, row_group_size=16384),
        "bss, zstd 3": dict(base, compression="zstd", compression_level=3, use_byte_stream_split=floats,
                            row_group_size=16384),
        "bss, zstd 9": dict(base, compression="zstd", compression_level=9, use_byte_stream_split=floats,
                            row_group_size=16384),
        "bss, zstd 15": dict(base, compression="zstd", compression_level=15, use_byte_stream_split=floats,
                             row_group_size=16384),
        "bss, 64k groups": dict(base, compression="zstd", use_byte_stream_split=floats, row_group_size=65536),
        "plain, zstd 9": dict(base, compression="zstd", compression_level=9, row_group_size=16384),
        "bss, brotli": dict(base, compression="brotli", use_byte_stream_split=floats, row_group_size=16384),
        "bss, lz4": dict(base, compression="lz4", use_byte_stream_split=floats, row_group_size=16384),
        "dictionary, zstd": dict(compression="zstd", write_statistics=False, row_group_size=16384),
    }


def series_sizes(folder: Path) -> list[tuple[str, int, float, float]]:
    """(candidate, bytes, write s, read s) over every time series of ``folder``."""
    import pyarrow.parquet as pq

    files = sorted(p for p in folder.glob("*.parquet") if p.stem.split("_")[0] in ("timeseries", "controller", "tcp"))
    tables = {p.name: pq.read_table(p) for p in files}
    names = list(candidates(next(iter(tables.values()))))
    out = []
    for name in names:
        size, write_s, read_s = 0, 0.0, 0.0
        for table in tables.values():
            buf = io.BytesIO()
            t0 = time.perf_counter()
            pq.write_table(table, buf, **candidates(table)[name])
            write_s += time.perf_counter() - t0
            size += buf.tell()
            t0 = time.perf_counter()
            back = pq.read_table(io.BytesIO(buf.getvalue()))
            read_s += time.perf_counter() - t0
            for col in table.column_names:  # lossless: the same bits (NaN included)
                a = table.column(col).to_numpy()
                b = back.column(col).to_numpy()
                if not np.array_equal(a.view(np.int64) if a.dtype == float else a,
                                      b.view(np.int64) if b.dtype == float else b):
                    raise SystemExit(f"{name}: column {col} does not read back bit for bit")
        out.append((name, size, write_s, read_s))
    return out


def can_sizes(folder: Path) -> list[tuple[str, int, int, float]]:
    """(file, BLF bytes, columnar Parquet bytes, Parquet write s) per CAN log."""
    import can
    import pyarrow as pa
    import pyarrow.parquet as pq

    out = []
    for blf in sorted(folder.glob("can_*.blf")):
        msgs = list(can.BLFReader(str(blf)))
        width = max((len(m.data) for m in msgs), default=0)
        data = np.zeros((len(msgs), width), dtype=np.uint8)
        for i, m in enumerate(msgs):
            data[i, :len(m.data)] = list(m.data)
        stamps = np.array([m.timestamp for m in msgs])
        t_ns = np.round(stamps * 1e9).astype(np.int64)
        exact = np.array_equal(t_ns / 1e9, stamps)
        table = pa.table({"t_ns": t_ns, "id": np.array([m.arbitration_id for m in msgs], dtype=np.int64),
                          "length": np.array([len(m.data) for m in msgs], dtype=np.int64),
                          **{f"b{k}": data[:, k] for k in range(width)},
                          "rx": np.array([m.is_rx for m in msgs]), "fd": np.array([m.is_fd for m in msgs])})
        buf = io.BytesIO()
        t0 = time.perf_counter()
        pq.write_table(table, buf, compression="zstd", use_dictionary=False,
                       column_encoding={"t_ns": "DELTA_BINARY_PACKED", "id": "DELTA_BINARY_PACKED",
                                        "length": "DELTA_BINARY_PACKED"})
        out.append((f"{blf.name} ({len(msgs)} frames{'' if exact else ', timestamps not exact in ns'})",
                    blf.stat().st_size, buf.tell(), time.perf_counter() - t0))
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", type=Path, default=None, help="a results folder of the main job")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.results
        if folder is None:  # the plain layout and BLF, which the candidates are measured against
            folder = run_job(Path(tmp) / "iso9283", plain=True)
        total = sum(p.stat().st_size for p in folder.iterdir() if p.is_file())
        print(f"{folder}: {total / 1e6:.1f} MB in all (load average {os.getloadavg()[0]:.2f})")
        print(f"{'time series, candidate':40s} {'MB':>7s} {'write s':>8s} {'read s':>7s}")
        for name, size, write_s, read_s in series_sizes(folder):
            print(f"{name:40s} {size / 1e6:7.2f} {write_s:8.3f} {read_s:7.3f}")
        for name, blf, parquet, write_s in can_sizes(folder):
            print(f"{name}: BLF {blf / 1e6:.2f} MB, columnar Parquet {parquet / 1e6:.2f} MB "
                  f"({blf / parquet:.2f}x smaller, written in {write_s:.2f} s)")


if __name__ == "__main__":
    main()
