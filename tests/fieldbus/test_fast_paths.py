"""The compiled fieldbus codec (fieldbus/codec.c) gives exactly what the Python nodes give:
every applied and observed value and the whole summary (counters, faults, saturations),
with random losses, late and corrupted frames, saturating values, fault reactions and
fault reset, on simbus and python-can's virtual interface."""
from __future__ import annotations

import numpy as np
import pytest

from fieldbus import DriveActuals, PowerlinkNetwork, Setpoints
from fieldbus import nodes
from fieldbus.codec import load_codec
from fieldbus_support import ENABLED, FAULT_CONFIGS, scaling


def trace(config: dict, cycles: int, seed: int) -> tuple[list, dict]:
    """Everything the network returns per cycle, and its summary, for varied set-points
    and actual values (including out-of-range ones that saturate) and fault resets."""
    rng = np.random.default_rng(seed)
    setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
    actuals.statusword[:] = ENABLED
    out = []
    with PowerlinkNetwork(config, scaling()) as network:
        for k in range(cycles):
            setpoints.controlword[:] = 0x8F if k % 97 == 50 else 0x0F
            setpoints.position[:] = rng.normal(0.0, 1.0, 6)
            setpoints.torque_offset[:] = rng.normal(0.0, 100.0, 6)
            setpoints.modes_of_operation[:] = rng.integers(8, 11, 6)
            setpoints.target_velocity[:] = rng.normal(0.0, 2.0, 6)
            setpoints.velocity_offset[:] = rng.normal(0.0, 0.5, 6)
            setpoints.target_torque[:] = rng.normal(0.0, 100.0, 6)
            actuals.position[:] = rng.normal(0.0, 1.0, 6)
            actuals.velocity[:] = rng.normal(0.0, 2.0, 6)
            actuals.torque[:] = rng.normal(0.0, 100.0, 6)
            actuals.modes_of_operation_display[:] = rng.integers(8, 11, 6)
            if k % 53 == 7:  # beyond the telegram ranges: saturated on both sides
                setpoints.torque_offset[2] = 1e6
                setpoints.target_torque[1] = -1e6
                setpoints.target_velocity[3] = 1e9
                actuals.velocity[4] = -1e9
            result = network.run_cycle(k, setpoints, actuals)
            out.append((result.applied.copy(), result.observed.copy()))
        summary = network.summary()
    return out, summary


CONFIGS = {**FAULT_CONFIGS,
           "virtual": {"bus": {"interface": "virtual"}, "seed": 2, "faults": {"loss_probability": 5e-3}}}


class CountingCodec:
    """The compiled codec, counting the calls that did the work (status 0 / a result)."""

    def __init__(self, codec) -> None:
        self.codec = codec
        self.done: dict[str, int] = {}

    def __getattr__(self, name: str):
        fn = getattr(self.codec, name)

        def call(*args):
            result = fn(*args)
            if name in ("receive_pres", "receive_preq", "pres_frames") or result == 0 or \
                    (name == "apply_due" and result >= 0):
                self.done[name] = self.done.get(name, 0) + 1
            return result
        return call


needs_codec = pytest.mark.skipif(load_codec() is None, reason="no C compiler / Python headers for the fieldbus codec")


@needs_codec
@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_compiled_codec_equals_the_python_nodes(monkeypatch, name):
    counting = CountingCodec(load_codec())
    monkeypatch.setattr(nodes, "load_codec", lambda: counting)
    fast, fast_summary = trace(CONFIGS[name], 300, 1)
    least = 250 if name == "clean" else 30  # latched faults go through Python: both paths are exercised
    for fn in ("pack_preq", "latch_pres", "apply_due", "scale_into", "pres_frames", "receive_pres", "receive_preq"):
        assert counting.done.get(fn, 0) > least, (fn, counting.done)
    monkeypatch.setattr(nodes, "load_codec", lambda: None)
    slow, slow_summary = trace(CONFIGS[name], 300, 1)
    assert fast_summary == slow_summary
    if name != "clean":
        assert fast_summary["faults"], "the faulty configurations must produce faults"
    assert fast_summary["scaling_saturations"]["torque"] > 0 and fast_summary["scaling_saturations"]["velocity"] > 0
    # the new set-points and the display really travel (not all defaults)
    assert {int(m) for fa, _ in fast for m in fa.modes_of_operation} == {8, 9, 10}
    assert {int(m) for _, fo in fast for m in fo.modes_of_operation_display} == {8, 9, 10}
    assert any(np.any(fa.target_velocity != 0) and np.any(fa.velocity_offset != 0) and np.any(fa.target_torque != 0)
               for fa, _ in fast)
    for k, ((fa, fo), (sa, so)) in enumerate(zip(fast, slow)):
        for field in ("controlword", "position", "torque_offset", "fresh", "comm_fault", "fault_code",
                      "modes_of_operation", "target_velocity", "velocity_offset", "target_torque"):
            np.testing.assert_array_equal(getattr(fa, field), getattr(sa, field), err_msg=f"cycle {k} applied.{field}")
        for field in ("statusword", "position", "velocity", "torque", "error_code", "fresh", "node_fault",
                      "modes_of_operation_display"):
            np.testing.assert_array_equal(getattr(fo, field), getattr(so, field), err_msg=f"cycle {k} observed.{field}")


@needs_codec
def test_codec_declines_what_python_must_report(monkeypatch):
    """Non-finite set-points and a statusword beyond 16 bits: the codec leaves them to
    Python, which raises the documented errors."""
    network = PowerlinkNetwork({}, scaling())
    setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
    actuals.statusword[:] = ENABLED
    network.run_cycle(0, setpoints, actuals)
    setpoints.position[3] = np.nan
    with pytest.raises(ValueError, match="expected finite numbers"):
        network.run_cycle(1, setpoints, actuals)
    network.close()
    network = PowerlinkNetwork({}, scaling())
    actuals.statusword[2] = 0x1_0000
    with pytest.raises(ValueError, match=r"actuals.statusword\[2\] = 65536"):
        network.run_cycle(0, Setpoints.zeros(6), actuals)
    network.close()


@needs_codec
def test_recorder_records_packed_by_the_codec_equal_struct_pack():
    import can

    from fieldbus.recorder import RECORD
    from fieldbus.telegrams import FastMessage

    frames = [FastMessage(0.25, 0x181, bytearray(b"\x01\x02\x03\x04\x05\x06\x07\x08")),
              FastMessage(1e-4, 0x080, bytearray(b"\x05")),
              FastMessage(3, 0x205, bytearray(b"\xa5"), is_error_frame=True),
              can.Message(timestamp=7.5, arbitration_id=0x7FF, is_extended_id=False, data=b"\x01\x02"),
              FastMessage(2.0, 0x281, bytearray(range(12)))]
    expected = b"".join(RECORD.pack(m.timestamp, m.arbitration_id, m.is_error_frame, len(m.data), m.data)
                        for m in frames)
    assert load_codec().pack_records(frames) == expected

    assert load_codec().pack_records([FastMessage(0.0, 0x1_0000, bytearray(8))]) is None  # struct.error in Python


@needs_codec
def test_recorder_add_many_appends_compiled_records_in_order_with_the_python_fallback(tmp_path):
    """The recorder's compiled add_many (pack_records_append into one bytearray) hands over the
    bytes the Python add_many hands over, in call order, also when a frame the codec declines
    (a NumPy timestamp) is packed in Python between compiled calls; a frame that fits no record
    raises struct.error as in Python and records nothing of its call. Each record's cell cycle is
    the cycle of the next end_cycle (records after the last one: the cycle after it)."""
    import struct

    import numpy as np

    from fieldbus.recorder import RECORD, FrameRecorder
    from fieldbus.telegrams import FastMessage

    batches = [[FastMessage(0.25, 0x181, bytearray(b"\x01\x02\x03")), FastMessage(1e-4, 0x080, bytearray(b"\x05"))],
               [FastMessage(0.5, 0x201, bytearray(range(20))), FastMessage(np.float64(0.75), 0x202, bytearray(b"\x07"))],
               (FastMessage(3, 0x205, bytearray(b"\xa5"), is_error_frame=True),), []]
    expected = b"".join(RECORD.pack(m.timestamp, m.arbitration_id, m.is_error_frame, len(m.data), m.data)
                        for batch in batches for m in batch)
    handed: list[bytes] = []
    handed_cycles: list[list[int]] = []

    class Sink:
        written = 0

        def feed(self, records, watermark_s, cycles):
            handed.append(records)
            handed_cycles.append(cycles.tolist())

        def close(self):
            pass

    recorder = FrameRecorder(tmp_path / "can.parquet")
    assert not hasattr(recorder.add_many, "__func__")  # the compiled one: no Python method
    recorder._sink = Sink()
    for k, batch in enumerate(batches):
        recorder.add_many(batch)
        if k == 0:
            recorder.end_cycle(3, 0.0)  # (not a hand-over cycle)
    with pytest.raises(struct.error):
        recorder.add_many([FastMessage(1.0, 0x181, bytearray(2)), FastMessage(1.0, 0x1_0000, bytearray(8))])
    recorder.flush(None)
    recorder.add_many(batches[0])
    recorder.flush(None)
    assert handed == [expected, expected[:2 * RECORD.size]]
    assert handed_cycles == [[3, 3, 4, 4, 4], [4, 4]]
    assert recorder.frames_recorded == 7


@pytest.mark.parametrize("codec", ["compiled", "python"])
def test_drive_side_accepts_a_classic_8_byte_rpdo1(monkeypatch, codec):
    """A controller on classic CAN sends the 8-byte CSP telegram: applied as mode 8 without
    velocity offset, target velocity and target torque, through both code paths."""
    import struct

    from fieldbus.telegrams import FastMessage

    if codec == "python":
        monkeypatch.setattr(nodes, "load_codec", lambda: None)
    elif load_codec() is None:
        pytest.skip("no compiled codec")
    network = PowerlinkNetwork({}, scaling())
    cn, actuals = network.cn, DriveActuals.zeros(6)
    cn.start_cycle(0, actuals)
    counts = 1000
    frames = [FastMessage(1e-5, 0x080, bytearray(b"\x01"))]
    frames += [FastMessage(2e-5 * (i + 1), 0x201 + i, bytearray(struct.pack("<Hih", 0x0F, counts * (i + 1), 5)))
               for i in range(6)]
    cn.receive_all(frames)
    cn.end_cycle(0)
    applied = cn.start_cycle(1, actuals)
    assert applied.fresh.all() and (applied.controlword == 0x0F).all()
    np.testing.assert_array_equal(applied.position, counts * np.arange(1, 7) * scaling().rad_per_count)
    assert (applied.modes_of_operation == 8).all()
    assert not applied.target_velocity.any() and not applied.velocity_offset.any() and not applied.target_torque.any()
    network.close()


def test_unknown_mode_of_operation_from_the_controller_is_a_clear_error(monkeypatch):
    for codec in (load_codec(), None):
        monkeypatch.setattr(nodes, "load_codec", lambda: codec)
        with PowerlinkNetwork({}, scaling()) as network:
            setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
            network.run_cycle(0, setpoints, actuals)
            setpoints.modes_of_operation[4] = 7
            with pytest.raises(ValueError, match=r"setpoints.modes_of_operation\[4\] = 7: expected 8 \(cyclic "
                                                 r"synchronous position\), 9 \(cyclic synchronous velocity\) or 10"):
                network.run_cycle(1, setpoints, actuals)
            setpoints.modes_of_operation = setpoints.modes_of_operation.astype(float)
            with pytest.raises(ValueError, match="setpoints.modes_of_operation has dtype float64: expected integers"):
                network.run_cycle(1, setpoints, actuals)
