"""``cosim run SCENARIO --split --realtime``: our own controller in this process, the served
cell (:func:`cosim.execution.cell_side.run_served_cell`) in another, both on the wall clock.

The cell side keeps the time, as real drives do, and never waits for the controller; this
process follows it (:meth:`fieldbus.ManagingNodeEndpoint.follow`): each batch of the cell's
PRes frames is one bus cycle, the controller steps on what it observed and its set-points
go out at once as the next cycle's SoC + PReqs, one ``udpcycle`` datagram per direction on
loopback. The cell starts its cycle 0 with the controller's first datagram, so both count
the same cycles and the run is comparable with the in-process one. A controller answer
that misses the cell's window is a lost cycle there (threshold counters); the controller
sees the skipped cycle as ``previous_output_late``.

The cell side writes its own results (time series, CAN log of the drive side, hil report)
into ``cell_side_<run>/`` of the results folder and sends its recording back, so the job
evaluates the run as any other; summary.json ``hil_split.<run>`` holds both sides' timing.
"""
from __future__ import annotations

import dataclasses
import multiprocessing
import os
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cosim.cell.description import CellDescription
from cosim.execution.cell_side import longest_run, percentiles_us
from cosim.execution.serve_settings import ServeSettings
from cosim.execution.split.protocol import free_udp_port

#: Wall seconds to wait for the cell process to come up (imports, FMU instantiation).
START_TIMEOUT_S = 180.0
#: Wall seconds without the cell's PRes after which the controller side gives up.
SILENCE_TIMEOUT_S = 5.0
#: The percentiles of the controller side's figures.
POINTS = (50.0, 99.0)


#: Seconds before each expected PRes (the last one's kernel arrival + one cycle) at which the split
#: controller stops sleeping and spins on its socket, as the served cell spins before its cycles
#: (150 µs). A sleeper is woken 40-160 µs late on these VMs, more under load (the kernel does not
#: preempt another task's kernel code for it: PREEMPT_NONE), a spinner reads the PRes at once.
#: Every µs spun is real-time CPU time: with 150 µs the paced loop used 65 % of its core at load 15
#: (``loop_cpu_fraction``; 100 µs: 62 %, the same wake-up p50/p99 as 250 µs), below the kernel's
#: real-time limit (95 % per CPU; above it every SCHED_FIFO task on that CPU is paused for the rest
#: of the second).
CONTROLLER_SPIN_S = 150e-6
#: Nanoseconds the controller keeps polling past its spin before it sleeps in ``select``: a PRes
#: later than that (a stalled cell) is waited for without a core.
SPIN_GRACE_NS = 250_000


def controller_spin_s() -> float:
    """The split controller's spin before each expected PRes, s: :data:`CONTROLLER_SPIN_S`, or
    ``COSIM_HIL_CONTROLLER_SPIN`` in µs (0: sleep in ``select`` until the PRes is there)."""
    override = os.environ.get("COSIM_HIL_CONTROLLER_SPIN")
    if override is not None and override.strip():
        try:
            value = float(override) * 1e-6
        except ValueError:
            raise ValueError(f"COSIM_HIL_CONTROLLER_SPIN={override!r}: expected microseconds >= 0") from None
        if not 0.0 <= value < 0.01:
            raise ValueError(f"COSIM_HIL_CONTROLLER_SPIN={override!r}: expected microseconds 0 .. 10000")
        return value
    return CONTROLLER_SPIN_S


class ControllerTimes:
    """The split controller's timing per answered cycle, preallocated for the run (ns; one
    row per PRes answered): the cell's cycle, the wait for the PRes, the controller port's
    step, encoding + sending the next cycle's frames, the step + send in thread CPU time,
    how long the PRes had waited in the socket (kernel arrival -> read; -1 unknown) and its
    kernel arrival time (ns since the epoch; 0 unknown)."""

    FIELDS = ("cycle", "wait", "step", "send", "cpu", "woke", "arrived")

    def __init__(self, capacity: int) -> None:
        self.data = np.zeros((max(int(capacity), 1), len(self.FIELDS)), dtype=np.int64)
        self._flat = memoryview(self.data).cast("B").cast("q")
        self.count = 0

    def add(self, cycle: int, wait: int, step: int, send: int, cpu: int, woke: int, arrived: int = 0) -> None:
        i = self.count
        if i >= self.data.shape[0]:
            return  # more PRes than cycles planned (the cell ran on): the figures cover the planned run
        flat, j = self._flat, 7 * i
        flat[j], flat[j + 1], flat[j + 2], flat[j + 3] = cycle, wait, step, send
        flat[j + 4], flat[j + 5], flat[j + 6] = cpu, woke, arrived
        self.count = i + 1

    def column(self, name: str) -> np.ndarray:
        return self.data[:self.count, self.FIELDS.index(name)]

    def reply_us(self) -> np.ndarray:
        """Per answered cycle whose PRes arrival is known: from that arrival to the answer
        sent (the PRes's wait in the socket + step + send), µs: the controller's own cycle."""
        woke = self.column("woke")
        known = woke >= 0
        return (woke[known] + self.column("step")[known] + self.column("send")[known]).astype(float) * 1e-3

    def report(self, period_s: float) -> dict:
        """The controller side's timing figures (µs percentiles, counts) for summary.json."""
        us = {name: self.column(name).astype(float) * 1e-3 for name in self.FIELDS[1:6]}
        compute = us["step"] + us["send"]
        woke = us["woke"][us["woke"] >= 0]
        cycles = self.column("cycle")
        reply = self.reply_us()
        late = reply > period_s * 1e6  # an answer later than one bus cycle after the PRes arrived
        out = {"overruns": int(late.sum()), "overrun_fraction": float(late.mean()) if late.size else 0.0,
               "longest_overrun_run": longest_run(late),
               "lateness": percentiles_us(reply),  # PRes arrival -> answer sent, p50/p99/p99.9/max
               "wait_for_pres": percentiles_us(us["wait"], POINTS),
               "compute": percentiles_us(compute, POINTS),
               "compute_cpu": percentiles_us(us["cpu"], POINTS),
               # compute split in two: the controller through its port, then the next cycle's
               # frames encoded and sent (one sendto to the cell)
               "compute_step": percentiles_us(us["step"], POINTS),
               "compute_send": percentiles_us(us["send"], POINTS),
               # computations longer than a cycle: mostly CPU (own work) or not (stalled)
               "compute_over_one_cycle": _compute_causes(compute, us["cpu"], period_s),
               # from the PRes datagram's kernel arrival to this process having read it: long
               # when the process was not running (a stall of the OS or the hypervisor)
               "wakeup_after_pres": percentiles_us(woke, POINTS),
               "stalls_over_one_cycle": int(np.count_nonzero(woke > period_s * 1e6))}
        if compute.size:
            out["compute"]["max_at_cycle"] = int(cycles[int(np.argmax(compute))])
        return out


def _compute_causes(wall_us: np.ndarray, cpu_us: np.ndarray, period_s: float) -> dict[str, int]:
    """Controller steps longer than a cycle: 'stalled' (less than half of it CPU time of this
    thread: the process was not running) or 'own_work'."""
    long = wall_us > period_s * 1e6
    stalled = long & (cpu_us < 0.5 * wall_us)
    return {"stalled": int(stalled.sum()), "own_work": int((long & ~stalled).sum())}


def _overrun_cycles(pacer: dict) -> set[int]:
    """The cell's cycles that started late (its pacer's overruns)."""
    cycles, overrun = np.asarray(pacer["cycles"]), np.asarray(pacer["overrun"], dtype=bool)
    return set(cycles[overrun].tolist()) if cycles.size else set()


#: Why a cycle was lost in a paced split run (summary ``hil_split.<run>.lost_cycle_causes``).
LOST_CAUSES = ("cell_late", "controller_stalled", "controller_compute", "transport")


def lost_cycle_causes(lost: list[dict], overrun_cycles: set[int], times: ControllerTimes,
                      period_s: float) -> dict:
    """Attribute each cycle the cell lost (``hil.lost_cycles``: its group of SoC + PReqs,
    the controller's answer to the PRes of the cycle before, missed its window) to one cause:

    * ``cell_late``: the cell started that cycle or the one before late (its pacer overran), or
      sent the PRes being answered late: its arrival here, against the run's median arrival
      relative to the cycle grid, took most of the time;
    * ``controller_stalled``: the controller was not running: the PRes waited in its socket
      (to being read and digested) longer than anything else, or a step took wall time that
      was not its CPU time, or it never answered that PRes (read it with a later one) after a
      short step;
    * ``controller_compute``: its own work: the step + send of the answer (for an unanswered
      PRes, the step before it), mostly CPU time, took most of the time;
    * ``transport``: none of these took over half a cycle: the datagram was late or lost
      on the way.
    Counts per cause and the first cycles of each (``examples``)."""
    counts = dict.fromkeys(LOST_CAUSES, 0)
    examples: dict[str, list[int]] = {k: [] for k in LOST_CAUSES}
    cycles = times.column("cycle")
    half_ns = 0.5 * period_s * 1e9
    step, send, cpu, woke, arrived = (times.column(n) for n in ("step", "send", "cpu", "woke", "arrived"))
    known = arrived > 0
    # when each PRes arrived relative to the cycle grid, against the run's median (ns)
    offset = arrived - cycles * int(round(period_s * 1e9))
    base = int(np.median(offset[known])) if known.any() else 0
    for entry in lost:
        k = int(entry["cycle"])
        answered = k - 1  # the group of cycle k answers the PRes of cycle k - 1
        if k in overrun_cycles or answered in overrun_cycles:
            cause = "cell_late"
        else:
            i = int(np.searchsorted(cycles, answered))
            if i < cycles.size and cycles[i] == answered:
                compute = int(step[i] + send[i])
                own = compute if cpu[i] >= 0.5 * compute else 0
                parts = {"cell_late": int(offset[i] - base) if known[i] else 0,
                         "controller_stalled": max(int(woke[i]), compute - own),
                         "controller_compute": own}
                worst = max(parts, key=parts.get)
                cause = worst if parts[worst] > half_ns else "transport"
            else:  # that PRes was never answered: the controller was busy or not running
                j = i - 1
                compute = int(step[j] + send[j]) if j >= 0 else 0
                cause = ("controller_compute" if compute > half_ns and cpu[j] >= 0.5 * compute
                         else "controller_stalled")
        counts[cause] += 1
        if len(examples[cause]) < 20:
            examples[cause].append(k)
    return {**counts, "examples": {k: v for k, v in examples.items() if v}}


def controller_faults(fieldbus: Any) -> Any:
    """The paced split controller's fault configuration: the scenario's with no bursts, no silent
    nodes and no random faults. The served cell applies them all on its cycle numbers (the
    SoC/PReq faults to the group it takes, :meth:`fieldbus.DriveEndpoint.run_cycle_paced`)."""
    return dataclasses.replace(fieldbus.faults, loss_probability=0.0, late_probability=0.0,
                               corrupt_probability=0.0, bursts=(), silent_nodes=())


def split_cpus(cpu: Any) -> tuple[str | None, str | None]:
    """(cell CPU, controller CPU) for a paced split run: with the realtime setting ``cpu = "auto"``
    and two or more usable CPUs, the cell on the highest-numbered one and the controller on
    the next lower, so neither waits for the other's core; otherwise no pinning.
    ``COSIM_HIL_CPUS=none`` turns the placement off, ``COSIM_HIL_CPUS=A,B`` chooses it."""
    import os

    override = os.environ.get("COSIM_HIL_CPUS")
    if override:
        if override == "none":
            return None, None
        a, _, b = override.partition(",")
        return a.strip() or None, b.strip() or None
    usable = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if cpu != "auto" or len(usable) < 2:
        return None, None
    return str(usable[-1]), str(usable[-2])


def picklable_cell(cell: CellDescription) -> CellDescription:
    """``cell`` with what the cell side needs only (read-only views and controller models dropped)."""
    import copy

    from cosim.execution.timing.network import deferred_recording

    info = dataclasses.replace(cell.controller, reference=None, kinematic_model=None, dynamics=None, parameters={})
    # the CAN log is buffered for the whole (bounded) run, as in the paced one-process run:
    # a writer process that falls behind on a loaded machine would stall the cycle
    return dataclasses.replace(cell, document=copy.deepcopy(dict(cell.document)), controller=info,
                               fieldbus=deferred_recording(cell.fieldbus))


@dataclass
class _Scenario:
    """What a RunContext needs of a scenario (the cell side's own results folder)."""

    name: str

    @property
    def job(self):
        return self

    @property
    def data(self) -> dict:
        return {}


def cell_side_main(cell: CellDescription, settings: ServeSettings, out_dir: str, conn) -> None:
    """Process target: serve ``cell`` into ``out_dir``; ``("ready", {})`` when it can take the
    controller's first datagram, then ``("done", {...})`` or ``("error", text)``."""
    from cosim.execution.cell_side import run_served_cell
    from cosim.scenario.context import RunContext

    try:
        ctx = RunContext(_Scenario(f"cell_side_{cell.label}"), out_dir, quiet=True)
        run = run_served_cell(cell, ctx, settings, on_ready=lambda: conn.send(("ready", {})),
                              start_on_first_frame_s=START_TIMEOUT_S)
        log = run.pacer.log
        failure = None if run.failure is None else {"component": run.failure.component, "time": run.failure.time,
                                                     "reason": run.failure.reason}
        ctx.summary.update(status="failed" if failure else "ok")
        ctx.summary.write()
        conn.send(("done", {"columns": run.recording.columns, "kinds": run.recording.kinds,
                            "data": run.recording.data, "reached_s": run.reached_s, "fieldbus": run.fieldbus,
                            "hil": run.hil, "failure": failure, "wall_s": run.loop_wall_time_s,
                            "engine": run.engine, "scheduling": run.scheduling,
                            "pacer": {"period_ns": run.pacer.period_ns, "tolerance_ns": run.pacer.tolerance_ns,
                                      "thresholds": run.pacer.thresholds, "cycles": log.cycles[:log.count],
                                      "lateness_ns": log.lateness_ns[:log.count], "work_ns": log.work_ns[:log.count],
                                      "overrun": log.overrun[:log.count], "missed_ticks": log.missed_ticks},
                            "preq_latency_us": getattr(run, "preq_latency_us", [])}))
    except BaseException:  # noqa: BLE001 - reported to the controller side
        try:
            conn.send(("error", traceback.format_exc()))
        except (BrokenPipeError, OSError):
            pass
    finally:
        conn.close()


class _PacerRecord:
    """The cell side's pacer as the execution report reads it (period, tolerance, log)."""

    def __init__(self, data: dict) -> None:
        from cosim.execution.timing.pacer import LatenessLog

        self.period_ns = data["period_ns"]
        self.tolerance_ns = data["tolerance_ns"]
        self.thresholds = data["thresholds"]
        n = len(data["cycles"])
        self.log = LatenessLog(n + 16)
        for i in range(n):
            self.log.append(int(data["cycles"][i]), int(data["lateness_ns"][i]), bool(data["overrun"][i]),
                            int(data["work_ns"][i]))
        self.log.missed_ticks = data["missed_ticks"]


def run_hil_split(cell: CellDescription, controller: Any, ctx: Any, *, options: Any) -> Any:
    """Run ``cell`` with ``controller`` split and paced as the module docstring says; returns
    the :class:`cosim.cell.run.CellRun` (recording from the cell side)."""
    from controller.port import ControllerFailure, ControllerPort
    from cosim.cell.run import CellRun
    from cosim.execution.cell_master import write_recording
    from cosim.cell.wiring import N_JOINTS, joint_scaling
    from cosim.master import MemorySink, SimulationError
    from cosim.execution.timing.pacer import locked_memory, no_cyclic_gc, realtime_scheduling
    from cosim.execution.timing.schedule import precompute_schedules
    from fieldbus import ManagingNodeEndpoint

    if cell.fieldbus.asynchronous:
        from cosim.scenario.errors import ScenarioError

        raise ScenarioError(cell.fieldbus.source, "fieldbus.asynchronous",
                            "no scripted SDO/NMT requests in a paced split run (--realtime --split: its served "
                            "cell carries the cyclic telegrams only); run them in process, with --realtime or "
                            "with --split", given=f"{len(cell.fieldbus.asynchronous)} request(s)")
    label, period, stop_time = cell.label, cell.period_s, cell.stop_time_s
    cell_port, ctrl_port = free_udp_port(), free_udp_port()
    while ctrl_port == cell_port:
        ctrl_port = free_udp_port()
    cell_cpu, controller_cpu = split_cpus(options.settings.cpu)
    lock = os.environ.get("COSIM_HIL_MLOCK", "1") != "0"
    settings = ServeSettings(channel=f"127.0.0.1:{cell_port}", peer=f"127.0.0.1:{ctrl_port}",
                             scheduling=options.settings.scheduling, cpu=cell_cpu, lock_memory=lock)
    side_dir = Path(ctx.path(f"cell_side_{label}"))
    context = multiprocessing.get_context("spawn")
    conn, child_conn = context.Pipe(duplex=True)
    # the cell's CAN log goes to its own folder: both processes writing the one file made it unreadable
    served = picklable_cell(cell)
    if served.can_log is not None:
        served = dataclasses.replace(served, can_log=side_dir / Path(served.can_log).name)
    process = context.Process(target=cell_side_main, args=(served, settings, str(side_dir), child_conn),
                              name=f"cosim-served-cell-{label}", daemon=False)  # it has a CAN-log writer child
    bus = dataclasses.replace(cell.fieldbus.bus, interface="udpcycle", channel=f"127.0.0.1:{ctrl_port}",
                              options={**dict(cell.fieldbus.bus.options), "peer": f"127.0.0.1:{cell_port}",
                                       "latency_samples": 1 << 20, "busy_poll_s": 0.0})
    from cosim.execution.timing.network import deferred_recording

    # no CAN-log hand-over in the loop; no injected faults: the cell applies the scenario's faults
    # by its own cycle numbers (a controller counting cycles otherwise would misplace them)
    config = deferred_recording(dataclasses.replace(cell.fieldbus, bus=bus, faults=controller_faults(cell.fieldbus)))
    port = ControllerPort(controller, N_JOINTS, q_start=cell.controller.q_start)
    stop_cycle = int(round(stop_time / period))
    failure: SimulationError | None = None
    child: dict[str, Any] | None = None
    # per answered cycle, preallocated (nothing allocated per cycle in the loop): the cell's cycle,
    # waiting for its PRes, compute = the controller port's step + send_following (encode, sendto)
    # in wall and thread CPU time, and the PRes's wait in the socket (kernel arrival -> read)
    times = ControllerTimes(stop_cycle + 2)
    skipped = 0
    caught_up = 0  # outputs of skipped cycles computed afterwards into the set-point buffer's plan
    buffer_depth = config.setpoint_buffer
    spin_ns = int(controller_spin_s() * 1e9)
    period_ns = int(round(period * 1e9))
    granted = "normal"
    wall0, cpu0 = time.perf_counter(), time.process_time()
    endpoint = None
    loop_cpu_fraction = None
    try:
        try:
            port.setup(cell.controller)
        except ControllerFailure as exc:
            raise SimulationError("controller", 0.0, exc.reason) from exc
        warm_up = getattr(controller, "warm_up", None)
        if callable(warm_up):  # the built-in controller: its Python path's first call, here, not in a cycle
            warm_up()
        process.start()
        child_conn.close()
        if not conn.poll(START_TIMEOUT_S):
            raise SimulationError("served cell", 0.0, f"the cell process did not start within {START_TIMEOUT_S} s")
        kind, payload = conn.recv()
        if kind != "ready":
            raise SimulationError("served cell", 0.0, f"the cell process failed to start: {payload}")
        endpoint = ManagingNodeEndpoint(config, joint_scaling(), log_path=cell.can_log)
        precompute_schedules((endpoint,), stop_cycle + 2, False, compact=True)  # no jitter blocks drawn in the loop
        bus = endpoint.bus
        if spin_ns:
            bus._busy_poll_s = (spin_ns + SPIN_GRACE_NS) * 1e-9  # spin on the socket from the wake-up, then select
        setpoints = port.setpoints
        last = -1
        expected_ns = 0  # wall time (time.time_ns) the next PRes is due: the last one's arrival + a cycle
        ctx.label = label
        with realtime_scheduling(options.settings.scheduling, options.settings.fifo_priority,
                                 controller_cpu) as granted, no_cyclic_gc(), locked_memory(lock) as memory_lock:
            granted = f"{granted}, memory {memory_lock}"
            endpoint.send_following(setpoints)  # the cell's cycle 0 starts with this datagram
            loop_wall0, loop_cpu0 = time.perf_counter_ns(), time.thread_time_ns()
            while True:
                waited = time.perf_counter_ns()
                if expected_ns:  # sleep, then spin: a sleeper is woken 40-160 us late, a spinner at once
                    rest = expected_ns - spin_ns - time.time_ns()
                    if rest > 0:
                        time.sleep(rest * 1e-9)
                got = endpoint.follow(SILENCE_TIMEOUT_S)
                got_at = time.perf_counter_ns()
                got_cpu = time.thread_time_ns()
                if got is None:
                    if process.is_alive() and last < stop_cycle - 1:
                        failure = SimulationError("served cell", last * period,
                                                  f"no PRes from the cell process for {SILENCE_TIMEOUT_S} s")
                    break
                cycle, observed = got
                arrived = bus.oldest_arrival_ns
                woke = time.time_ns() - arrived if arrived else -1
                if cycle >= stop_cycle:
                    break
                jumped = cycle - last > 1
                skipped += max(cycle - last - 1, 0)
                try:
                    if jumped and buffer_depth and last >= 0:
                        # the drives buffer set-points: compute the outputs of the cycles this
                        # controller did not run (in order, with what it observed now) into the
                        # managing node's plan instead of leaving an interpolation over the stall
                        for j in range(max(last + 1, cycle - buffer_depth), cycle):
                            endpoint.plan_ahead(j + 1, port.step(j, j * period, observed, False, False))
                            caught_up += 1
                    last = cycle
                    setpoints = port.step(cycle, cycle * period, observed, jumped, False)
                except ControllerFailure as exc:
                    failure = SimulationError("controller", exc.time_s, exc.reason)
                    break
                stepped_at = time.perf_counter_ns()
                endpoint.send_following(setpoints)
                sent_at = time.perf_counter_ns()
                times.add(cycle, got_at - waited, stepped_at - got_at, sent_at - stepped_at,
                          time.thread_time_ns() - got_cpu, woke, arrived)
                if spin_ns and arrived:
                    expected_ns = arrived + period_ns
                stopped_at = port.stopped_at_s
                if stopped_at is not None and cycle * period - stopped_at >= cell.stop_grace_s - 1e-12:
                    failure = SimulationError("controller", stopped_at, f"motion stopped: {port.stop_reason}")
                    break
            # the share of its CPU the paced loop used (spin included): real-time CPU time
            loop_cpu_fraction = (time.thread_time_ns() - loop_cpu0) / max(time.perf_counter_ns() - loop_wall0, 1)
        if conn.poll(stop_time + START_TIMEOUT_S):
            kind, payload = conn.recv()
            if kind == "done":
                child = payload
            elif failure is None:
                failure = SimulationError("served cell", last * period, f"the cell process failed: {payload}")
    finally:
        port.close()
        if endpoint is not None:
            controller_latency = np.asarray(endpoint.bus.latency_ns, dtype=float) * 1e-3
            endpoint.close()
        else:
            controller_latency = np.zeros(0)
        process.join(timeout=30)
        if process.is_alive():
            process.terminate()
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    memory = MemorySink()
    if child is not None:
        memory.open(child["columns"], child["kinds"])
        if len(child["data"]):
            memory.write(child["data"])
        if child["failure"] is not None and failure is None:
            f = child["failure"]
            failure = SimulationError(f["component"], f["time"], f["reason"])
    if memory.columns:
        write_recording(memory, ctx.csv_sink(cell.record_file))
    cell_latency = np.asarray(child["preq_latency_us"] if child else [], dtype=float)
    n = min(cell_latency.size, controller_latency.size)
    rtt = cell_latency[:n] + controller_latency[:n]
    cell_hil = child["hil"] if child else {}
    overrun_cycles = _overrun_cycles(child["pacer"]) if child else set()
    report = {
        "controller_side": {"cycles": last + 1, "cycles_skipped": skipped, "cycles_caught_up": caught_up,
                            **times.report(period),
                            "pres_one_way_latency": percentiles_us(controller_latency, POINTS),
                            "spin_us": spin_ns * 1e-3, "loop_cpu_fraction": loop_cpu_fraction,
                            "scheduling": granted},
        "lost_cycle_causes": lost_cycle_causes(cell_hil.get("lost_cycles") or [], overrun_cycles, times, period),
        "cell_side": cell_hil,
        "round_trip": percentiles_us(rtt, POINTS),
        "cell_results": side_dir.name,
    }
    reply = times.reply_us()
    if reply.size:
        side = report["controller_side"]
        side["figure"] = _controller_figure(
            Path(ctx.path(f"hil_split_controller_{label}.png")), reply, period,
            f"{label}: split controller side, {reply.size} answers, {side['overruns']} overruns, "
            f"{skipped} cell cycles skipped").name
    summary = dict(ctx.summary.data.get("hil_split") or {})
    summary[label] = report
    ctx.summary.update(hil_split=summary)
    pacer = _PacerRecord(child["pacer"]) if child else None
    run = CellRun(label, ctx.path(cell.record_file), len(memory.data) if memory.columns else 0,
                  child["reached_s"] if child else 0.0, child["fieldbus"] if child else {}, wall,
                  child["engine"] if child else "", memory, failure, cpu, pacer=pacer,
                  scheduling=child["scheduling"] if child else "normal")
    run.hil = report
    return run


def _controller_figure(path: Path, reply_us: np.ndarray, period_s: float, title: str) -> Path:
    """The controller side's time per answered cycle (PRes arrival to answer sent) and its overruns."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 3.5))
    k = np.arange(reply_us.size)
    values = np.maximum(reply_us, 1e-3)
    ax.semilogy(k, values, ".", ms=1.5, color="tab:blue", label="PRes arrival to answer sent")
    late = reply_us > period_s * 1e6
    if late.any():
        ax.semilogy(k[late], values[late], "x", ms=4, color="tab:red", label=f"overrun ({int(late.sum())})")
    ax.axhline(period_s * 1e6, color="grey", lw=0.8, ls="--", label="one bus cycle")
    ax.set_xlabel("answered cycle")
    ax.set_ylabel("[µs]")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
