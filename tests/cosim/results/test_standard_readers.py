"""Every Parquet file a run writes reads right in any tool: for a short main job (the ISO 9283
path cut at 0.6 s, its three modes, CAN logs on) and a short ``compare`` (a built-in mode and a
user controller class on the ISO path and a user joint CSV), pandas, pyarrow, polars and DuckDB
return exactly the float64 values ``cosim.results.read_series`` returns (bit for bit, derived
columns such as the TCP error included), and the CAN logs' frames ``fieldbus.canlog.read_frames``
returns (sorted by ``seq``)."""
from __future__ import annotations

from pathlib import Path

import duckdb
import numpy as np
import pandas as pd
import polars as pl
import pyarrow.parquet as pq
import pytest

from cosim.results.timeseries import read_series, read_units
from fieldbus.canlog import FORMAT, LAYOUTS, read_frames
from scenario_files import run_scenario, write_variant

ROOT = Path(__file__).resolve().parents[3]
SHORT = [('stop_time = "12.6 s"', 'stop_time = "0.6 s"'), ('settle_time = "0.2 s"', 'settle_time = "0.1 s"'),
         ("figures = true", "figures = false")]
STANDARD_ENCODINGS = {"PLAIN", "RLE", "RLE_DICTIONARY", "PLAIN_DICTIONARY", "BYTE_STREAM_SPLIT", "DELTA_BINARY_PACKED"}


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("readers")
    main = write_variant((ROOT / "scenarios" / "iso9283.toml").read_text(encoding="utf-8"), tmp / "main.toml", SHORT)
    code, summary = run_scenario(main, tmp / "main")
    assert code == 0 and summary["status"] == "ok", summary.get("reason")
    t = np.linspace(0.0, 0.3, 31)
    s = t / 0.3
    q = np.array([0.0, 0.4, 1.8, 0.0, 0.9, np.pi]) + np.outer(10 * s**3 - 15 * s**4 + 6 * s**5,
                                                               [0.05, 0.03, -0.04, 0.06, -0.05, 0.08])
    (tmp / "wave.csv").write_text("t, " + ", ".join(f"q{j} [deg]" for j in range(1, 7)) + "\n" + "".join(
        ",".join(repr(float(v)) for v in (t[k], *np.degrees(q[k]))) + "\n" for k in range(t.size)), encoding="utf-8")
    (tmp / "hold.py").write_text(
        "from controller import ControllerOutput\n"
        "from controller.tracking_clock import TrackingClock\n"
        "class Follow:\n"
        "    def setup(self, info):\n"
        "        self.clock = TrackingClock(info, settle_time_s=0.05)\n"
        "        self.out = ControllerOutput.zeros(info.n_joints)\n"
        "    def step(self, inputs):\n"
        "        tau = self.clock.update(inputs, self.out.controlword)\n"
        "        self.out.target_position[:] = self.clock.reference(tau)[0]\n"
        "        return self.out\n"
        "    def close(self):\n"
        "        pass\n", encoding="utf-8")
    compare = write_variant((ROOT / "scenarios" / "iso9283_rigid.toml").read_text(encoding="utf-8"),
                            tmp / "compare.toml", [
        ('job = "iso9283"', 'job = "compare"'), *SHORT,
        ("[results]", '[compare]\ncontrollers = ["model_based", "hold.py:Follow"]\n'
                      'trajectories = ["iso9283", "wave.csv"]\nfigures = false\n\n[results]')])
    code, summary = run_scenario(compare, tmp / "compare")
    assert code in (0, 4) and summary["entries"], summary.get("reason")
    return tmp / "main", tmp / "compare"


def _bits(values: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(values).astype(np.float64).view(np.int64)


def _check_series(path: Path) -> None:
    names, data = read_series(path)
    assert len(data), path.name
    table = pq.read_table(path)
    frame = pd.read_parquet(path)
    polars = pl.read_parquet(path)
    duck = duckdb.connect().execute("SELECT * FROM read_parquet(?)", [str(path)]).fetchnumpy()
    assert table.column_names == list(frame.columns) == polars.columns == list(duck) == names, path.name
    for i, name in enumerate(names):
        want = _bits(data[:, i])
        for reader, got in (("pyarrow", table.column(name).to_numpy()), ("pandas", frame[name].to_numpy()),
                            ("polars", polars[name].to_numpy()), ("duckdb", np.asarray(duck[name]))):
            assert got.dtype.kind in "fi", (path.name, name, reader, got.dtype)
            assert np.array_equal(_bits(got), want), (path.name, name, reader)
    units = read_units(path)
    assert units == {f.name: (f.metadata or {}).get(b"unit", b"").decode() for f in table.schema}, path.name
    meta = pq.ParquetFile(path).metadata
    for g in range(meta.num_row_groups):
        for c in range(meta.num_columns):
            assert set(meta.row_group(g).column(c).encodings) <= STANDARD_ENCODINGS, (path.name, c)


def _check_can_log(path: Path) -> None:
    log = read_frames(path)
    frames = log.frames
    assert len(frames) > 1000, path.name
    frame = pd.read_parquet(path).sort_values("seq")
    assert np.array_equal(frame["seq"].to_numpy(), np.arange(len(frames)))
    for name in ("t_ns", "id", "length"):
        assert np.array_equal(frame[name].to_numpy(), frames[name]), (path.name, name)
    assert np.array_equal(frame["error"].to_numpy(), frames["error"] != 0)
    # every telegram field a standard reader sees is the payload's value (little endian)
    ids, lengths = frames["id"], frames["length"]
    for lo, hi, size, dtype in LAYOUTS:
        rows = (ids >= lo) & (ids <= hi) & (lengths == size) & (frames["error"] == 0)
        if not rows.any():
            continue
        payload = np.ascontiguousarray(frames["data"][rows, :dtype.itemsize]).view(dtype).ravel()
        for name in dtype.names:
            got = frame[name].to_numpy()[rows]
            assert np.array_equal(got.astype(np.int64), payload[name].astype(np.int64)), (path.name, name)
    duck = duckdb.connect().execute("SELECT t_ns, id FROM read_parquet(?) ORDER BY seq", [str(path)]).fetchnumpy()
    assert np.array_equal(np.asarray(duck["t_ns"]), frames["t_ns"])
    pol = pl.read_parquet(path).sort("seq")
    assert np.array_equal(pol["id"].to_numpy(), frames["id"])
    assert pq.read_metadata(path).metadata[b"format"] == FORMAT.encode()


def _check_folder(folder: Path) -> set[str]:
    kinds = set()
    for path in sorted(folder.glob("*.parquet")):
        meta = pq.read_metadata(path).metadata or {}
        if meta.get(b"format", b"").startswith(b"rx130l-cosim CAN log"):
            _check_can_log(path)
            kinds.add("can")
        else:
            _check_series(path)
            kinds.add(path.stem.split("_")[0])
    assert not list(folder.glob("*.partial")) and not list(folder.glob("*.tmp"))
    return kinds


def test_every_parquet_file_of_the_main_job_reads_the_same_in_every_tool(folders):
    main, _ = folders
    assert _check_folder(main) == {"can", "controller", "tcp", "timeseries"}
    # the TCP errors are in the file, the values the evaluation computed
    frame = pd.read_parquet(main / "tcp_model_based.parquet")
    measured = frame[["x_measured", "y_measured", "z_measured"]].to_numpy()
    commanded = frame[["x_commanded", "y_commanded", "z_commanded"]].to_numpy()
    assert np.array_equal(frame["tcp_error_mm"].to_numpy(), np.linalg.norm(measured - commanded, axis=1) * 1e3)
    assert np.array_equal(frame["lag3"].to_numpy(), (frame["q_d3"] - frame["q3"]).to_numpy())
    assert pq.read_schema(main / "tcp_model_based.parquet").field("tcp_error_mm").metadata[b"unit"] == b"mm"


def test_every_parquet_file_of_a_compare_reads_the_same_in_every_tool(folders):
    _, compare = folders
    assert {"timeseries", "tcp", "can"} <= _check_folder(compare)
