"""The drive node's CiA 301 side (fieldbus/canopen_node.py) against the ``canopen`` library's
master (a CANopen stack nobody here wrote, loading the generated EDS) over a python-can bus:
boot-up, NMT commands and states, heartbeats, SDO (expedited and segmented), EMCY, PDO
configuration; and the bad input a library would never send."""
from __future__ import annotations

import math
import struct
import threading
import time
import uuid

import can
import canopen
import pytest

from fieldbus.canopen_node import CanopenNode
from fieldbus.device_files import to_eds
from fieldbus.sdo import MAPPING_TOO_LONG, NO_OBJECT, NOT_MAPPABLE, PARAMETER_INCOMPATIBLE, VALUE_TOO_HIGH
from fmus.servo_drive.object_dictionary import drive_object_dictionary

NODE = 2


class _Drive(can.Listener):
    """Hands every frame to the node and sends its answers on the same bus (the drive side)."""

    def __init__(self, bus: can.BusABC, node: CanopenNode) -> None:
        self.bus, self.node, self.lock = bus, node, threading.Lock()
        self.now = 0.0

    def send(self, frames) -> None:
        for m in frames:
            self.bus.send(m)

    def on_message_received(self, msg: can.Message) -> None:
        with self.lock:
            self.send(self.node.receive(msg, self.now))


@pytest.fixture
def cell(tmp_path):
    od = drive_object_dictionary(NODE)
    eds = tmp_path / "drive.eds"
    eds.write_text(to_eds(od), encoding="utf-8", newline="")
    written = []
    node = CanopenNode(NODE, od, on_write=lambda entry, value: written.append((entry.index, entry.subindex, value)))
    channel = f"co-{uuid.uuid4().hex}"
    drive_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    drive = _Drive(drive_bus, node)
    notifier = can.Notifier(drive_bus, [drive], timeout=0.05)
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.05  # the listener thread checks for the end this often (default 1 s)
    network.connect(interface="virtual", channel=channel)
    remote = canopen.RemoteNode(NODE, str(eds))
    network.add_node(remote)
    remote.sdo.RESPONSE_TIMEOUT = 2.0
    try:
        yield network, remote, node, drive, written
    finally:
        network.disconnect()
        notifier.stop()
        drive_bus.shutdown()


def _until(condition, timeout_s: float = 2.0) -> bool:
    """Whether ``condition()`` became true within the timeout (NMT commands are unconfirmed: the
    drive's listener thread takes them a moment later)."""
    end = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > end:
            return False
        time.sleep(0.002)
    return True


def _abort_code(call) -> int:
    with pytest.raises(canopen.SdoAbortedError) as info:
        call()
    return info.value.code


def test_boot_nmt_states_and_heartbeat(cell):
    network, remote, node, drive, _ = cell
    assert node.nmt_state == "initialising" and not node.pdo_active
    with drive.lock:
        drive.send(node.boot(0.0))
    remote.nmt.wait_for_bootup(2.0)
    assert node.nmt_state == "pre-operational" and node.next_tick_s == math.inf  # 0x1017 = 0: no heartbeat
    remote.sdo[0x1017].raw = 100  # ms
    assert node.next_tick_s == pytest.approx(0.1)
    assert node.tick(0.05) == []
    with drive.lock:
        drive.send(node.tick(0.1))
    assert remote.nmt.wait_for_heartbeat(2.0) == "PRE-OPERATIONAL"
    remote.nmt.state = "OPERATIONAL"
    assert _until(lambda: node.nmt_state == "operational") and node.pdo_active
    with drive.lock:
        drive.send(node.tick(0.25))  # 50 ms late: the next one stays on the 100 ms grid
    assert remote.nmt.wait_for_heartbeat(2.0) == "OPERATIONAL"
    assert node.next_tick_s == pytest.approx(0.3)
    assert len(node.tick(0.65)) == 1 and node.next_tick_s == pytest.approx(0.75)  # periods missed: from now
    remote.nmt.state = "STOPPED"
    assert _until(lambda: node.nmt_state == "stopped") and not node.pdo_active
    with pytest.raises(canopen.SdoCommunicationError):  # no SDO in stopped
        remote.sdo.RESPONSE_TIMEOUT = 0.2
        remote.sdo[0x1000].raw
    remote.sdo.RESPONSE_TIMEOUT = 2.0
    with drive.lock:
        drive.send(node.tick(0.75))
    assert remote.nmt.wait_for_heartbeat(2.0) == "STOPPED"
    remote.nmt.state = "PRE-OPERATIONAL"
    assert _until(lambda: node.nmt_state == "pre-operational")
    network.nmt.state = "OPERATIONAL"  # node id 0: every node
    assert _until(lambda: node.nmt_state == "operational")
    counters = node.counters
    assert counters["nmt_commands"] == 4 and counters["heartbeats"] == 4 and counters["boot_ups"] == 1


def test_reset_communication_and_reset_node(cell):
    network, remote, node, drive, written = cell
    with drive.lock:
        drive.send(node.boot(0.0))
    remote.nmt.wait_for_bootup(2.0)
    remote.sdo[0x1017].raw = 50
    window = node.od.entry(0x6065).default
    remote.sdo[0x6065].raw = window // 4
    remote.nmt.state = "OPERATIONAL"
    remote.nmt.state = "RESET COMMUNICATION"
    remote.nmt.wait_for_bootup(2.0)
    assert node.nmt_state == "pre-operational"
    assert remote.sdo[0x1017].raw == 0 and remote.sdo[0x6065].raw == window // 4  # only the 0x1xxx area
    remote.nmt.state = "RESET"
    remote.nmt.wait_for_bootup(2.0)
    assert remote.sdo[0x6065].raw == window  # the drive's limit back to its default ...
    assert written[-1] == (0x6065, 0, window)  # ... and handed to the drive
    assert node.counters["boot_ups"] == 3


def test_sdo_expedited_segmented_and_aborts(cell):
    network, remote, node, drive, written = cell
    with drive.lock:
        drive.send(node.boot(0.0))
    remote.nmt.wait_for_bootup(2.0)
    assert remote.sdo[0x1008].raw == "RX130L virtual servo drive"  # segmented upload
    assert remote.sdo[0x1018][1].raw == node.od.identity["vendor_id"]
    remote.sdo.download(0x6073, 0, struct.pack("<H", 1500), force_segment=True)  # segmented download
    assert remote.sdo[0x6073].raw == 1500
    remote.sdo["Position loop gain"].raw = 55.0
    assert written == [(0x6073, 0, 1500), (0x2001, 0, pytest.approx(55.0))]
    assert _abort_code(lambda: remote.sdo.upload(0x5555, 0)) == NO_OBJECT
    assert _abort_code(lambda: remote.sdo.download(0x6060, 0, struct.pack("<b", 12))) == VALUE_TOO_HIGH
    counters = node.counters
    assert counters["sdo_transfers"] == 5
    assert counters["sdo_aborts"] == {"0x06020000": 1, "0x06090031": 1}
    assert counters["malformed"] == 0


def test_pdo_mapping_configured_by_the_master(cell):
    """The library reads the mappings, writes them back (disable, clear, map, enable) and starts
    the node; a mapping longer than the PDO's frame, one naming an object that cannot be mapped
    and one the fixed telegrams do not carry are refused with their abort codes."""
    network, remote, node, drive, _ = cell
    with drive.lock:
        drive.send(node.boot(0.0))
    remote.nmt.wait_for_bootup(2.0)
    remote.tpdo.read()
    remote.rpdo.read()
    assert [v.index for v in remote.tpdo[1].map] == [0x6041, 0x6064, 0x6077]
    remote.tpdo[1].save()
    remote.rpdo[1].save()
    remote.nmt.state = "OPERATIONAL"
    assert _until(lambda: node.pdo_active)
    remote.nmt.state = "PRE-OPERATIONAL"
    sdo = remote.sdo
    sdo.download(0x1A00, 0, b"\x00")
    sdo.download(0x1A00, 3, struct.pack("<I", 0x606C0020))  # velocity, 32 bits, instead of the 16-bit torque
    assert _abort_code(lambda: sdo.download(0x1A00, 0, b"\x03")) == MAPPING_TOO_LONG  # 80 bits in an 8-byte PRes
    assert _abort_code(lambda: sdo.download(0x1A00, 0, b"\x04")) == MAPPING_TOO_LONG  # TPDO1 has three entries
    assert _abort_code(lambda: sdo.download(0x1A00, 3, struct.pack("<I", 0x10080008))) == NOT_MAPPABLE
    sdo.download(0x1A00, 3, struct.pack("<I", 0x60610008))  # fits, but not what the bus packs
    assert _abort_code(lambda: sdo.download(0x1A00, 0, b"\x03")) == PARAMETER_INCOMPATIBLE
    sdo.download(0x1A00, 3, struct.pack("<I", 0x60770010))
    sdo.download(0x1A00, 0, b"\x03")
    assert node.counters["sdo_aborts"] == {"0x06040041": 1, "0x06040042": 2, "0x06040043": 1}


def test_emcy_reaches_the_master(cell):
    network, remote, node, drive, _ = cell
    with drive.lock:
        drive.send(node.boot(0.0))
    remote.nmt.wait_for_bootup(2.0)
    with drive.lock:
        drive.send([node.emcy(0x8611, 0x21, 0.5)])
    error = remote.emcy.wait(0x8611, 2.0)
    assert error is not None and error.register == 0x21
    assert remote.sdo[0x1001].raw == 0x21
    assert remote.sdo[0x1003][1].raw == 0x8611 and remote.sdo[0x1003][0].raw == 1


def test_bad_input_without_a_client_library():
    """Frames no library would send: counted, answered as CiA 301 says, never raised."""
    node = CanopenNode(4, drive_object_dictionary(4))
    msg = lambda cob, data: can.Message(arbitration_id=cob, data=data, is_extended_id=False)  # noqa: E731
    assert node.receive(msg(0x000, b"\x01\x00"), 0.0) == []  # before the boot-up: nothing
    assert node.nmt_state == "initialising"
    node.boot(0.0)
    assert node.receive(msg(0x604, b"\x40\x00"), 0.0)[0].data[0] == 0x80  # short SDO request: abort
    assert node.receive(msg(0x604, bytes((0xE0, 0, 0x10, 0, 0, 0, 0, 0))), 0.0)[0].data[4:] == bytes.fromhex("01000405")
    assert node.receive(msg(0x605, bytes(8)), 0.0) == []  # another node's SDO
    assert node.receive(msg(0x000, b"\x01"), 0.0) == []  # NMT without a node id
    assert node.receive(msg(0x000, b"\x07\x04"), 0.0) == []  # unknown command specifier
    assert node.receive(msg(0x000, b"\x01\x09"), 0.0) == []  # start node 9: not this one
    assert node.nmt_state == "pre-operational"
    c = node.counters
    assert (c["malformed"], c["nmt_ignored"], c["nmt_commands"], c["sdo_requests"]) == (2, 2, 0, 2)
    with pytest.raises(ValueError, match="node 4's"):
        CanopenNode(5, node.od)
