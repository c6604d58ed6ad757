"""The two sides of the network, each with its own python-can bus connection, so they
can run in one process (``PowerlinkNetwork`` calls their phases in order) or in two
processes connected by an inter-process interface such as ``udp_multicast``.

Both sides derive the frame schedule and the injected faults of every cycle from the
same configuration and seed (:class:`CycleSchedule`, :class:`FaultPlan`), so each
knows which frames the other puts on the wire and when: a receiver waits (wall clock,
up to ``bus.receive_timeout_s``) only for frames that were really sent, restores their
simulated timestamps on interfaces that overwrite them, and detects losses by absence.
Each side applies the injected faults to the frames it sends.

Controller side::

    mn = ManagingNodeEndpoint(config, scaling)
    observed = mn.run_cycle(k, setpoints)        # = send_setpoints + collect_actuals

Drive side::

    drives = DriveEndpoint(config, scaling)
    applied = drives.run_cycle(k, actuals)       # SoC, PReqs in, PRes out, EMCY
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import can

from fieldbus.config import FieldbusConfig
from fieldbus.events import EventLog, FieldbusEvent
from fieldbus.faults import CycleFaults, FaultPlan
from fieldbus.lifecycle import Closeable
from fieldbus.nodes import ControlledNodes, ManagingNode
from fieldbus.process_data import AppliedSetpoints, DriveActuals, ObservedActuals, Setpoints
from fieldbus.recorder import FrameRecorder
from fieldbus.scaling import JointScaling
from fieldbus.simbus import register as register_simbus
from fieldbus.simbus import unique_channel
from fieldbus.udpcycle import register as register_udpcycle
from fieldbus.telegrams import EMCY_BASE, RPDO1_BASE, SYNC_ID, TPDO1_BASE, TPDO2_BASE, FastMessage, rpdo1_length
from fieldbus.timing import CycleLayout, CycleSchedule, check_cycle_budget

# Setpoints fields in the order of ManagingNode.frames' arguments
_SETPOINT_FIELDS = ("controlword", "position", "torque_offset", "modes_of_operation", "target_torque",
                    "target_velocity", "velocity_offset")
SYNCHRONOUS_INTERFACES = ("simbus", "virtual")  # deliver inside send(), keep timestamps
_NO_FAULTS: dict[int, str] = {}  # the medium's faults of a fault-free cycle (never modified)


class ControllerCadence:
    """How fast the controller's SoC counter advances against the paced cell's cycles: a
    controller that runs its own clock at another cycle time than the cell's is detected,
    counted and logged (a *cycle-time mismatch*), not only seen as lost frames.

    Every SoC the cell reads (taken or late) is noted with the cell cycle in which it was
    read. Over blocks of at least ``block_cycles`` cell cycles holding at least
    ``min_groups`` SoCs, the unwrapped counter advance divided by the cycles elapsed is the
    ratio of the two cycle times (cell / controller): 1 for a controller in step (also one
    that follows the cell and catches up after a miss), 0.4 for a 1 ms controller against a
    400 µs cell, 2 for a 200 µs one. A block whose ratio is outside ``[1 - tolerance,
    1 + tolerance]`` is out of band; two in a row are a mismatch (one alone may hold the
    counter jump of a controller that restarted). The start of each mismatch episode is
    logged as an event ``cycle_time_mismatch`` with the estimated controller cycle.
    """

    def __init__(self, overflow: int, cycle_time_s: float, block_cycles: int = 250, min_groups: int = 10,
                 tolerance: float = 0.2) -> None:
        self.overflow = overflow
        self.cycle_time_s = cycle_time_s
        self.block_cycles = block_cycles
        self.min_groups = min_groups
        self.tolerance = tolerance
        self.blocks = 0  # judged blocks
        self.mismatched_blocks = 0
        self.episodes = 0
        self.first_cycle: int | None = None  # cell cycle of the first mismatched block's end
        self.ratios: list[float] = []  # cell / controller cycle time per mismatched block
        self._in_episode = False
        self._pending: float | None = None  # ratio of an out-of-band block not yet confirmed by the next
        self._start: int | None = None  # cell cycle of the block's first SoC
        self._last_counter = 0
        self._advance = 0
        self._groups = 0

    def note(self, cycle: int, counter: int, time_s: float | None = None) -> tuple[float, float] | None:
        """A SoC with ``counter`` read in cell cycle ``cycle`` at wall time ``time_s`` (s, any
        origin; default ``cycle`` times the cycle time: a cell that never misses a tick);
        returns (ratio, controller cycle time estimate in s) when this SoC closed a mismatched
        block, else None. Elapsed time is measured on the wall clock, so a cell that dropped
        ticks after a stall does not misjudge the controller."""
        if time_s is not None:
            cycle_or_time = time_s / self.cycle_time_s  # in cycles of the cell, on the wall clock
        else:
            cycle_or_time = float(cycle)
        if self._start is None:
            self._start, self._last_counter, self._advance, self._groups = cycle_or_time, counter, 0, 1
            return None
        step = (counter - self._last_counter) % self.overflow
        if step > self.overflow // 2:  # older than the newest (a late duplicate of the sender's): not an advance
            return None
        self._advance += step
        self._last_counter = counter
        self._groups += 1
        elapsed = cycle_or_time - self._start
        if elapsed < self.block_cycles or self._groups < self.min_groups:
            if elapsed >= 4 * self.block_cycles:  # too few SoCs to judge (a silent controller): start over
                self._start, self._advance, self._groups = cycle_or_time, 0, 1
            return None
        ratio = self._advance / elapsed
        self.blocks += 1
        self._start, self._advance, self._groups = cycle_or_time, 0, 1
        if abs(ratio - 1.0) <= self.tolerance:
            self._in_episode, self._pending = False, None
            return None
        if not self._in_episode and self._pending is None:
            self._pending = ratio  # one block alone may hold a restarted controller's counter jump
            return None
        if self._pending is not None:
            self.mismatched_blocks += 1
            self.ratios.append(self._pending)
            self._pending = None
        self.mismatched_blocks += 1
        self.ratios.append(ratio)
        if self._in_episode:
            return None
        self._in_episode = True
        self.episodes += 1
        if self.first_cycle is None:
            self.first_cycle = cycle
        return ratio, (self.cycle_time_s / ratio if ratio > 0 else float("inf"))

    def report(self) -> dict[str, Any] | None:
        """The mismatch for a summary (None when none was seen)."""
        if not self.mismatched_blocks:
            return None
        import statistics

        ratio = statistics.median(self.ratios)
        return {"episodes": self.episodes, "blocks": self.mismatched_blocks, "blocks_judged": self.blocks,
                "first_cycle": self.first_cycle, "cell_cycle_time_s": self.cycle_time_s,
                "controller_cycle_time_s_estimate": self.cycle_time_s / ratio if ratio > 0 else None}


def default_channel(config: FieldbusConfig) -> str | int:
    """The configured channel; when empty a fresh in-process channel (simbus, virtual)
    or python-can's default multicast group (udp_multicast)."""
    channel = config.bus.channel
    if channel == "":
        if config.bus.interface in SYNCHRONOUS_INTERFACES:
            return unique_channel()
        if config.bus.interface == "udp_multicast":
            return can.interfaces.udp_multicast.UdpMulticastBus.DEFAULT_GROUP_IPv4
    return channel


def open_bus(config: FieldbusConfig, side: str, channel: str | int) -> can.BusABC:
    """Open the python-can bus of one side ('mn' or 'cn') as configured.

    On interfaces that echo a sender's own frames (udp_multicast, hardware with
    loopback) each side filters for the identifiers the other side sends."""
    bus_cfg = config.bus
    kwargs: dict[str, Any] = dict(bus_cfg.options)
    interface = bus_cfg.interface
    if interface == "udpcycle":
        register_udpcycle()
    if interface == "simbus":
        register_simbus()
    elif interface == "virtual":
        kwargs.setdefault("preserve_timestamps", True)
    else:
        n = config.nodes
        if side == "mn":
            wanted = [base + k for base in (TPDO1_BASE, TPDO2_BASE, EMCY_BASE) for k in range(1, n + 1)]
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


class _Endpoint(Closeable):
    """One side: configuration, schedule, fault plan, bus, medium, optional recording."""

    side = ""

    def __init__(self, config: FieldbusConfig | dict | None, scaling: JointScaling, *,
                 channel: str | int | None = None, events: EventLog | None = None,
                 log_path: str | Path | None = None, recorder: FrameRecorder | None = None,
                 record_received: bool = True, record_data_bytes: int | None = None) -> None:
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
        self.plan = FaultPlan(config)
        self.events = events if events is not None else EventLog()
        self.channel = default_channel(config) if channel is None else channel
        self.synchronous = config.bus.interface in SYNCHRONOUS_INTERFACES
        self.bus = open_bus(config, self.side, self.channel)
        self._drain = getattr(self.bus, "drain", None)  # simbus: all queued frames at once
        self._send_many = getattr(self.bus, "send_many", None)  # simbus: a cycle's frames at once
        if recorder is None and log_path is not None:
            # the longest frame: the RPDO1 with this configuration's look-ahead (64: any CAN FD frame)
            recorder = FrameRecorder(log_path, config.recording.flush_every_cycles, config.recording.background,
                                     record_data_bytes or (64 if config.setpoint_buffer
                                                           else rpdo1_length(config.setpoint_lookahead)))
            self._owns_recorder = True
        else:
            self._owns_recorder = False
        self.recorder = recorder
        self._record = recorder.add_many if recorder is not None else None
        self._record_received = record_received and recorder is not None and not self.synchronous
        self._t0 = config.start_time_s
        self._cycle_time = config.cycle_time_s
        self._cycle = -1
        self._times: list = []
        self._kinds: dict[int, str] = {}
        self.frames_sent = 0
        self.frames_dropped = 0
        self.frames_missing = 0  # sent, but an asynchronous interface did not deliver it in time
        self.frames_late = 0  # paced cell side: frames that missed their cycle's window
        self._follow_cycle = -1  # controller side following a paced cell: the cell's cycle as counted
        self._follow_lost = 0
        self._align: int | None = None  # paced cell side: controller SoC counter - 1 - cycle (mod overflow)
        self._last_taken = -1  # paced cell side: last cycle whose group was taken

    # ------------------------------------------------------------------ cycle bookkeeping
    def _begin(self, cycle: int) -> None:
        if (self._cycle >= 0 and cycle != self._cycle + 1) or cycle < 0:
            expected = "a cycle number >= 0" if self._cycle < 0 else f"cycle {self._cycle + 1} (cycles run consecutively)"
            raise ValueError(f"run_cycle(cycle={cycle}): expected {expected}")
        self._cycle = cycle
        self._schedule_sending(cycle)

    def _schedule_sending(self, cycle: int) -> None:
        """This cycle's frame times and the injected faults of the frames this side sends."""
        faults = self.plan.for_cycle(cycle)
        if faults is None:
            self._times = self.schedule.timestamps(cycle)
            self._kinds = _NO_FAULTS
        else:
            self._times = self.schedule.faulty_timestamps(cycle, faults)
            self._kinds = faults.kinds
            self._record_injected(cycle, faults)

    def _record_injected(self, cycle: int, faults: CycleFaults) -> None:
        """Note the injected faults this side applies (frames it sends)."""
        t = self._t0 + cycle * self._cycle_time
        mine = ("soc", "preq") if self.side == "mn" else ("pres",)
        for frame, node, kind in faults.describe(self.config.nodes):
            if frame in mine:
                self.events.add(FieldbusEvent(t, cycle, "medium", node, f"{frame}_{kind}", "injected",
                                              -1, -1, -1, f"fault injection: {frame.upper()} {kind}"))

    # ------------------------------------------------------------------ medium
    def _frame_index(self, arbitration_id: int) -> int:
        if arbitration_id == SYNC_ID:
            return 0
        base, node = arbitration_id & ~0x7F, arbitration_id & 0x7F
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

    def _transmit(self, frames: list) -> list:
        """Put ``frames`` on the wire (through the injected faults of this cycle)."""
        kinds = self._kinds
        if kinds:
            frames = [m for m in (self._through_medium(m, kinds) for m in frames) if m is not None]
        if self._send_many is not None:
            self._send_many(frames)
        else:
            send = self.bus.send
            for msg in frames:
                send(msg)
        self.frames_sent += len(frames)
        if self._record is not None:
            self._record(frames)
        return frames

    def _receive(self, expected: dict[int, float]) -> list:
        """Frames that reached this side. Synchronous interfaces have delivered already;
        otherwise wait for the ``expected`` identifiers (-> simulated timestamp)."""
        bus = self.bus
        if self.synchronous:
            return self._read_now()
        waiting = dict(expected)
        received = []
        deadline = time.monotonic() + self.config.bus.receive_timeout_s
        while waiting:
            msg = bus.recv(max(deadline - time.monotonic(), 0.0))
            if msg is None:
                self.frames_missing += len(waiting)
                break
            stamp = waiting.pop(msg.arbitration_id, None)
            msg.timestamp = stamp if stamp is not None else self._t0 + self._cycle * self._cycle_time
            received.append(msg)
        msg = bus.recv(0)
        while msg is not None:  # anything else that is already there
            msg.timestamp = expected.get(msg.arbitration_id, self._t0 + self._cycle * self._cycle_time)
            received.append(msg)
            msg = bus.recv(0)
        if self._record_received and received:
            self._record(received)
        return received

    def _read_now(self) -> list:
        """Every frame that has arrived, without waiting."""
        if self._drain is not None:
            return self._drain()
        bus, batch = self.bus, []
        msg = bus.recv(0)
        while msg is not None:
            batch.append(msg)
            msg = bus.recv(0)
        return batch

    def _flush_own_recording(self, cycle: int) -> None:
        if self._owns_recorder:
            self.recorder.end_cycle(cycle, self._t0 + cycle * self._cycle_time)

    def _delay(self, index: int) -> float:
        return self.config.faults.late_delay_s if self._kinds.get(index) == "late" else 0.0

    # ------------------------------------------------------------------ life cycle
    def _release(self) -> None:
        """Flush an own recording and shut the bus down."""
        try:
            if self.recorder is not None and self._owns_recorder:
                self.recorder.close()
        finally:
            self.bus.shutdown()


class ManagingNodeEndpoint(_Endpoint):
    """Controller side: the POWERLINK MN with its bus connection.

    ``log_path`` records the frames this side sends and receives."""

    side = "mn"

    def __init__(self, config: FieldbusConfig | dict | None, scaling: JointScaling, **kwargs: Any) -> None:
        super().__init__(config, scaling, **kwargs)
        self.node = ManagingNode(self.config, scaling, self.layout, self.events)
        #: following a paced cell: the frame time the cell put on its newest PRes of node 1, as
        #: received (its simulated time, so its own cycle number; on interfaces that keep the
        #: sender's timestamps, such as udpcycle), None before the first
        self.peer_time_s: float | None = None

    def send_setpoints(self, cycle: int, setpoints: Setpoints) -> None:
        """SoC and PReqs of ``cycle`` carrying ``setpoints`` (SI units)."""
        if setpoints.controlword.dtype.kind not in "iu":
            raise ValueError(f"setpoints.controlword has dtype {setpoints.controlword.dtype}: expected integers")
        if setpoints.modes_of_operation.dtype.kind not in "iu":
            raise ValueError(f"setpoints.modes_of_operation has dtype {setpoints.modes_of_operation.dtype}: "
                             "expected integers (8, 9 or 10)")
        self._begin(cycle)
        node = self.node
        node.start_cycle(cycle)
        frames = node.encode(cycle, self._times, setpoints)  # compiled codec, None: Python
        if frames is None:
            frames = self._python_frames(cycle, self._times, setpoints)
        self._transmit(frames)

    def _python_frames(self, cycle: int, times: Any, setpoints: Setpoints) -> list:
        """SoC and PReqs of ``cycle`` from the Python nodes (no compiled codec), after checking
        that every set-point field has one entry per node."""
        values = [getattr(setpoints, name).tolist() for name in _SETPOINT_FIELDS]
        n = self.config.nodes
        if any(len(v) != n for v in values):
            raise ValueError(f"setpoints: expected {n} entries per field, got "
                             + ", ".join(f"{name} {len(v)}" for name, v in zip(_SETPOINT_FIELDS, values)))
        return self.node.frames(cycle, times, *values)

    def collect_actuals(self, cycle: int) -> ObservedActuals:
        """Receive this cycle's PRes frames (and EMCYs); the controller's view of cycle k."""
        expected: dict[int, float] = {}
        if not self.synchronous:
            times, n = self._times, self.config.nodes
            for i in range(n):
                ts = times[n + 1 + i]
                if ts is not None and self._kinds.get(n + 1 + i) != "loss":
                    ts += self._delay(n + 1 + i)
                    expected[TPDO1_BASE + i + 1] = ts
                    expected[TPDO2_BASE + i + 1] = ts
        received = self._receive(expected)
        if received:
            self.node.receive_all(received)
        observed = self.node.end_cycle(cycle)
        self._flush_own_recording(cycle)
        return observed

    # ------------------------------------------------------------------ following a paced cell
    def follow(self, timeout_s: float) -> tuple[int, ObservedActuals] | None:
        """The controller side of a hardware-in-the-loop run (the cell keeps the time,
        :meth:`DriveEndpoint.run_cycle_paced`): wait up to ``timeout_s`` (wall) for the
        cell's next PRes frames, digest everything that has arrived, and return
        ``(cycle, observed)``: the cell's cycle as counted here (+1 per batch of PRes
        frames - a TPDO1 of a node not above the one before starts a batch -, and per
        datagram the transport reports lost) and the newest actual
        values. None when nothing arrived in time. Then call :meth:`send_following`
        with the set-points for the next cycle."""
        bus = self.bus
        first = bus.recv(timeout_s)
        if first is None:
            return None
        batch = [first] + self._read_now()
        n = self.config.nodes
        head = TPDO1_BASE + 1
        # a batch of PRes frames is one cycle: the nodes answer in ascending order, so a TPDO1 of a
        # node not above the one before starts the next cycle (node 1's PRes may be missing: a
        # fault burst, a silent node; counting node 1's alone let this side fall behind the cell)
        batches, previous = 0, n + 1
        for m in batch:
            if m.arbitration_id & ~0x7F == TPDO1_BASE:
                node = m.arbitration_id & 0x7F
                if node <= previous:
                    batches += 1
                previous = node
        batches = batches or 1
        stats = getattr(bus, "stats", None)
        lost = getattr(stats, "lost", 0)
        batches += lost - self._follow_lost
        self._follow_lost = lost
        cycle = self._follow_cycle + batches
        self._follow_cycle = self._cycle = cycle
        times = self.schedule.timestamps(cycle)  # receiving only: the injected faults apply when sending
        for msg in batch:
            if msg.arbitration_id == head:
                self.peer_time_s = msg.timestamp  # as the cell stamped it (before this side's restamping)
            base, node = msg.arbitration_id & ~0x7F, msg.arbitration_id & 0x7F
            if base in (TPDO1_BASE, TPDO2_BASE) and 1 <= node <= n and times[n + node] is not None:
                msg.timestamp = times[n + node]  # the cell judged their timing
            else:
                msg.timestamp = times[0]
        node = self.node
        node.start_cycle(cycle)
        latest = node._latest
        for i in range(n):  # every PRes that came is in time here: the cell keeps the time
            if times[n + 1 + i] is not None:
                latest[i] = times[n + 1 + i]
        if self._record is not None:
            self._record(batch)
        node.receive_all(batch)
        observed = node.end_cycle(cycle)
        self._flush_own_recording(cycle)
        return cycle, observed

    def send_following(self, setpoints: Setpoints) -> None:
        """SoC and PReqs for the cell's next cycle (after :meth:`follow`), in one batch."""
        cycle = self._follow_cycle + 1
        self._schedule_sending(cycle)  # the scenario's injected faults apply to what this side sends
        node = self.node
        frames = node.encode(cycle, self._times, setpoints)
        if frames is None:
            frames = node.frames(cycle, self._times, *[getattr(setpoints, name).tolist()
                                                       for name in _SETPOINT_FIELDS])
        self._transmit(frames)

    def plan_ahead(self, cycle: int, setpoints: Setpoints) -> None:
        """Take ``setpoints``, the controller's output for the PReqs of ``cycle``, into the
        set-point buffer's plan without sending anything: a controller that stalled and did
        not run the cycles before ``cycle`` catches up on them (in order) before it answers the
        cell's newest cycle, so the buffer holds the set-points it would have sent rather than
        an interpolation over the stall. Only with ``setpoint_lookahead`` > 0."""
        node = self.node
        if not node._k:
            raise ValueError("plan_ahead: this bus has no set-point look-ahead (setpoint_lookahead = 0)")
        if node.encode(cycle, self._times, setpoints, build=False) is None:
            node.frames(cycle, self._times, *[getattr(setpoints, name).tolist() for name in _SETPOINT_FIELDS],
                        build=False)

    def run_cycle(self, cycle: int, setpoints: Setpoints) -> ObservedActuals:
        """send_setpoints + collect_actuals (for a controller in its own process)."""
        self.send_setpoints(cycle, setpoints)
        return self.collect_actuals(cycle)


class DriveEndpoint(_Endpoint):
    """Drive side: the six POWERLINK CNs with their (shared) bus connection.

    ``log_path`` records the frames this side sends and receives."""

    side = "cn"
    #: paced cell side: cycles without the controller's group after which its next SoC re-synchronises
    REALIGN_AFTER = 2
    #: ... unless that SoC's counter is that of one of the last LATE_GROUP_CYCLES cycles: a group the
    #: same controller sent late (a stall after it computed the group, before or in its sendto:
    #: 23 cycles late was seen), not a restart; it re-synchronises only when RESYNC_STREAK cycles in
    #: a row bring a group exactly that far behind (a restarted controller in step whose counter
    #: happens to land there: 10 ms at 400 µs; a controller late by the same amount that long is
    #: taken as it is). Re-synchronising on a late group shifted every set-point after it by the
    #: lateness until the next re-synchronisation. 119: just under half of the SoC counter's 240
    #: values, so that "behind" is unambiguous.
    LATE_GROUP_CYCLES = 119
    RESYNC_STREAK = 25

    def __init__(self, config: FieldbusConfig | dict | None, scaling: JointScaling, **kwargs: Any) -> None:
        super().__init__(config, scaling, **kwargs)
        self.nodes = ControlledNodes(self.config, scaling, self.layout, self.events)
        self._behind_streak, self._behind_last, self._behind_cycle = 0, 0, -2  # late groups in a row (_late_group)
        self.cadence = ControllerCadence(self.config.scaling.sync_counter_overflow, self.config.cycle_time_s)
        self._emcy_offset = (self.layout.nominal_end_of_isochronous + self.layout.mn_turnaround
                             + self.layout.wire_soa + self.layout.cn_response)

    def _end_of_cycle(self, cycle: int) -> None:
        """EMCYs of nodes that tripped (asynchronous slot, never faulted by injection), own recording."""
        emcy = self.nodes.emergency_messages(self._t0 + cycle * self._cycle_time + self._emcy_offset)
        if emcy:
            saved, self._kinds = self._kinds, _NO_FAULTS
            self._transmit(emcy)
            self._kinds = saved
        self._flush_own_recording(cycle)

    def run_cycle_paced(self, cycle: int, actuals: DriveActuals, deadline: float,
                        clock=time.monotonic) -> AppliedSetpoints:
        """The cell side of a hardware-in-the-loop run: like :meth:`run_cycle`, but the
        drives keep their own time and never wait for the controller beyond ``deadline``
        (a ``clock()`` value, wall seconds).

        The window of cycle k collects what the controller (the managing node, any
        program on the bus) sent: a *group* is a SoC followed by PReqs. The first group
        taken fixes how the controller's SoC counter maps onto the cell's cycles; from
        then on cycle k takes only the group carrying cycle k's counter (its frames get
        this cycle's scheduled timestamps). Anything else in the window - a group that
        missed its own cycle's window, frames without a SoC - is late and dropped
        (counted in :attr:`frames_late`, logged). A cycle whose window ends without its
        group has lost its SoC and PReqs: the nodes' threshold counters count it (+8,
        -1 per good cycle) exactly as for frames lost on the wire, and the drives hold
        or extrapolate the set-point. Nothing counts as lost before the first group (the
        nodes are not yet operational) nor while every node's fault reaction is latched
        and no group comes. After more than ``REALIGN_AFTER`` cycles without
        a group (a controller that restarted), the newest group is taken and fixes the
        mapping anew. The PRes frames go out every cycle, polled or
        not, so a controller can pace itself on them."""
        self._begin(cycle)
        cn = self.nodes
        applied = cn.start_cycle(cycle, actuals)
        group = self._newest_group(cycle, deadline, clock)
        if group:
            cn.receive_all(group)
        self._transmit(cn.responses(self._times, answer_all=True))
        # nothing is lost before the controller's first frames (the nodes are not yet
        # operational) nor once every node has reacted to a controller that went silent
        judge = self._align is not None and (bool(group) or not all(cn.comm_fault))
        cn.end_cycle(cycle, judge)
        self._end_of_cycle(cycle)
        return applied

    def _newest_group(self, cycle: int, deadline: float, clock) -> list:
        """This cycle's SoC + PReqs (restamped), see :meth:`run_cycle_paced`."""
        n = self.config.nodes
        overflow = self.nodes._sync_overflow
        groups: list[list] = []
        stale = 0
        preqs = {RPDO1_BASE + i + 1 for i in range(n)}
        expected = None if self._align is None else bytes([(cycle + self._align) % overflow + 1])
        pending: list = []
        while True:
            for msg in pending + self._read_now():
                if msg.arbitration_id == SYNC_ID and not msg.is_error_frame:
                    groups.append([msg])
                elif groups:
                    groups[-1].append(msg)
                else:
                    stale += 1
            if groups and bytes(groups[-1][0].data[:1]) == expected and \
                    preqs <= {m.arbitration_id for m in groups[-1]}:
                break
            remaining = deadline - clock()
            if remaining <= 0.0:
                break
            msg = self.bus.recv(min(remaining, 0.002))
            pending = [] if msg is None else [msg]
        if groups:
            self._note_cadence(cycle, groups, deadline)
        chosen = None
        for index in range(len(groups) - 1, -1, -1):
            if bytes(groups[index][0].data[:1]) == expected:
                chosen = index
                break
        if chosen is None and groups and (self._align is None or cycle - self._last_taken > self.REALIGN_AFTER) \
                and not self._late_group(cycle, groups[-1], expected, overflow):
            chosen = len(groups) - 1  # (re)synchronise on the controller's newest SoC
            align = (groups[chosen][0].data[0] - 1 - cycle) % overflow if groups[chosen][0].data else 0
            if self._align is not None and align != self._align:
                self.events.add(FieldbusEvent(self._t0 + cycle * self._cycle_time, cycle, "cn", 0, "sync_counter",
                                              "resynchronised", align, self._align, -1,
                                              f"the controller's SoC counter re-synchronised after "
                                              f"{cycle - self._last_taken - 1} cycles without its group "
                                              f"(mapping {self._align} -> {align})"))
            self._align = align
        late = stale + sum(len(g) for i, g in enumerate(groups) if i != chosen)
        if late:
            self.frames_late += late
            self.events.add(FieldbusEvent(self._t0 + cycle * self._cycle_time, cycle, "cn", 0, "late_frames",
                                          "dropped", late, self.frames_late, -1,
                                          f"{late} frame(s) from the controller missed their cycle's window"))
        if chosen is None:
            return []
        self._last_taken = cycle
        times = self._times
        # the nodes take the SoC as this cell cycle's (its counter is how the controller numbers
        # it); the CAN log keeps the counter byte the controller sent (what was on the wire)
        sync = FastMessage(times[0], SYNC_ID, bytearray([cycle % overflow + 1]))
        out = [sync]
        for msg in groups[chosen][1:]:
            base, node = msg.arbitration_id & ~0x7F, msg.arbitration_id & 0x7F
            on_time = base == RPDO1_BASE and 1 <= node <= n and times[node] is not None
            msg.timestamp = times[node] if on_time else times[0]
            out.append(msg)
        if self._kinds:
            # the scenario's injected SoC/PReq faults of THIS cell cycle act here, as the medium
            # between a controller that keeps no fault plan (any program on the bus) and the drives
            # (a controller numbering its cycles otherwise would misplace them)
            out = [m for m in (self._through_medium(m, self._kinds) for m in out) if m is not None]
            t = self._t0 + cycle * self._cycle_time
            for frame, node, kind in CycleFaults(cycle, self._kinds).describe(n):
                if frame != "pres":
                    self.events.add(FieldbusEvent(t, cycle, "medium", node, f"{frame}_{kind}", "injected",
                                                  -1, -1, -1, f"fault injection: {frame.upper()} {kind}"))
        if self._record is not None and (self._record_received or self._owns_recorder):
            wire = groups[chosen][0]
            logged = out
            if out and out[0] is sync and bytes(wire.data) != bytes(sync.data):
                logged = [FastMessage(sync.timestamp, SYNC_ID, bytearray(wire.data)), *out[1:]]
            self._record(logged)  # what the cell took as it was on the wire, with the cycle's timestamps
        return out

    def _late_group(self, cycle: int, group: list, expected: bytes | None, overflow: int) -> bool:
        """True when ``group`` (the newest, not this cycle's) carries the counter of one of the last
        :attr:`LATE_GROUP_CYCLES` cycles under the current mapping and has not done so, equally far
        behind, in :attr:`RESYNC_STREAK` cycles in a row: a late group, dropped, not a restart."""
        if expected is None or not group[0].data:
            return False
        behind = (expected[0] - group[0].data[0]) % overflow
        if not 0 < behind <= self.LATE_GROUP_CYCLES:
            return False
        streak = self._behind_streak + 1 if (behind == self._behind_last and cycle == self._behind_cycle + 1) else 1
        self._behind_streak, self._behind_last, self._behind_cycle = streak, behind, cycle
        return streak < self.RESYNC_STREAK

    def _note_cadence(self, cycle: int, groups: list, time_s: float) -> None:
        """Judge the controller's SoC counter against this cell's cycles (:class:`ControllerCadence`)."""
        cadence = self.cadence
        for group in groups:
            if not group[0].data:
                continue
            found = cadence.note(cycle, group[0].data[0], time_s)
            if found is not None:
                ratio, estimate = found
                self.events.add(FieldbusEvent(
                    self._t0 + cycle * self._cycle_time, cycle, "cn", 0, "cycle_time_mismatch", "error", -1,
                    cadence.mismatched_blocks, -1,
                    f"cycle-time mismatch: the controller's SoC counter advances {ratio:.3g} per cell cycle, "
                    f"its cycle is about {estimate * 1e3:.4g} ms, the cell's {self._cycle_time * 1e3:.4g} ms "
                    f"(hil_endpoint.json cycle_time_s); its frames miss their cycles"))

    def run_cycle(self, cycle: int, actuals: DriveActuals) -> AppliedSetpoints:
        """SoC of ``cycle``: latch ``actuals``, apply the due set-points, receive the
        PReqs, answer with the PRes frames, judge the cycle, send EMCYs of tripped
        nodes. Returns what the drives apply on [t_k, t_k+1)."""
        self._begin(cycle)
        cn = self.nodes
        applied = cn.start_cycle(cycle, actuals)
        expected: dict[int, float] = {}
        if not self.synchronous:
            times, kinds, n = self._times, self._kinds, self.config.nodes
            if kinds.get(0) != "loss":
                expected[SYNC_ID] = times[0]
            for i in range(n):
                if kinds.get(i + 1) != "loss":
                    expected[RPDO1_BASE + i + 1] = times[i + 1] + self._delay(i + 1)
        received = self._receive(expected)
        if received:
            cn.receive_all(received)
        self._transmit(cn.responses(self._times))
        cn.end_cycle(cycle)
        self._end_of_cycle(cycle)
        return applied
