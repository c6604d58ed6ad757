"""The served cell: plant + drives + controlled nodes + tracker + recorder, paced at the bus
cycle, answering whatever controller is on the bus (the ``serve`` mode of
:func:`cosim.execution.run_cell`).

Per bus cycle k, :class:`CellSideLink` (master task, priority 0): wait for the cycle's wall
deadline ``W_k`` (:class:`cosim.execution.timing.pacer.Pacer`: sleep, then spin), latch the drives'
actual values at ``t_k``, run the controlled nodes' cycle with a window that closes at
``W_k + window`` (:meth:`fieldbus.DriveEndpoint.run_cycle_paced`: the controller's SoC +
PReqs of cycle k if they came in time, else a lost cycle for the threshold counters; the
PRes frames go out), and write what the drives apply from ``t_k`` to the ``bus.*``
variables. The master then steps the FMUs to ``t_k+1``. The cell never waits for the
controller beyond the window.

Just before its first cycle the cell writes ``hil_endpoint.json`` into the results folder: the
addresses, the bus cycle, the nodes, the CiA 402 scaling of each node and the start pose,
everything a controller in another program needs (``examples/hil_external_controller.py``).
"""
from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from cosim.cell.description import CellDescription
from cosim.cell.wiring import N_JOINTS, joint_scaling
from cosim.execution.serve_settings import ENDPOINT_FILE, ServeSettings
from cosim.master import Master, MemorySink, SimulationError
from fieldbus import DriveActuals, DriveEndpoint, FieldbusConfig
from fieldbus.telegrams import RPDO1_BASE, RPDO1_MAX_BYTES, SYNC_ID, TPDO1_BASE, TPDO2_BASE


#: bytes of one recorded frame in the CAN-log hand-over (fieldbus/recorder.py record_struct(64)): the
#: served cell records frames of up to 64 data bytes, so an RPDO1 with a set-point look-ahead from any
#: controller is logged whole
RECORD_DATA_BYTES = RPDO1_MAX_BYTES
RECORD_BYTES = 12 + RECORD_DATA_BYTES
#: runs whose CAN-log records fit this (bytes; 256 MB = 168 s at 400 µs with six nodes) keep them
#: in memory until the end: no hand-over to the writer process inside the paced loop
DEFERRED_RECORDING_BYTES = 256 * 2**20
#: longer runs hand over every this many cycles (~12 kB each, well inside a pipe's buffer)
SERVED_FLUSH_CYCLES = 20
#: lost cycles listed one by one in the report (with every node's counter values); more are counted only
MAX_LOST_CYCLES_LISTED = 1000
#: overrun cycles listed one by one in the report (cycle, lateness µs); more are counted only
MAX_OVERRUNS_LISTED = 5000


def _now_s() -> float:
    return time.perf_counter_ns() * 1e-9


class CellSideLink:
    """The served cell's bus-cycle task (see module docstring)."""

    def __init__(self, endpoint: DriveEndpoint, pacer: Any, window_s: float, cycles: int) -> None:
        self.endpoint = endpoint
        self.pacer = pacer
        self.window_ns = int(round(window_s * 1e9))
        self.cycle = 0
        self.taken = np.zeros(cycles + 1, dtype=bool)  # the controller's group came in time
        # every node's communication fault latched at the start of the cycle (then a missing group is
        # not counted: cosim serve's loss judging, DriveEndpoint.run_cycle_paced)
        self.all_faulted = np.zeros(cycles + 1, dtype=bool)
        self.held = np.zeros(N_JOINTS, dtype=np.int64)  # cycles a drive held / extrapolated its set-point
        self.actuals = DriveActuals.zeros(N_JOINTS)
        self.bus = None
        # per cycle, wall and CPU (this thread) time of the work after the bus exchange up to the
        # next cycle's wait (FMU steps, tracker, recorder): tells a stall of the process (wall
        # without CPU: it was not running) from its own slow work (CPU)
        self.after_wall_ns = np.zeros(cycles + 1, dtype=np.int64)
        self.after_cpu_ns = np.zeros(cycles + 1, dtype=np.int64)
        self._after = (0, 0)
        # what the external controller did, seen from the drives: the cycles in which all drives
        # reported Operation enabled (first, last) and in which an applied target position changed
        # after the first of those (first, last)
        self.enabled_first: int | None = None
        self.enabled_last: int | None = None
        self.motion_first: int | None = None
        self.motion_last: int | None = None
        self._target = np.full(N_JOINTS, np.nan)

    def setup(self, master: Master) -> None:
        from cosim.cell.link import CellBus

        self.bus = CellBus(master)
        self.actuals = self.bus.actuals
        self.endpoint.nodes.bind_applied(self.bus.applied)

    def __call__(self, t: float) -> None:
        k = self.cycle
        if k:
            i = min(k - 1, self.after_wall_ns.size - 1)
            self.after_wall_ns[i] = time.perf_counter_ns() - self._after[0]
            self.after_cpu_ns[i] = time.thread_time_ns() - self._after[1]
        pacer = self.pacer
        pacer.wait(k)
        deadline = (pacer.deadline_ns(k) + self.window_ns) * 1e-9
        self.bus.read()
        endpoint = self.endpoint
        if endpoint.nodes._any_fault and all(endpoint.nodes.comm_fault):
            self.all_faulted[min(k, self.all_faulted.size - 1)] = True
        applied = endpoint.run_cycle_paced(k, self.actuals, deadline, clock=_now_s)
        if endpoint._last_taken == k:
            self.taken[min(k, self.taken.size - 1)] = True
        if ((self.actuals.statusword & 0x6F) == 0x27).all():  # CiA 402 Operation enabled, every drive
            if self.enabled_first is None:
                self.enabled_first = k
            self.enabled_last = k
        if not np.array_equal(applied.position, self._target):
            if self.enabled_first is not None and k > self.enabled_first:
                if self.motion_first is None:
                    self.motion_first = k
                self.motion_last = k
            self._target[:] = applied.position
        fresh = applied.fresh
        if not fresh.all():
            self.held += ~fresh
            covered = endpoint.nodes.covered_now  # applied exactly from the set-point look-ahead: not held
            if covered:
                self.held[covered] -= 1
        self.cycle = k + 1
        self._after = (time.perf_counter_ns(), time.thread_time_ns())

    def controller_run(self, period_s: float) -> dict[str, Any]:
        """What the external controller did as the drives saw it (times s = cycle x period; None:
        never): ``enabled_at_s`` (all drives in Operation enabled), ``motion_start_s`` /
        ``motion_end_s`` (the first / last cycle an applied target position changed after that),
        ``enabled_until_s`` (the last cycle all drives were enabled) and ``enabled_at_end``."""
        def at(k):
            return None if k is None else k * period_s

        return {"enabled_at_s": at(self.enabled_first), "motion_start_s": at(self.motion_first),
                "motion_end_s": at(self.motion_last), "enabled_until_s": at(self.enabled_last),
                "enabled_at_end": self.enabled_last is not None and self.enabled_last == self.cycle - 1}


def endpoint_description(cell: CellDescription, settings: ServeSettings, config: FieldbusConfig,
                         window_s: float) -> dict[str, Any]:
    """What a controller in another program needs to know (written as ``hil_endpoint.json``)."""
    scaling = joint_scaling()
    host, _, port = settings.channel.rpartition(":")
    controller_channel = settings.peer or f"{host}:{int(port) + 1}"
    return {
        "format": "rx130l-cosim hil endpoint 1",
        "interface": "udpcycle",
        "cell_channel": settings.channel,
        "controller_channel": controller_channel,
        "peer_fixed": settings.peer is not None,
        "cycle_time_s": config.cycle_time_s,
        "window_s": window_s,
        "dead_time_cycles": config.dead_time_cycles,
        "setpoint_lookahead": config.setpoint_lookahead,
        # the drives' set-point buffer (0x60C4 sub 1; 0: none): fill it through 64-byte RPDO1s whose
        # entries start where the TPDO2's byte 7 says the buffer ends (docs/reference/fieldbus.md, Telegrams)
        "setpoint_buffer": config.setpoint_buffer,
        "nodes": config.nodes,
        "sync_counter_overflow": config.scaling.sync_counter_overflow,
        "counts_per_rad": scaling.counts_per_rad.tolist(),
        "torque_units_per_nm": scaling.units_per_newton_metre.tolist(),
        "rated_torque_nm": scaling.rated_torque.tolist(),
        "q_start_rad": np.asarray(cell.controller.q_start, dtype=float).tolist(),
        "stop_time_s": cell.stop_time_s,
        "label": cell.label,
        "frames": {"soc": f"0x{SYNC_ID:03X} UINT8 counter 1..overflow",
                   "preq": f"0x{RPDO1_BASE:03X}+node, 8 bytes (CSP) or 20 bytes CAN FD (all modes), or 32/48/64 "
                           f"bytes with a set-point look-ahead (byte 9 = entries, 10 bytes each; with a set-point "
                           f"buffer 64 bytes, bytes 60-61 <H = entry skip): docs/reference/fieldbus.md, Telegrams",
                   "pres": f"0x{TPDO1_BASE:03X}+node <H statusword, <i position actual [counts], <h torque actual; "
                           f"0x{TPDO2_BASE:03X}+node (8 bytes with a set-point buffer: byte 7 = set-points held "
                           f"ahead): docs/reference/fieldbus.md, Telegrams"},
        "busy_poll_s": settings.busy_poll_s,
    }


def percentiles_us(values: np.ndarray, points=(50.0, 99.0, 99.9)) -> dict[str, float | None]:
    """``p50_us``/``p99_us``/``p99_9_us`` (those of ``points``) and ``max_us`` of ``values`` (µs); None when empty."""
    keys = {50.0: "p50_us", 99.0: "p99_us", 99.9: "p99_9_us"}
    if values.size == 0:
        return {**{keys[p]: None for p in points}, "max_us": None}
    out = {keys[p]: float(v) for p, v in zip(points, np.percentile(values, points))}
    out["max_us"] = float(values.max())
    return out


def longest_run(flags: np.ndarray) -> int:
    """The longest run of consecutive True in ``flags``."""
    longest = run = 0
    for flag in flags.tolist():
        run = run + 1 if flag else 0
        longest = max(longest, run)
    return longest


def runs_of(flags: np.ndarray) -> list[list[int]]:
    """[first, last] index ranges of the runs of True in ``flags``."""
    f = np.concatenate([[False], np.asarray(flags, dtype=bool), [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(f))
    return [[int(a), int(b) - 1] for a, b in zip(edges[::2], edges[1::2])]


#: a cycle's work after the bus exchange counts as a stall of the process when less than this
#: fraction of its wall time was CPU time of the cell's thread
STALL_CPU_FRACTION = 0.5


def overrun_causes(link: CellSideLink, pacer: Any) -> dict[str, Any]:
    """Why the cell started cycles late, the machine or the model: for each overrun cycle k,
    how late the OS woke the pacer from its sleep before W_k (wake-up time minus the requested
    time) and the work after the bus exchange of cycle k-1 (FMU steps, tracker, recorder) in
    wall and CPU time. ``stalled``: the whole process was held up - ``woken_late`` (asleep, it
    was woken more than half the cycle's lateness late) or ``descheduled`` (the work's wall
    time was mostly not CPU time of the cell); ``own_work``: the work was CPU time (the
    cell's own computation was too slow); ``other``: neither (the bus exchange, the wait)."""
    log = pacer.log
    n = log.count
    overrun = log.overrun[:n]
    over = log.cycles[:n][overrun]
    oversleep = log.oversleep_ns[:n][overrun]
    lateness = log.lateness_ns[:n][overrun]
    period = pacer.period_ns
    counts = {"stalled": 0, "own_work": 0, "other": 0}
    stalls = {"woken_late": 0, "descheduled": 0}
    examples = []
    for k, slept, late in zip(over.tolist(), oversleep.tolist(), lateness.tolist()):
        wall = cpu = -1
        if 1 <= k <= link.after_wall_ns.size:
            wall, cpu = int(link.after_wall_ns[k - 1]), int(link.after_cpu_ns[k - 1])
        if slept > 0 and 2 * slept >= late:
            kind, detail = "stalled", "woken_late"
        elif wall >= period // 2 and cpu < STALL_CPU_FRACTION * wall:
            kind, detail = "stalled", "descheduled"
        elif wall >= period // 2:
            kind, detail = "own_work", None
        else:
            kind, detail = "other", None
        counts[kind] += 1
        if detail is not None:
            stalls[detail] += 1
        if len(examples) < 50:
            examples.append({"cycle": k, "lateness_us": late * 1e-3, "woken_late_us": None if slept < 0 else slept * 1e-3,
                             "work_wall_us": None if wall < 0 else wall * 1e-3,
                             "work_cpu_us": None if cpu < 0 else cpu * 1e-3, "cause": detail or kind})
    counts["stalls"] = stalls  # type: ignore[assignment]
    slept_all = log.oversleep_ns[:n]
    counts["woken_late_us"] = percentiles_us(slept_all[slept_all >= 0] * 1e-3)  # type: ignore[assignment]
    n = min(link.cycle, link.after_wall_ns.size)
    return {**counts, "work_after_bus_us": percentiles_us(link.after_wall_ns[:max(n - 1, 0)] * 1e-3),
            "work_after_bus_cpu_us": percentiles_us(link.after_cpu_ns[:max(n - 1, 0)] * 1e-3),
            "examples": examples}


MAX_FAULT_REACTIONS_LISTED = 200
MAX_LOST_RUNS_LISTED = 200


def lost_cycle_runs(lost_at: dict[int, float]) -> dict[str, Any]:
    """Runs of consecutive lost cycles: count, longest, a histogram of their lengths and the runs
    (``first_cycle``, ``length``, ``time_s`` of the first), longest first, cut at
    MAX_LOST_RUNS_LISTED (``cut`` says so; ``count`` is the full number)."""
    runs: list[dict[str, Any]] = []
    for c in sorted(lost_at):
        if runs and c == runs[-1]["first_cycle"] + runs[-1]["length"]:
            runs[-1]["length"] += 1
        else:
            runs.append({"first_cycle": int(c), "length": 1, "time_s": float(lost_at[c])})
    lengths: dict[str, int] = {}
    for r in runs:
        lengths[str(r["length"])] = lengths.get(str(r["length"]), 0) + 1
    ordered = sorted(runs, key=lambda r: (-r["length"], r["first_cycle"]))
    return {"count": len(runs), "longest": ordered[0]["length"] if runs else 0,
            "length_histogram": dict(sorted(lengths.items(), key=lambda kv: int(kv[0]))),
            "runs": ordered[:MAX_LOST_RUNS_LISTED], "cut": len(runs) > MAX_LOST_RUNS_LISTED}


def timing_report(link: CellSideLink, endpoint: DriveEndpoint, pacer: Any) -> dict[str, Any]:
    """The served cell's side of the timing report (summary.json ``hil``)."""
    log = pacer.log
    lateness = log.lateness_us
    overrun = log.overrun[:log.count]
    cycles = link.cycle
    taken = link.taken[:cycles]
    first = int(np.argmax(taken)) if taken.any() else None
    lost_by_node = {str(i + 1): 0 for i in range(N_JOINTS)}
    faults = []
    losses: dict[int, dict[str, list]] = {}  # cycle -> counter value per node after its loss errors
    lost_at: dict[int, float] = {}  # every cycle with a loss error (time of its SoC, s)
    for e in endpoint.events.events:
        if e.side == "cn" and e.kind in ("loss_of_soc", "loss_of_preq") and e.event == "error":
            lost_at.setdefault(e.cycle, e.time_s)
            if e.kind == "loss_of_preq":
                lost_by_node[str(e.node)] += 1
            if 1 <= e.node <= N_JOINTS and (e.cycle in losses or len(losses) < MAX_LOST_CYCLES_LISTED):
                row = losses.setdefault(e.cycle, {"loss_of_soc": [None] * N_JOINTS,
                                                  "loss_of_preq": [None] * N_JOINTS})
                row[e.kind][e.node - 1] = e.counter
        elif e.event in ("fault_reaction", "fault_cleared") and e.side == "cn":
            faults.append({"cycle": e.cycle, "time_s": e.time_s, "node": e.node, "event": e.event, "kind": e.kind})
    stats = getattr(endpoint.bus, "stats", None)
    latency = np.asarray(getattr(endpoint.bus, "latency_ns", []), dtype=float) * 1e-3
    return {
        "cycles": cycles,
        "overruns": int(overrun.sum()),
        "overrun_fraction": float(overrun.mean()) if overrun.size else 0.0,
        "longest_overrun_run": longest_run(overrun),
        "lateness": {**percentiles_us(lateness),
                     "max_at_cycle": int(log.cycles[int(np.argmax(lateness))]) if lateness.size else None},
        "missed_ticks": int(log.missed_ticks),
        "overrun_causes": overrun_causes(link, pacer),
        # the cycles the cell itself started late (window opened late: a group that missed its
        # window may still be taken in such a cycle), with their lateness, first MAX_OVERRUNS_LISTED
        "overrun_cycles": [[int(c), float(x)] for c, x in zip(log.cycles[:log.count][overrun][:MAX_OVERRUNS_LISTED].tolist(),
                                                              lateness[overrun][:MAX_OVERRUNS_LISTED].tolist())],
        # [first, last] cycle ranges in which every node's communication fault was latched (first MAX_OVERRUNS_LISTED)
        "all_nodes_faulted_cycles": runs_of(link.all_faulted[:cycles])[:MAX_OVERRUNS_LISTED],
        "controller": {"first_cycle": first, "cycles_in_time": int(taken.sum()),
                       "cycles_missed_after_first": int((~taken[first:]).sum()) if first is not None else 0},
        "frames_lost_per_node": lost_by_node,
        "frames_late": endpoint.frames_late,
        "lost_cycles": [{"cycle": c, "counters": row} for c, row in sorted(losses.items())],
        "lost_cycles_total": len(lost_at),
        "lost_cycles_cut": len(lost_at) > len(losses),
        # runs of consecutive lost cycles (what the thresholds let through or reacted to), longest first
        "lost_cycle_runs": lost_cycle_runs(lost_at),
        "cycles_held_per_node": {str(i + 1): int(v) for i, v in enumerate(link.held)},
        "setpoint_lookahead": {"cycles_covered_per_node": {str(i + 1): int(v) for i, v in
                                                           enumerate(endpoint.nodes.cycles_covered)},
                               "cycles_covered": int(sum(endpoint.nodes.cycles_covered))},
        "fault_reactions": faults[:MAX_FAULT_REACTIONS_LISTED],
        "fault_reactions_total": len(faults),
        "fault_reactions_cut": len(faults) > MAX_FAULT_REACTIONS_LISTED,
        "cycle_time_mismatch": endpoint.cadence.report(),
        "preq_one_way_latency": percentiles_us(latency, (50.0, 99.0)),
        "transport": stats.as_dict() if stats is not None else {},
    }


def write_timing_figure(path: Path, link: CellSideLink, pacer: Any, title: str) -> Path:
    """Lateness per cycle, and when the controller's frames were missed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    log = pacer.log
    n = log.count
    t = np.arange(n) * pacer.period_ns * 1e-9
    fig, (a, b) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    lateness = np.maximum(log.lateness_us, 1e-3)
    a.semilogy(t, lateness, ".", ms=1.5, color="tab:blue", label="lateness")
    over = log.overrun[:n]
    if over.any():
        a.semilogy(t[over], lateness[over], "x", ms=4, color="tab:red", label=f"overrun ({int(over.sum())})")
    a.axhline(pacer.tolerance_ns * 1e-3, color="grey", lw=0.8, ls="--", label="tolerance")
    a.set_ylabel("cycle start lateness [µs]")
    a.legend(loc="upper right", fontsize=8)
    a.set_title(title, fontsize=9)
    cycles = min(link.cycle, n)
    missed = ~link.taken[:cycles]
    b.step(t[:cycles], np.cumsum(missed), where="post", color="tab:orange", label="cycles without the controller's frames")
    b.set_ylabel("cumulative cycles")
    b.set_xlabel("wall time since the first cycle [s]")
    b.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def run_served_cell(cell: CellDescription, ctx: Any, settings: ServeSettings, *, pacer: Any = None,
                    on_ready: Any = None, start_on_first_frame_s: float | None = None):
    """Serve ``cell`` until its stop time (wall = simulated time, paced) or an interrupt;
    returns the :class:`cosim.cell.run.CellRun` (``pacer`` set, ``hil`` = the report).

    ``on_ready()`` is called when the bus is open and the FMUs are initialised;
    ``start_on_first_frame_s``: then wait up to this many wall seconds for the controller's
    first datagram and make it cycle 0 (a split run, whose controller starts with the cell),
    instead of starting at once (``cosim serve``)."""
    from cosim.cell.run import CellRun
    from cosim.execution.cell_master import build_cell_master, write_recording
    from cosim.tracking.laser_tracker import LaserTracker
    from cosim.execution.timing.pacer import Pacer, locked_memory, no_cyclic_gc, realtime_scheduling
    from cosim.execution.timing.schedule import precompute_schedules

    base = cell.fieldbus
    options = {**dict(base.bus.options), **settings.bus_options()}
    bus = dataclasses.replace(base.bus, interface="udpcycle", channel=settings.channel, options=options)
    period, stop_time = cell.period_s, cell.stop_time_s
    recording = base.recording
    # The CAN log: a hand-over to the writer process blocks the cycle whenever the pipe is full,
    # i.e. whenever that (normal-priority) process did not get a core in time - on a loaded
    # machine a lost cycle every 0.1-0.2 s, measured. So the records of a run that fits
    # DEFERRED_RECORDING_BYTES stay in memory until the run ends; a longer one hands over
    # small batches (one of 250 cycles, ~150 kB, never fits the pipe).
    frames_per_cycle = 3 * base.nodes + 1
    if stop_time / period * frames_per_cycle * RECORD_BYTES <= DEFERRED_RECORDING_BYTES:
        from cosim.execution.timing.network import DEFERRED_FLUSH_CYCLES

        recording = dataclasses.replace(recording, flush_every_cycles=DEFERRED_FLUSH_CYCLES)
    elif recording.background and recording.flush_every_cycles > SERVED_FLUSH_CYCLES:
        recording = dataclasses.replace(recording, flush_every_cycles=SERVED_FLUSH_CYCLES)
    config = dataclasses.replace(base, bus=bus, recording=recording)
    window_s = settings.window_fraction * period
    cycles = int(round(stop_time / period)) + 1
    laser = LaserTracker(cell.true_robot.kinematic_model(), cell.tracker)
    master = build_cell_master(cell)
    memory = MemorySink()
    endpoint = DriveEndpoint(config, joint_scaling(), log_path=cell.can_log, record_data_bytes=RECORD_DATA_BYTES)
    # the frame timestamps of the whole run now: the schedule draws its jitter 1024 cycles at a
    # time, 0.4-10 ms per block on the loaded 2-core development VM (0.41 ms median, 34 ms worst
    # over 39 blocks at load average 15) - a lost cycle every 0.4 s inside the loop
    precompute_schedules((endpoint,), cycles + 1, False, compact=True)
    description = endpoint_description(cell, settings, config, window_s)
    description_path = Path(ctx.path(ENDPOINT_FILE))
    if pacer is None:
        pacer = Pacer(period, settings.spin_s, period - window_s, capacity=cycles + 16)
    pacer.thresholds = {"window": window_s, "whole_cycle": period}
    if endpoint.recorder is not None and getattr(endpoint.recorder, "background", False):
        endpoint.recorder.wait_ready()  # a writer still starting would stall the first hand-over
    link = CellSideLink(endpoint, pacer, window_s, cycles)
    master.add_task(link, period, priority=0, name="served cell (fieldbus)", setup=link.setup)
    master.add_task(laser, laser.config.period_s, priority=1, name="laser_tracker", setup=laser.setup)
    recorder = master.add_recorder(list(cell.signals), cell.record_period_s, memory, name="cell")
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
                # ready: the endpoint description appears just before the first cycle
                tmp = description_path.with_suffix(".json.tmp")
                tmp.write_text(json.dumps(description, indent=1))
                tmp.replace(description_path)
                if on_ready is not None:
                    on_ready()
                if start_on_first_frame_s is not None:
                    import select

                    select.select([endpoint.bus.fileno()], [], [], start_on_first_frame_s)
                with realtime_scheduling(settings.scheduling, 10, settings.cpu) as granted, no_cyclic_gc(), \
                        locked_memory(settings.lock_memory) as memory_lock:
                    granted = f"{granted}, memory {memory_lock}"
                    ctx.execute(master, stop_time)
            except SimulationError as exc:
                failure = exc
    finally:
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        endpoint.close()
        if memory.columns:
            write_recording(memory, ctx.csv_sink(cell.record_file))
        if link.cycle:
            report = timing_report(link, endpoint, pacer)
            report["settings"] = settings.as_dict()
            report["endpoint_file"] = ENDPOINT_FILE
            report["figure"] = write_timing_figure(
                Path(ctx.path(f"hil_{cell.label}.png")), link, pacer,
                f"{cell.label}: served cell, {link.cycle} cycles, {report['overruns']} overruns, "
                f"{sum(report['frames_lost_per_node'].values())} lost PReqs").name
            hil = dict(ctx.summary.data.get("hil") or {})
            hil[cell.label] = report
            ctx.summary.update(hil=hil)
    summary = endpoint.summary() if hasattr(endpoint, "summary") else _endpoint_summary(endpoint)
    run = CellRun(cell.label, ctx.path(cell.record_file), recorder.rows_written, master.time, summary, wall, engine,
                  memory, failure, cpu, pacer=pacer, scheduling=granted)
    run.hil = report
    run.external_controller = link.controller_run(period)
    run.preq_latency_us = [x * 1e-3 for x in getattr(endpoint.bus, "latency_ns", ())]
    return run


def _endpoint_summary(endpoint: DriveEndpoint) -> dict[str, Any]:
    from fieldbus.network import network_summary

    return network_summary(endpoint.config, endpoint.events, None, endpoint, endpoint.recorder, endpoint._cycle + 1)
