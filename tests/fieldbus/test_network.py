"""PowerlinkNetwork end to end: dead time, SYNC spacing and frame completeness read back
from the python-can log, latched actual values, other interfaces, recording."""
import os
import subprocess
import sys

import can
import numpy as np
import pytest

from fieldbus import DriveActuals, PowerlinkNetwork, Setpoints, decode
from fieldbus.telegrams import RxPdo1
from fieldbus_support import scaling

T = 400e-6
NO_JITTER = {"timing": {"soc_jitter_us": 0.0, "response_jitter_us": 0.0}}
NODE_IDS = {0x200 + n for n in range(1, 7)} | {0x180 + n for n in range(1, 7)} | {0x280 + n for n in range(1, 7)}


def drive(network, cycles, first=0):
    """Run ``cycles`` cycles with a distinct set-point per cycle and node and actual
    values that follow a different ramp; returns copies of what came out."""
    setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
    setpoints.controlword[:] = 0x0F
    actuals.statusword[:] = 0x1237
    gains = np.arange(1, 7)
    history = []
    for k in range(first, first + cycles):
        setpoints.position[:] = 1e-3 * (k + 1) * gains
        setpoints.torque_offset[:] = 0.5 * k * gains
        actuals.position[:] = -2e-3 * k * gains
        actuals.velocity[:] = 0.01 * k * gains
        actuals.torque[:] = -0.25 * k * gains
        result = network.run_cycle(k, setpoints, actuals)
        history.append((result.applied.copy(), result.observed.copy(),
                        (setpoints.position.copy(), actuals.position.copy(), actuals.velocity.copy(),
                         actuals.torque.copy())))
    return history


def read_log(path):
    return list(can.LogReader(str(path)))


def cycles_of(frames):
    """Split a time-ordered frame list at the SYNC frames."""
    cycles, current = [], None
    for msg in frames:
        if msg.arbitration_id == 0x080:
            current = [msg]
            cycles.append(current)
        elif current is not None:
            current.append(msg)
    return cycles


@pytest.mark.parametrize("dead_time", [1, 2, 3])
def test_measured_dead_time_equals_the_configured_cycles(tmp_path, dead_time):
    sc = scaling()
    path = tmp_path / "dead.blf"
    with PowerlinkNetwork({"dead_time_cycles": dead_time}, sc, log_path=path) as network:
        history = drive(network, 40)
    applied_counts = [sc.position_to_counts(applied.position) for applied, _, _ in history]
    measured = []
    for cycle in cycles_of(read_log(path))[:30]:
        soc = cycle[0].timestamp
        k = round(soc / T)
        for msg in cycle[1:]:
            telegram = decode(msg)
            if not isinstance(telegram, RxPdo1):
                continue
            i = telegram.node - 1
            effect = next(j for j in range(len(history)) if applied_counts[j][i] == telegram.target_position)
            effect_time = effect * T
            assert effect > k
            assert (dead_time - 1) * T < effect_time - msg.timestamp < dead_time * T
            measured.append((effect_time - soc) / T)
    assert len(measured) == 30 * 6
    assert np.allclose(measured, dead_time, atol=1e-3)


def test_sync_spacing_in_the_log_is_the_cycle_time(tmp_path):
    path = tmp_path / "sync.blf"
    with PowerlinkNetwork(NO_JITTER, scaling(), log_path=path) as network:
        drive(network, 200)
    syncs = [m.timestamp for m in read_log(path) if m.arbitration_id == 0x080]
    assert len(syncs) == 200
    assert np.allclose(np.diff(syncs), T, rtol=0, atol=2e-9)  # BLF stores nanoseconds
    # with the default SoC jitter (+-0.1 us) the spacing stays within twice the jitter
    path = tmp_path / "jitter.blf"
    with PowerlinkNetwork({}, scaling(), log_path=path) as network:
        drive(network, 200)
    spacing = np.diff([m.timestamp for m in read_log(path) if m.arbitration_id == 0x080])
    assert np.all(np.abs(spacing - T) <= 0.2e-6 + 2e-9)
    assert np.std(spacing) > 0


@pytest.mark.parametrize("suffix", [".blf", ".asc"])
def test_every_node_sends_and_receives_once_per_cycle(tmp_path, suffix):
    path = tmp_path / f"frames{suffix}"
    with PowerlinkNetwork({}, scaling(), log_path=path) as network:
        drive(network, 120)
        sent = network.frames_sent
    frames = read_log(path)
    assert len(frames) == sent == 120 * 19
    stamps = [m.timestamp for m in frames]
    assert stamps == sorted(stamps)
    cycles = cycles_of(frames)
    assert len(cycles) == 120
    for cycle in cycles:
        ids = [m.arbitration_id for m in cycle[1:]]
        assert sorted(ids) == sorted(NODE_IDS)
        # POWERLINK order: PReq n, then PRes n (TPDO1, TPDO2), node after node
        assert ids == [x for n in range(1, 7) for x in (0x200 + n, 0x180 + n, 0x280 + n)]
        assert cycle[-1].timestamp - cycle[0].timestamp < T


def test_controller_sees_the_values_latched_at_the_soc_quantised():
    sc = scaling()
    with PowerlinkNetwork({}, sc) as network:
        history = drive(network, 30)
    for applied, observed, (_, q, qd, tau) in history:
        assert observed.fresh.all() and not observed.node_fault.any()
        np.testing.assert_array_equal(observed.position, sc.quantise_position(q))
        np.testing.assert_allclose(observed.velocity, sc.counts_to_velocity(sc.velocity_to_counts(qd)))
        np.testing.assert_array_equal(observed.torque, sc.quantise_torque(tau))
        np.testing.assert_array_equal(observed.statusword, 0x1237)
        assert np.all(np.abs(observed.position - q) <= 0.5 * sc.rad_per_count + 1e-15)


def test_applied_setpoints_are_the_quantised_commands_one_cycle_late():
    sc = scaling()
    with PowerlinkNetwork({}, sc) as network:
        history = drive(network, 20)
    for k in range(1, 20):
        applied = history[k][0]
        commanded = history[k - 1][2][0]
        assert applied.fresh.all()
        np.testing.assert_array_equal(applied.position, sc.quantise_position(commanded))
        np.testing.assert_array_equal(applied.controlword, 0x0F)
        np.testing.assert_allclose(applied.torque_offset, sc.quantise_torque(0.5 * (k - 1) * np.arange(1, 7)))
    assert not history[0][0].fresh.any()  # nothing was sent before cycle 0: drives hold


def test_cycles_must_run_consecutively_and_setpoints_must_be_finite():
    with PowerlinkNetwork({}, scaling()) as network:
        network.run_cycle(5, Setpoints.zeros(6), DriveActuals.zeros(6))
        with pytest.raises(ValueError, match="expected cycle 6"):
            network.run_cycle(7, Setpoints.zeros(6), DriveActuals.zeros(6))
        bad = Setpoints.zeros(6)
        bad.position[2] = np.nan
        with pytest.raises(ValueError, match="position"):
            network.run_cycle(6, bad, DriveActuals.zeros(6))


def test_scaling_must_match_the_node_count():
    with pytest.raises(ValueError, match="nodes"):
        PowerlinkNetwork({"nodes": 5}, scaling())


def _outputs(history):
    return [(a.position.tolist(), a.fresh.tolist(), o.position.tolist(), o.velocity.tolist(), o.fresh.tolist())
            for a, o, _ in history]


def test_virtual_interface_gives_the_same_result_as_simbus(tmp_path):
    with PowerlinkNetwork({}, scaling()) as network:
        reference = _outputs(drive(network, 40))
    with PowerlinkNetwork({"bus": {"interface": "virtual"}}, scaling(), log_path=tmp_path / "v.blf") as network:
        assert type(network.mn_bus).__name__ == "VirtualBus"
        assert _outputs(drive(network, 40)) == reference
    stamps = [m.timestamp for m in read_log(tmp_path / "v.blf")]
    assert stamps[0] < 1e-6 and stamps[-1] < 40 * T  # simulated, not wall-clock, timestamps


def test_udp_multicast_interface_gives_the_same_result_as_simbus():
    with PowerlinkNetwork({}, scaling()) as network:
        reference = _outputs(drive(network, 15))
    port = 41000 + os.getpid() % 2000
    config = {"bus": {"interface": "udp_multicast", "channel": "239.74.163.2",
                      "receive_timeout_s": 2.0, "options": {"port": port}}}
    with PowerlinkNetwork(config, scaling()) as network:
        assert _outputs(drive(network, 15)) == reference
        assert network.frames_missing == 0


def test_unknown_interface_is_a_config_error():
    with pytest.raises(ValueError, match="bus.interface"):
        PowerlinkNetwork({"bus": {"interface": "no_such_can"}}, scaling())


def test_background_recording_writes_the_same_log(tmp_path):
    with PowerlinkNetwork({}, scaling(), log_path=tmp_path / "inline.blf") as network:
        drive(network, 300)
    with PowerlinkNetwork({"recording": {"background": True, "flush_every_cycles": 50}}, scaling(),
                          log_path=tmp_path / "background.blf") as network:
        drive(network, 300)
    inline = [(m.timestamp, m.arbitration_id, bytes(m.data)) for m in read_log(tmp_path / "inline.blf")]
    background = [(m.timestamp, m.arbitration_id, bytes(m.data)) for m in read_log(tmp_path / "background.blf")]
    assert len(inline) == 300 * 19
    assert background == inline


def test_can_player_replays_the_log(tmp_path):
    path = tmp_path / "replay.blf"
    with PowerlinkNetwork(NO_JITTER, scaling(), log_path=path) as network:
        drive(network, 10)
    result = subprocess.run([sys.executable, "-m", "can.player", "-i", "virtual", "-c", "replay", "-v", str(path)],
                            capture_output=True, text=True, timeout=60, check=True)
    lines = [line for line in result.stdout.splitlines() if "ID:" in line]
    assert len(lines) == 10 * 19
    assert "080" in lines[0] and "201" in lines[1]


def test_bad_words_are_rejected_by_name():
    with PowerlinkNetwork({}, scaling()) as network:
        setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
        setpoints.controlword[1] = 0x1FFFF
        with pytest.raises(ValueError, match=r"setpoints.controlword\[1\]"):
            network.run_cycle(0, setpoints, actuals)
        setpoints.controlword = np.full(6, 15.0)
        with pytest.raises(ValueError, match="setpoints.controlword has dtype float64"):
            network.run_cycle(0, setpoints, actuals)
    with PowerlinkNetwork({}, scaling()) as network:
        setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
        actuals.statusword = np.full(6, 0x27, dtype=float)
        with pytest.raises(ValueError, match=r"actuals.statusword\[0\]"):
            network.run_cycle(0, setpoints, actuals)


def test_values_beyond_the_telegram_range_saturate_and_are_counted():
    sc = scaling()
    with PowerlinkNetwork({}, sc) as network:
        setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
        setpoints.torque_offset[1] = 1e6  # far beyond 3276.7 % of rated torque
        actuals.torque[4] = -1e6
        network.run_cycle(0, setpoints, actuals)
        result = network.run_cycle(1, setpoints, actuals)
        saturations = network.summary()["scaling_saturations"]
    assert result.applied.torque_offset[1] == pytest.approx(32767 * sc.newton_metre_per_unit[1])
    assert result.observed.torque[4] == pytest.approx(-32768 * sc.newton_metre_per_unit[4])
    assert saturations["torque"] == 4  # two cycles, one set-point and one actual value each
