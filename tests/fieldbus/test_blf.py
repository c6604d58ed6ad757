"""The array-encoded BLF CAN log (fieldbus/blf.py) is byte for byte what python-can's BLFWriter
writes for the same frames, through the recorder's sorting and watermarks too."""
from __future__ import annotations

import can
import numpy as np
import pytest

from fieldbus.blf import RECORD_DTYPE, BlfRecordWriter
from fieldbus.recorder import RECORD, FrameRecorder, _BlfSink, _LogSink
from fieldbus.telegrams import FastMessage


def random_records(n: int, seed: int, t0: float = 0.0123456) -> bytes:
    """``n`` recorder records: classic frames (0-8 bytes), CAN FD (9-20 bytes), error frames,
    timestamps mostly rising at the POWERLINK cadence with ties and some out of order."""
    rng = np.random.default_rng(seed)
    t = t0 + np.cumsum(rng.choice([0.0, 2e-6, 21e-6, 400e-6], size=n, p=[0.1, 0.5, 0.3, 0.1]))
    late = rng.random(n) < 0.02
    t[late] -= 3e-4  # late frames: recorded out of time order
    lengths = rng.choice(np.arange(21), size=n)
    errors = rng.random(n) < 0.01
    out = []
    for k in range(n):
        data = rng.integers(0, 256, size=lengths[k], dtype=np.uint8).tobytes()
        out.append(RECORD.pack(float(t[k]), int(rng.integers(0, 0x7FF)), int(errors[k]), len(data), data))
    return b"".join(out)


def python_can_file(path, batches) -> None:
    """The reference: the records through the can.Logger sink (FastMessage + BLFWriter)."""
    sink = _LogSink(str(path))
    for records, watermark in batches:
        sink.feed(records, watermark)
    sink.close()


def test_same_bytes_as_python_can_for_mixed_frames(tmp_path):
    records = random_records(12000, seed=3)  # about 1 MB of objects: several 128 KiB containers
    ours, theirs = tmp_path / "ours.blf", tmp_path / "theirs.blf"
    writer = BlfRecordWriter(ours)
    for part in range(0, 12000, 1700):  # batches of any size
        writer.write_records(records[part * RECORD.size:(part + 1700) * RECORD.size])
    writer.close()
    reference = can.BLFWriter(str(theirs))
    for t, i, e, n, d in RECORD.iter_unpack(records):
        reference.on_message_received(FastMessage(t, i, bytearray(d[:n]), bool(e)))
    reference.stop()
    assert ours.read_bytes() == theirs.read_bytes()
    frames = list(can.LogReader(str(ours)))
    assert len(frames) == 12000 and sum(f.is_fd for f in frames) > 4000 and sum(f.is_error_frame for f in frames) > 50


@pytest.mark.parametrize("level", [1, 0])
def test_other_compression_levels_read_back(tmp_path, level):
    records = random_records(3000, seed=5)
    writer = BlfRecordWriter(tmp_path / "x.blf", compression_level=level)
    writer.write_records(records)
    writer.close()
    reference = can.BLFWriter(str(tmp_path / "ref.blf"), compression_level=level)
    for t, i, e, n, d in RECORD.iter_unpack(records):
        reference.on_message_received(FastMessage(t, i, bytearray(d[:n]), bool(e)))
    reference.stop()
    assert (tmp_path / "x.blf").read_bytes() == (tmp_path / "ref.blf").read_bytes()


def test_sink_sorts_and_holds_back_by_watermark_as_the_logger_sink(tmp_path):
    records = random_records(9000, seed=7)
    size = RECORD.size
    times = np.frombuffer(records, dtype=RECORD_DTYPE)["t"]
    batches = []
    for start in range(0, 9000, 1000):  # hand-overs with a watermark a little behind the newest frame
        chunk = records[start * size:(start + 1000) * size]
        batches.append((chunk, float(times[min(start + 1000, 8999)]) - 5e-4))
    batches.append((b"", 1e9))
    python_can_file(tmp_path / "theirs.blf", batches)
    sink = _BlfSink(str(tmp_path / "ours.blf"))
    for chunk, watermark in batches:
        sink.feed(chunk, watermark)
    sink.close()
    assert (tmp_path / "ours.blf").read_bytes() == (tmp_path / "theirs.blf").read_bytes()
    assert sink.written == 9000


def test_empty_log_is_the_same_and_readable(tmp_path):
    writer = BlfRecordWriter(tmp_path / "e.blf")
    writer.close()
    writer.close()  # again: no-op
    reference = can.BLFWriter(str(tmp_path / "r.blf"))
    reference.stop()
    assert (tmp_path / "e.blf").read_bytes() == (tmp_path / "r.blf").read_bytes()
    assert list(can.LogReader(str(tmp_path / "e.blf"))) == []


@pytest.mark.parametrize("background", [False, True])
def test_frame_recorder_blf_in_process_and_in_the_writer_process(tmp_path, background):
    recorder = FrameRecorder(tmp_path / "rec.blf", flush_every_cycles=4, background=background)
    frames = [FastMessage(0.0004 * (k // 3) + 1e-6 * (k % 3), 0x100 + k % 3, bytearray(range(k % 13)))
              for k in range(600)]
    for cycle in range(200):
        recorder.add_many(frames[3 * cycle:3 * cycle + 3])
        recorder.end_cycle(cycle, 0.0004 * cycle)
    recorder.close()
    read = list(can.LogReader(str(tmp_path / "rec.blf")))
    assert recorder.frames_written == 600 and len(read) == 600
    assert [bytes(m.data) for m in read] == [bytes(f.data) for f in frames]
    assert [m.arbitration_id for m in read] == [f.arbitration_id for f in frames]
    assert np.allclose([m.timestamp for m in read], [f.timestamp for f in frames], atol=1e-9)
