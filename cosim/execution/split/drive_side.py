"""The drive process of a split run: plant + six drive FMUs, the POWERLINK controlled
nodes, the laser tracker and the recorder, driven by the controller process's frames.

Started by :func:`cosim.execution.split.controller_side.run_split_cell` with :func:`drive_side_main` as the
target of a ``spawn`` process. Its controller-cycle task (:class:`DriveLink`) does, at
cycle k (time t_k): read the drives' actual values at t_k, wait for the cycle marker of
k through the pipe (:mod:`cosim.execution.split.protocol`), run the controlled nodes' cycle k
(``fieldbus.DriveEndpoint.run_cycle``: SoC, PReqs in, PRes out) and write what the
drives apply from t_k to the ``bus.*`` master variables - the same values the
one-process cell's :class:`~cosim.cell.link.FieldbusLink` writes. The master then
steps the FMUs to t_k+1.

Rows are appended to a raw float64 file as the recorder hands them over, so what was
recorded survives a killed process; the controller side turns it into the CSV.
"""
from __future__ import annotations

import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from cosim.cell import wiring
from cosim.cell.link import CellBus
from cosim.tracking.laser_tracker import LaserTracker, TrackerConfig
from cosim.master import EndSimulation, Master, SimulationError
from cosim.execution.timing.pacer import no_cyclic_gc, realtime_scheduling
from cosim.execution.timing.policy import OverrunFaultPlan
from cosim.results.timeseries import FileSink
from cosim.execution.split.protocol import END, LOST, pres_expected, unpack_marker_offer, use_directional_bus
from fieldbus import DriveActuals, DriveEndpoint, FieldbusConfig
from fieldbus.asynchronous import AsyncNodes


@dataclass
class DriveSideSpec:
    """Everything the drive process needs (pickled into it).

    cell_doc: the scenario document with the cell's FMU start values filled in.
    signals, record_period_s: what the recorder samples, and how often (s).
    tracker, true_model: the laser tracker's settings and the true robot's kinematic model.
    stop_time_s: end of the run, s. config: the drive side's fieldbus configuration.
    raw_path: file of recorded rows (float64, row-major). marker_timeout_s: wall seconds
    to wait for a cycle marker before giving up. scheduling: 'fifo'/'normal' (None =
    'normal') with fifo_priority. can_log: the drive side's own CAN log or None.
    ports: the (down, up) multicast ports (:func:`cosim.execution.split.protocol.use_directional_bus`).
    """

    cell_doc: dict[str, Any]
    signals: list[str]
    record_period_s: float
    tracker: TrackerConfig | None
    true_model: Any
    stop_time_s: float
    config: FieldbusConfig
    raw_path: str
    marker_timeout_s: float
    scheduling: str | None = None
    fifo_priority: int = 10
    can_log: str | None = None
    ports: tuple[int, int] = (0, 0)


class RawRowSink(FileSink):
    """Recorder sink appending rows to a raw float64 file (flushed per hand-over)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.columns: list[str] = []
        self.kinds: list[str] = []
        self._file = None

    def open(self, columns: Sequence[str], kinds: Sequence[str]) -> None:
        self.columns, self.kinds = list(columns), list(kinds)
        self._file = open(self.path, "wb")

    def write(self, block: np.ndarray) -> None:
        np.ascontiguousarray(block, dtype=np.float64).tofile(self._file)


def read_raw_rows(path: str | Path, columns: int) -> np.ndarray:
    """The complete rows of a RawRowSink file, shape (rows, columns)."""
    flat = np.fromfile(path, dtype=np.float64) if Path(path).exists() else np.zeros(0)
    rows = flat.size // columns
    return flat[:rows * columns].reshape(rows, columns)


class DriveLink:
    """The drive side's controller-cycle task (see module docstring)."""

    def __init__(self, endpoint: DriveEndpoint, plan: OverrunFaultPlan, conn, marker_timeout_s: float,
                 nodes: AsyncNodes | None = None) -> None:
        self.endpoint = endpoint
        self.nodes = nodes  # the nodes' half of the asynchronous slot (SDO, NMT)
        self._offer: tuple[int, bytes] | None = None
        self.plan = plan
        self.conn = conn
        self.marker_timeout_s = marker_timeout_s
        self.cycle = 0
        self.lost_cycles: list[int] = []
        self.ended_at: int | None = None
        self.actuals: DriveActuals | None = None

    def setup(self, master: Master) -> None:
        self.bus = CellBus(master)
        self.actuals = self.bus.actuals

    def _wait_marker(self, t: float) -> int:
        conn = self.conn
        if not conn.poll(self.marker_timeout_s):
            raise SimulationError("split drive side", t, f"no cycle marker for cycle {self.cycle} from the "
                                                         f"controller process within {self.marker_timeout_s} s")
        try:
            cycle, flags, self._offer = unpack_marker_offer(conn.recv_bytes())
        except EOFError:
            raise SimulationError("split drive side", t, "the controller process closed the pipe") from None
        if cycle != self.cycle:
            raise SimulationError("split drive side", t, f"cycle marker for cycle {cycle}, expected {self.cycle}")
        return flags

    def __call__(self, t: float) -> None:
        n = wiring.N_JOINTS
        self.bus.read()
        flags = self._wait_marker(t)
        if flags & END:
            self.ended_at = self.cycle
            raise EndSimulation()
        cycle = self.cycle
        if flags & LOST:
            self.plan.mark_lost(cycle)
            self.lost_cycles.append(cycle)
        applied = self.endpoint.run_cycle(cycle, self.actuals)
        nodes, offer = self.nodes, self._offer
        if nodes is not None and (offer is not None or nodes.busy):
            owed = offer is not None or nodes.owes_answer
            t0 = self.endpoint.config.start_time_s
            outcome = nodes.slot(cycle, t0 + cycle * self.endpoint.config.cycle_time_s, applied, self.actuals, offer,
                                 self.endpoint.nodes.last_emcy_cycle == cycle)
            if owed:  # the controller side's SDO client waits for this
                self.conn.send(("async", cycle, *(outcome or (None, None))))
        if not pres_expected(self.plan.for_cycle(cycle), n):
            self.conn.send(("ack", cycle))
        self.bus.write(applied)
        self.cycle = cycle + 1


def drive_side_main(spec: DriveSideSpec, conn) -> None:
    """Process target: build, report ``("ready", {...})``, run (cycle markers in, acks out),
    report ``("done", {...})`` (or ``("error", text)``) on the duplex pipe ``conn``."""
    import signal

    from cosim.execution.cell_master import build_cell_master
    from fieldbus.network import network_summary

    # Ctrl-C reaches the whole process group: the parent ends this side (END marker, or kill after
    # a grace period) once it has what it needs, so this process must not die first
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, signal.SIG_IGN)
    endpoint = None
    try:
        master = build_cell_master(spec.cell_doc)
        endpoint = DriveEndpoint(spec.config, wiring.joint_scaling(), log_path=spec.can_log)
        use_directional_bus(endpoint, "cn", spec.config.bus.channel, *spec.ports)
        plan = OverrunFaultPlan(endpoint.plan, spec.config.nodes)
        endpoint.plan = plan
        from cosim.cell.drive_objects import DriveParameterWriter, cell_object_dictionaries

        ods = cell_object_dictionaries(spec.config)
        writer = DriveParameterWriter(ods, lambda instance, name, value: master.fmus[instance].set_value(name, value))
        nodes = AsyncNodes(ods, spec.config.start_time_s, spec.config.reaction.abort_connection_option, writer,
                           wiring.joint_scaling(), endpoint.nodes.invalidate_applied)
        endpoint.nodes.on_emcy = nodes.note_emcy
        link = DriveLink(endpoint, plan, conn, spec.marker_timeout_s, nodes)
        laser = LaserTracker(spec.true_model, spec.tracker)
        period = spec.config.cycle_time_s
        master.add_task(link, period, priority=0, name="split drive side", setup=link.setup)
        master.add_task(laser, laser.config.period_s, priority=1, name="laser_tracker", setup=laser.setup)
        sink = RawRowSink(spec.raw_path)
        recorder = master.add_recorder(spec.signals, spec.record_period_s, sink, name="cell", flush_interval_s=0.25)
        failure = None
        with master:
            master.initialize(spec.stop_time_s)
            conn.send(("ready", {"columns": sink.columns, "kinds": sink.kinds, "engine": master.engine.name}))
            wall0 = time.perf_counter()
            policy = spec.scheduling or "normal"  # SCHED_FIFO when asked, paced or not (see cosim.execution.split.controller_side)
            with realtime_scheduling(policy, spec.fifo_priority) as granted, no_cyclic_gc():
                try:
                    master.run(spec.stop_time_s)
                except SimulationError as exc:
                    failure = {"component": exc.component, "time": exc.time, "reason": exc.reason,
                               "messages": list(exc.messages)}
            wall = time.perf_counter() - wall0
            reached = master.time
        cycles = link.cycle
        summary = network_summary(endpoint.config, endpoint.events, None, endpoint, endpoint.recorder, cycles)
        summary["asynchronous_nodes"] = nodes.summary()
        endpoint.close()
        conn.send(("done", {"reached_s": reached, "rows": recorder.rows_written, "fieldbus": summary,
                            "failure": failure, "wall_s": wall, "lost_cycles": link.lost_cycles,
                            "ended_at_cycle": link.ended_at, "scheduling": granted,
                            "frames_missing": endpoint.frames_missing}))
    except BaseException:  # report anything to the controller side, then exit non-zero
        try:
            conn.send(("error", traceback.format_exc()))
        except (BrokenPipeError, OSError):
            pass
        if endpoint is not None:
            endpoint.close()
        raise
    finally:
        conn.close()
