"""fieldbus configuration: defaults file, overrides, validation errors naming the key,
and the POWERLINK frame-time arithmetic."""
import math

import pytest

from fieldbus import FieldbusConfig, FieldbusConfigError, defaults_table
from fieldbus.timing import CycleLayout, CycleSchedule, propagation_delay, wire_time


def test_every_default_has_value_unit_and_source():
    table = defaults_table()
    assert len(table) > 40
    for key, item in table.items():
        assert set(item) == {"value", "unit", "source"}, key
        assert str(item["unit"]).strip() and str(item["source"]).strip(), key


def test_defaults_build_the_papers_network():
    config = FieldbusConfig.from_dict({})
    assert config.nodes == 6
    assert math.isclose(config.cycle_time_s, 400e-6)
    assert config.dead_time_cycles == 1
    assert config.thresholds.increment == 8 and config.thresholds.decrement == 1
    assert config.thresholds.cn_loss_of_preq == 15 and config.thresholds.mn_loss_of_pres == 15
    assert config.bus.interface == "simbus"
    assert config.faults.bursts == () and not config.faults.random_enabled


def test_overrides_are_applied_and_converted_to_seconds():
    config = FieldbusConfig.from_dict({
        "cycle_time_us": 500, "dead_time_cycles": 2,
        "timing": {"hub_latency_us": 0.25, "topology": "star"},
        "thresholds": {"cn_loss_of_preq": 0},
        "faults": {"bursts": [{"node": 2, "start_cycle": 10, "cycles": 3, "frames": "both", "kind": "late"}],
                   "silent_nodes": [{"node": 4, "from_cycle": 7}]},
    })
    assert math.isclose(config.cycle_time_s, 500e-6)
    assert config.dead_time_cycles == 2
    assert math.isclose(config.timing.hub_latency_s, 0.25e-6)
    assert config.timing.topology == "star"
    assert config.thresholds.cn_loss_of_preq == 0
    burst = config.faults.bursts[0]
    assert (burst.node, burst.start_cycle, burst.cycles, burst.frames, burst.kind) == (2, 10, 3, "both", "late")
    assert burst.active(12) and not burst.active(13)
    assert config.faults.silent_nodes[0].active(10**9)


@pytest.mark.parametrize("table, key, fragment", [
    ({"cycle_tme_us": 400}, "fieldbus.cycle_tme_us", "known key"),
    ({"timing": {"hub_latncy_us": 1}}, "fieldbus.timing.hub_latncy_us", "known key"),
    ({"cycle_time_us": "fast"}, "fieldbus.cycle_time_us", "finite number"),
    ({"cycle_time_us": -1}, "fieldbus.cycle_time_us", "> 0"),
    ({"dead_time_cycles": 0}, "fieldbus.dead_time_cycles", "integer in [1"),
    ({"dead_time_cycles": 1.5}, "fieldbus.dead_time_cycles", "an integer"),
    ({"nodes": True}, "fieldbus.nodes", "an integer"),
    ({"timing": 3}, "fieldbus.timing", "a table"),
    ({"timing": {"topology": "ring"}}, "fieldbus.timing.topology", "'line', 'star'"),
    ({"faults": {"loss_probability": 1.5}}, "fieldbus.faults.loss_probability", "<= 1"),
    ({"faults": {"bursts": [{"node": 9, "start_cycle": 0, "cycles": 1, "frames": "preq"}]}},
     "fieldbus.faults.bursts[0].node", "integer in [1, 6]"),
    ({"faults": {"bursts": [{"node": 1, "start_cycle": 0, "cycles": 1, "frames": "pdo"}]}},
     "fieldbus.faults.bursts[0].frames", "'soc'"),
    ({"faults": {"bursts": [{"node": 1, "cycles": 1, "frames": "preq"}]}},
     "fieldbus.faults.bursts[0].start_cycle", "required"),
    ({"faults": {"silent_nodes": [{"node": 1, "from_cycle": 5, "until_cycle": 5}]}},
     "fieldbus.faults.silent_nodes[0].until_cycle", "integer in [6"),
    ({"reaction": {"abort_connection_option": "panic"}}, "fieldbus.reaction.abort_connection_option", "'fault'"),
    ({"timing": {"response_jitter_us": 5.0}}, "fieldbus.timing.response_jitter_us", "cn_response_time_us"),
    ({"cycle_time_us": 100}, "fieldbus.cycle_time_us", "worst-case schedule"),
    ({"bus": {"options": 5}}, "fieldbus.bus.options", "table"),
])
def test_bad_values_name_the_key_the_value_and_the_expectation(table, key, fragment):
    with pytest.raises(FieldbusConfigError) as info:
        FieldbusConfig.from_dict(table, source="scenario.toml")
    message = str(info.value)
    assert message.startswith("scenario.toml: ")
    assert key in message
    assert fragment in message
    assert isinstance(info.value, ValueError)


def test_from_toml_reads_the_fieldbus_table(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('[fieldbus]\ncycle_time_us = 800\n[fieldbus.faults]\nloss_probability = 0.01\n')
    config = FieldbusConfig.from_toml(path)
    assert math.isclose(config.cycle_time_s, 800e-6)
    assert config.faults.loss_probability == 0.01
    assert config.source == str(path)
    bad = tmp_path / "bad.toml"
    bad.write_text("[fieldbus\n")
    with pytest.raises(FieldbusConfigError, match="bad.toml"):
        FieldbusConfig.from_toml(bad)


def test_frame_times_follow_ethernet_framing_at_100_mbit():
    timing = FieldbusConfig.from_dict({}).timing
    # a short frame is padded to 64 bytes + 8 preamble + 12 gap = 84 byte times = 6.72 us
    assert math.isclose(wire_time(timing, 10), 84 * 8 / 100e6)
    # the 300-byte async frame: 300 + 38 bytes
    assert math.isclose(wire_time(timing, 300), 338 * 8 / 100e6)
    assert math.isclose(propagation_delay(timing, 3), 3 * 0.5e-6 + 3 * 0.1e-6)


def test_nominal_schedule_orders_frames_and_fits_the_cycle():
    config = FieldbusConfig.from_dict({"timing": {"soc_jitter_us": 0.0, "response_jitter_us": 0.0}})
    layout = CycleLayout.from_config(config)
    times = CycleSchedule(config, layout).timestamps(10)
    soc, preq, pres = times[0], times[1:7], times[7:13]
    assert soc == pytest.approx(10 * 400e-6, abs=1e-15)
    sequence = [soc] + [t for pair in zip(preq, pres) for t in pair]
    assert sequence == sorted(sequence)
    # PReq1 starts after the SoC (6.72 us) and the MN turnaround (2 us)
    assert preq[0] - soc == pytest.approx(8.72e-6)
    # PRes1 = PReq1 end + hop to node 1 + response time
    assert pres[0] - preq[0] == pytest.approx(6.72e-6 + 0.6e-6 + 2e-6)
    assert layout.nominal_end_of_async < layout.worst_case_end_of_async < config.cycle_time_s


def test_jitter_is_seeded_and_bounded():
    a = CycleSchedule(FieldbusConfig.from_dict({"seed": 1}))
    b = CycleSchedule(FieldbusConfig.from_dict({"seed": 1}))
    c = CycleSchedule(FieldbusConfig.from_dict({"seed": 2}))
    assert a.timestamps(5000) == b.timestamps(5000)
    assert a.timestamps(5000) != c.timestamps(5000)
    socs = [a.timestamps(k)[0] - k * 400e-6 for k in range(3000)]
    assert max(abs(x) for x in socs) <= 0.1e-6 + 1e-15
    assert max(abs(x) for x in socs) > 0.05e-6
