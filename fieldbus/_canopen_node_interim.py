"""INTERIM stand-in for fieldbus.canopen_node.CanopenNode (helper cocell), same API; removed when it lands."""
from __future__ import annotations

import struct

import can

from fieldbus.sdo import SDO_RX_BASE, SDO_TX_BASE, SdoServer

_NMT = {0x01: "operational", 0x02: "stopped", 0x80: "pre-operational", 0x81: "reset", 0x82: "reset"}
_HB = {"pre-operational": 0x7F, "operational": 0x05, "stopped": 0x04}


class CanopenNode:
    def __init__(self, node_id: int, od, *, on_write=None) -> None:
        self.node_id = node_id
        self.od = od
        self.sdo = SdoServer(od, on_write=on_write)
        self.values = self.sdo.values
        self._state = "initialising"
        self._next_hb: float | None = None
        self._counters = {"sdo_requests": 0, "malformed": 0, "nmt_commands": 0, "nmt_ignored": 0}

    @property
    def counters(self):
        return {**self._counters, "sdo_aborts": dict(self.sdo.aborts)}

    @property
    def nmt_state(self) -> str:
        return self._state

    def _msg(self, cob, data, t):
        return can.Message(arbitration_id=cob, data=bytes(data), is_extended_id=False, timestamp=t)

    def boot(self, time_s: float):
        self._state = "pre-operational"
        self.sdo.state = "pre-operational"
        self._next_hb = None
        return [self._msg(0x700 + self.node_id, [0], time_s)]

    def receive(self, msg, time_s):
        cob = msg.arbitration_id
        if cob == 0:
            if len(msg.data) != 2:
                self._counters["malformed"] += 1
                return []
            cs, target = msg.data[0], msg.data[1]
            if target not in (0, self.node_id):
                self._counters["nmt_ignored"] += 1
                return []
            if cs not in _NMT:
                self._counters["malformed"] += 1
                return []
            self._counters["nmt_commands"] += 1
            if _NMT[cs] == "reset":
                return self.boot(time_s)
            self._state = _NMT[cs]
            self.sdo.state = self._state
            return []
        if cob == SDO_RX_BASE + self.node_id:
            self._counters["sdo_requests"] += 1
            if len(msg.data) != 8:
                self._counters["malformed"] += 1
            answer = self.sdo.handle(bytes(msg.data))
            return [] if answer is None else [self._msg(SDO_TX_BASE + self.node_id, answer, time_s)]
        return []

    def tick(self, time_s):
        period = self.values.get((0x1017, 0), 0) * 1e-3
        if not period or self._state == "initialising":
            return []
        if self._next_hb is None or time_s >= self._next_hb:
            self._next_hb = time_s + period
            return [self._msg(0x700 + self.node_id, [_HB[self._state]], time_s)]
        return []

    def emcy(self, error_code, error_register, time_s):
        return self._msg(0x080 + self.node_id, struct.pack("<HB5x", error_code, error_register), time_s)

    @property
    def pdo_active(self):
        return self._state == "operational"
