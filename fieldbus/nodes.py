"""The managing node (controller side) and the controlled nodes (drive side).

Both are reactive: they build the frames they send and digest the frames they
receive through ``receive(msg)``, which never raises; a frame that cannot be decoded
is counted, recorded as an event and logged. Threshold counters live on both sides.

Synchronous semantics (one cycle k, SoC at t_k):

* At the SoC each controlled node latches its drive's actual values (sent in this
  cycle's PRes) and applies the set-point that arrived in the PReq of cycle
  k - dead_time_cycles (held or extrapolated if it never arrived).
* The PReq of cycle k carries the set-point the controller computed after cycle
  k - 1; it takes effect at the SoC of cycle k + dead_time_cycles.

Fault reactions:

* Controlled node n, threshold reached (loss of SoC/PReq, CRC, SoC jitter): it latches
  ``comm_fault[n]``, sends an EMCY frame in the asynchronous slot and - with abort
  option 'quick_stop' (CiA 402 0x6007 = 3) - presents controlword 0x0002 (quick stop)
  to its drive instead of the received one; with option 'fault' only the flag is set
  and the drive runs its fault reaction. The latch clears when a received controlword
  with a rising fault-reset bit is applied while no counter of the node is at its
  threshold; that controlword then passes to the drive.
* Managing node, threshold reached for node n (loss of PRes, late PRes, CRC): it
  latches ``node_fault[n]`` for the controller, which must stop commanding motion;
  cleared by the controller sending a fault reset (rising bit 7) to node n once the
  node's counters are below threshold.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import can

from fieldbus.cia402 import CW_FAULT_RESET, Command
from fieldbus.events import CounterBank, EventLog, FieldbusEvent, ThresholdCounter
from fieldbus.process_data import AppliedSetpoints, DriveActuals, ObservedActuals
from fieldbus.telegrams import (
    EMCY, EMCY_BASE, EMCY_COMMUNICATION, EMCY_ERROR_REGISTER_COMMUNICATION, RPDO1_BASE,
    RPDO1_SIGNED, SYNC_ID, TPDO1, TPDO1_BASE, TPDO2, TPDO2_BASE, FastMessage, check_frame,
    classify,
)

if TYPE_CHECKING:
    from fieldbus.config import FieldbusConfig
    from fieldbus.scaling import JointScaling
    from fieldbus.timing import CycleLayout

_TPDO1_LEN = TPDO1.size
_TPDO2_LEN = TPDO2.size
_RPDO1_LEN = RPDO1_SIGNED.size
_PACK_RPDO1 = RPDO1_SIGNED.pack
_PACK_TPDO1 = TPDO1.pack
_PACK_TPDO2 = TPDO2.pack
_UNPACK_RPDO1 = RPDO1_SIGNED.unpack
_UNPACK_TPDO1 = TPDO1.unpack
_UNPACK_TPDO2 = TPDO2.unpack

COUNTER_IDS = {"cn_loss_of_soc": 1, "cn_loss_of_preq": 2, "cn_crc_error": 3, "cn_soc_jitter": 4}


def _decode_error(log: EventLog, side: str, msg: can.Message, cycle: int, time_s: float) -> tuple[str, int]:
    """Classify an undecodable frame, record it; returns (reason, node)."""
    kind, node = classify(msg.arbitration_id)
    try:
        check_frame(msg, kind, node)
        reason, detail = "unexpected_id", f"{kind.upper()} 0x{msg.arbitration_id:03X} is not for the {side.upper()}"
    except ValueError as error:
        reason = getattr(error, "reason", "invalid")
        detail = str(error)
    log.add(FieldbusEvent(time_s, cycle, side, node, reason, "decode_error", -1, -1, -1, detail))
    return reason, node


class ManagingNode:
    """Controller-side POWERLINK MN: sends SoC (SYNC) and PReqs (RPDO1), collects PRes
    (TPDO1 + TPDO2) into :class:`ObservedActuals`."""

    def __init__(self, config: "FieldbusConfig", scaling: "JointScaling",
                 layout: "CycleLayout", log: EventLog) -> None:
        n = config.nodes
        self.nodes = n
        self.config = config
        self.scaling = scaling
        self.layout = layout
        self.log = log
        self.observed = ObservedActuals.zeros(n)
        self.cycle = -1
        self._cycle_time = config.cycle_time_s
        self._t0 = config.start_time_s
        self._sync_overflow = config.scaling.sync_counter_overflow
        self._wire_preq_timeout = layout.wire_preq + layout.pres_timeout
        self._prop = layout.propagation
        # per node (index = node id), raw telegram values
        self._sw = [0] * (n + 1)
        self._pos = [0] * (n + 1)
        self._tq = [0] * (n + 1)
        self._vel = [0] * (n + 1)
        self._err = [0] * (n + 1)
        self._got1 = [False] * (n + 1)
        self._got2 = [False] * (n + 1)
        self._late = [False] * (n + 1)
        self._crc = [False] * (n + 1)
        self._deadline = [0.0] * (n + 1)
        self._last_cw = [0] * (n + 1)
        self.node_fault = [False] * (n + 1)
        self._ids: dict[int, tuple[int, int]] = {}
        for node in range(1, n + 1):
            self._ids[TPDO1_BASE + node] = (1, node)
            self._ids[TPDO2_BASE + node] = (2, node)
            self._ids[EMCY_BASE + node] = (3, node)
        th = config.thresholds
        self.counters = CounterBank(log, self._on_threshold)
        self._loss = [None] + [self.counters.new("mn", k, "loss_of_pres", th.mn_loss_of_pres, th.increment, th.decrement) for k in range(1, n + 1)]
        self._late_c = [None] + [self.counters.new("mn", k, "late_pres", th.mn_late_pres, th.increment, th.decrement) for k in range(1, n + 1)]
        self._crc_c = [None] + [self.counters.new("mn", k, "crc_error", th.mn_crc_error, th.increment, th.decrement) for k in range(1, n + 1)]
        self.frames_received = 0
        self.decode_errors = 0
        self.emcy_received: list[FieldbusEvent] = []

    # ------------------------------------------------------------------ sending
    def sync_message(self, cycle: int, timestamp: float) -> FastMessage:
        """SYNC (SoC) of ``cycle`` with the CiA 301 counter 1..overflow."""
        return FastMessage(timestamp, SYNC_ID, bytearray(((cycle % self._sync_overflow) + 1,)))

    def start_cycle(self, cycle: int) -> None:
        self.cycle = cycle
        got1, got2 = self._got1, self._got2
        for node in range(1, self.nodes + 1):
            got1[node] = got2[node] = False
            self._late[node] = self._crc[node] = False

    def preq_message(self, node: int, timestamp: float, controlword: int, position: float,
                     torque_offset: float) -> FastMessage:
        """RPDO1 for ``node`` (1-based) with SI set-points, quantised; also arms the PRes
        timeout and notes a fault-reset edge."""
        self._deadline[node] = timestamp + self._wire_preq_timeout
        if controlword & CW_FAULT_RESET and not self._last_cw[node] & CW_FAULT_RESET and self.node_fault[node]:
            self._clear_fault(node, timestamp)
        self._last_cw[node] = controlword
        index = node - 1
        data = bytearray(_PACK_RPDO1(controlword, self.scaling.position_count(index, position),
                                     self.scaling.torque_unit(index, torque_offset)))
        return FastMessage(timestamp, RPDO1_BASE + node, data)

    # ------------------------------------------------------------------ receiving
    def receive(self, msg: can.Message) -> None:
        """Digest one received frame; never raises."""
        self.frames_received += 1
        entry = self._ids.get(msg.arbitration_id)
        data = msg.data
        if entry is not None and not msg.is_error_frame and not msg.is_remote_frame and not msg.is_extended_id:
            which, node = entry
            if which == 1 and len(data) == _TPDO1_LEN:
                if msg.timestamp + self._prop[node] > self._deadline[node]:
                    self._late[node] = True
                    return
                self._sw[node], self._pos[node], self._tq[node] = _UNPACK_TPDO1(data)
                self._got1[node] = True
                return
            if which == 2 and len(data) == _TPDO2_LEN:
                if msg.timestamp + self._prop[node] > self._deadline[node]:
                    self._late[node] = True
                    return
                self._vel[node], self._err[node] = _UNPACK_TPDO2(data)
                self._got2[node] = True
                return
            if which == 3 and len(data) == EMCY.size:
                code, register, counter_id, value, threshold = EMCY.unpack(data)
                event = FieldbusEvent(msg.timestamp, self.cycle, "mn", node, "emcy", "emcy_received",
                                      value, -1, threshold,
                                      f"EMCY 0x{code:04X} register 0x{register:02X} counter id {counter_id}")
                self.emcy_received.append(event)
                self.log.add(event)
                return
        self._bad_frame(msg)

    def _bad_frame(self, msg: can.Message) -> None:
        self.decode_errors += 1
        reason, node = _decode_error(self.log, "mn", msg, self.cycle, msg.timestamp)
        if node and reason in ("error_frame", "short_frame", "long_frame", "remote_frame") and \
                node <= self.nodes and msg.arbitration_id & ~0x7F in (TPDO1_BASE, TPDO2_BASE):
            if not self._crc[node]:
                self._crc[node] = True
                self._crc_c[node].error(self.cycle, msg.timestamp, f"PRes {reason}")

    # ------------------------------------------------------------------ end of cycle
    def end_cycle(self, cycle: int) -> ObservedActuals:
        """Judge this cycle's PRes frames, update counters, publish ObservedActuals."""
        obs = self.observed
        t = self._t0 + cycle * self._cycle_time
        fresh = obs.fresh
        got1, got2 = self._got1, self._got2
        for node in range(1, self.nodes + 1):
            ok = got1[node] and got2[node]
            fresh[node - 1] = ok
            if not ok:
                if self._late[node]:
                    self._late_c[node].error(cycle, t, "PRes arrived after the PRes timeout")
                else:
                    self._loss[node].error(cycle, t, "no valid PRes" + (" (CRC error)" if self._crc[node] else ""))
        self.counters.end_cycle(cycle, t)
        s = self.scaling
        obs.statusword[:] = self._sw[1:]
        obs.error_code[:] = self._err[1:]
        obs.position[:] = self._pos[1:]
        obs.position *= s.rad_per_count
        obs.velocity[:] = self._vel[1:]
        obs.velocity *= s.rad_per_count
        obs.torque[:] = self._tq[1:]
        obs.torque *= s.newton_metre_per_unit
        return obs

    # ------------------------------------------------------------------ faults
    def _on_threshold(self, counter: ThresholdCounter, cycle: int, time_s: float) -> None:
        node = counter.node
        if not self.node_fault[node]:
            self.node_fault[node] = True
            self.observed.node_fault[node - 1] = True
            self.log.add(FieldbusEvent(time_s, cycle, "mn", node, counter.kind, "fault_reaction",
                                       counter.value, counter.cumulative, counter.threshold,
                                       "MN reports the node faulted: controller must stop commanding motion"))

    def _clear_fault(self, node: int, time_s: float) -> None:
        if any(c.node == node and c.tripped for c in self.counters.counters):
            return
        self.node_fault[node] = False
        self.observed.node_fault[node - 1] = False
        self.log.add(FieldbusEvent(time_s, self.cycle, "mn", node, "node_fault", "fault_cleared",
                                   -1, -1, -1, "fault reset sent with all counters below threshold"))


class ControlledNodes:
    """The drive-side POWERLINK CNs (node ids 1..N) sharing one bus connection."""

    def __init__(self, config: "FieldbusConfig", scaling: "JointScaling",
                 layout: "CycleLayout", log: EventLog) -> None:
        n = config.nodes
        self.nodes = n
        self.config = config
        self.scaling = scaling
        self.layout = layout
        self.log = log
        self.applied = AppliedSetpoints.zeros(n)
        self.cycle = -1
        self._t0 = config.start_time_s
        self._cycle_time = config.cycle_time_s
        self._d = config.dead_time_cycles
        self._hold = config.reaction.missing_setpoint == "hold"
        self._quick_stop = config.reaction.abort_connection_option == "quick_stop"
        self._jitter_range = config.timing.cn_soc_jitter_range_s
        self._sync_overflow = config.scaling.sync_counter_overflow
        self._arrival = [0.0] + [layout.wire_preq + layout.propagation[k] for k in range(1, n + 1)]
        self._pipe: list[list[tuple[int, int, int] | None]] = [[None] * self._d for _ in range(n + 1)]
        self._preq_ok = [False] * (n + 1)
        self._preq_late = [False] * (n + 1)
        self._crc = [False] * (n + 1)
        self._sync_seen = False
        self._sync_ts = 0.0
        self._sync_bad = False
        self._next_soc = 0.0
        # latched actuals (telegram units), index = node id
        self._a_sw = [0] * (n + 1)
        self._a_pos = [0] * (n + 1)
        self._a_tq = [0] * (n + 1)
        self._a_vel = [0] * (n + 1)
        self._a_err = [0] * (n + 1)
        # applied set-points (telegram units), index = node - 1
        self._cw = [0] * n
        self._pos: list[int | None] = [None] * n
        self._prev_pos: list[int | None] = [None] * n
        self._tq = [0] * n
        self._fresh = [False] * n
        self.comm_fault = [False] * (n + 1)
        self._emcy_due: list[tuple[int, ThresholdCounter]] = []
        self._ids: dict[int, int] = {RPDO1_BASE + k: k for k in range(1, n + 1)}
        self._traffic = {TPDO1_BASE + k for k in range(1, n + 1)} | {TPDO2_BASE + k for k in range(1, n + 1)} \
            | {EMCY_BASE + k for k in range(1, n + 1)}
        th = config.thresholds
        self.counters = CounterBank(log, self._on_threshold)
        mk = self.counters.new
        self._c_soc = [None] + [mk("cn", k, "loss_of_soc", th.cn_loss_of_soc, th.increment, th.decrement) for k in range(1, n + 1)]
        self._c_preq = [None] + [mk("cn", k, "loss_of_preq", th.cn_loss_of_preq, th.increment, th.decrement) for k in range(1, n + 1)]
        self._c_crc = [None] + [mk("cn", k, "crc_error", th.cn_crc_error, th.increment, th.decrement) for k in range(1, n + 1)]
        self._c_jit = [None] + [mk("cn", k, "soc_jitter", th.cn_soc_jitter, th.increment, th.decrement) for k in range(1, n + 1)]
        self.frames_received = 0
        self.decode_errors = 0

    # ------------------------------------------------------------------ receiving
    def receive(self, msg: can.Message) -> None:
        """Digest one received frame; never raises."""
        self.frames_received += 1
        arb = msg.arbitration_id
        data = msg.data
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            self._bad_frame(msg)
            return
        node = self._ids.get(arb)
        if node is not None:
            if len(data) != _RPDO1_LEN:
                self._bad_frame(msg)
                return
            if msg.timestamp + self._arrival[node] > self._next_soc:
                self._preq_late[node] = True
                return
            self._pipe[node][self.cycle % self._d] = _UNPACK_RPDO1(data)
            self._preq_ok[node] = True
            return
        if arb == SYNC_ID and len(data) <= 1:
            if data and self.cycle >= 0 and data[0] != (self.cycle + 1) % self._sync_overflow + 1:
                self._sync_bad = True  # counter of a SYNC that is not the one due now
                self.decode_errors += 1
                self.log.add(FieldbusEvent(msg.timestamp, self.cycle + 1, "cn", 0, "sync_counter", "decode_error",
                                           -1, -1, -1, f"SYNC counter {data[0]}, expected {(self.cycle + 1) % self._sync_overflow + 1}"))
                return
            self._sync_seen = True
            self._sync_ts = msg.timestamp
            return
        if arb in self._traffic and len(data) in (_TPDO1_LEN, _TPDO2_LEN):
            return  # other nodes' PRes / EMCY on the shared medium
        self._bad_frame(msg)

    def _bad_frame(self, msg: can.Message) -> None:
        self.decode_errors += 1
        reason, node = _decode_error(self.log, "cn", msg, self.cycle, msg.timestamp)
        targets: list[int] = []
        if msg.arbitration_id == SYNC_ID and reason in ("error_frame", "long_frame", "remote_frame"):
            targets = list(range(1, self.nodes + 1))  # the multicast SoC was bad at every CN
        elif node and node <= self.nodes and msg.arbitration_id & ~0x7F == RPDO1_BASE:
            targets = [node]
        for target in targets:
            if not self._crc[target]:
                self._crc[target] = True
                self._c_crc[target].error(self.cycle, msg.timestamp, f"{reason}")

    # ------------------------------------------------------------------ cycle
    def start_cycle(self, cycle: int, actuals: DriveActuals) -> AppliedSetpoints:
        """SoC of ``cycle``: check the SoC, latch ``actuals``, apply due set-points."""
        self.cycle = cycle
        t = self._t0 + cycle * self._cycle_time
        self._next_soc = t + self._cycle_time
        n = self.nodes
        if not self._sync_seen:
            for node in range(1, n + 1):
                self._c_soc[node].error(cycle, t, "no SoC")
        elif abs(self._sync_ts - t) > self._jitter_range:
            for node in range(1, n + 1):
                self._c_jit[node].error(cycle, t, f"SoC {(self._sync_ts - t) * 1e6:.2f} us off")
        self._sync_seen = False
        self._sync_bad = False
        # latch actual values (quantised as they enter the PRes)
        s = self.scaling
        sw = actuals.statusword.tolist()
        pos = actuals.position.tolist()
        vel = actuals.velocity.tolist()
        tq = actuals.torque.tolist()
        err = actuals.error_code.tolist()
        a_sw, a_pos, a_tq, a_vel, a_err = self._a_sw, self._a_pos, self._a_tq, self._a_vel, self._a_err
        position_count, velocity_count, torque_unit = s.position_count, s.velocity_count, s.torque_unit
        for i in range(n):
            node = i + 1
            a_sw[node] = sw[i]
            a_pos[node] = position_count(i, pos[i])
            a_vel[node] = velocity_count(i, vel[i])
            a_tq[node] = torque_unit(i, tq[i])
            a_err[node] = err[i]
        # apply the set-points due at this SoC
        slot = cycle % self._d
        cws, poss, prev, tqs, fresh = self._cw, self._pos, self._prev_pos, self._tq, self._fresh
        for i in range(n):
            node = i + 1
            pipe = self._pipe[node]
            due = pipe[slot]
            pipe[slot] = None
            if due is not None:
                cw = due[0]
                if self.comm_fault[node] and cw & CW_FAULT_RESET and not cws[i] & CW_FAULT_RESET:
                    self._clear_fault(node, cycle, t)
                cws[i] = cw
                prev[i] = poss[i]
                poss[i] = due[1]
                tqs[i] = due[2]
                fresh[i] = True
            else:
                fresh[i] = False
                last = poss[i]
                if last is None:
                    poss[i] = a_pos[node]  # nothing received yet: hold where the drive is
                elif not self._hold and prev[i] is not None:
                    poss[i] = last + (last - prev[i])
                    prev[i] = last
        app = self.applied
        if any(self.comm_fault):
            forced = list(cws)
            for i in range(n):
                if self.comm_fault[i + 1]:
                    app.comm_fault[i] = True
                    if self._quick_stop:
                        forced[i] = int(Command.QUICK_STOP)
                else:
                    app.comm_fault[i] = False
            app.controlword[:] = forced
        else:
            app.controlword[:] = cws
            app.comm_fault[:] = False
        app.position[:] = poss
        app.position *= s.rad_per_count
        app.torque_offset[:] = tqs
        app.torque_offset *= s.newton_metre_per_unit
        app.fresh[:] = fresh
        return app

    def pres_messages(self, node: int, timestamp: float) -> tuple[FastMessage, FastMessage]:
        """TPDO1 and TPDO2 (the PRes) of ``node`` with the values latched at the SoC."""
        return (FastMessage(timestamp, TPDO1_BASE + node,
                            bytearray(_PACK_TPDO1(self._a_sw[node], self._a_pos[node], self._a_tq[node]))),
                FastMessage(timestamp, TPDO2_BASE + node,
                            bytearray(_PACK_TPDO2(self._a_vel[node], self._a_err[node]))))

    def preq_received(self, node: int) -> bool:
        """True when a valid, timely PReq for ``node`` arrived in this cycle."""
        return self._preq_ok[node]

    def end_cycle(self, cycle: int) -> None:
        """Count PReqs that never arrived (or arrived late), decrement counters."""
        t = self._t0 + cycle * self._cycle_time
        for node in range(1, self.nodes + 1):
            if not self._preq_ok[node]:
                detail = "PReq arrived after the next SoC" if self._preq_late[node] else "no valid PReq"
                self._c_preq[node].error(cycle, t, detail)
            self._preq_ok[node] = self._preq_late[node] = self._crc[node] = False
        self.counters.end_cycle(cycle, t)

    def emergency_messages(self, timestamp: float) -> list[FastMessage]:
        """EMCY frames due in this cycle's asynchronous slot (one per tripped counter)."""
        if not self._emcy_due:
            return []
        out = []
        for node, counter in self._emcy_due:
            data = bytearray(EMCY.pack(EMCY_COMMUNICATION, EMCY_ERROR_REGISTER_COMMUNICATION,
                                       COUNTER_IDS.get(f"cn_{counter.kind}", 0),
                                       min(counter.value, 0xFFFF), counter.threshold))
            out.append(FastMessage(timestamp, EMCY_BASE + node, data))
            self.log.add(FieldbusEvent(timestamp, self.cycle, "cn", node, counter.kind, "emcy_sent",
                                       counter.value, counter.cumulative, counter.threshold,
                                       f"EMCY 0x{EMCY_COMMUNICATION:04X}"))
        self._emcy_due = []
        return out

    # ------------------------------------------------------------------ faults
    def _on_threshold(self, counter: ThresholdCounter, cycle: int, time_s: float) -> None:
        node = counter.node
        self._emcy_due.append((node, counter))
        if not self.comm_fault[node]:
            self.comm_fault[node] = True
            what = ("drive gets quick stop controlword 0x0002 and comm_fault" if self._quick_stop
                    else "drive gets comm_fault (abort option 'fault')")
            self.log.add(FieldbusEvent(time_s, cycle, "cn", node, counter.kind, "fault_reaction",
                                       counter.value, counter.cumulative, counter.threshold, what))

    def _clear_fault(self, node: int, cycle: int, time_s: float) -> None:
        if any(c.node == node and c.tripped for c in self.counters.counters):
            return
        self.comm_fault[node] = False
        self.log.add(FieldbusEvent(time_s, cycle, "cn", node, "comm_fault", "fault_cleared",
                                   -1, -1, -1, "fault reset applied with all counters below threshold"))
