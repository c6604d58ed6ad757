"""The ``udpcycle`` python-can interface: one datagram per cycle, documented wire format,
sequence accounting, sender filtering, seeded transport faults."""
from __future__ import annotations

import os
import socket
import struct
import time

import can
import pytest

from fieldbus import DriveActuals, JointScaling, PowerlinkNetwork, Setpoints
from fieldbus.udpcycle import UdpCycleError, register

register()

BASE_PORT = 43000 + (os.getpid() % 1500) * 4


def _port(k: int) -> int:
    return BASE_PORT + k


# A client that knows only the wire format in docs/reference/fieldbus.md (socket + struct).
def _plain_datagram(frames, sender=7, sequence=1):
    out = struct.pack(">4sBBHIIQ", b"RXCB", 1, 0, len(frames), sender, sequence, 0)
    for can_id, data, stamp in frames:
        out += struct.pack(">IBBHd", can_id, len(data), 0, 0, stamp) + data
    return out


def _plain_parse(payload):
    magic, version, _flags, count, sender, sequence, _ns = struct.unpack_from(">4sBBHIIQ", payload, 0)
    assert (magic, version) == (b"RXCB", 1)
    offset, frames = 24, []
    for _ in range(count):
        can_id, length, _f, _r, stamp = struct.unpack_from(">IBBHd", payload, offset)
        offset += 16
        frames.append((can_id, payload[offset:offset + length], stamp))
        offset += length
    assert offset == len(payload)
    return sender, sequence, frames


def _wait_frames(bus, count, timeout=2.0):
    got, deadline = [], time.monotonic() + timeout
    while len(got) < count and time.monotonic() < deadline:
        msg = bus.recv(0.05)
        if msg is not None:
            got.append(msg)
    return got


def test_plain_socket_client_speaks_the_documented_wire_format():
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.bind(("127.0.0.1", _port(0)))
    client.settimeout(2.0)
    with can.Bus(interface="udpcycle", channel=f"127.0.0.1:{_port(1)}") as bus:
        client.sendto(_plain_datagram([(0x080, b"\x05", 0.0), (0x201, bytes(range(8)), 25e-6)]),
                      ("127.0.0.1", _port(1)))
        got = _wait_frames(bus, 2)
        assert [(m.arbitration_id, bytes(m.data), m.timestamp) for m in got] == \
            [(0x080, b"\x05", 0.0), (0x201, bytes(range(8)), 25e-6)]
        # no peer given: the bus answers the last accepted sender, all frames in ONE datagram
        bus.send_many([can.Message(arbitration_id=0x181 + k, data=bytes([k] * 8), is_extended_id=False,
                                   timestamp=1e-4 * k) for k in range(6)])
        payload, _ = client.recvfrom(65535)
        sender, sequence, frames = _plain_parse(payload)
        assert sequence == 1 and sender == bus.sender_id
        assert [f[0] for f in frames] == [0x181 + k for k in range(6)]
        assert frames[3] == (0x184, bytes([3] * 8), 1e-4 * 3)
        bus.send(can.Message(arbitration_id=0x12345, is_extended_id=True, data=b"ab", timestamp=2.5))
        _, sequence, frames = _plain_parse(client.recvfrom(65535)[0])
        assert sequence == 2 and frames == [(0x12345 | 1 << 31, b"ab", 2.5)]
        assert bus.stats.received == 1 and bus.stats.sent == 2
    client.close()


def test_loss_reordering_duplicates_are_counted():
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    with can.Bus(interface="udpcycle", channel=f"127.0.0.1:{_port(2)}") as bus:
        for seq in (1, 2, 5, 3, 3, 6, 6, 7):  # 4 never comes, 3 comes late and twice, 6 twice
            client.sendto(_plain_datagram([(0x201, bytes([seq]), 0.0)], sequence=seq), ("127.0.0.1", _port(2)))
        got = _wait_frames(bus, 6)
        assert [m.data[0] for m in got] == [1, 2, 5, 3, 6, 7]
        time.sleep(0.05)
        assert bus.drain() == []
        stats = bus.stats
        assert (stats.lost, stats.reordered, stats.duplicates, stats.received) == (1, 1, 2, 6)
    client.close()


def test_malformed_and_truncated_datagrams_are_counted_and_dropped():
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    good = _plain_datagram([(0x201, bytes(8), 0.0)], sequence=1)
    bad = [b"", b"RXCB", b"XXXX" + good[4:], good[:-3], good[:4] + b"\x02" + good[5:],
           good + b"\x00", _plain_datagram([(0x201, bytes(8), 0.0)], sequence=2)[:30]]
    with can.Bus(interface="udpcycle", channel=f"127.0.0.1:{_port(3)}") as bus:
        for payload in bad:
            client.sendto(payload, ("127.0.0.1", _port(3)))
        client.sendto(good, ("127.0.0.1", _port(3)))
        got = _wait_frames(bus, 1)
        assert len(got) == 1 and bytes(got[0].data) == bytes(8)
        assert bus.stats.malformed == len(bad) and bus.stats.received == 1
    client.close()


def test_datagrams_from_an_unexpected_sender_are_dropped():
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    stranger.bind(("127.0.0.1", _port(4)))
    friend = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    with can.Bus(interface="udpcycle", channel=f"127.0.0.1:{_port(5)}",
                 accept_from=[f"127.0.0.1:{_port(6)}"]) as bus:
        friend.bind(("127.0.0.1", _port(6)))
        stranger.sendto(_plain_datagram([(0x201, b"x", 0.0)]), ("127.0.0.1", _port(5)))
        friend.sendto(_plain_datagram([(0x202, b"y", 0.0)]), ("127.0.0.1", _port(5)))
        got = _wait_frames(bus, 1)
        time.sleep(0.05)
        got += bus.drain()
        assert [m.arbitration_id for m in got] == [0x202]
        assert bus.stats.foreign == 1
    stranger.close()
    friend.close()


def test_peer_only_accepts_the_learned_peer_and_counts_everyone_else_as_foreign():
    """What ``cosim serve`` uses: the first valid sender becomes the peer; a second program
    sending to the port (valid or garbage) is foreign, counted, and injects nothing."""
    first = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    first.bind(("127.0.0.1", _port(14)))
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    with can.Bus(interface="udpcycle", channel=f"127.0.0.1:{_port(15)}", peer_only=True) as bus:
        first.sendto(_plain_datagram([(0x201, b"a", 0.0)]), ("127.0.0.1", _port(15)))
        assert [m.arbitration_id for m in _wait_frames(bus, 1)] == [0x201]
        stranger.sendto(_plain_datagram([(0x202, b"b", 0.0)], sender=9), ("127.0.0.1", _port(15)))
        stranger.sendto(b"garbage", ("127.0.0.1", _port(15)))
        first.sendto(_plain_datagram([(0x203, b"c", 0.0)], sequence=2), ("127.0.0.1", _port(15)))
        got = _wait_frames(bus, 1)
        time.sleep(0.05)
        got += bus.drain()
        assert [m.arbitration_id for m in got] == [0x203]
        assert bus.stats.foreign == 2 and bus.stats.malformed == 0
        bus.send(can.Message(arbitration_id=0x181, data=b"d", is_extended_id=False))
        first.settimeout(2.0)
        assert _plain_parse(first.recv(2048))[-1][0][0] == 0x181  # it answers the learned peer
    first.close()
    stranger.close()


def test_seeded_transport_faults_are_reproducible():
    def run(seed):
        with can.Bus(interface="udpcycle", channel=f"127.0.0.1:{_port(7)}", peer=f"127.0.0.1:{_port(8)}",
                     drop_probability=0.2, duplicate_probability=0.1, delay_probability=0.1, delay_s=0.03,
                     fault_seed=seed) as tx, \
                can.Bus(interface="udpcycle", channel=f"127.0.0.1:{_port(8)}") as rx:
            for k in range(200):
                tx.send(can.Message(arbitration_id=0x201, data=struct.pack(">I", k), is_extended_id=False))
            time.sleep(0.05)
            tx.send_many([])  # releases delayed datagrams that are due
            time.sleep(0.05)
            got = [struct.unpack(">I", bytes(m.data))[0] for m in rx.drain() if m.data]
            return got, tx.stats.as_dict(), rx.stats.as_dict()

    got_a, tx_a, rx_a = run(11)
    got_b, tx_b, _ = run(11)
    assert got_a == got_b and tx_a == tx_b
    assert 20 < tx_a["injected_drops"] < 70 and tx_a["injected_duplicates"] > 5 and tx_a["injected_delays"] > 5
    assert len(got_a) == 200 - tx_a["injected_drops"]  # duplicates dropped at the receiver
    assert rx_a["duplicates"] == tx_a["injected_duplicates"]
    assert rx_a["reordered"] > 0  # delayed datagrams come after later ones


def test_port_in_use_and_bad_addresses_are_clear_errors():
    with can.Bus(interface="udpcycle", channel=f"127.0.0.1:{_port(9)}"):
        with pytest.raises(UdpCycleError, match="in use"):
            can.Bus(interface="udpcycle", channel=f"127.0.0.1:{_port(9)}")
    with pytest.raises(UdpCycleError, match="expected 'host:port'"):
        can.Bus(interface="udpcycle", channel="nohostport")
    with pytest.raises(UdpCycleError, match="port 1..65535"):
        can.Bus(interface="udpcycle", channel="127.0.0.1:70000")
    with pytest.raises(UdpCycleError, match="probability"):
        can.Bus(interface="udpcycle", channel=f"127.0.0.1:{_port(9)}", drop_probability=2)
    with pytest.raises(ValueError, match="bus.interface"):  # through the fieldbus config: key named
        PowerlinkNetwork({"bus": {"interface": "udpcycle", "channel": "nohostport"}},
                         JointScaling([100.0] * 6, 2**20, [10.0] * 6))


def test_powerlink_cycle_over_udpcycle_multicast_matches_simbus():
    sc = JointScaling([100.0] * 6, 2**20, [10.0] * 6)

    def drive(network, cycles):
        setpoints, actuals = Setpoints.zeros(6), DriveActuals.zeros(6)
        out = []
        for k in range(cycles):
            actuals.position[:] = 1e-3 * k
            actuals.statusword[:] = 0x27
            setpoints.controlword[:] = 0x0F
            setpoints.position[:] = 2e-3 * k
            r = network.run_cycle(k, setpoints, actuals)
            out.append((r.applied.position.tolist(), r.observed.position.tolist(), r.observed.fresh.tolist()))
        return out

    with PowerlinkNetwork({}, sc) as network:
        reference = drive(network, 30)
    config = {"bus": {"interface": "udpcycle", "channel": f"239.74.163.9:{_port(10)}", "receive_timeout_s": 2.0}}
    with PowerlinkNetwork(config, sc) as network:
        assert type(network.mn_bus).__name__ == "UdpCycleBus"
        assert drive(network, 30) == reference
        assert network.frames_missing == 0
        # one datagram per direction per cycle: SoC+PReqs, PRes (no EMCY in a healthy run)
        assert network.mn_bus.stats.sent == 30 and network.cn_bus.stats.sent == 30


def test_one_way_latency_from_kernel_arrival_and_header_send_time():
    with can.Bus(interface="udpcycle", channel=f"127.0.0.1:{_port(11)}", peer=f"127.0.0.1:{_port(12)}") as tx, \
            can.Bus(interface="udpcycle", channel=f"127.0.0.1:{_port(12)}", latency_samples=100) as rx:
        for _ in range(20):
            tx.send(can.Message(arbitration_id=0x201, data=b"\x01", is_extended_id=False))
        assert len(_wait_frames(rx, 20)) == 20
        latencies = list(rx.latency_ns)
        assert len(latencies) == 20
        assert all(0 < ns < 200_000_000 for ns in latencies)  # same host: positive, far below 0.2 s


def test_an_unreachable_peer_is_counted_not_raised():
    # nothing listens on loopback port 9: whatever the kernel reports, send never raises
    with can.Bus(interface="udpcycle", channel=f"127.0.0.1:{_port(13)}", peer="127.0.0.1:9") as bus:
        for _ in range(3):
            bus.send(can.Message(arbitration_id=0x201, data=b"\x00", is_extended_id=False))
        assert bus.stats.sent + bus.stats.send_errors == 3


def test_busy_poll_receives_what_arrives_while_spinning_and_times_out_otherwise():
    """``busy_poll_s``: recv spins (readiness checks, no exception per turn) and returns a datagram
    that arrives while it spins; with nothing sent it returns None after its timeout."""
    import threading

    rx = can.Bus(interface="udpcycle", channel=f"127.0.0.1:{_port(40)}", busy_poll_s=0.2)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        started = time.monotonic()
        assert rx.recv(0.05) is None
        assert 0.04 <= time.monotonic() - started < 1.0
        timer = threading.Timer(0.02, tx.sendto, (_plain_datagram([(0x181, b"\x01\x02", 0.5)]),
                                                  ("127.0.0.1", _port(40))))
        timer.start()
        msg = rx.recv(1.0)
        timer.join()
        assert msg is not None and msg.arbitration_id == 0x181 and bytes(msg.data) == b"\x01\x02"
        assert rx.stats.received == 1
    finally:
        tx.close()
        rx.shutdown()
