"""``PowerlinkNetwork``: the managing node, the controlled nodes and the bus, run
cycle by cycle in simulated time in one process.

Per cycle k (SoC at t_k = start_time + k * cycle_time)::

    result = network.run_cycle(k, setpoints, actuals)

* ``setpoints``: what the controller computed after cycle k-1 (SI units); they go
  into the PReqs of cycle k and reach the drives at the SoC of k + dead_time_cycles.
* ``actuals``: the drives' values at t_k; the CNs latch them at the SoC and send them
  in this cycle's PRes frames.
* ``result.applied``: what each drive applies from t_k to t_{k+1} (quantised, with
  ``fresh`` and ``comm_fault`` flags). ``result.observed``: what the controller sees
  in cycle k (the values latched at t_k, with ``fresh`` and ``node_fault``).

Frames go through a real python-can bus (``[fieldbus.bus] interface``: the lean
``simbus`` by default, ``virtual``, ``udp_multicast`` or hardware), in POWERLINK
order: SYNC, then per node RPDO1 and the answer TPDO1 + TPDO2, then EMCY frames of
tripped nodes in the asynchronous slot. Fault injection acts as the medium between
the sender and the bus. Every frame on the wire is recorded with ``can.Logger``.

The returned arrays are reused every cycle: copy what you keep.
"""
from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import can
import numpy as np

from fieldbus.config import FieldbusConfig
from fieldbus.events import EventLog, FieldbusEvent
from fieldbus.faults import FaultPlan
from fieldbus.nodes import ControlledNodes, ManagingNode
from fieldbus.process_data import AppliedSetpoints, CycleResult, DriveActuals, ObservedActuals, Setpoints
from fieldbus.recorder import FrameRecorder
from fieldbus.scaling import JointScaling
from fieldbus.simbus import register as register_simbus
from fieldbus.simbus import unique_channel
from fieldbus.telegrams import EMCY_BASE, RPDO1_BASE, SYNC_ID, TPDO1_BASE, TPDO2_BASE, FastMessage
from fieldbus.timing import CycleLayout, CycleSchedule, check_cycle_budget

SYNCHRONOUS_INTERFACES = ("simbus", "virtual")  # deliver inside send(), keep timestamps


def open_bus(config: FieldbusConfig, side: str, channel: str | int) -> can.BusABC:
    """Open the python-can bus of one side ('mn' or 'cn') as configured.

    On interfaces that echo a sender's own frames (udp_multicast, hardware with
    loopback) each side filters for the identifiers the other side sends."""
    bus_cfg = config.bus
    kwargs: dict[str, Any] = dict(bus_cfg.options)
    interface = bus_cfg.interface
    if interface == "simbus":
        register_simbus()
    elif interface == "virtual":
        kwargs.setdefault("preserve_timestamps", True)
    else:
        n = config.nodes
        if side == "mn":
            wanted = [TPDO1_BASE + k for k in range(1, n + 1)] + [TPDO2_BASE + k for k in range(1, n + 1)] \
                + [EMCY_BASE + k for k in range(1, n + 1)]
        else:
            wanted = [SYNC_ID] + [RPDO1_BASE + k for k in range(1, n + 1)]
        kwargs.setdefault("can_filters", [{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in wanted])
    try:
        return can.Bus(interface=interface, channel=channel, **kwargs)
    except (ImportError, NotImplementedError, can.CanError, OSError, TypeError, ValueError) as error:
        from fieldbus.errors import FieldbusConfigError
        raise FieldbusConfigError(config.source, "bus.interface", interface,
                                  f"a python-can interface that opens with channel {channel!r} "
                                  f"and options {dict(bus_cfg.options)!r} ({type(error).__name__}: {error})") from error


class PowerlinkNetwork:
    """POWERLINK-timed CiA 402 network of one MN and ``config.nodes`` CNs.

    Args:
        config: a :class:`FieldbusConfig` or the ``[fieldbus]`` table as a dict.
        scaling: joint scaling (gear ratios, encoder counts, rated torques) with one
            joint per node.
        log_path: CAN log to write (.blf or .asc); None records nothing.
    """

    def __init__(self, config: FieldbusConfig | Mapping[str, Any] | None, scaling: JointScaling,
                 log_path: str | Path | None = None) -> None:
        if not isinstance(config, FieldbusConfig):
            config = FieldbusConfig.from_dict(config)
        if scaling.joints != config.nodes:
            from fieldbus.errors import FieldbusConfigError
            raise FieldbusConfigError(config.source, "nodes", config.nodes,
                                      f"as many nodes as the scaling has joints ({scaling.joints})")
        self.config = config
        self.scaling = scaling
        self.layout: CycleLayout = check_cycle_budget(config)
        self.schedule = CycleSchedule(config, self.layout)
        self.faults = FaultPlan(config)
        self.events = EventLog()
        self.mn = ManagingNode(config, scaling, self.layout, self.events)
        self.cn = ControlledNodes(config, scaling, self.layout, self.events)
        channel = config.bus.channel
        if channel == "":
            if config.bus.interface in SYNCHRONOUS_INTERFACES:
                channel = unique_channel()
            elif config.bus.interface == "udp_multicast":
                channel = can.interfaces.udp_multicast.UdpMulticastBus.DEFAULT_GROUP_IPv4
        self.channel = channel
        self._synchronous = config.bus.interface in SYNCHRONOUS_INTERFACES
        self.mn_bus = open_bus(config, "mn", channel)
        try:
            self.cn_bus = open_bus(config, "cn", channel)
        except Exception:
            self.mn_bus.shutdown()
            raise
        self.recorder = (FrameRecorder(log_path, config.recording.flush_every_cycles,
                                       config.recording.background) if log_path is not None else None)
        self._record_many = self.recorder.add_many if self.recorder is not None else None
        self._t0 = config.start_time_s
        self._cycle_time = config.cycle_time_s
        self._last_cycle: int | None = None
        self.frames_sent = 0
        self.frames_dropped = 0
        self.frames_missing = 0  # sent but never delivered by an asynchronous interface
        self._emcy_offset = (self.layout.nominal_end_of_isochronous + self.layout.mn_turnaround
                             + self.layout.wire_soa + self.layout.cn_response)
        self._closed = False

    # ------------------------------------------------------------------ context
    def __enter__(self) -> "PowerlinkNetwork":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Flush the recording and shut the buses down (idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            if self.recorder is not None:
                self.recorder.close()
        finally:
            self.mn_bus.shutdown()
            self.cn_bus.shutdown()

    # ------------------------------------------------------------------ medium
    def _transmit(self, bus: can.BusABC, frames: list, kinds: dict[int, str]) -> list:
        """Put ``frames`` on the wire through ``bus``; with ``kinds`` (frame index ->
        'loss' | 'late' | 'corrupt' | 'silent') the medium drops, delays or corrupts
        them. Returns the frames actually sent."""
        if kinds:
            frames = [m for m in (self._through_medium(m, kinds) for m in frames) if m is not None]
        send = bus.send
        for msg in frames:
            send(msg)
        self.frames_sent += len(frames)
        if self._record_many is not None:
            self._record_many(frames)
        return frames

    def _frame_index(self, arbitration_id: int) -> int:
        if arbitration_id == SYNC_ID:
            return 0
        node = arbitration_id & 0x7F
        base = arbitration_id & ~0x7F
        if base == RPDO1_BASE:
            return node
        if base in (TPDO1_BASE, TPDO2_BASE):
            return self.config.nodes + node
        return -1

    def _through_medium(self, msg: can.Message, kinds: dict[int, str]) -> can.Message | None:
        """The frame as the medium passes it on: None (lost), a delayed or a corrupted
        copy (the node's own message object stays untouched), or ``msg`` itself."""
        kind = kinds.get(self._frame_index(msg.arbitration_id))
        if kind is None:
            return msg
        if kind in ("loss", "silent"):
            self.frames_dropped += 1
            return None
        if kind == "late":
            delay = 0.0 if msg.arbitration_id == SYNC_ID else self.config.faults.late_delay_s
            return FastMessage(msg.timestamp + delay, msg.arbitration_id, bytearray(msg.data))
        data = bytearray(msg.data) or bytearray(1)
        data[0] ^= 0xA5  # bits flipped on the wire; the receiver's checksum fails
        return FastMessage(msg.timestamp, msg.arbitration_id, data, is_error_frame=True)

    def _deliver(self, bus: can.BusABC, receive_all: Any, sent: list) -> None:
        """Hand the frames that reached ``bus`` to ``receive_all`` (a node's batch
        receiver). On asynchronous interfaces wait (wall clock, up to
        receive_timeout_s) for the ``sent`` frames and restore their simulated
        timestamps, which those interfaces overwrite."""
        if self._synchronous:
            drain = getattr(bus, "drain", None)
            if drain is not None:
                received = drain()
            else:
                received = []
                msg = bus.recv(0)
                while msg is not None:
                    received.append(msg)
                    msg = bus.recv(0)
            if received:
                receive_all(received)
            return
        stamps = {m.arbitration_id: m.timestamp for m in sent}
        deadline = time.monotonic() + self.config.bus.receive_timeout_s
        received = []
        while len(received) < len(sent):
            msg = bus.recv(max(deadline - time.monotonic(), 0.0))
            if msg is None:
                self.frames_missing += len(sent) - len(received)
                break
            msg.timestamp = stamps.get(msg.arbitration_id, msg.timestamp)
            received.append(msg)
        if received:
            receive_all(received)

    # ------------------------------------------------------------------ cycle
    def run_cycle(self, cycle: int, setpoints: Setpoints, actuals: DriveActuals) -> CycleResult:
        """Run POWERLINK cycle ``cycle`` (consecutive calls: cycle, cycle + 1, ...).

        Frames are exchanged in three bursts (SoC + PReqs, PRes, EMCY); their
        timestamps follow the POWERLINK schedule (PReq1, PRes1, PReq2, ...), and every
        decision (late, lost) is taken on timestamps, so the outcome equals a
        frame-by-frame exchange; the recording is written in timestamp order."""
        last = self._last_cycle
        if (last is not None and cycle != last + 1) or cycle < 0:
            expected = "a cycle number >= 0" if last is None else f"cycle {last + 1} (cycles run consecutively)"
            raise ValueError(f"run_cycle(cycle={cycle}): expected {expected}")
        self._last_cycle = cycle
        mn, cn = self.mn, self.cn
        faults = self.faults.for_cycle(cycle)
        if faults is None:
            times = self.schedule.timestamps(cycle)
            kinds: dict[int, str] = {}
        else:
            times = self.schedule.faulty_timestamps(cycle, faults)
            kinds = faults.kinds
            self._record_injected(cycle, faults)
        cws = setpoints.controlword.tolist()
        poss = setpoints.position.tolist()
        tqs = setpoints.torque_offset.tolist()
        n = self.config.nodes
        if len(cws) != n or len(poss) != n or len(tqs) != n:
            raise ValueError(f"setpoints: expected {n} entries per field, got "
                             f"{len(cws)}, {len(poss)}, {len(tqs)}")
        # SoC: the CNs latch and apply; MN sends SoC and PReqs
        applied = cn.start_cycle(cycle, actuals)
        mn.start_cycle(cycle)
        sent = self._transmit(self.mn_bus, mn.frames(cycle, times, cws, poss, tqs), kinds)
        self._deliver(self.cn_bus, cn.receive_all, sent)
        # PRes of every node whose PReq arrived
        sent = self._transmit(self.cn_bus, cn.responses(times), kinds)
        self._deliver(self.mn_bus, mn.receive_all, sent)
        # asynchronous slot: EMCY of nodes whose counters tripped
        cn.end_cycle(cycle)
        t = self._t0 + cycle * self._cycle_time
        emcy = cn.emergency_messages(t + self._emcy_offset)
        if emcy:
            sent = self._transmit(self.cn_bus, emcy, {})
            self._deliver(self.mn_bus, mn.receive_all, sent)
        observed = mn.end_cycle(cycle)
        if self.recorder is not None:
            self.recorder.end_cycle(cycle, t)
        return CycleResult(cycle, t, applied, observed)

    def _record_injected(self, cycle: int, faults: Any) -> None:
        t = self.schedule.nominal_soc_time(cycle)
        for frame, node, kind in faults.describe(self.config.nodes):
            self.events.add(FieldbusEvent(t, cycle, "medium", node, f"{frame}_{kind}", "injected",
                                          -1, -1, -1, f"fault injection: {frame.upper()} {kind}"))

    # ------------------------------------------------------------------ reporting
    @property
    def applied(self) -> AppliedSetpoints:
        return self.cn.applied

    @property
    def observed(self) -> ObservedActuals:
        return self.mn.observed

    def summary(self) -> dict[str, Any]:
        """JSON-ready summary: configuration essentials, frame counts, counters, faults."""
        lay = self.layout
        faults = [e.as_dict() for e in self.events.events
                  if e.event in ("error", "threshold_reached", "fault_reaction", "fault_cleared",
                                 "decode_error", "emcy_sent", "emcy_received", "injected")]
        return {
            "interface": self.config.bus.interface,
            "cycle_time_s": self.config.cycle_time_s,
            "dead_time_cycles": self.config.dead_time_cycles,
            "nodes": self.config.nodes,
            "cycles_run": (self._last_cycle + 1) if self._last_cycle is not None else 0,
            "frames_sent": self.frames_sent,
            "frames_dropped": self.frames_dropped,
            "frames_missing": self.frames_missing,
            "frames_recorded": self.recorder.frames_written if self.recorder is not None else 0,
            "log_path": str(self.recorder.path) if self.recorder is not None else None,
            "decode_errors": {"mn": self.mn.decode_errors, "cn": self.cn.decode_errors},
            "scaling_saturations": self.scaling.saturations(),
            "nominal_isochronous_phase_s": lay.nominal_end_of_isochronous,
            "nominal_busy_time_s": lay.nominal_end_of_async,
            "node_fault": [bool(x) for x in self.mn.node_fault],
            "comm_fault": [bool(x) for x in self.cn.comm_fault],
            "counters": self.mn.counters.snapshot() + self.cn.counters.snapshot(),
            "event_tally": self.events.tally(),
            "faults": faults,
        }
