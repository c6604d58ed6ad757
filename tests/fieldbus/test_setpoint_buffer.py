"""Set-point buffer (``[fieldbus] setpoint_buffer = D``, after CiA 402 object 0x60C4): the drive
side keeps a FIFO of up to D (+ dead time) future set-points per node, refilled by every PReq's
look-ahead entries from the first cycle it reports missing in its PRes (byte 7 of an 8-byte
TPDO2); a run of lost PReqs no longer than D is applied exactly as without loss, while POWERLINK's
consequences (lost frames, threshold counters, CAN log) stay those of every lost frame."""
import can
import numpy as np
import pytest

from fieldbus import DriveActuals, FieldbusConfig, PowerlinkNetwork, Setpoints, decode
from fieldbus.errors import FieldbusConfigError
from fieldbus.telegrams import encode_rpdo1, encode_tpdo2
from fieldbus_support import lost_preqs, output, scaling, stack


def run(tmp_path, name, cycles=200, buffer=16, lookahead=4, bursts=(), missing="hold", catch_up=True):
    """The network for ``cycles`` with the outputs of fieldbus_support.output computed ``buffer`` cycles
    ahead; in ``bursts`` ((first cycle, cycles)) every PReq is lost and the controller computes
    nothing (it stalled): with ``catch_up`` it computes the skipped outputs in the first cycle
    after (``ManagingNodeEndpoint.plan_ahead``), else the managing node interpolates the jump."""
    table = {"setpoint_lookahead": lookahead, "setpoint_buffer": buffer, "reaction": {"missing_setpoint": missing},
             "thresholds": {"cn_loss_of_preq": 0, "cn_loss_of_soc": 0, "mn_loss_of_pres": 0},
             "faults": {"bursts": [{"node": node, "start_cycle": start, "cycles": length, "frames": "preq"}
                                   for start, length in bursts for node in range(1, 7)]}}
    stalled = {start + i for start, length in bursts for i in range(length)}
    path = tmp_path / f"{name}.blf"
    setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
    setpoints.controlword[:] = 0x0F
    actuals.statusword[:] = 0x1237
    applied, held = [], []
    last = -1
    with PowerlinkNetwork(table, scaling(), log_path=path) as network:
        mn = network.mn_side
        frames = network.mn._lookahead_frames
        # a stalled controller sends nothing: its PReqs are lost (the bursts) and plan nothing
        network.mn._lookahead_frames = lambda cycle, build=True: (
            network.mn._frames_sent if build and cycle in stalled else frames(cycle, build))
        for k in range(cycles):
            result = network.run_cycle(k, setpoints, actuals)
            a = result.applied
            applied.append((a.position.copy(), a.torque_offset.copy(), a.velocity_offset.copy(),
                            a.controlword.copy(), a.fresh.copy()))
            held.append(list(network.mn.buffer_missing_from))
            if k + 1 in stalled:
                continue  # the PReq of k + 1 is lost: this controller cycle did not run
            if catch_up:
                for j in range(last + 1, k):
                    setpoints.position[:], setpoints.torque_offset[:], setpoints.velocity_offset[:] = output(j)
                    mn.plan_ahead(j + 1, setpoints)
            last = k
            setpoints.position[:], setpoints.torque_offset[:], setpoints.velocity_offset[:] = output(k)
        summary = network.summary()
    return applied, summary, path, held


def test_config_defaults_and_bad_values():
    config = FieldbusConfig.from_dict({"setpoint_lookahead": 4, "setpoint_buffer": 64})
    assert FieldbusConfig.from_dict({}).setpoint_buffer == 0
    assert config.lead_cycles == 1 + 1 + 64 and config.planned_ahead_cycles == 64
    for table, expected in (({"setpoint_buffer": 8}, "setpoint_lookahead >= 1"),
                            ({"setpoint_lookahead": 4, "setpoint_buffer": 3}, "at least setpoint_lookahead"),
                            ({"setpoint_lookahead": 4, "setpoint_buffer": 251}, "[0, 250]"),
                            ({"setpoint_lookahead": 4, "setpoint_buffer": 1.5}, "[0, 250]")):
        with pytest.raises(FieldbusConfigError, match="setpoint_buffer") as info:
            FieldbusConfig.from_dict(table)
        assert expected in str(info.value)


def test_telegram_layout_skip_and_held():
    data = encode_rpdo1(0x0F, 1000, -5, 8, 0, 0, 77, [(1010, -6, 78)] * 4, lookahead_skip=37)
    assert len(data) == 64 and data[9] == 4 and data[60:62] == (37).to_bytes(2, "little")
    telegram = decode(can.Message(arbitration_id=0x201, data=data, is_fd=True, is_extended_id=False))
    assert telegram.lookahead_skip == 37 and len(telegram.lookahead) == 4
    tpdo2 = encode_tpdo2(-12, 0, 8, setpoints_held=65)
    assert len(tpdo2) == 8 and decode(can.Message(arbitration_id=0x281, data=tpdo2, is_extended_id=False)).setpoints_held == 65


@pytest.mark.parametrize("bursts", [((60, 10),), ((50, 16), (100, 3), (130, 12))])
def test_stalls_within_the_buffer_apply_exactly_the_no_loss_setpoints(tmp_path, bursts):
    reference, ref_summary, _, _ = run(tmp_path, "reference")
    lossy, summary, path, held = run(tmp_path, "lossy", bursts=bursts)
    for field in range(4):  # position, torque offset, velocity offset, controlword: bit for bit
        assert np.array_equal(stack(reference, field), stack(lossy, field)), field
    lost = sum(length for _, length in bursts)
    fresh = stack(lossy, 4)
    assert (~fresh).sum() == 6 * lost + 6  # every lost PReq is not fresh (+ cycle 0, before any PReq)
    covered = summary["setpoint_lookahead"]["cycles_covered_per_node"]
    assert covered == {str(n): lost for n in range(1, 7)}
    assert summary["setpoint_lookahead"]["cycles_without_setpoint_per_node"] == {str(n): 1 for n in range(1, 7)}
    tally = summary["event_tally"]
    assert tally["cn.loss_of_preq.error"] == tally["mn.loss_of_pres.error"] == 6 * lost
    seen = lost_preqs(path)
    for start, length in bursts:
        for c in range(start, start + length):
            assert seen[c] == set()  # no PReq of a lost cycle in the CAN log
        assert seen[start + length] == set(range(1, 7))
    # steady state: the drives report holding dead time + D set-points ahead
    assert held[40] == [40 + 1 + 1 + 16] * 6
    # the refill after the longest stall (net +3 per cycle) is done before the next one
    assert held[-1] == [199 + 1 + 1 + 16] * 6


def test_a_stall_longer_than_the_buffer_falls_back_and_is_counted(tmp_path):
    reference, _, _, _ = run(tmp_path, "reference", missing="extrapolate")
    lossy, summary, _, _ = run(tmp_path, "lossy", bursts=((60, 20),), missing="extrapolate")
    position = stack(lossy, 0)
    ref = stack(reference, 0)
    # PReqs 60..79 lost: the drives hold set-points up to the SoC of 59 + 1 + 16 = 76 (exact),
    # from the SoC of 77 on nothing: missing_setpoint (extrapolate one cycle, then hold)
    assert np.array_equal(position[:77], ref[:77])
    assert not np.array_equal(position[77], ref[77]) and np.array_equal(position[78], position[79])
    covered = summary["setpoint_lookahead"]["cycles_covered_per_node"]
    without = summary["setpoint_lookahead"]["cycles_without_setpoint_per_node"]
    # SoCs 61..76 covered (16), 77..80 without (the PReq of 80 applies at 81)
    assert covered == {str(n): 16 for n in range(1, 7)} and without == {str(n): 1 + 4 for n in range(1, 7)}
    assert np.array_equal(position[100:], ref[100:])  # refilled and exact again


def test_plain_rpdo1_empties_the_buffer_and_k_only_is_unchanged(tmp_path):
    """Without the buffer nothing changes (test_lookahead's runs); the drive side of a buffered
    configuration serves a controller that sends plain RPDO1s as before (8-byte TPDO2 reporting 0)."""
    table = {"setpoint_lookahead": 4, "setpoint_buffer": 16}
    config = FieldbusConfig.from_dict(table)
    with PowerlinkNetwork({"setpoint_lookahead": 0}, scaling()) as plain, \
            PowerlinkNetwork(table, scaling()) as network:
        cn = network.cn
        for k in range(5):
            cn.start_cycle(k, DriveActuals.zeros(6))
            cn.receive_all([can.Message(arbitration_id=0x201, data=encode_rpdo1(0x0F, 100 + k, 0), is_fd=True,
                                        is_extended_id=False)])
            frames = cn.responses([0.0] * 13, answer_all=True)
            cn.end_cycle(k)
        tpdo2 = [m for m in frames if m.arbitration_id == 0x281][0]
        assert len(tpdo2.data) == 8 and tpdo2.data[7] == 0
        assert config.setpoint_buffer == 16 and plain.config.setpoint_buffer == 0
