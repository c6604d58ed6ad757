"""The served cell on any python-can bus, driven by a CANopen master's SYNC (``cosim serve
--interface NAME --channel CH``; docs/how-to/can_master.md).

The cell opens ``can.Bus(interface=NAME, channel=CH, **options)`` - ``virtual``,
``udp_multicast``, ``socketcan``, a vendor adapter's interface: python-can's own, nothing
special-cased - and the six drives are CANopen devices on it (:class:`fieldbus.canopen_drives.
CanopenDrives`: NMT, SDO, heartbeat, EMCY through :class:`fieldbus.canopen_node.CanopenNode`,
PDOs as the master mapped them). The master's cycle is the cell's:

* :class:`SyncLink`, the bus-cycle task of cycle k, waits for the master's next SYNC (COB-ID
  0x080), answering every other frame as it comes (SDO, NMT, RPDOs into the receive buffers,
  heartbeats when due). At the SYNC the drives' actual values at ``t_k`` are latched, the RPDOs
  received since the previous SYNC take effect, the TPDOs go out, and the master steps the
  FMUs one cycle (``[fieldbus] cycle_time_us``) to ``t_k+1``. Simulated time is SYNC count x
  cycle time: the plant does not move between two SYNCs in wall time, however late the second
  one is.
* A SYNC later than ``cycle x (1 + SYNC_LATE_FRACTION)`` after the previous one counts as late,
  one later than two cycles as skipping ``round(interval / cycle) - 1`` cycles; an operational
  drive without an RPDO since the previous SYNC keeps its set-point (``rpdo_missing``), a
  second RPDO of the same number in one interval replaces the first (``rpdo_overwritten``).
  All of it is in the timing report (summary.json ``hil.<run>``).
* Before the first SYNC (the master's commissioning: SDO, NMT, PDO mapping) simulated time
  stands at 0. The run ends at the scenario's stop time, or ``sync_timeout_s`` after the last
  SYNC once the master stopped sending them (its end of the session), or when no SYNC came
  within ``wait_for_controller_s`` (if given).
"""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import can
import numpy as np

from cosim.cell.description import CellDescription
from cosim.cell.wiring import N_JOINTS, joint_scaling
from cosim.execution.cell_side import percentiles_us
from cosim.execution.serve_settings import ENDPOINT_FILE, ServeSettings
from cosim.master import EndSimulation, Master, MemorySink, SimulationError
from fieldbus.canopen_drives import SYNC_ID, CanopenDrives, FreeMappingNode
from fieldbus.sdo import UNKNOWN_OBJECT_ABORTS

#: a SYNC more than this fraction of the cycle after its due time (previous SYNC + cycle) is late
SYNC_LATE_FRACTION = 0.5
#: the longest the cell blocks in one receive while it waits for a SYNC, s (heartbeats and
#: time-outs are checked at least this often)
POLL_S = 0.002
#: CiA 301 abort codes counted as bad input in the served summary (with fieldbus.sdo.UNKNOWN_OBJECT_ABORTS)
MALFORMED_ABORTS = (0x05040001, 0x06070010, 0x05030000)


class BusOpenError(ValueError):
    """python-can could not open the interface / channel (names both and python-can's reason)."""


def open_can_bus(settings: ServeSettings) -> can.BusABC:
    """``can.Bus(interface=..., channel=..., bitrate=..., **options)`` or BusOpenError."""
    kwargs: dict[str, Any] = dict(settings.bus_kwargs or {})
    if settings.bitrate is not None:
        kwargs["bitrate"] = settings.bitrate
    import gc
    import logging

    log = logging.getLogger("can")
    level = log.level
    log.setLevel(logging.ERROR)  # a half-opened bus warns on collection that it was not shut down
    reason = ""
    try:
        return can.Bus(interface=settings.interface, channel=settings.channel, **kwargs)
    except Exception as exc:  # noqa: BLE001 - python-can raises many kinds (CanInterfaceNotImplementedError, OSError, ...)
        reason = " ".join(str(exc).split()) or type(exc).__name__
        cause = exc.__cause__
        if cause is not None and str(cause):
            reason += f" ({' '.join(str(cause).split())})"
        del exc, cause
    finally:
        gc.collect()
        log.setLevel(level)
    raise BusOpenError(f"--interface {settings.interface!r} --channel {settings.channel!r}: python-can cannot open "
                       f"it: {reason}; expected an interface python-can has installed "
                       f"(e.g. udp_multicast, virtual, socketcan, pcan) and a channel of it")


class SyncLink:
    """The served cell's bus-cycle task on a python-can bus (see the module docstring)."""

    def __init__(self, bus: can.BusABC, drives: CanopenDrives, period_s: float, cycles: int,
                 sync_timeout_s: float, first_sync_timeout_s: float | None) -> None:
        self.bus = bus
        self.drives = drives
        self.period_s = period_s
        self.sync_timeout_s = sync_timeout_s
        self.first_sync_timeout_s = first_sync_timeout_s
        self.cycle = 0
        self.sync_wall_ns = np.zeros(cycles + 1, dtype=np.int64)  # SYNC k's arrival (perf_counter ns)
        self.answer_ns = np.zeros(cycles + 1, dtype=np.int64)  # SYNC k arrival -> its TPDOs sent
        self.rpdo_fresh = np.zeros((cycles + 1, N_JOINTS), dtype=bool)
        self.frames_in = 0
        self.frames_out = 0
        self.send_errors = 0
        self.ended: str = "stop_time"
        self.cellbus = None
        self.actuals = None
        self.applied = None
        self._error = np.zeros(N_JOINTS, dtype=np.int64)
        self._t0 = time.monotonic()
        self.enabled_first: int | None = None
        self.enabled_last: int | None = None
        self.motion_first: int | None = None
        self.motion_last: int | None = None
        self._target = np.full(N_JOINTS, np.nan)
        self.emcy_sent = 0
        self.following_max = np.zeros(N_JOINTS)  # rad, while enabled: applied target - actual position

    # ---------------------------------------------------------------- set-up
    def setup(self, master: Master) -> None:
        from cosim.cell.link import CellBus

        self.cellbus = CellBus(master)
        self.actuals = self.cellbus.actuals
        self.applied = self.cellbus.applied
        self.cellbus.read()
        for i in range(N_JOINTS):  # SDO uploads before the first SYNC read the drives at t = 0
            self.drives.latch(i, self.actuals)
        self._error[:] = self.actuals.error_code
        self._send(self.drives.boot(0.0))

    def _send(self, frames: list) -> None:
        for msg in frames:
            try:
                self.bus.send(msg)
                self.frames_out += 1
            except can.CanError:
                self.send_errors += 1

    # ---------------------------------------------------------------- the cycle
    def _wait_for_sync(self, t: float) -> can.Message:
        bus, drives = self.bus, self.drives
        last = self.sync_wall_ns[self.cycle - 1] if self.cycle else None
        start = time.perf_counter_ns()
        while True:
            msg = bus.recv(POLL_S)
            now = time.perf_counter_ns()
            wall = time.monotonic() - self._t0
            if msg is not None:
                self.frames_in += 1
                if msg.arbitration_id == SYNC_ID and not msg.is_error_frame and not msg.is_remote_frame \
                        and len(msg.data) <= 1:
                    return msg
                self._send(drives.receive(msg, t))
            self._send(drives.tick(wall))
            if last is not None:
                if now - last > self.sync_timeout_s * 1e9:
                    self.ended = "sync_timeout"
                    raise EndSimulation()
            elif self.first_sync_timeout_s is not None and now - start > self.first_sync_timeout_s * 1e9:
                self.ended = "no_sync"
                raise EndSimulation()

    def __call__(self, t: float) -> None:
        k = self.cycle
        msg = self._wait_for_sync(t)
        arrived = time.perf_counter_ns()
        n = self.sync_wall_ns.size
        self.sync_wall_ns[min(k, n - 1)] = arrived
        self.cellbus.read()
        actuals, applied = self.actuals, self.applied
        if self.enabled_first is not None:  # the drives' following error: the target applied since t_k-1 - q(t_k)
            err = np.abs(applied.position - actuals.position)
            np.maximum(self.following_max, np.where((actuals.statusword & 0x6F) == 0x27, err, 0.0),
                       out=self.following_max)
        tpdos = self.drives.sync(msg, actuals, applied, t)
        self._send(tpdos)
        self.answer_ns[min(k, n - 1)] = time.perf_counter_ns() - arrived
        self.rpdo_fresh[min(k, n - 1)] = applied.fresh
        self._emcy(t)
        if ((actuals.statusword & 0x6F) == 0x27).all():  # CiA 402 Operation enabled, every drive
            if self.enabled_first is None:
                self.enabled_first = k
            self.enabled_last = k
        if not np.array_equal(applied.position, self._target):
            if self.enabled_first is not None and k > self.enabled_first:
                if self.motion_first is None:
                    self.motion_first = k
                self.motion_last = k
            self._target[:] = applied.position
        self.cycle = k + 1

    def _emcy(self, t: float) -> None:
        """EMCY when a drive's error code (0x603F) changes: the new code, or 0x0000 when it clears."""
        codes = self.actuals.error_code
        if np.array_equal(codes, self._error):
            return
        for i in np.flatnonzero(codes != self._error).tolist():
            code = int(codes[i]) & 0xFFFF
            register = 0 if code == 0 else 0x01 | (0x02 if 0x2000 <= code < 0x3000 else 0) | \
                (0x20 if 0x8000 <= code < 0x9000 else 0)
            self._send([self.drives.drives[i].node.emcy(code, register, t)])
            self.emcy_sent += 1
        self._error[:] = codes

    # ---------------------------------------------------------------- figures
    def controller_run(self) -> dict[str, Any]:
        period = self.period_s

        def at(k):
            return None if k is None else k * period

        return {"enabled_at_s": at(self.enabled_first), "motion_start_s": at(self.motion_first),
                "motion_end_s": at(self.motion_last), "enabled_until_s": at(self.enabled_last),
                "enabled_at_end": self.enabled_last is not None and self.enabled_last == self.cycle - 1}

    def timing_report(self, settings: ServeSettings) -> dict[str, Any]:
        cycles = min(self.cycle, self.sync_wall_ns.size)
        period_ns = self.period_s * 1e9
        arrivals = self.sync_wall_ns[:cycles].astype(float)
        intervals = np.diff(arrivals)
        lateness = np.maximum(intervals - period_ns, 0.0)
        late = intervals > period_ns * (1.0 + SYNC_LATE_FRACTION)
        skipped = np.maximum(np.rint(intervals / period_ns) - 1.0, 0.0)
        fresh = self.rpdo_fresh[:cycles]
        totals = self.drives.totals()
        aborts = {f"0x{int(str(k), 0):08X}": int(v) for k, v in (totals.get("sdo_aborts") or {}).items()}

        def abort_count(codes) -> int:
            return sum(int(v) for k, v in aborts.items() if int(str(k), 0) in codes)

        return {
            "interface": settings.interface,
            "channel": settings.channel,
            "cycle_time_s": self.period_s,
            "cycles": cycles,
            "ended_by": self.ended,
            "sync": {
                "received": self.drives.syncs,
                "interval_us": percentiles_us(intervals * 1e-3),
                "interval_mean_us": float(intervals.mean() * 1e-3) if intervals.size else None,
                "lateness_us": percentiles_us(lateness * 1e-3),
                "late": int(late.sum()),
                "late_fraction": float(late.mean()) if late.size else 0.0,
                "cycles_skipped": int(skipped.sum()),
                "counter_errors": self.drives.sync_counter_errors,
                "late_threshold_us": period_ns * (1.0 + SYNC_LATE_FRACTION) * 1e-3,
            },
            "tpdo_answer_us": percentiles_us(self.answer_ns[:cycles] * 1e-3),
            # |target position applied over the cycle before - position actual| at each SYNC, while
            # the drive was in Operation enabled (what the drive's position loop lags its set-point by)
            "following_error_max_rad": self.following_max.tolist(),
            "rpdo": {"cycles_fresh_per_node": {str(i + 1): int(v) for i, v in enumerate(fresh.sum(axis=0))},
                     "missing": int(totals.get("rpdo_missing", 0)), "overwritten": int(totals.get("rpdo_overwritten", 0)),
                     "short": int(totals.get("rpdo_short", 0)), "ignored_not_operational": int(totals.get("rpdo_ignored", 0)),
                     "taken": int(totals.get("rpdo_taken", 0)), "foreign": self.drives.rpdo_foreign},
            "bad_input": {"sdo_malformed": max(int(totals.get("malformed", 0)), abort_count(MALFORMED_ABORTS)),
                          "sdo_unknown_object": abort_count(UNKNOWN_OBJECT_ABORTS),
                          "nmt_to_missing_node": self.drives.nmt_to_missing_node,
                          "pdo_mapping_invalid": int(totals.get("pdo_mapping_invalid", 0))},
            "sdo_aborts": aborts,
            "nodes": self.drives.counters,
            "frames_in": self.frames_in,
            "frames_out": self.frames_out,
            "send_errors": self.send_errors,
            "emcy_sent": self.emcy_sent,
            "sync_late_fraction": SYNC_LATE_FRACTION,
        }


def endpoint_description(cell: CellDescription, settings: ServeSettings, ods: list) -> dict[str, Any]:
    """What a CANopen master needs besides the EDS (written as ``hil_endpoint.json``)."""
    return {"format": "rx130l-cosim hil endpoint 1", "interface": settings.interface, "channel": settings.channel,
            "bus_options": dict(settings.bus_kwargs or {}), "bitrate": settings.bitrate,
            "cycle_time_s": cell.fieldbus.cycle_time_s, "nodes": [od.node for od in ods],
            "q_start_rad": np.asarray(cell.controller.q_start, dtype=float).tolist(),
            "stop_time_s": cell.stop_time_s, "label": cell.label, "sync_cob_id": SYNC_ID,
            "sync_timeout_s": settings.sync_timeout_s,
            "counts_per_rad": joint_scaling().counts_per_rad.tolist(),
            "torque_units_per_nm": joint_scaling().units_per_newton_metre.tolist(),
            "device_description": "python -m cosim device-files OUT (servo_drive_node<N>.eds)"}


def run_can_served_cell(cell: CellDescription, ctx: Any, settings: ServeSettings, *, bus: can.BusABC | None = None,
                        on_ready: Any = None):
    """Serve ``cell`` on the python-can bus of ``settings`` (or ``bus``, already open) until its
    stop time, the master's SYNC time-out or an interrupt; returns the
    :class:`cosim.cell.run.CellRun` (``hil`` = the timing report)."""
    from cosim.cell.run import CellRun
    from cosim.execution.cell_master import build_cell_master, write_recording
    from cosim.execution.timing.pacer import no_cyclic_gc, realtime_scheduling
    from cosim.tracking.laser_tracker import LaserTracker
    from fmus.servo_drive.object_dictionary import drive_object_dictionary

    period, stop_time = cell.period_s, cell.stop_time_s
    cycles = int(round(stop_time / period)) + 1
    ods = [drive_object_dictionary(axis, cell.fieldbus) for axis in range(1, N_JOINTS + 1)]
    drives_box: list[CanopenDrives] = []

    def on_write(node_id: int):
        def write(entry, value) -> None:
            if drives_box:
                drives_box[0].mark_dirty(node_id, entry.index)
        return write

    nodes = [FreeMappingNode(od.node, od, on_write=on_write(od.node)) for od in ods]
    drives = CanopenDrives(nodes, ods, joint_scaling())
    drives_box.append(drives)
    own_bus = bus is None
    if bus is None:
        bus = open_can_bus(settings)
    laser = LaserTracker(cell.true_robot.kinematic_model(), cell.tracker)
    master = build_cell_master(cell)
    memory = MemorySink()
    link = SyncLink(bus, drives, period, cycles, settings.sync_timeout_s, settings.wait_for_controller_s)
    master.add_task(link, period, priority=0, name="served cell (CANopen, SYNC-driven)", setup=link.setup)
    master.add_task(laser, laser.config.period_s, priority=1, name="laser_tracker", setup=laser.setup)
    recorder = master.add_recorder(list(cell.signals), cell.record_period_s, memory, name="cell")
    description_path = Path(ctx.path(ENDPOINT_FILE))
    failure: SimulationError | None = None
    engine, granted = "", "normal"
    ctx.label = cell.label
    wall0, cpu0 = time.perf_counter(), time.process_time()
    report: dict[str, Any] = {}
    try:
        with master:
            try:
                master.initialize(stop_time)
                engine = master.engine.name
                tmp = description_path.with_suffix(".json.tmp")
                tmp.write_text(json.dumps(endpoint_description(cell, settings, ods), indent=1))
                tmp.replace(description_path)
                if on_ready is not None:
                    on_ready()
                with realtime_scheduling(settings.scheduling, 10, settings.cpu) as granted, no_cyclic_gc():
                    ctx.execute(master, stop_time)
            except SimulationError as exc:
                failure = exc
    finally:
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        if own_bus:
            bus.shutdown()
        if memory.columns:
            write_recording(memory, ctx.csv_sink(cell.record_file))
        report = link.timing_report(settings)
        report["settings"] = settings.as_dict()
        report["endpoint_file"] = ENDPOINT_FILE
        hil = dict(ctx.summary.data.get("hil") or {})
        hil[cell.label] = report
        ctx.summary.update(hil=hil)
    summary = {"cycles_run": link.cycle, "frames_sent": link.frames_out, "frames_dropped": link.send_errors,
               "frames_recorded": 0, "log_path": None, "dead_time_cycles": 1,
               "node_fault": [False] * N_JOINTS, "comm_fault": [False] * N_JOINTS,
               "scaling_saturations": drives.scaling.saturations(), "event_tally": {}, "faults": [],
               "canopen": {"interface": settings.interface, "channel": settings.channel,
                           "nodes": drives.counters}}
    run = CellRun(cell.label, ctx.path(cell.record_file), recorder.rows_written, master.time, summary, wall, engine,
                  memory, failure, cpu, pacer=None, scheduling=granted)
    run.hil = report
    run.external_controller = link.controller_run()
    return run
