"""Set-point look-ahead (``[fieldbus] setpoint_lookahead``): each PReq carries the set-points
of the following k cycles; a drive whose PReq is lost or late applies the buffered one for
that cycle exactly, and only a burst longer than the buffer falls back to
``missing_setpoint``. POWERLINK's consequences (lost frames, threshold counters, CAN log)
stay exactly those of the run without look-ahead."""

import can
import numpy as np
import pytest

from fieldbus import DriveActuals, FieldbusConfig, JointScaling, PowerlinkNetwork, Setpoints, decode
from fieldbus.errors import FieldbusConfigError
from fieldbus.telegrams import RxPdo1, encode_rpdo1, rpdo1_length
from fieldbus_support import PREQ_IDS, lost_preqs, output, scaling, stack
from paced_support import paced_run


def run(tmp_path, name, cycles=120, lookahead=0, bursts=(), missing="hold"):
    """Run the network for ``cycles`` with fieldbus_support.output, PReqs lost in ``bursts``
    ((node or None for all, first cycle, cycles)); returns the applied values per cycle,
    the summary and the CAN log path."""
    table = {"setpoint_lookahead": lookahead, "reaction": {"missing_setpoint": missing},
             "thresholds": {"cn_loss_of_preq": 0, "cn_loss_of_soc": 0},
             "faults": {"bursts": [{"node": node, "start_cycle": start, "cycles": length, "frames": "preq"}
                                   for nodes, start, length in bursts
                                   for node in ([nodes] if nodes else range(1, 7))]}}
    path = tmp_path / f"{name}.blf"
    setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
    setpoints.controlword[:] = 0x0F
    actuals.statusword[:] = 0x1237
    applied = []
    with PowerlinkNetwork(table, scaling(), log_path=path) as network:
        for k in range(cycles):
            result = network.run_cycle(k, setpoints, actuals)
            a = result.applied
            applied.append((a.position.copy(), a.torque_offset.copy(), a.velocity_offset.copy(),
                            a.controlword.copy(), a.fresh.copy()))
            setpoints.position[:], setpoints.torque_offset[:], setpoints.velocity_offset[:] = output(k)
        summary = network.summary()
    return applied, summary, path


def test_telegram_layout_round_trip_and_lengths():
    assert [rpdo1_length(k) for k in range(5)] == [20, 32, 48, 64, 64]
    data = encode_rpdo1(0x0F, 1000, -5, 8, 0, 0, 77, [(1010, -6, 78), (1020, -7, 79), (1030, -8, 80)])
    assert len(data) == 64 and data[9] == 3
    telegram = decode(can.Message(arbitration_id=0x203, data=data, is_fd=True, is_extended_id=False))
    assert isinstance(telegram, RxPdo1)
    assert (telegram.node, telegram.target_position, telegram.velocity_offset) == (3, 1000, 77)
    assert telegram.lookahead == ((1010, -6, 78), (1020, -7, 79), (1030, -8, 80))
    # the first 20 bytes are the plain RPDO1 (reserved byte = entry count)
    assert data[:9] == encode_rpdo1(0x0F, 1000, -5, 8, 0, 0, 77)[:9]
    with pytest.raises(ValueError, match="at most 4"):
        encode_rpdo1(0x0F, 0, 0, lookahead=[(0, 0, 0)] * 5)


@pytest.mark.parametrize("value", [-1, 5, 1.5, "2", True])
def test_bad_lookahead_values_name_file_key_and_range(value):
    with pytest.raises(FieldbusConfigError) as info:
        FieldbusConfig.from_dict({"setpoint_lookahead": value}, source="scn.toml")
    text = str(info.value)
    assert "scn.toml" in text and "setpoint_lookahead" in text and "[0, 4]" in text and "64 bytes" in text


def test_default_is_off_and_lead_includes_the_lookahead():
    assert FieldbusConfig.from_dict({}).setpoint_lookahead == 0
    assert FieldbusConfig.from_dict({}).lead_cycles == 2
    assert FieldbusConfig.from_dict({"setpoint_lookahead": 3, "dead_time_cycles": 2}).lead_cycles == 6


@pytest.mark.parametrize("k, bursts", [(1, [(None, 40, 1), (2, 70, 1)]),
                                        (3, [(None, 40, 3), (4, 80, 2), (None, 100, 1)]),
                                        (4, [(None, 30, 4), (1, 60, 1), (1, 62, 3)])])
def test_bursts_within_the_buffer_apply_exactly_the_no_loss_setpoints(tmp_path, k, bursts):
    clean, clean_summary, _ = run(tmp_path, "clean", lookahead=k)
    lossy, summary, path = run(tmp_path, "lossy", lookahead=k, bursts=bursts)
    for field in (0, 1, 2, 3):  # position, torque offset, velocity offset, controlword: bit-identical
        assert np.array_equal(stack(clean, field), stack(lossy, field))
    # ... while every loss is still counted and missing from the CAN log
    lost = sum(length * (6 if node is None else 1) for node, _, length in bursts)
    counts = _lost_per_node(summary)
    assert sum(counts.values()) == lost
    seen = lost_preqs(path)
    for node, start, length in bursts:
        for cycle in range(start, start + length):
            for n in ([node] if node else range(1, 7)):
                assert n not in seen[cycle]
    assert _covered(summary) == lost
    # the CAN log holds the whole RPDO1s: each look-ahead entry is what the later PReq carried
    preqs = {}
    for msg in can.LogReader(str(path)):
        if msg.arbitration_id in PREQ_IDS:
            assert len(msg.data) == rpdo1_length(k)
            preqs[(round(msg.timestamp / 400e-6), msg.arbitration_id - 0x200)] = decode(msg)
    checked = 0
    for (cycle, node), telegram in preqs.items():
        assert len(telegram.lookahead) == k
        for j, (target, offset, velocity) in enumerate(telegram.lookahead, 1):
            later = preqs.get((cycle + j, node))
            if later is not None:
                assert (later.target_position, later.torque_offset, later.velocity_offset) == (target, offset, velocity)
                checked += 1
    assert checked > 100 * k
    fresh = stack(lossy, 4)
    assert (~fresh[5:]).sum() == lost  # the covered cycles are not fresh PReqs
    assert _covered(clean_summary) == 0


def test_a_burst_longer_than_the_buffer_falls_back_from_the_first_uncovered_cycle(tmp_path):
    k, start, length, d = 2, 50, 5, 1
    for missing in ("hold", "extrapolate"):
        clean, _, _ = run(tmp_path, f"clean_{missing}", lookahead=k, missing=missing)
        lossy, summary, _ = run(tmp_path, f"lossy_{missing}", lookahead=k, bursts=[(None, start, length)],
                                missing=missing)
        pos_clean, pos_lossy = stack(clean, 0), stack(lossy, 0)
        first_missing = start + d  # the SoC that applies the first lost PReq's set-point
        covered_until = first_missing + k  # cycles first_missing .. covered_until - 1 from the buffer
        assert np.array_equal(pos_clean[:covered_until], pos_lossy[:covered_until])
        uncovered = pos_lossy[covered_until]
        if missing == "hold":
            assert np.array_equal(uncovered, pos_lossy[covered_until - 1])
        else:  # one cycle extrapolated from the last two applied (both from the buffer), then held
            step = pos_lossy[covered_until - 1] - pos_lossy[covered_until - 2]
            assert np.allclose(uncovered, pos_lossy[covered_until - 1] + step, atol=1e-9)
            assert np.array_equal(pos_lossy[covered_until + 1], uncovered)
        assert not np.array_equal(uncovered, pos_clean[covered_until])
        assert _covered(summary) == 6 * k


def test_without_lookahead_nothing_changes(tmp_path):
    a, s, _ = run(tmp_path, "a", bursts=[(None, 40, 2)])
    assert _covered(s) == 0
    assert np.array_equal(stack(a, 0)[41], stack(a, 0)[40])  # held, as before


def _lost_per_node(summary):
    return {c["node"]: c["cumulative"] for c in summary["counters"]
            if c["side"] == "cn" and c["kind"] == "loss_of_preq"}


def _covered(summary):
    return sum(summary["setpoint_lookahead"]["cycles_covered_per_node"].values())


def test_python_path_and_compiled_codec_apply_the_same(tmp_path, monkeypatch):
    bursts = [(None, 40, 3), (2, 70, 6)]
    compiled, s1, _ = run(tmp_path, "compiled", lookahead=3, bursts=bursts, missing="extrapolate")
    monkeypatch.setattr("fieldbus.nodes.load_codec", lambda: None)  # the nodes in Python only
    plain, s2, _ = run(tmp_path, "plain", lookahead=3, bursts=bursts, missing="extrapolate")
    for field in range(5):
        assert np.array_equal(stack(compiled, field), stack(plain, field))
    assert s1["setpoint_lookahead"] == s2["setpoint_lookahead"]
    assert _covered(s1) == 6 * 3 + 3


# ---------------------------------------------------------------------------------------
# the paced cell side (virtual clock): a controller late in chosen cycles


PACED_SCALING = JointScaling([100.0] * 6, 2**20, [10.0] * 6)


def _paced(lookahead, late=(), cycles=60, log_path=None):
    def setpoint(k: int, sp: Setpoints) -> None:
        sp.position[:] = 1e-3 * k * k
        sp.torque_offset[:] = 0.1 * k

    config = {"seed": 1, "setpoint_lookahead": lookahead,  # counters: +8 per loss, no trip at two in a row
              "thresholds": {"cn_loss_of_soc": 40, "cn_loss_of_preq": 40}}
    return paced_run(config, PACED_SCALING, cycles, setpoint, late=late, log_path=log_path)


def test_paced_cell_covers_late_cycles_exactly_with_the_same_counters(tmp_path):
    late = {10, 20, 21, 40, 41}
    on_time, ref = _paced(2)
    cell, got = _paced(2, late, log_path=tmp_path / "cell.blf")
    for (p0, t0, _), (p1, t1, _) in zip(ref, got):
        assert np.array_equal(p0, p1) and np.array_equal(t0, t1)
    # the same POWERLINK consequences as without the look-ahead
    plain, held = _paced(0, late)
    errors = lambda cn: sorted((e.cycle, e.node, e.counter) for e in cn.events.events  # noqa: E731
                               if e.event == "error" and e.kind in ("loss_of_preq", "loss_of_soc"))
    assert errors(cell) == errors(plain) and {c for c, _, _ in errors(cell)} == late
    assert {c: v for c, n, v in errors(cell) if n == 1} == {10: 8, 20: 8, 21: 16, 40: 8, 41: 16}
    assert cell.frames_late == plain.frames_late == 5 * 7
    assert sum(cell.nodes.cycles_covered) == 6 * 5 and sum(plain.nodes.cycles_covered) == 0
    assert not np.array_equal(held[11][0], ref[11][0])  # without it the drives held
    frames = list(can.LogReader(str(tmp_path / "cell.blf")))
    assert {len(m.data) for m in frames if m.arbitration_id in PREQ_IDS} == {48}
    assert sorted(round(m.timestamp / 4e-4) for m in frames if m.arbitration_id == 0x080) == \
        [k for k in range(60) if k not in late]


def test_a_controller_that_jumped_cycles_gets_interpolated_lookahead():
    from fieldbus.events import EventLog
    from fieldbus.nodes import ManagingNode
    from fieldbus.timing import CycleLayout

    config = FieldbusConfig.from_dict({"setpoint_lookahead": 3})
    mn = ManagingNode(config, PACED_SCALING, CycleLayout.from_config(config), EventLog())
    times = [0.0] * 13
    cpr = PACED_SCALING.counts_per_rad[0]
    sent = {}
    for cycle in list(range(0, 10)) + [16, 17]:  # cycles 10..15 skipped: the controller fell behind
        frames = mn.frames(cycle, times, [0x0F] * 6, [cycle * 100 / cpr] * 6, [0.0] * 6)
        t = decode(can.Message(arbitration_id=0x201, data=frames[1].data, is_fd=True, is_extended_id=False))
        sent[cycle] = [t.target_position] + [e[0] for e in t.lookahead]
    assert sent[9] == [600, 700, 800, 900]  # each output 3 cycles late, and ahead in the 3 PReqs before
    # the new output (1600) goes last; the set-points between 900 and 1600 are interpolated
    assert sent[16] == [1300, 1400, 1500, 1600]
    assert sent[17] == [1400, 1500, 1600, 1700]
    # a new controlword replaces the plan at once
    frames = mn.frames(18, times, [0x07] * 6, [5.0 / cpr] * 6, [0.0] * 6)
    t = decode(can.Message(arbitration_id=0x201, data=frames[1].data, is_fd=True, is_extended_id=False))
    assert (t.controlword, t.target_position, [e[0] for e in t.lookahead]) == (0x07, 5, [5, 5, 5])


def test_velocity_and_torque_modes_take_their_own_setpoint_from_the_lookahead(tmp_path):
    """Modes 9 (CSV: target velocity) and 10 (CST: target torque) carry their own set-point in
    the entries: a covered burst applies exactly the no-loss values of the active mode."""

    def run_modes(name, bursts):
        table = {"setpoint_lookahead": 3, "thresholds": {"cn_loss_of_preq": 0, "cn_loss_of_soc": 0},
                 "faults": {"bursts": [{"node": n, "start_cycle": s, "cycles": c, "frames": "preq"}
                                       for s, c in bursts for n in range(1, 7)]}}
        sp, act = Setpoints.zeros(6), DriveActuals.zeros(6)
        sp.controlword[:] = 0x0F
        sp.modes_of_operation[:] = [8, 9, 10, 9, 10, 8]
        act.statusword[:] = 0x1237
        out = []
        with PowerlinkNetwork(table, scaling(), log_path=tmp_path / f"{name}.blf") as network:
            for k in range(90):
                a = network.run_cycle(k, sp, act).applied
                out.append(np.concatenate([a.position, a.target_velocity, a.target_torque, a.torque_offset,
                                           a.velocity_offset, a.modes_of_operation]))
                q, tau, qd = output(k)
                sp.position[:], sp.torque_offset[:], sp.velocity_offset[:] = q, tau, qd
                sp.target_velocity[:] = 2.0 * qd
                sp.target_torque[:] = 10.0 * np.sin(3e-2 * k * np.arange(1, 7))
            return np.array(out), network.summary()

    clean, _ = run_modes("clean", [])
    lossy, summary = run_modes("lossy", [(30, 3), (60, 2)])
    for block, nodes in ((1, [1, 3]), (2, [2, 4])):  # target velocity of the CSV drives, target torque of the CST
        cols = [block * 6 + i for i in nodes]
        assert np.array_equal(clean[:, cols], lossy[:, cols])
        assert np.abs(np.diff(clean[:, cols], axis=0)).max() > 0  # they do change every cycle
    for block in (3, 4):  # torque and velocity offsets of every drive
        assert np.array_equal(clean[:, block * 6:(block + 1) * 6], lossy[:, block * 6:(block + 1) * 6])
    assert np.array_equal(clean[:, [0, 5]], lossy[:, [0, 5]])  # target position of the CSP drives
    assert _covered(summary) == 6 * 5
