"""The drive's SDO server answers the ``canopen`` library's SDO client (a CANopen master nobody here
wrote, loading the generated EDS) over a python-can bus: identity and device name read back (the
name through a segmented upload), a limit and a gain written and read back, and each refused
request answered with its CiA 301 abort code."""
from __future__ import annotations

import struct
import uuid

import can
import canopen
import pytest

from fieldbus.device_files import to_eds
from fieldbus.sdo import (COMMAND_UNKNOWN, NO_OBJECT, NO_SUBINDEX, READ_WRITE_ONLY, SDO_RX_BASE, SDO_TX_BASE,
                          TOGGLE_NOT_ALTERNATED, VALUE_TOO_HIGH, VALUE_TOO_LOW, WRITE_READ_ONLY, WRONG_STATE,
                          SdoServer)
from fmus.servo_drive.object_dictionary import drive_object_dictionary

NODE = 3


class _Answering(can.Listener):
    """Hands the requests to the server and sends its answers on the same bus."""

    def __init__(self, bus: can.BusABC, server: SdoServer) -> None:
        self.bus, self.server = bus, server

    def on_message_received(self, msg: can.Message) -> None:
        if msg.arbitration_id == SDO_RX_BASE + self.server.node:
            answer = self.server.handle(bytes(msg.data))
            if answer is not None:
                self.bus.send(can.Message(arbitration_id=SDO_TX_BASE + self.server.node, data=answer,
                                          is_extended_id=False))


@pytest.fixture
def master(tmp_path):
    od = drive_object_dictionary(NODE)
    eds = tmp_path / "drive.eds"
    eds.write_text(to_eds(od), encoding="utf-8", newline="")
    written = []
    server = SdoServer(od, on_write=lambda entry, value: written.append((entry.index, entry.subindex, value)))
    channel = f"sdo-{uuid.uuid4().hex}"
    drive_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    notifier = can.Notifier(drive_bus, [_Answering(drive_bus, server)])
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel)
    node = canopen.RemoteNode(NODE, str(eds))
    network.add_node(node)
    node.sdo.RESPONSE_TIMEOUT = 2.0
    try:
        yield node, server, od, written
    finally:
        network.disconnect()
        notifier.stop()
        drive_bus.shutdown()


def _abort_code(call) -> int:
    with pytest.raises(canopen.SdoAbortedError) as info:
        call()
    return info.value.code


def test_identity_and_name_read_over_sdo(master):
    node, server, od, _ = master
    assert node.sdo[0x1000].raw == 0x00020192
    assert node.sdo["Identity object"]["Vendor-ID"].raw == od.identity["vendor_id"]
    assert node.sdo[0x1018][2].raw == od.identity["product_code"]
    assert node.sdo[0x1018][4].raw == NODE
    assert node.sdo[0x1008].raw == "RX130L virtual servo drive"  # 26 bytes: segmented upload
    assert node.sdo[0x1014].raw == 0x80 + NODE
    assert node.sdo[0x1A00][2].raw == 0x60640020  # position actual value, 32 bits, as the codec packs it
    for index, sub in ((0x6065, 0), (0x6072, 0), (0x6085, 0), (0x607D, 1), (0x607D, 2), (0x1006, 0)):
        variable = node.sdo[index] if not sub else node.sdo[index][sub]
        assert variable.raw == od.entry(index, sub).default


def test_limit_and_gain_written_and_read_back(master):
    node, server, od, written = master
    window = od.entry(0x6065).default
    node.sdo[0x6065].raw = window // 2  # following error window, counts
    assert node.sdo[0x6065].raw == window // 2
    node.sdo["Position loop gain"].raw = 42.5  # REAL32, 1/s
    assert node.sdo[0x2001].raw == pytest.approx(42.5)
    node.sdo[0x6060].raw = 9  # cyclic synchronous velocity
    assert node.sdo[0x6061].raw == 8  # the display is the drive's, not written over SDO
    assert written == [(0x6065, 0, window // 2), (0x2001, 0, pytest.approx(42.5)), (0x6060, 0, 9)]
    assert server.aborts == {}


def test_refused_requests_get_their_abort_codes(master):
    node, server, od, written = master
    assert _abort_code(lambda: node.sdo.upload(0x2222, 0)) == NO_OBJECT
    assert _abort_code(lambda: node.sdo.upload(0x1018, 9)) == NO_SUBINDEX
    assert _abort_code(lambda: node.sdo.download(0x6041, 0, struct.pack("<H", 0x0237))) == WRITE_READ_ONLY
    assert _abort_code(lambda: node.sdo.upload(0x60C4, 6)) == READ_WRITE_ONLY
    assert _abort_code(lambda: node.sdo.download(0x6060, 0, struct.pack("<b", 11))) == VALUE_TOO_HIGH
    assert _abort_code(lambda: node.sdo.download(0x6060, 0, struct.pack("<b", 1))) == VALUE_TOO_LOW
    server.state = "operational"
    assert _abort_code(lambda: node.sdo.download(0x1600, 1, struct.pack("<I", 0x60400010))) == WRONG_STATE
    server.state = "pre-operational"
    node.sdo.download(0x1600, 1, struct.pack("<I", 0x60400010))  # allowed in pre-operational
    assert written == [(0x1600, 1, 0x60400010)]
    assert server.aborts == {NO_OBJECT: 1, NO_SUBINDEX: 1, WRITE_READ_ONLY: 1, READ_WRITE_ONLY: 1, VALUE_TOO_HIGH: 1,
                             VALUE_TOO_LOW: 1, WRONG_STATE: 1}


def test_protocol_errors_without_a_client_library():
    """Requests the library would never send: a wrong length, an unknown command, a segment
    without a transfer, a segmented download of the wrong size, a broken toggle; a stopped node
    does not answer."""
    server = SdoServer(drive_object_dictionary(1))

    def code(answer: bytes) -> int:
        assert answer[0] == 0x80
        return struct.unpack_from("<I", answer, 4)[0]

    assert code(server.handle(b"\x40\x00\x10")) == COMMAND_UNKNOWN
    assert code(server.handle(bytes((0xE0, 0, 0x10, 0, 0, 0, 0, 0)))) == COMMAND_UNKNOWN
    assert code(server.handle(bytes((0x00, 1, 2, 3, 4, 5, 6, 7)))) == COMMAND_UNKNOWN  # no download initiated
    assert server.handle(bytes((0x21, 0x65, 0x60, 0, 4, 0, 0, 0)))[0] == 0x60  # segmented, 4 bytes announced
    assert code(server.handle(bytes((0x0B, 1, 2, 3, 4, 0, 0, 0)))) == 0x06070010  # last segment with 2 bytes
    assert server.malformed == 3 and server.transfers == 0  # short request, command 7, stray segment
    assert code(server.handle(bytes((0x2B, 0x65, 0x60, 0, 1, 0, 0, 0)))) == 0x06070010  # 2 bytes for a UNSIGNED32
    first = server.handle(bytes((0x40, 0x08, 0x10, 0, 0, 0, 0, 0)))
    assert first[0] == 0x41 and struct.unpack_from("<I", first, 4)[0] == 26
    assert code(server.handle(bytes((0x70, 0, 0, 0, 0, 0, 0, 0)))) == TOGGLE_NOT_ALTERNATED
    server.state = "stopped"
    assert server.handle(bytes((0x40, 0x00, 0x10, 0, 0, 0, 0, 0))) is None
