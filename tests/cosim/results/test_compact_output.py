"""Nothing lost: a short ISO 9283 run written in the compact layout (columnar CAN log,
scaled/delta-coded/derived Parquet columns) gives back, through the documented readers, every
value of the plain layout (``$COSIM_COMPACT=0`` and ``can_log_format = "blf"``: the files as
written before) bit for bit, the same units, and the BLF file byte for byte; a generic Parquet
reader with the documented recipe decodes the columns without our code."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from cosim.api import RunResult, read_can_log
from cosim.results.timeseries import derived_spec, read_series, read_units, series_columns
from fieldbus.canlog import to_blf
from scenario_files import run_scenario, write_variant

ROOT = Path(__file__).resolve().parents[3]
FILES = ("controller", "tcp", "timeseries")
MODES = ("standard", "model_based")


def _run(tmp: Path, name: str, *, blf: bool) -> Path:
    text = (ROOT / "scenarios" / "iso9283.toml").read_text(encoding="utf-8")
    edits = [('stop_time = "12.6 s"', 'stop_time = "0.6 s"'),
             ('modes = ["standard", "model_based", "model_based_elastic"]', 'modes = ["standard", "model_based"]'),
             ('settle_time = "0.2 s"', 'settle_time = "0.1 s"'), ("figures = true", "figures = false")]
    if blf:
        edits.append(("can_log = true", 'can_log = true\ncan_log_format = "blf"'))
    path = write_variant(text, tmp / f"{name}.toml", edits)
    code, summary = run_scenario(path, tmp / name)
    assert code == 0 and summary["status"] == "ok"
    return tmp / name


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("compact")
    mp = pytest.MonkeyPatch()
    try:
        mp.setenv("COSIM_COMPACT", "0")
        plain = _run(tmp, "plain", blf=True)
    finally:
        mp.undo()
    return plain, _run(tmp, "compact", blf=False)


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


def test_every_value_comes_back_bit_for_bit(runs):
    plain, compact = runs
    for mode in MODES:
        for stem in FILES:
            a, b = plain / f"{stem}_{mode}.parquet", compact / f"{stem}_{mode}.parquet"
            (na, da), (nb, db) = read_series(a), read_series(b)
            assert na == nb == series_columns(b) and da.shape == db.shape and len(da) > 500, (stem, mode)
            assert read_units(a) == read_units(b), (stem, mode)
            for i, name in enumerate(na):
                if name == "compute_us":  # wall-clock time of the controller step: differs run to run
                    continue
                assert np.array_equal(_bits(da[:, i]), _bits(db[:, i])), (stem, mode, name)
        blf = plain / f"can_{mode}.blf"
        assert to_blf(compact / f"can_{mode}.parquet", compact.parent / "again.blf").read_bytes() == blf.read_bytes()
        assert len(list(read_can_log(compact / f"can_{mode}.parquet"))) == len(list(read_can_log(blf)))
    # the public API reads the compact files as the plain ones
    ts_a = RunResult.open(plain).timeseries("tcp_model_based", kind="numpy")
    ts_b = RunResult.open(compact).timeseries("tcp_model_based", kind="numpy")
    assert ts_a.columns == ts_b.columns
    assert all(np.array_equal(_bits(ts_a[c]), _bits(ts_b[c])) for c in ts_a.columns)
    assert RunResult.open(compact).can_log == sorted(compact.glob("can_*.parquet"))
    assert "can_model_based" not in RunResult.open(compact).timeseries_names


def test_compact_files_are_smaller_and_use_the_encodings(runs):
    plain, compact = runs
    size = {folder: sum(p.stat().st_size for p in folder.iterdir() if p.name.startswith(("can_", *FILES)))
            for folder in (plain, compact)}
    assert size[compact] < 0.6 * size[plain]
    schema = pq.read_schema(compact / "controller_model_based.parquet")
    encodings = {f.name: (f.metadata or {}).get(b"cosim.encoding", b"").decode() for f in schema}
    assert {encodings[f"q_obs{j}"] for j in range(1, 7)} == {"scaled"}
    assert encodings["q_d1"].startswith("delta") and encodings["t"].startswith("delta")
    assert derived_spec(compact / "controller_standard.parquet")["same"]["target1"] == "q_d1"  # CSP: target = q_d
    spec = derived_spec(compact / "tcp_model_based.parquet")
    assert spec["copy"]["q1"] == "plant.q[1]" and spec["difference"]["lag1"] == ["q_d1", "q1"]
    assert "q1" not in pq.read_schema(compact / "tcp_model_based.parquet").names


def test_the_documented_recipe_decodes_without_our_reader(runs):
    plain, compact = runs
    pf = pq.ParquetFile(compact / "controller_model_based.parquet")
    _, reference = read_series(plain / "controller_model_based.parquet")
    names = series_columns(plain / "controller_model_based.parquet")
    for name in ("q_d2", "q_obs3", "tau_ff2"):
        field = pf.schema_arrow.field(name)
        how = field.metadata[b"cosim.encoding"].decode()
        parts = []
        for g in range(pf.num_row_groups):  # per row group: k cumulative sums, then float64 bits
            stored = pf.read_row_group(g, columns=[name]).column(0).to_numpy().astype(np.int64)
            if how == "scaled":
                parts.append(stored * float(field.metadata[b"cosim.scale"]))
            else:
                for _ in range(int(how[len("delta"):])):
                    stored = np.cumsum(stored)
                parts.append(stored.view(np.float64))
        assert np.array_equal(_bits(np.concatenate(parts)), _bits(reference[:, names.index(name)])), name


def test_some_columns_of_a_file_with_derived_columns(runs):
    """Asking for some columns reads only what they are made of, and gives the same values as
    the whole file (copies from the source, same-as, differences, distances)."""
    from cosim.results.timeseries import iter_series

    _, compact = runs
    for path, pick in ((compact / "controller_standard.parquet", ["target3", "t_apply", "q_d3"]),
                       (compact / "tcp_model_based.parquet", ["lag2", "tcp_error_mm"]),
                       (compact / "tcp_model_based.parquet", ["q1", "t"]),
                       (compact / "tcp_model_based.parquet", ["path_error_mm"])):
        names, whole = read_series(path)
        got = np.concatenate([block for _, block in iter_series(path, pick, rows=100)])
        assert np.array_equal(_bits(got), _bits(whole[:, [names.index(c) for c in pick]])), (path.name, pick)
