"""``PowerlinkNetwork``: the managing node, the controlled nodes and the bus, run
cycle by cycle in simulated time in one process.

Per cycle k (SoC at t_k = start_time + k * cycle_time)::

    result = network.run_cycle(k, setpoints, actuals)

* ``setpoints``: what the controller computed after cycle k-1 (SI units); they go
  into the PReqs of cycle k and reach the drives at the SoC of k + dead_time_cycles.
* ``actuals``: the drives' values at t_k; the CNs latch them at the SoC and send them
  in this cycle's PRes frames.
* ``result.applied``: what each drive applies from t_k to t_{k+1} (quantised, with
  ``fresh``, ``comm_fault`` and ``fault_code``). ``result.observed``: what the
  controller sees in cycle k (the values latched at t_k, with ``fresh`` and
  ``node_fault``).

Frames go through a real python-can bus (``[fieldbus.bus] interface``: the lean
``simbus`` by default, ``virtual``, ``udp_multicast`` or hardware): the managing-node
endpoint sends SoC and PReqs, the drive endpoint answers with the PRes frames (and
EMCY frames of tripped nodes in the asynchronous slot), each through its own bus
connection. Frame timestamps follow the POWERLINK schedule (SoC, PReq1, PRes1, ...)
and every decision (late, lost) is taken on them. Injected faults act as the medium
between sender and bus. Every frame on the wire is recorded with ``can.Logger``.

The returned arrays are reused every cycle: copy what you keep.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fieldbus.asynchronous import AsyncClient, AsyncNodes, AsynchronousPhase, slot_offsets
from fieldbus.config import FieldbusConfig
from fieldbus.endpoints import (_NO_FAULTS, SYNCHRONOUS_INTERFACES, DriveEndpoint,
                                ManagingNodeEndpoint, default_channel)
from fieldbus.events import EventLog
from fieldbus.lifecycle import Closeable
from fieldbus.process_data import AppliedSetpoints, CycleResult, DriveActuals, ObservedActuals, Setpoints
from fieldbus.recorder import FrameRecorder
from fieldbus.scaling import JointScaling
from fieldbus.telegrams import rpdo1_length


class PowerlinkNetwork(Closeable):
    """POWERLINK-timed CiA 402 network of one MN and ``config.nodes`` CNs in one process.

    Args:
        config: a :class:`FieldbusConfig` or the ``[fieldbus]`` table as a dict.
        scaling: joint scaling (gear ratios, encoder counts, rated torques) with one
            joint per node.
        log_path: CAN log to write (.blf or .asc); None records nothing.
        canopen: the nodes' object dictionaries: the asynchronous phase answers SDO and NMT with
            them (``fieldbus.asynchronous``; the requests of ``config.asynchronous`` and of
            :meth:`submit`); None: no asynchronous phase besides the EMCYs.
        on_write: ``on_write(node, entry, value)`` for every value an SDO download changes.
    """

    def __init__(self, config: FieldbusConfig | Mapping[str, Any] | None, scaling: JointScaling,
                 log_path: str | Path | None = None, canopen: Sequence[Any] | None = None,
                 on_write: Callable[[int, Any, Any], None] | None = None) -> None:
        if not isinstance(config, FieldbusConfig):
            config = FieldbusConfig.from_dict(config)
        self.config = config
        self.scaling = scaling
        self.events = EventLog()
        self.channel = default_channel(config)
        self.recorder = (FrameRecorder(log_path, config.recording.flush_every_cycles, config.recording.background,
                                       64 if config.setpoint_buffer else rpdo1_length(config.setpoint_lookahead))
                         if log_path is not None else None)
        shared = {"channel": self.channel, "events": self.events, "recorder": self.recorder,
                  "record_received": False}
        try:
            self.mn_side = ManagingNodeEndpoint(config, scaling, **shared)
            try:
                self.drive_side = DriveEndpoint(config, scaling, **shared)
            except Exception:
                self.mn_side.close()
                raise
        except Exception:
            if self.recorder is not None:
                self.recorder.close()
            raise
        self.layout = self.mn_side.layout
        self.schedule = self.mn_side.schedule
        self.mn = self.mn_side.node
        self.cn = self.drive_side.nodes
        self.mn_bus = self.mn_side.bus
        self.cn_bus = self.drive_side.bus
        self._t0 = config.start_time_s
        self._cycle_time = config.cycle_time_s
        self._last_cycle: int | None = None
        #: run a nominal cycle through :meth:`_run_nominal` (False: always the endpoints' phases,
        #: the reference it is tested against)
        self.nominal_path = (config.bus.interface in SYNCHRONOUS_INTERFACES and config.setpoint_lookahead == 0
                             and self.mn._codec is not None and self.cn._codec is not None
                             and self.mn_side._send_many is not None and self.drive_side._send_many is not None
                             and self.mn_side._drain is not None and self.drive_side._drain is not None)
        # the endpoints' fault plans when neither injects anything (a wrapper installed later, e.g.
        # cosim.execution.timing's overrun plan, is asked every cycle)
        quiet = not (self.mn_side.plan.enabled or self.drive_side.plan.enabled)
        self._quiet_plans = (self.mn_side.plan, self.drive_side.plan) if quiet else (None, None)
        self._checked_integers: tuple = ()  # (controlword, modes) arrays whose dtypes were checked
        self.asynchronous: AsynchronousPhase | None = None
        self._async_next: float = math.inf  # the next cycle whose asynchronous slot has work
        if canopen is not None:
            client = AsyncClient(config.asynchronous, config.node_ids, slot_offsets(self.layout), self._t0,
                                 self._cycle_time, canopen)
            nodes = AsyncNodes(canopen, self._t0, config.reaction.abort_connection_option, on_write, scaling,
                               self.cn.invalidate_applied)
            self.asynchronous = AsynchronousPhase(client, nodes, self._t0, self._cycle_time)
            client.on_submit = self._wake
            self.cn.on_emcy = self.asynchronous.note_emcy
            self._async_next = self.asynchronous.next_cycle

    # ------------------------------------------------------------------ life cycle
    def _release(self) -> None:
        """Flush the recording and shut the buses down."""
        try:
            if self.recorder is not None:
                self.recorder.close()
        finally:
            self.mn_side.close()
            self.drive_side.close()

    # ------------------------------------------------------------------ cycle
    def run_cycle(self, cycle: int, setpoints: Setpoints, actuals: DriveActuals) -> CycleResult:
        """Run POWERLINK cycle ``cycle`` (consecutive calls: cycle, cycle + 1, ...)."""
        if self.nominal_path:
            result = self._run_nominal(cycle, setpoints, actuals)
            if result is not None:
                return result
        self.mn_side.send_setpoints(cycle, setpoints)
        applied = self.drive_side.run_cycle(cycle, actuals)
        observed = self.mn_side.collect_actuals(cycle)
        self._last_cycle = cycle
        if cycle >= self._async_next:
            self._asynchronous(cycle, applied, actuals)
        t = self._t0 + cycle * self._cycle_time
        if self.recorder is not None:
            self.recorder.end_cycle(cycle, t)
        return CycleResult(cycle, t, applied, observed)

    def _run_nominal(self, cycle: int, setpoints: Setpoints, actuals: DriveActuals) -> CycleResult | None:
        """The cycle of :meth:`run_cycle` with the endpoints' phases run inline, for a cycle
        without injected faults on a synchronous bus without set-point look-ahead: the same
        calls of the nodes (and their compiled codec) in the same order, the same frames on
        the same bus, the same recording; None (nothing changed) for any other cycle, which
        then runs through the endpoints. Tested frame by frame against them
        (tests/fieldbus/test_nominal_cycle.py)."""
        mn_side, cn_side = self.mn_side, self.drive_side
        if mn_side._cycle != cycle - 1 or cn_side._cycle != cycle - 1 or cycle < 0:
            return None  # not consecutive (the endpoints raise), or a first cycle other than 0
        mn_plan, cn_plan = mn_side.plan, cn_side.plan
        quiet = self._quiet_plans
        if (mn_plan is not quiet[0] or cn_plan is not quiet[1]) and (mn_plan.for_cycle(cycle) is not None
                                                                  or cn_plan.for_cycle(cycle) is not None):
            return None
        cw, modes = setpoints.controlword, setpoints.modes_of_operation
        checked = self._checked_integers
        if not checked or cw is not checked[0] or modes is not checked[1]:
            # the dtypes send_setpoints checks, once per pair of arrays (an ndarray keeps its dtype)
            if type(cw) is not np.ndarray or type(modes) is not np.ndarray or cw.dtype.kind not in "iu" \
                    or modes.dtype.kind not in "iu":
                return None
            self._checked_integers = (cw, modes)
        # managing node: SoC and PReqs (ManagingNodeEndpoint.send_setpoints)
        times = mn_side.schedule.timestamps(cycle)
        mn_side._cycle = cycle
        mn_side._times = times
        mn_side._kinds = _NO_FAULTS
        mn = self.mn
        mn.start_cycle(cycle)
        frames = mn.encode(cycle, times, setpoints)
        if frames is None:
            frames = mn_side._python_frames(cycle, times, setpoints)
        mn_side._send_many(frames)
        mn_side.frames_sent += len(frames)
        record = mn_side._record
        if record is not None:
            record(frames)
        # controlled nodes: SoC, PReqs in, PRes out (DriveEndpoint.run_cycle)
        cn_side._cycle = cycle
        cn_side._times = times = cn_side.schedule.timestamps(cycle)
        cn_side._kinds = _NO_FAULTS
        cn = self.cn
        applied = cn.start_cycle(cycle, actuals)
        received = cn_side._drain()
        if received:
            cn.receive_all(received)
        frames = cn.responses(times)
        cn_side._send_many(frames)
        cn_side.frames_sent += len(frames)
        record = cn_side._record
        if record is not None:
            record(frames)
        cn.end_cycle(cycle)
        if cn._emcy_due or cn_side._owns_recorder:
            cn_side._end_of_cycle(cycle)
        # managing node: PRes in (ManagingNodeEndpoint.collect_actuals)
        received = mn_side._drain()
        if received:
            mn.receive_all(received)
        observed = mn.end_cycle(cycle)
        if mn_side._owns_recorder:
            mn_side._flush_own_recording(cycle)
        self._last_cycle = cycle
        if cycle >= self._async_next:
            self._asynchronous(cycle, applied, actuals)
        t = self._t0 + cycle * self._cycle_time
        if self.recorder is not None:
            self.recorder.end_cycle(cycle, t)
        return CycleResult(cycle, t, applied, observed)

    def _asynchronous(self, cycle: int, applied: AppliedSetpoints, actuals: DriveActuals) -> None:
        """The asynchronous slot of ``cycle`` with SDO/NMT work (fieldbus.asynchronous)."""
        phase = self.asynchronous
        assert phase is not None
        frames = phase.run(cycle, applied, actuals, emcy_sent=self.cn.last_emcy_cycle == cycle)
        if frames and self.recorder is not None:
            self.recorder.add_many(frames)
        self._async_next = phase.next_cycle

    def _wake(self) -> None:
        self._async_next = 0  # a request was queued: the next slot runs

    def submit(self, request: Any) -> Any:
        """Queue an SDO/NMT request (:class:`fieldbus.asynchronous.AsyncRequest`) for the
        asynchronous slot of the next cycle that is free; returns its
        :class:`~fieldbus.asynchronous.AsyncResult` (filled in when answered)."""
        if self.asynchronous is None:
            raise RuntimeError("this network has no asynchronous phase (no object dictionaries given)")
        return self.asynchronous.submit(request)

    def async_port(self) -> Any:
        """The :class:`~fieldbus.asynchronous.AsyncPort` a controller gets (None without the slot)."""
        from fieldbus.asynchronous import AsyncPort

        return None if self.asynchronous is None else AsyncPort(self.asynchronous.client)

    def bind_applied(self, applied: AppliedSetpoints) -> None:
        """Have the drives' applied set-points written into ``applied``'s arrays (e.g. views
        of a co-simulation master's variables; see ``ControlledNodes.bind_applied``):
        ``run_cycle(...).applied`` is then that object."""
        self.cn.bind_applied(applied)

    # ------------------------------------------------------------------ reporting
    @property
    def applied(self) -> AppliedSetpoints:
        return self.cn.applied

    @property
    def observed(self) -> ObservedActuals:
        return self.mn.observed

    @property
    def frames_sent(self) -> int:
        return self.mn_side.frames_sent + self.drive_side.frames_sent

    @property
    def frames_dropped(self) -> int:
        return self.mn_side.frames_dropped + self.drive_side.frames_dropped

    @property
    def frames_missing(self) -> int:
        return self.mn_side.frames_missing + self.drive_side.frames_missing

    def summary(self) -> dict[str, Any]:
        """JSON-ready summary: configuration essentials, frame counts, counters, faults."""
        out = network_summary(self.config, self.events, self.mn_side, self.drive_side, self.recorder,
                              (self._last_cycle + 1) if self._last_cycle is not None else 0)
        if self.asynchronous is not None:
            out["asynchronous"] = self.asynchronous.summary()
        return out


def network_summary(config: FieldbusConfig, events: EventLog, mn_side: ManagingNodeEndpoint | None,
                    drive_side: DriveEndpoint | None, recorder: FrameRecorder | None, cycles: int) -> dict[str, Any]:
    """Summary of one side or both (what summary.json holds under 'fieldbus')."""
    sides = [s for s in (mn_side, drive_side) if s is not None]
    layout = sides[0].layout
    faults = [e.as_dict() for e in events.events
              if e.event in ("error", "threshold_reached", "fault_reaction", "fault_cleared",
                             "decode_error", "emcy_sent", "emcy_received", "injected")]
    counters = []
    if mn_side is not None:
        counters += mn_side.node.counters.snapshot()
    if drive_side is not None:
        counters += drive_side.nodes.counters.snapshot()
    return {
        "interface": config.bus.interface,
        "cycle_time_s": config.cycle_time_s,
        "dead_time_cycles": config.dead_time_cycles,
        "nodes": config.nodes,
        "cycles_run": cycles,
        "frames_sent": sum(s.frames_sent for s in sides),
        "frames_dropped": sum(s.frames_dropped for s in sides),
        "frames_missing": sum(s.frames_missing for s in sides),
        "frames_recorded": recorder.frames_written if recorder is not None else 0,
        "log_path": str(recorder.path) if recorder is not None else None,
        "decode_errors": {s.side: (s.node.decode_errors if s.side == "mn" else s.nodes.decode_errors)
                          for s in sides},
        "scaling_saturations": sides[0].scaling.saturations(),
        "nominal_isochronous_phase_s": layout.nominal_end_of_isochronous,
        "nominal_busy_time_s": layout.nominal_end_of_async,
        "node_fault": [bool(x) for x in mn_side.node.node_fault] if mn_side is not None else None,
        "comm_fault": [bool(x) for x in drive_side.nodes.comm_fault] if drive_side is not None else None,
        "counters": counters,
        "setpoint_lookahead": {
            "cycles": config.setpoint_lookahead,
            "cycles_covered_per_node": ({str(i + 1): int(v) for i, v in enumerate(drive_side.nodes.cycles_covered)}
                                        if drive_side is not None else None),
            # cycles whose set-point neither a PReq nor the buffer had (missing_setpoint applied)
            "cycles_without_setpoint_per_node": (
                {str(i + 1): int(v) for i, v in enumerate(drive_side.nodes.cycles_without_setpoint)}
                if drive_side is not None else None),
            "buffer": config.setpoint_buffer},
        "event_tally": events.tally(),
        "faults": faults,
    }
