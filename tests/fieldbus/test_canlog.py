"""The columnar CAN log (fieldbus/canlog.py): every frame back bit for bit, the BLF written from
it byte for byte the one python-can writes for the same frames, python-can Messages equal to
BLFReader's, a partial stream readable after a crash, and a real network run logged both ways."""
from __future__ import annotations

import can
import numpy as np
import pyarrow.parquet as pq
import pytest

from fieldbus.blf import to_blf
from fieldbus.canlog import FORMAT, CanLogReader, CanLogWriter, read_frames
from fieldbus.recorder import RECORD, _BlfSink
from tests.fieldbus.test_blf import random_records


def _telegram_records(cycles: int, seed: int = 1) -> bytes:
    """Frames as the POWERLINK network sends them: SYNC, RPDO1 (20 B), TPDO1 (8 B), TPDO2 (7 B)
    for six nodes, jittered times, plus an EMCY and some odd frames."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(cycles):
        t = k * 400e-6
        out.append(RECORD.pack(t, 0x080, 0, 1, bytes([k % 256])))
        for node in range(1, 7):
            pos = int(1e5 * np.sin(k * 1e-3 + node))
            rp = np.array([(0x0F, pos, -12, 8, 0, 0, 0, 7)], dtype=[("a", "<u2"), ("b", "<i4"), ("c", "<i2"), ("d", "i1"),
                                                                   ("e", "u1"), ("f", "<i2"), ("g", "<i4"), ("h", "<i4")])
            ts = t + node * 2e-5 + float(rng.normal(0, 3e-7))
            out.append(RECORD.pack(ts, 0x200 + node, 0, 20, rp.tobytes()))
            tp1 = np.array([(0x27, pos - 3, 55)], dtype=[("a", "<u2"), ("b", "<i4"), ("c", "<i2")]).tobytes()
            out.append(RECORD.pack(ts + 1e-5, 0x180 + node, 0, 8, tp1))
            tp2 = np.array([(pos % 977, 0, 8)], dtype=[("a", "<i4"), ("b", "<u2"), ("c", "i1")]).tobytes()
            out.append(RECORD.pack(ts + 1e-5, 0x280 + node, 0, 7, tp2))
        if k == cycles // 2:
            out.append(RECORD.pack(t + 3e-4, 0x083, 0, 8, bytes([0, 0x81, 0x10, 2, 9, 0, 8, 0])))
            out.append(RECORD.pack(t + 3e-4, 0x7FF, 0, 3, b"abc"))  # no layout: kept as raw bytes
            out.append(RECORD.pack(t + 3e-4, 0x181, 1, 4, b"\x01\x02\x03\x04"))  # error frame
    return b"".join(out)


def _log_both(tmp_path, batches, row_group_rows=None):
    """The batches through the recorder's BLF sink and its columnar sink."""
    blf = _BlfSink(str(tmp_path / "ref.blf"))
    col = _BlfSink(str(tmp_path / "log.parquet"), columnar=True)
    if row_group_rows:
        col.writer.row_group_rows = row_group_rows
    for records, watermark in batches:
        blf.feed(records, watermark)
        col.feed(records, watermark)
    blf.close()
    col.close()
    return tmp_path / "ref.blf", tmp_path / "log.parquet"


@pytest.mark.parametrize("kind", ["telegrams", "random"])
def test_blf_from_the_columnar_log_is_byte_identical(tmp_path, kind):
    records = _telegram_records(700) if kind == "telegrams" else random_records(6000, seed=11)
    size = RECORD.size
    n = len(records) // size
    batches = [(records[s * size:(s + 950) * size], None if s + 950 >= n else
                float(np.frombuffer(records[(s + 949) * size:(s + 950) * size], dtype="<f8", count=1)[0]) - 4e-4)
               for s in range(0, n, 950)]
    ref, log = _log_both(tmp_path, batches, row_group_rows=4096)
    assert not (tmp_path / "log.parquet.partial").exists()
    assert pq.ParquetFile(log).metadata.num_row_groups > 1
    out = to_blf(log, tmp_path / "again.blf")
    assert out.read_bytes() == ref.read_bytes()
    theirs = list(can.BLFReader(str(ref)))
    ours = list(CanLogReader(log))
    assert len(ours) == len(theirs) == n
    for a, b in zip(ours, theirs):
        assert a.equals(b, timestamp_delta=None) and a.timestamp == b.timestamp and a.channel == b.channel


def test_columns_are_the_telegram_fields_and_smaller_than_blf(tmp_path):
    ref, log = _log_both(tmp_path, [(_telegram_records(3000), None)])
    table = pq.read_table(log)
    meta = pq.ParquetFile(log).metadata.metadata
    assert meta[b"format"].decode() == FORMAT and float(meta[b"start_s"]) == 0.0
    rpdo = table.filter(pq.read_table(log).column("id").to_numpy() == 0x203)
    assert rpdo.column("target_position").to_pylist()[:2] == [int(1e5 * np.sin(3)), int(1e5 * np.sin(1e-3 + 3))]
    assert set(rpdo.column("modes_of_operation").to_pylist()) == {8}
    raw = [v for v in table.column("data").to_pylist() if v is not None]
    assert sorted(raw) == [b"\x01\x02\x03\x04", b"abc"]
    assert log.stat().st_size < ref.stat().st_size / 3


def test_partial_stream_is_readable_while_writing_and_after_a_crash(tmp_path):
    records = _telegram_records(500)
    writer = CanLogWriter(tmp_path / "x.parquet")
    half = len(records) // RECORD.size // 2 * RECORD.size
    writer.write_records(records[:half])
    log = read_frames(tmp_path / "x.parquet")  # the run is going: the partial stream
    assert not log.complete and len(log) == half // RECORD.size
    with open(writer.partial, "ab") as f:  # a torn batch at the end (killed mid-write)
        f.write(b"\xff\xff\xff\xff\x10\x00")
    assert len(read_frames(tmp_path / "x.parquet")) == half // RECORD.size
    assert len(list(CanLogReader(tmp_path / "x.parquet"))) == half // RECORD.size


def test_row_groups_are_encoded_as_they_fill_and_a_killed_run_keeps_every_frame(tmp_path):
    """Row groups go into ``<file>.tmp`` during the run (no second pass at close); a run killed
    before close leaves the stream with every frame written so far, and partial_to_parquet
    turns it into the very file close() writes."""
    from fieldbus.canlog import partial_to_parquet

    records = _telegram_records(600)
    n = len(records) // RECORD.size
    done = CanLogWriter(tmp_path / "done.parquet", row_group_rows=2000)
    killed = CanLogWriter(tmp_path / "killed.parquet", row_group_rows=2000)
    for begin in range(0, n, 950):
        chunk = records[begin * RECORD.size:(begin + 950) * RECORD.size]
        done.write_records(chunk)
        killed.write_records(chunk)
    tmp = tmp_path / "killed.parquet.tmp"
    assert tmp.stat().st_size > 0  # full row groups are already encoded
    done.close()
    assert not (tmp_path / "done.parquet.tmp").exists() and not done.partial.exists()
    killed._stream.close()  # the process dies: no footer, no rename
    killed._file.close()
    log = read_frames(tmp_path / "killed.parquet")
    assert not log.complete and len(log) == n
    assert np.array_equal(log.frames, read_frames(tmp_path / "done.parquet").frames)
    partial_to_parquet(killed.partial, tmp_path / "killed.parquet", row_group_rows=2000)
    assert (tmp_path / "killed.parquet").read_bytes() == (tmp_path / "done.parquet").read_bytes()
    assert not killed.partial.exists() and not tmp.exists()


def test_the_first_partial_stream_layout_is_still_read(tmp_path):
    """A stream written by the first writer (the record's fields as columns t, id, error,
    length, data) reads as the same frames as today's (one column of whole records)."""
    import pyarrow as pa

    from fieldbus.canlog import RECORD_DTYPE, partial_to_parquet

    records = _telegram_records(300)
    new = CanLogWriter(tmp_path / "new.parquet")
    new.write_records(records)
    new._stream.close()
    new._file.close()
    rec = np.frombuffer(records, dtype=RECORD_DTYPE)
    schema = pa.schema([("t", pa.float64()), ("id", pa.uint16()), ("error", pa.uint8()), ("length", pa.uint8()),
                        ("data", pa.binary(20))], metadata={b"format": (FORMAT + " partial").encode()})
    old = tmp_path / "old.parquet.partial"
    with pa.OSFile(str(old), "wb") as sink, pa.ipc.new_stream(sink, schema) as stream:
        for part in (rec[:1000], rec[1000:]):
            data = pa.FixedSizeBinaryArray.from_buffers(pa.binary(20), part.size,
                                                        [None, pa.py_buffer(np.ascontiguousarray(part["data"]))])
            stream.write_batch(pa.RecordBatch.from_arrays(
                [pa.array(np.ascontiguousarray(part[name])) for name in ("t", "id", "error", "length")] + [data],
                schema=schema))
    assert np.array_equal(read_frames(old).frames, read_frames(new.partial).frames)
    partial_to_parquet(old, tmp_path / "old.parquet")
    partial_to_parquet(new.partial, tmp_path / "new.parquet")
    assert (tmp_path / "old.parquet").read_bytes() == (tmp_path / "new.parquet").read_bytes()


def test_network_run_logged_as_parquet_equals_blf(tmp_path):
    from fieldbus import PowerlinkNetwork
    from tests.fieldbus.test_network import drive, scaling

    logs = {}
    for suffix in (".blf", ".parquet"):
        with PowerlinkNetwork({"recording": {"flush_every_cycles": 37}}, scaling(),
                              log_path=tmp_path / f"run{suffix}") as network:
            drive(network, 300)
        logs[suffix] = tmp_path / f"run{suffix}"
    assert to_blf(logs[".parquet"], tmp_path / "back.blf").read_bytes() == logs[".blf"].read_bytes()


def test_lookahead_frames_of_64_bytes_round_trip(tmp_path):
    """PReqs carrying a set-point look-ahead are 32-64 byte frames (records of 64 data bytes):
    kept whole in the raw ``data`` column, the BLF the same bytes as logged directly."""
    from fieldbus import PowerlinkNetwork
    from tests.fieldbus.test_network import drive, scaling

    logs = {}
    for suffix in (".blf", ".parquet"):
        with PowerlinkNetwork({"setpoint_lookahead": 4}, scaling(), log_path=tmp_path / f"k{suffix}") as network:
            drive(network, 120)
        logs[suffix] = tmp_path / f"k{suffix}"
    assert to_blf(logs[".parquet"], tmp_path / "back.blf").read_bytes() == logs[".blf"].read_bytes()
    frames = read_frames(logs[".parquet"]).frames
    assert frames["length"].max() > 20 and frames.dtype["data"].shape[0] == 64


def test_export_blf_command(tmp_path, capsys):
    from cosim.cli import main

    ref, log = _log_both(tmp_path, [(_telegram_records(200), None)])
    assert main(["export-blf", str(tmp_path)]) == 2  # a folder without can_*.parquet
    assert main(["export-blf", str(log), "-o", str(tmp_path / "x.blf")]) == 0
    assert (tmp_path / "x.blf").read_bytes() == ref.read_bytes()
    (tmp_path / "can_a.parquet").write_bytes(log.read_bytes())
    assert main(["export-blf", str(tmp_path), "-o", str(tmp_path / "blf")]) == 0
    assert (tmp_path / "blf" / "can_a.blf").read_bytes() == ref.read_bytes()
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.table({"x": [1.0]}), tmp_path / "not_a_log.parquet")
    assert main(["export-blf", str(tmp_path / "not_a_log.parquet")]) == 2
    assert main(["export-blf", str(tmp_path / "missing.parquet")]) == 2
    assert "not a CAN log" in capsys.readouterr().err


@pytest.mark.parametrize("background", [False, True])
def test_cycle_column_is_the_cells_cycle_of_every_frame(tmp_path, background):
    """In process (the recorder in this process or in its writer process), every frame's
    ``cycle`` is the cycle that sent it; pandas reads the column as int64; the BLF export is
    unchanged by it."""
    import pandas as pd

    from fieldbus import PowerlinkNetwork
    from tests.fieldbus.test_network import drive, scaling

    path = tmp_path / "run.parquet"
    with PowerlinkNetwork({"recording": {"flush_every_cycles": 37, "background": background}}, scaling(),
                          log_path=path) as network:
        drive(network, 120)
        period, t0 = network.config.cycle_time_s, network.config.start_time_s
    log = read_frames(path)
    assert np.array_equal(np.bincount(log.cycles), [19] * 120) and (np.diff(log.cycles) >= 0).all()
    # each frame within its cycle's window (a jittered SoC may be stamped just before the cycle's
    # nominal start: floor(t / cycle_time) would put it into the cycle before)
    phase = (log.timestamps - t0) / period - log.cycles
    assert phase.min() > -0.01 and phase.max() < 1 and (np.floor(phase) < 0).any()
    table = pd.read_parquet(path).sort_values("seq")
    assert str(table["cycle"].dtype) == "int64" and table["cycle"].tolist() == log.cycles.tolist()
    socs = table[table["id"] == 0x080]
    assert (socs["sync_counter"] == socs["cycle"] % network.config.scaling.sync_counter_overflow + 1).all()
    field = pq.read_schema(path).field("cycle")
    assert b"POWERLINK cycle" in field.metadata[b"description"]
    assert pq.ParquetFile(path).metadata.metadata[b"format"] == FORMAT.encode()


def test_split_endpoints_log_their_cycle(tmp_path):
    """Managing node and drives as separate endpoints, each writing its own columnar log (as
    in split processes): each frame's ``cycle`` is the cycle of the endpoint that logged it,
    in the partial stream while the run goes and in the file after."""
    from fieldbus.config import FieldbusConfig
    from fieldbus.endpoints import DriveEndpoint, ManagingNodeEndpoint, default_channel
    from fieldbus import DriveActuals, Setpoints
    from tests.fieldbus.test_network import scaling

    config = FieldbusConfig.from_dict({"recording": {"flush_every_cycles": 10}})
    channel = default_channel(config)
    setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
    with ManagingNodeEndpoint(config, scaling(), channel=channel, log_path=tmp_path / "mn.parquet") as mn, \
            DriveEndpoint(config, scaling(), channel=channel, log_path=tmp_path / "cn.parquet") as cn:
        for k in range(50):
            mn.send_setpoints(k, setpoints)
            cn.run_cycle(k, actuals)
            mn.collect_actuals(k)
        going = read_frames(tmp_path / "mn.parquet")
        phase = going.timestamps / config.cycle_time_s - going.cycles
        assert not going.complete and going.cycles.size and phase.min() > -0.01 and phase.max() < 1
    for side, per_cycle in (("mn", 7), ("cn", 12)):
        log = read_frames(tmp_path / f"{side}.parquet")
        assert np.array_equal(np.bincount(log.cycles), [per_cycle] * 50), side


def test_a_log_without_the_cycle_column_still_reads(tmp_path):
    """A format-2 file (before the ``cycle`` column) reads as the same frames, ``cycles`` None."""
    from fieldbus.canlog import FORMAT_2

    ref, log = _log_both(tmp_path, [(_telegram_records(100), None)])
    table = pq.read_table(log).drop_columns(["cycle"])
    meta = dict(pq.ParquetFile(log).metadata.metadata)
    meta[b"format"] = FORMAT_2.encode()
    pq.write_table(table.replace_schema_metadata(meta), tmp_path / "old.parquet")
    old = read_frames(tmp_path / "old.parquet")
    assert old.cycles is None and np.array_equal(old.frames, read_frames(log).frames)
    assert to_blf(tmp_path / "old.parquet", tmp_path / "old.blf").read_bytes() == ref.read_bytes()
