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
from fieldbus.telegrams import EMCY_BASE, RPDO1_BASE, SYNC_ID, TPDO1_BASE, TPDO2_BASE
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
        self._record = self.recorder.add if self.recorder is not None else None
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
    def _corrupt(self, msg: can.Message) -> can.Message:
        """The frame as it arrives after corruption on the wire: payload bits flipped,
        flagged as an error frame (the receiver's checksum fails)."""
        data = bytearray(msg.data) or bytearray(1)
        data[0] ^= 0xA5
        msg.data = data
        msg.dlc = len(data)
        msg.is_error_frame = True
        return msg

    def _put(self, bus: can.BusABC, msg: can.Message, kind: str | None) -> None:
        """Send one frame through the medium (kind: None, 'late', 'corrupt')."""
        if kind == "late":
            msg.timestamp += self.config.faults.late_delay_s
        elif kind == "corrupt":
            self._corrupt(msg)
        bus.send(msg)
        self.frames_sent += 1
        if self._record is not None:
            self._record(msg)

    def _deliver(self, bus: can.BusABC, handler: Any, expected: int, timestamp: float) -> None:
        """Hand frames that reached ``bus`` to ``handler``. On asynchronous interfaces wait
        (wall clock) for the ``expected`` frames and give them their simulated timestamp."""
        if self._synchronous:
            recv = bus.recv
            msg = recv(0)
            while msg is not None:
                handler(msg)
                msg = recv(0)
            return
        deadline = time.monotonic() + self.config.bus.receive_timeout_s
        got = 0
        while got < expected:
            remaining = deadline - time.monotonic()
            msg = bus.recv(max(remaining, 0.0))
            if msg is None:
                self.frames_missing += expected - got
                break
            msg.timestamp = timestamp
            handler(msg)
            got += 1

    # ------------------------------------------------------------------ cycle
    def run_cycle(self, cycle: int, setpoints: Setpoints, actuals: DriveActuals) -> CycleResult:
        """Run POWERLINK cycle ``cycle`` (consecutive calls: cycle, cycle + 1, ...)."""
        last = self._last_cycle
        if last is not None and cycle != last + 1:
            raise ValueError(f"run_cycle(cycle={cycle}): expected cycle {last + 1} (cycles run consecutively)")
        if cycle < 0:
            raise ValueError(f"run_cycle(cycle={cycle}): expected a cycle number >= 0")
        self._last_cycle = cycle
        n = self.config.nodes
        mn, cn = self.mn, self.cn
        mn_bus, cn_bus = self.mn_bus, self.cn_bus
        put, deliver = self._put, self._deliver
        faults = self.faults.for_cycle(cycle)
        if faults is None:
            ts = self.schedule.timestamps(cycle)
            kinds: dict[int, str] = {}
        else:
            ts = self.schedule.faulty_timestamps(cycle, faults)
            kinds = faults.kinds
            self._record_injected(cycle, faults)
        # --- SoC
        soc = ts[0]
        if kinds.get(0) == "loss":
            self.frames_dropped += 1
        else:
            put(mn_bus, mn.sync_message(cycle, soc), kinds.get(0))
            deliver(cn_bus, cn.receive, 1, soc)
        applied = cn.start_cycle(cycle, actuals)
        mn.start_cycle(cycle)
        # --- PReq / PRes per node
        cws = setpoints.controlword.tolist()
        poss = setpoints.position.tolist()
        tqs = setpoints.torque_offset.tolist()
        if len(cws) != n or len(poss) != n or len(tqs) != n:
            raise ValueError(f"setpoints: expected {n} entries per field, got "
                             f"{len(cws)}, {len(poss)}, {len(tqs)}")
        preq_message, pres_messages = mn.preq_message, cn.pres_messages
        mn_receive, cn_receive, preq_received = mn.receive, cn.receive, cn.preq_received
        for node in range(1, n + 1):
            i = node - 1
            msg = preq_message(node, ts[node], cws[i], poss[i], tqs[i])
            kind = kinds.get(node) if kinds else None
            if kind == "loss":
                self.frames_dropped += 1
            else:
                put(mn_bus, msg, kind)
                deliver(cn_bus, cn_receive, 1, msg.timestamp)
            pres_ts = ts[n + node]
            if pres_ts is not None and preq_received(node):
                first, second = pres_messages(node, pres_ts)
                kind = kinds.get(n + node) if kinds else None
                if kind == "loss":
                    self.frames_dropped += 2
                    continue
                put(cn_bus, first, kind)
                put(cn_bus, second, kind)
                deliver(mn_bus, mn_receive, 2, first.timestamp)
        # --- asynchronous slot: EMCY of nodes whose counters tripped
        cn.end_cycle(cycle)
        emcy = cn.emergency_messages(self.schedule.nominal_soc_time(cycle) + self._emcy_offset)
        if emcy:
            for msg in emcy:
                put(cn_bus, msg, None)
            deliver(mn_bus, mn_receive, len(emcy), emcy[0].timestamp)
        observed = mn.end_cycle(cycle)
        if self.recorder is not None:
            self.recorder.end_cycle(cycle, self.schedule.nominal_soc_time(cycle))
        return CycleResult(cycle, self.schedule.nominal_soc_time(cycle), applied, observed)

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
            "node_fault": [bool(x) for x in self.mn.node_fault[1:]],
            "comm_fault": [bool(x) for x in self.cn.comm_fault[1:]],
            "counters": self.mn.counters.snapshot() + self.cn.counters.snapshot(),
            "event_tally": self.events.tally(),
            "faults": faults,
        }
