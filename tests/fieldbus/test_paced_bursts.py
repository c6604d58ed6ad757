"""Scenario fault bursts in a paced hardware-in-the-loop run (``cosim run --split --realtime``,
``cosim serve``): the served cell applies them by its own cycle numbers, the controller sends
without a fault plan, and exactly the burst's cycles are lost - the same counters as the
in-process network (one fieldbus, both sides in lock-step) in those cycles."""
from __future__ import annotations

import dataclasses

from cosim.execution.split.paced import controller_faults
from fieldbus import DriveActuals, DriveEndpoint, FieldbusConfig, JointScaling, ManagingNodeEndpoint, Setpoints
from fieldbus.simbus import unique_channel

SCALING = JointScaling([100.0] * 6, 2**20, [10.0] * 6)
BURSTS = [{"node": 3, "start_cycle": 25, "cycles": 1, "frames": "preq", "kind": "loss"},
          {"node": 5, "start_cycle": 40, "cycles": 2, "frames": "pres", "kind": "loss"},
          {"node": 0, "start_cycle": 55, "cycles": 1, "frames": "soc", "kind": "loss"}]
CYCLES = 80


def _config() -> FieldbusConfig:
    return FieldbusConfig.from_dict({"seed": 1, "faults": {"bursts": BURSTS}})


def _errors(side) -> list[tuple[int, str, int, int]]:
    return sorted((e.cycle, e.kind, e.node, e.counter) for e in side.events.events if e.event == "error")


def _setpoints(k: int, sp: Setpoints, act: DriveActuals) -> None:
    sp.controlword[:] = 0x0F
    sp.position[:] = 1e-3 * k
    act.statusword[:] = 0x27


def _in_process():
    config, channel = _config(), unique_channel("burst")
    mn = ManagingNodeEndpoint(config, SCALING, channel=channel)
    cn = DriveEndpoint(config, SCALING, channel=channel)
    sp, act = Setpoints.zeros(6), DriveActuals.zeros(6)
    for k in range(CYCLES):
        _setpoints(k, sp, act)
        mn.send_setpoints(k, sp)
        cn.run_cycle(k, act)
        mn.collect_actuals(k)
    mn.close()
    cn.close()
    return mn, cn


def _paced():
    """The cell paced on a virtual clock (every window closed), the controller following it
    with the configuration the split controller uses (no injected faults)."""
    config, channel = _config(), unique_channel("burst")
    controller_config = dataclasses.replace(config, faults=controller_faults(config))
    mn = ManagingNodeEndpoint(controller_config, SCALING, channel=channel)
    cn = DriveEndpoint(config, SCALING, channel=channel)
    sp, act = Setpoints.zeros(6), DriveActuals.zeros(6)
    followed = []
    _setpoints(0, sp, act)
    mn.send_following(sp)  # the cell's cycle 0 starts with the controller's first frames
    for k in range(CYCLES):
        t = k * 4e-4 + 2e-4
        cn.run_cycle_paced(k, act, deadline=t, clock=lambda: t)
        got = mn.follow(1.0)
        assert got is not None
        followed.append(got[0])
        _setpoints(k + 1, sp, act)
        mn.send_following(sp)
    mn.close()
    cn.close()
    return mn, cn, followed


def test_paced_cell_loses_exactly_the_burst_cycles_like_the_in_process_network():
    mn_ref, cn_ref = _in_process()
    mn, cn, followed = _paced()
    assert followed == list(range(CYCLES))  # both sides count the same cycles
    assert mn.frames_dropped == 0  # the controller injects nothing
    cn_errors = _errors(cn)
    # the burst cycles and nothing else, with the in-process counter values
    assert {c for c, *_ in cn_errors} == {25, 55}
    assert cn_errors == _errors(cn_ref)
    assert ((25, "loss_of_preq", 3, 8) in cn_errors and (55, "loss_of_soc", 1, 8) in cn_errors)
    mn_errors = _errors(mn)
    assert {c for c, *_ in mn_errors} == {25, 40, 41}
    assert mn_errors == _errors(mn_ref)
    injected = sorted((e.cycle, e.node, e.kind) for e in cn.events.events if e.event == "injected")
    assert injected == sorted((e.cycle, e.node, e.kind) for side in (mn_ref, cn_ref)
                              for e in side.events.events if e.event == "injected")


def test_split_controller_keeps_no_fault_plan():
    config = FieldbusConfig.from_dict({"seed": 1, "faults": {"bursts": BURSTS, "loss_probability": 1e-3,
                                                              "silent_nodes": [{"node": 2, "from_cycle": 5}]}})
    faults = controller_faults(config)
    assert not faults.random_enabled and faults.bursts == () and faults.silent_nodes == ()
    assert faults.late_delay_s == config.faults.late_delay_s


def test_controller_counts_cell_cycles_without_node_1_pres():
    """A burst that silences node 1's PRes (its PReqs lost) while the controller reads several
    cycles' PRes at once (it was late): it still counts every cell cycle, so it ends with the
    cell instead of waiting for PRes that never come."""
    bursts = [{"node": 1, "start_cycle": 30, "cycles": 3, "frames": "preq", "kind": "loss"}]
    config, channel = FieldbusConfig.from_dict({"seed": 1, "faults": {"bursts": bursts}}), unique_channel("burst")
    mn = ManagingNodeEndpoint(dataclasses.replace(config, faults=controller_faults(config)), SCALING, channel=channel)
    cn = DriveEndpoint(config, SCALING, channel=channel)
    sp, act = Setpoints.zeros(6), DriveActuals.zeros(6)
    _setpoints(0, sp, act)
    mn.send_following(sp)
    followed = []
    for k in range(50):
        t = k * 4e-4 + 2e-4
        cn.run_cycle_paced(k, act, deadline=t, clock=lambda: t)
        if k in (30, 31, 32, 40):  # the controller is late: reads these with the next cycle's PRes
            continue
        got = mn.follow(1.0)
        assert got is not None
        followed.append(got[0])
        mn.send_following(sp)
    mn.close()
    cn.close()
    assert followed == list(range(30)) + list(range(33, 40)) + list(range(41, 50))
