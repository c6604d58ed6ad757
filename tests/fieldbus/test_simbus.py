"""The 'simbus' python-can interface plugin: found by can.Bus through its entry point,
delivers in order without touching timestamps, honours filters, isolates channels."""
from importlib.metadata import entry_points

import can
import pytest

from fieldbus.simbus import SimulatedTimeBus, unique_channel


@pytest.fixture
def pair():
    channel = unique_channel("test")
    a = can.Bus(interface="simbus", channel=channel)
    b = can.Bus(interface="simbus", channel=channel)
    yield a, b
    a.shutdown()
    b.shutdown()


def test_plugin_is_registered_through_the_can_interface_entry_point():
    names = {ep.name: ep.value for ep in entry_points(group="can.interface")}
    assert names.get("simbus") == "fieldbus.simbus:SimulatedTimeBus"
    assert "simbus" in can.interfaces.VALID_INTERFACES


def test_delivers_in_order_with_simulated_timestamps(pair):
    a, b = pair
    assert isinstance(a, SimulatedTimeBus)
    sent = [can.Message(timestamp=1e-6 * i, arbitration_id=0x180 + i, data=bytes([i]), is_extended_id=False)
            for i in range(5)]
    for msg in sent:
        a.send(msg)
    received = [b.recv(0) for _ in range(5)]
    assert [m.timestamp for m in received] == [1e-6 * i for i in range(5)]
    assert [m.arbitration_id for m in received] == [0x180 + i for i in range(5)]
    assert b.recv(0) is None and b.recv(1.0) is None  # never blocks
    assert a.recv(0) is None  # no echo of own frames


def test_filters_and_drain(pair):
    a, b = pair
    b.set_filters([{"can_id": 0x080, "can_mask": 0x7FF, "extended": False}])
    for arbitration_id in (0x080, 0x201, 0x080):
        a.send(can.Message(arbitration_id=arbitration_id, is_extended_id=False))
    assert [m.arbitration_id for m in b.drain()] == [0x080, 0x080]
    assert b.drain() == []


def test_channels_are_isolated_and_own_messages_optional():
    one, two = unique_channel(), unique_channel()
    a = can.Bus(interface="simbus", channel=one, receive_own_messages=True)
    b = can.Bus(interface="simbus", channel=two)
    try:
        a.send(can.Message(arbitration_id=1, is_extended_id=False))
        assert b.recv(0) is None
        assert a.recv(0).arbitration_id == 1
    finally:
        a.shutdown()
        b.shutdown()
