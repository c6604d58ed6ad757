"""Telegram layouts, SI scaling and CiA 402 words: property-based round trips and a
decoder that only ever answers with a telegram or a FrameDecodeError."""
import math
import struct
import tomllib
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fieldbus import (Command, DriveState, FrameDecodeError, JointScaling, ScalingError, command_name,
                      decode, decode_statusword, statusword_for)
from fieldbus.cia402 import StatuswordError, motion_enabled
from fieldbus.telegrams import (INT16_MAX, INT16_MIN, INT32_MAX, INT32_MIN, RxPdo1, Sync, TxPdo1, TxPdo2,
                                classify, encode_rpdo1, encode_tpdo1, encode_tpdo2)

PARAMS = tomllib.loads((Path(__file__).resolve().parents[2] / "robot" / "rx130l_params.toml").read_text())
TRAIN = PARAMS["drive_train"]
SCALING = JointScaling(TRAIN["gear_ratio"]["value"], TRAIN["encoder_counts_per_motor_rev"]["value"],
                       TRAIN["rated_torque"]["value"])

uint16 = st.integers(0, 0xFFFF)
int16 = st.integers(INT16_MIN, INT16_MAX)
int32 = st.integers(INT32_MIN, INT32_MAX)
joint = st.integers(0, 5)


def message(arbitration_id, data, **flags):
    return can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False, **flags)


@given(node=st.integers(1, 127), cw=uint16, pos=int32, tq=int16)
def test_rpdo1_round_trip(node, cw, pos, tq):
    assert decode(message(0x200 + node, encode_rpdo1(cw, pos, tq))) == RxPdo1(node, cw, pos, tq)


@given(node=st.integers(1, 127), sw=uint16, pos=int32, tq=int16, vel=int32, err=uint16)
def test_tpdo_round_trip(node, sw, pos, tq, vel, err):
    assert decode(message(0x180 + node, encode_tpdo1(sw, pos, tq))) == TxPdo1(node, sw, pos, tq)
    assert decode(message(0x280 + node, encode_tpdo2(vel, err))) == TxPdo2(node, vel, err)


def test_encoders_name_the_field_out_of_range():
    with pytest.raises(ValueError, match="target_position"):
        encode_rpdo1(0, INT32_MAX + 1, 0)
    with pytest.raises(ValueError, match="torque_actual"):
        encode_tpdo1(0, 0, INT16_MIN - 1)


def test_telegram_sizes():
    """The RPDO1 with all cyclic synchronous set-points is a 20-byte CAN FD frame whose first
    8 bytes are the classic CSP telegram; the PRes telegrams fit classic CAN."""
    full = encode_rpdo1(0x0F, 1, 2)
    assert len(full) == 20 and full[:8] == struct.pack("<Hih", 0x0F, 1, 2)
    assert len(encode_tpdo1(0x27, 1, 2)) == 8
    assert len(encode_tpdo2(1, 0)) == 7
    assert decode(message(0x080, b"\x05")) == Sync(5)


def test_rpdo1_carries_the_modes_of_operation_and_their_set_points():
    data = encode_rpdo1(0x0F, -5, 7, 10, -300, 123456, -42)
    assert decode(message(0x203, data)) == RxPdo1(3, 0x0F, -5, 7, 10, -300, 123456, -42)
    # layout: controlword, position, torque offset, mode, reserved, target torque, target velocity, offset
    assert struct.unpack("<HihbBhii", data) == (0x0F, -5, 7, 10, 0, -300, 123456, -42)
    # a classic 8-byte RPDO1 (controller on classic CAN) reads as CSP without offsets
    classic = struct.pack("<Hih", 0x0F, -5, 7)
    assert decode(message(0x203, classic)) == RxPdo1(3, 0x0F, -5, 7, 8, 0, 0, 0)
    assert decode(message(0x283, encode_tpdo2(9, 0x8611, 9))) == TxPdo2(3, 9, 0x8611, 9)


@pytest.mark.parametrize("mode", [0, 1, 7, 11, -1, True])
def test_unknown_mode_of_operation_is_refused_by_the_encoder(mode):
    with pytest.raises(ValueError, match=r"modes_of_operation = .*expected 8 \(cyclic synchronous position\), 9"):
        encode_rpdo1(0x0F, 0, 0, mode)


def test_rpdo1_field_ranges_are_named():
    with pytest.raises(ValueError, match="target_velocity"):
        encode_rpdo1(0, 0, 0, 9, 0, INT32_MAX + 1, 0)
    with pytest.raises(ValueError, match="target_torque"):
        encode_rpdo1(0, 0, 0, 10, INT16_MAX + 1, 0, 0)
    with pytest.raises(ValueError, match="modes_of_operation_display"):
        encode_tpdo2(0, 0, 200)


def test_counts_per_radian_follow_gear_and_encoder():
    expected = 65536 * np.array(TRAIN["gear_ratio"]["value"]) / (2 * math.pi)
    np.testing.assert_allclose(SCALING.counts_per_rad, expected)
    # 0.1 % of rated torque per unit
    np.testing.assert_allclose(SCALING.newton_metre_per_unit, np.array(TRAIN["rated_torque"]["value"]) / 1000)
    # the INT32 position covers far more than a joint's travel
    assert np.all(SCALING.max_position > 2 * math.pi)


@given(i=joint, q=st.floats(-6.0, 6.0), qd=st.floats(-10.0, 10.0), tau=st.floats(-1000.0, 1000.0))
def test_si_round_trip_within_one_count(i, q, qd, tau):
    counts = SCALING.position_count(i, q)
    assert abs(counts * SCALING.rad_per_count[i] - q) <= 0.5 * SCALING.rad_per_count[i] * (1 + 1e-9)
    velocity = SCALING.velocity_count(i, qd)
    assert abs(velocity * SCALING.rad_per_count[i] - qd) <= 0.5 * SCALING.rad_per_count[i] * (1 + 1e-9)
    units = SCALING.torque_unit(i, tau)
    if abs(tau) < SCALING.max_torque[i]:
        assert abs(units * SCALING.newton_metre_per_unit[i] - tau) <= 0.5 * SCALING.newton_metre_per_unit[i] * (1 + 1e-9)


@given(i=joint, counts=st.integers(-10**7, 10**7), units=int16)
def test_decoded_values_encode_to_the_same_integer(i, counts, units):
    assert SCALING.position_count(i, counts * SCALING.rad_per_count[i]) == counts
    assert SCALING.torque_unit(i, units * SCALING.newton_metre_per_unit[i]) == units


@given(q=st.lists(st.floats(-6.0, 6.0), min_size=6, max_size=6))
def test_vector_and_scalar_encoders_agree(q):
    vector = SCALING.position_to_counts(np.array(q))
    assert vector.tolist() == [SCALING.position_count(i, x) for i, x in enumerate(q)]
    np.testing.assert_allclose(SCALING.quantise_position(np.array(q)), vector * SCALING.rad_per_count)


def test_out_of_range_values_saturate_and_are_counted():
    scaling = JointScaling([100.0] * 6, 65536, [10.0] * 6)
    units = scaling.torque_to_units(np.full(6, 1e6))
    assert units.tolist() == [INT16_MAX] * 6
    assert scaling.saturations()["torque"] == 6
    assert scaling.position_count(0, 1e6) == INT32_MAX
    assert scaling.saturations()["position"] == 1
    with pytest.raises(ScalingError, match="finite"):
        scaling.position_to_counts(np.array([np.nan] * 6))


@pytest.mark.parametrize("kwargs, fragment", [
    ({"gear_ratio": [100.0, 0.0], "encoder_counts_per_motor_rev": 65536, "rated_torque": 1.0}, "gear_ratio"),
    ({"gear_ratio": [1.0, 1.0], "encoder_counts_per_motor_rev": -1, "rated_torque": 1.0}, "encoder_counts"),
    ({"gear_ratio": [1.0, 1.0], "encoder_counts_per_motor_rev": 1, "rated_torque": [1.0, 2.0, 3.0]}, "rated_torque has 3"),
])
def test_bad_scaling_is_rejected_by_name(kwargs, fragment):
    with pytest.raises(ScalingError, match=fragment):
        JointScaling(**kwargs)


# ---------------------------------------------------------------- robust decoding

frames = st.builds(
    lambda arbitration_id, data, error, remote, extended: can.Message(
        arbitration_id=arbitration_id, data=b"" if remote else data, is_error_frame=error,
        is_remote_frame=remote and not error, is_extended_id=extended),
    arbitration_id=st.integers(0, 0x7FF), data=st.binary(max_size=8), error=st.booleans(),
    remote=st.booleans(), extended=st.booleans())


@settings(max_examples=500)
@given(msg=frames)
def test_decoder_answers_with_a_telegram_or_a_frame_decode_error(msg):
    try:
        telegram = decode(msg)
    except FrameDecodeError as error:
        assert error.reason in {"unknown_id", "short_frame", "long_frame", "error_frame", "remote_frame"}
        assert f"0x{msg.arbitration_id:03X}" in str(error)
    else:
        kind, node = classify(msg.arbitration_id)
        assert kind != "unknown" and not msg.is_error_frame
        assert getattr(telegram, "node", node) == node


def test_decoder_reasons():
    with pytest.raises(FrameDecodeError) as info:
        decode(message(0x7E5, b"\x00"))
    assert info.value.reason == "unknown_id"
    with pytest.raises(FrameDecodeError) as info:
        decode(message(0x203, b"\x01\x02\x03"))
    assert (info.value.reason, info.value.node) == ("short_frame", 3)
    with pytest.raises(FrameDecodeError) as info:
        decode(message(0x183, bytes(8), is_error_frame=True))
    assert info.value.reason == "error_frame"


# ---------------------------------------------------------------- CiA 402 words


@pytest.mark.parametrize("state", list(DriveState))
def test_statusword_encoder_and_decoder_agree(state):
    assert decode_statusword(statusword_for(state)) is state
    assert decode_statusword(statusword_for(state, remote=False, warning=True)) is state
    assert motion_enabled(statusword_for(state)) is (state is DriveState.OPERATION_ENABLED)


def test_statusword_examples_from_the_cia402_table():
    assert decode_statusword(0x0250) is DriveState.SWITCH_ON_DISABLED
    assert decode_statusword(0x0231) is DriveState.READY_TO_SWITCH_ON
    assert decode_statusword(0x0233) is DriveState.SWITCHED_ON
    assert decode_statusword(0x1237) is DriveState.OPERATION_ENABLED
    assert decode_statusword(0x0217) is DriveState.QUICK_STOP_ACTIVE
    assert decode_statusword(0x021F) is DriveState.FAULT_REACTION_ACTIVE
    assert decode_statusword(0x0218) is DriveState.FAULT
    with pytest.raises(StatuswordError, match="0x0061"):
        decode_statusword(0x0061)


def test_controlword_commands_have_their_names():
    assert [command_name(int(c)) for c in (Command.SHUTDOWN, Command.SWITCH_ON, Command.ENABLE_OPERATION,
                                           Command.QUICK_STOP, Command.DISABLE_VOLTAGE, Command.FAULT_RESET)] == [
        "shutdown", "switch on", "enable operation", "quick stop", "disable voltage", "fault reset"]
    assert (int(Command.SHUTDOWN), int(Command.SWITCH_ON), int(Command.ENABLE_OPERATION),
            int(Command.FAULT_RESET)) == (0x06, 0x07, 0x0F, 0x80)
