"""fieldbus.canopen_drives: the drive side of a frame-by-frame CANopen network (one process, no bus)."""
from __future__ import annotations

import struct

import can
import numpy as np

from fieldbus.canopen_drives import CanopenDrives, FreeMappingNode, applied_setpoints
from fieldbus.process_data import DriveActuals
from fmus.servo_drive.object_dictionary import drive_object_dictionary
from cosim.cell.wiring import joint_scaling


def _drives():
    ods = [drive_object_dictionary(axis) for axis in range(1, 7)]
    nodes = [FreeMappingNode(od.node, od) for od in ods]
    drives = CanopenDrives(nodes, ods, joint_scaling())
    drives.boot(0.0)
    return drives


def _msg(cob, data):
    return can.Message(arbitration_id=cob, data=bytes(data), is_extended_id=False)


def _sdo_write(drives, node, index, sub, fmt, value):
    data = struct.pack("<" + fmt, value)
    command = 0x23 | ((4 - len(data)) << 2)
    answer = drives.receive(_msg(0x600 + node, struct.pack("<BHB", command, index, sub) + data.ljust(4, b"\0")), 0.0)
    return answer[0].data


def _actuals(q):
    n = 6
    return DriveActuals(statusword=np.full(n, 0x0237, dtype=np.int64), position=np.asarray(q, dtype=float),
                        velocity=np.zeros(n), torque=np.zeros(n), error_code=np.zeros(n, dtype=np.int64),
                        modes_of_operation_display=np.full(n, 8, dtype=np.int64))


def test_a_classic_rpdo_takes_effect_at_the_next_sync_and_tpdos_answer_it():
    drives = _drives()
    # remap node 1's RPDO1 to 8 bytes (controlword, target position, torque offset): a CAN master's mapping
    assert _sdo_write(drives, 1, 0x1400, 1, "I", 0x80000201)[0] == 0x60
    assert _sdo_write(drives, 1, 0x1600, 0, "B", 0)[0] == 0x60
    for k, index in enumerate((0x60400010, 0x607A0020, 0x60B20010), start=1):
        assert _sdo_write(drives, 1, 0x1600, k, "I", index)[0] == 0x60
    assert _sdo_write(drives, 1, 0x1600, 0, "B", 3)[0] == 0x60
    assert _sdo_write(drives, 1, 0x1400, 1, "I", 0x201)[0] == 0x60
    # a mapping longer than a CAN FD frame is refused with the CiA 301 abort code
    for k in range(1, 9):
        _sdo_write(drives, 2, 0x1A00, k, "I", 0x60640020)
    abort = _sdo_write(drives, 2, 0x1A00, 0, "B", 17)
    assert abort[0] == 0x80
    drives.receive(_msg(0x000, [0x01, 0]), 0.0)  # NMT start, all nodes
    drives.receive(_msg(0x000, [0x01, 42]), 0.0)  # to a node that is not there: no reaction, counted
    assert drives.nmt_to_missing_node == 1
    applied = applied_setpoints(6)
    q = np.linspace(0.1, 0.6, 6)
    drives.receive(_msg(0x201, struct.pack("<Hih", 0x0F, 12345, 7)), 0.0)
    assert applied.position[0] == 0.0  # buffered: not applied before the SYNC
    tpdos = drives.sync(_msg(0x080, []), _actuals(q), applied, 0.0)
    assert applied.controlword[0] == 0x0F and applied.fresh[0] and not applied.fresh[1]
    assert applied.position[0] == 12345 * joint_scaling().rad_per_count[0]
    tpdo1 = {m.arbitration_id: m for m in tpdos}[0x181]
    status, position, _ = struct.unpack("<Hih", bytes(tpdo1.data))
    assert status == 0x0237 and position == joint_scaling().position_count(0, q[0])
    assert len(tpdos) == 12  # TPDO1 + TPDO2 of six operational nodes
    drives.sync(_msg(0x080, []), _actuals(q), applied, 0.005)  # no RPDO in this interval: set-point kept
    assert applied.controlword[0] == 0x0F and not applied.fresh[0]
    drives.receive(_msg(0x201, struct.pack("<Hih", 0x0F, 1, 0)), 0.0)
    drives.receive(_msg(0x201, struct.pack("<Hih", 0x0F, 2, 0)), 0.0)
    drives.sync(_msg(0x080, []), _actuals(q), applied, 0.01)
    counts = drives.counters["1"]
    assert counts["rpdo_missing"] == 1 and counts["rpdo_overwritten"] == 1 and counts["rpdo_taken"] == 3
    assert applied.position[0] == 2 * joint_scaling().rad_per_count[0]
