"""``cosim run SCENARIO --split --realtime``: our own controller in this process, the served
cell (:func:`cosim.hil.cell_side.run_served_cell`) in another, both on the wall clock.

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
from cosim.hil.cell_side import longest_run, percentiles_us
from cosim.hil.settings import ServeSettings
from cosim.split.protocol import free_udp_port

#: Wall seconds to wait for the cell process to come up (imports, FMU instantiation).
START_TIMEOUT_S = 180.0
#: Wall seconds without the cell's PRes after which the controller side gives up.
SILENCE_TIMEOUT_S = 5.0
#: The percentiles of the controller side's figures.
POINTS = (50.0, 99.0)


def _compute_causes(wall_ns: list, cpu_ns: list, period_s: float) -> dict[str, int]:
    """Controller steps longer than a cycle: 'stalled' (less than half of it CPU time of this
    thread: the process was not running) or 'own_work'."""
    wall, cpu = np.asarray(wall_ns, dtype=float), np.asarray(cpu_ns, dtype=float)
    long = wall > period_s * 1e9
    stalled = long & (cpu < 0.5 * wall)
    return {"stalled": int(stalled.sum()), "own_work": int((long & ~stalled).sum())}


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

    from cosim.realtime.network import deferred_recording

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
    from cosim.hil.cell_side import run_served_cell
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
        from cosim.realtime.pacer import LatenessLog

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
    the :class:`cosim.cell.runner.CellRun` (recording from the cell side)."""
    from controller.port import ControllerFailure, ControllerPort
    from cosim.cell.runner import CellRun, write_recording
    from cosim.cell.wiring import N_JOINTS, joint_scaling
    from cosim.master import MemorySink, SimulationError
    from cosim.realtime.pacer import locked_memory, no_cyclic_gc, realtime_scheduling
    from cosim.realtime.schedule import precompute_schedules
    from fieldbus import ManagingNodeEndpoint

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
    process = context.Process(target=cell_side_main, args=(picklable_cell(cell), settings, str(side_dir), child_conn),
                              name=f"cosim-served-cell-{label}", daemon=False)  # it has a CAN-log writer child
    bus = dataclasses.replace(cell.fieldbus.bus, interface="udpcycle", channel=f"127.0.0.1:{ctrl_port}",
                              options={**dict(cell.fieldbus.bus.options), "peer": f"127.0.0.1:{cell_port}",
                                       "latency_samples": 1 << 20, "busy_poll_s": 0.0})
    from cosim.realtime.network import deferred_recording

    config = deferred_recording(dataclasses.replace(cell.fieldbus, bus=bus))  # no CAN-log hand-over in the loop
    port = ControllerPort(controller, N_JOINTS, q_start=cell.controller.q_start)
    stop_cycle = int(round(stop_time / period))
    failure: SimulationError | None = None
    child: dict[str, Any] | None = None
    wait_ns, compute_ns, compute_cpu_ns, wakeup_ns, skipped = [], [], [], [], 0
    reply_ns: list[int] = []  # per answered cycle: the PRes datagram's kernel arrival -> our answer sent
    step_ns, send_ns = [], []  # compute = the controller port's step + send_following (encode, sendto)
    granted = "normal"
    wall0, cpu0 = time.perf_counter(), time.process_time()
    endpoint = None
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
        setpoints = port.setpoints
        last = -1
        ctx.label = label
        with realtime_scheduling(options.settings.scheduling, options.settings.fifo_priority,
                                 controller_cpu) as granted, no_cyclic_gc(), locked_memory(lock) as memory_lock:
            granted = f"{granted}, memory {memory_lock}"
            endpoint.send_following(setpoints)  # the cell's cycle 0 starts with this datagram
            while True:
                waited = time.perf_counter_ns()
                got = endpoint.follow(SILENCE_TIMEOUT_S)
                got_at = time.perf_counter_ns()
                got_cpu = time.thread_time_ns()
                if got is None:
                    if process.is_alive() and last < stop_cycle - 1:
                        failure = SimulationError("served cell", last * period,
                                                  f"no PRes from the cell process for {SILENCE_TIMEOUT_S} s")
                    break
                cycle, observed = got
                arrived = endpoint.bus.oldest_arrival_ns
                if arrived:
                    wakeup_ns.append(time.time_ns() - arrived)
                if cycle >= stop_cycle:
                    break
                jumped = cycle - last > 1
                skipped += max(cycle - last - 1, 0)
                last = cycle
                try:
                    setpoints = port.step(cycle, cycle * period, observed, jumped, False)
                except ControllerFailure as exc:
                    failure = SimulationError("controller", exc.time_s, exc.reason)
                    break
                stepped_at = time.perf_counter_ns()
                endpoint.send_following(setpoints)
                sent_at = time.perf_counter_ns()
                if arrived:
                    reply_ns.append(time.time_ns() - arrived)
                wait_ns.append(got_at - waited)
                step_ns.append(stepped_at - got_at)
                send_ns.append(sent_at - stepped_at)
                compute_ns.append(sent_at - got_at)
                compute_cpu_ns.append(time.thread_time_ns() - got_cpu)
                stopped_at = port.stopped_at_s
                if stopped_at is not None and cycle * period - stopped_at >= cell.stop_grace_s - 1e-12:
                    failure = SimulationError("controller", stopped_at, f"motion stopped: {port.stop_reason}")
                    break
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
    reply_us = np.asarray(reply_ns, dtype=float) * 1e-3
    late = reply_us > period * 1e6
    report = {
        "controller_side": {"cycles": last + 1, "cycles_skipped": skipped,
                            # the controller's own cycle starts when the cell's PRes datagram arrives and
                            # ends when its answer is sent: an overrun is an answer later than one bus cycle
                            "overruns": int(late.sum()),
                            "overrun_fraction": float(late.mean()) if late.size else 0.0,
                            "longest_overrun_run": longest_run(late),
                            "lateness": percentiles_us(reply_us),
                            "wait_for_pres": percentiles_us(np.asarray(wait_ns, dtype=float) * 1e-3, POINTS),
                            "compute": percentiles_us(np.asarray(compute_ns, dtype=float) * 1e-3, POINTS),
                            "compute_cpu": percentiles_us(np.asarray(compute_cpu_ns, dtype=float) * 1e-3, POINTS),
                            # compute split in two: the controller through its port, then the next
                            # cycle's frames encoded and sent (one sendto to the cell)
                            "compute_step": percentiles_us(np.asarray(step_ns, dtype=float) * 1e-3, POINTS),
                            "compute_send": percentiles_us(np.asarray(send_ns, dtype=float) * 1e-3, POINTS),
                            # computations longer than a cycle: mostly CPU (own work) or not (stalled)
                            "compute_over_one_cycle": _compute_causes(compute_ns, compute_cpu_ns, period),
                            "pres_one_way_latency": percentiles_us(controller_latency, POINTS),
                            # from the PRes datagram's kernel arrival to this process having read it: long
                            # when the process was not running (a stall of the OS or the hypervisor)
                            "wakeup_after_pres": percentiles_us(np.asarray(wakeup_ns, dtype=float) * 1e-3,
                                                                POINTS),
                            "stalls_over_one_cycle": int(np.count_nonzero(np.asarray(wakeup_ns) > period * 1e9)),
                            "scheduling": granted},
        "cell_side": child["hil"] if child else {},
        "round_trip": percentiles_us(rtt, POINTS),
        "cell_results": side_dir.name,
    }
    if reply_us.size:
        report["controller_side"]["figure"] = _controller_figure(
            Path(ctx.path(f"hil_split_controller_{label}.png")), reply_us, period,
            f"{label}: split controller side, {reply_us.size} answers, {int(late.sum())} overruns, "
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
