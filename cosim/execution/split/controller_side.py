"""The controller side of a split run: the controller and the POWERLINK managing node in
this process, the drives and plant in a spawned drive process (:mod:`cosim.execution.split.drive_side`).

Per cycle k (t_k = k T), optionally paced (:class:`cosim.execution.timing.pacer.Pacer`):
cycle marker (pipe) -> SoC + PReqs carrying the set-points of cycle k-1 (through the overrun
policy when late) -> wait for the PRes frames of cycle k -> ``Controller.step`` -> the
set-points for cycle k+1. The run ends at ``stop_time`` (both sides run cycles
0..stop_time/T, as the one-process cell), or ``stop_grace_s`` after the controller
stopped (an END marker tells the drive side), or as soon as the controller stopped
while the drive process is gone (it was detected through the fieldbus threshold
counters: no PRes -> loss of PRes +8 per cycle -> node fault at 15 -> the controller
stops commanding motion).
"""
from __future__ import annotations

import dataclasses
import multiprocessing
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from controller.port import ControllerFailure, ControllerPort
from cosim.cell.description import CellDescription
from cosim.cell.run import CellRun
from cosim.execution.cell_master import controller_record_name, write_recording
from cosim.cell.wiring import N_JOINTS, joint_scaling
from cosim.master import MemorySink, SimulationError
from cosim.execution.config import ExecutionOptions
from cosim.execution.timing.network import auto_tolerance_s, deferred_recording, lateness_thresholds
from cosim.execution.timing.pacer import Pacer, no_cyclic_gc, realtime_scheduling
from cosim.execution.timing.policy import OverrunFaultPlan, SetpointGate
from cosim.execution.timing.schedule import precompute_schedules
from cosim.results.progress import ProgressBar
from cosim.execution.split.drive_side import DriveSideSpec, drive_side_main, read_raw_rows
from cosim.execution.split.protocol import (END, LOST, free_udp_port, pack_marker, pres_expected, side_configs,
                                  use_directional_bus)
from fieldbus import ManagingNodeEndpoint
from cosim.cell.drive_objects import cell_object_dictionaries
from fieldbus.asynchronous import AsyncClient, AsyncPort, merged_summary, slot_offsets
from fieldbus.network import network_summary

#: Wall seconds to wait for the drive process to start (imports, FMU instantiation).
START_TIMEOUT_S = 180.0


@dataclass
class SplitSession:
    """State of a running split cell, handed to ``on_cycle(cycle, session)`` hooks.

    process: the drive process (``multiprocessing.Process``); endpoint: the managing
    node; cycle: the cycle just completed; controller_stop_cycle: the cycle in which the
    controller stopped (None: running); drive_exit_code: the drive process's exit code
    once it is seen gone (None: alive)."""

    process: Any
    endpoint: ManagingNodeEndpoint
    cycle: int = -1
    controller_stop_cycle: int | None = None
    drive_exit_code: int | None = None
    info: dict[str, Any] = field(default_factory=dict)
    asynchronous: Any = None  # the managing node's half of the asynchronous slot (fieldbus.asynchronous.AsyncClient)


def _merge_fieldbus(mn: dict[str, Any], cn: dict[str, Any] | None) -> dict[str, Any]:
    """One fieldbus summary from the two sides' (frames, counters, faults of both)."""
    if cn is None:
        out = dict(mn)
        out["drive_side"] = "unavailable (drive process gone)"
        return out
    out = dict(mn)
    for key in ("frames_sent", "frames_dropped", "frames_missing"):
        out[key] = mn[key] + cn[key]
    out["decode_errors"] = {**mn["decode_errors"], **cn["decode_errors"]}
    out["comm_fault"] = cn["comm_fault"]
    out["counters"] = mn["counters"] + cn["counters"]
    tally = dict(mn["event_tally"])
    for k, v in cn["event_tally"].items():
        tally[k] = tally.get(k, 0) + v
    out["event_tally"] = tally
    out["faults"] = sorted(mn["faults"] + cn["faults"], key=lambda e: (e["cycle"], e["time_s"]))
    out["cycles_run_drive_side"] = cn["cycles_run"]
    return out


def run_split_cell(cell: CellDescription, controller, ctx, *, options: ExecutionOptions, pacer: Pacer | None = None,
                   on_cycle: Callable[[int, SplitSession], None] | None = None) -> CellRun:
    """Run ``cell`` split over two processes (the ``split`` mode of :func:`cosim.execution.run_cell`);
    returns the CellRun with ``pacer`` (None unless paced), ``scheduling`` and ``split`` =
    {"port", "drive_process_exit_code", "controller_stop_cycle", "drive_side_wall_s", "loop_wall_s"
    (cycles only, after the drive process is ready), "realtime_factor" (incl. start-up),
    "loop_realtime_factor", "frames_missing_*", ...}."""
    if options.realtime and pacer is None and on_cycle is None:
        # paced split: the served cell keeps the time in its own process, this one follows it
        from cosim.execution.split.paced import run_hil_split

        return run_hil_split(cell, controller, ctx, options=options)
    label, stop_time, stop_grace_s = cell.label, cell.stop_time_s, cell.stop_grace_s
    record_file, can_log, true_robot = cell.record_file, cell.can_log, cell.true_robot
    fb_config = cell.fieldbus
    paced = options.realtime
    if paced:
        fb_config = deferred_recording(fb_config)
    period = fb_config.cycle_time_s
    cinfo = cell.controller
    controller_port = ControllerPort(controller, N_JOINTS, q_start=cinfo.q_start)
    command_log = controller_port.start_log()  # a user's controller: what it commanded, written after the loop
    port, up_port = free_udp_port(), free_udp_port()
    while up_port == port:
        up_port = free_udp_port()
    bus_config = side_configs(fb_config, port, options.receive_timeout_s)
    signals = list(cell.signals)
    raw = Path(tempfile.mkdtemp(prefix="cosim-split-")) / "rows.f64"
    settings = options.settings
    spec = DriveSideSpec(cell_doc=cell.master_document(), signals=signals, record_period_s=cell.record_period_s,
                         tracker=cell.tracker, true_model=true_robot.kinematic_model(), stop_time_s=stop_time,
                         config=bus_config, raw_path=str(raw),
                         marker_timeout_s=max(30.0, 5.0 * options.receive_timeout_s),
                         scheduling=settings.scheduling, fifo_priority=settings.fifo_priority,
                         ports=(port, up_port))
    context = multiprocessing.get_context("spawn")
    conn, child_conn = context.Pipe(duplex=True)
    process = context.Process(target=drive_side_main, args=(spec, child_conn), name=f"cosim-split-drives-{label}",
                              daemon=True)
    wall0 = time.perf_counter()
    cpu0 = time.process_time()
    endpoint = ManagingNodeEndpoint(bus_config, joint_scaling(), log_path=can_log)
    use_directional_bus(endpoint, "mn", bus_config.bus.channel, port, up_port)
    n_cycles = int(round(stop_time / period)) + 1
    info: dict[str, Any] = {"interface": "udp_multicast", "channel": bus_config.bus.channel,
                            "ports": {"down": port, "up": up_port},
                            "receive_timeout_s": options.receive_timeout_s}
    session = SplitSession(process, endpoint, info=info)
    # the managing node's half of the asynchronous slot (SDO client, NMT; fieldbus.asynchronous)
    client = AsyncClient(fb_config.asynchronous, fb_config.node_ids, slot_offsets(endpoint.layout),
                         fb_config.start_time_s, period, cell_object_dictionaries(fb_config))
    session.asynchronous = client
    failure: SimulationError | None = None
    granted = "normal"
    memory = MemorySink()
    child: dict[str, Any] | None = None
    ready: dict[str, Any] = {}
    interrupted: BaseException | None = None
    try:
        try:
            controller_port.setup(dataclasses.replace(cinfo, asynchronous=AsyncPort(client)))
        except ControllerFailure as exc:
            raise SimulationError("controller", 0.0, exc.reason) from exc
        process.start()
        child_conn.close()
        ready = _receive(conn, process, START_TIMEOUT_S, "ready")
        loop_t0 = time.perf_counter()
        tolerance = settings.tolerance_s if settings.tolerance_s is not None else auto_tolerance_s(endpoint.layout)
        if paced and pacer is None:
            pacer = Pacer(period, settings.spin_s, tolerance, capacity=n_cycles + 16)
        if not paced:
            pacer = None
        else:
            pacer.thresholds = lateness_thresholds(endpoint.layout)
        gate = SetpointGate(settings.overrun_policy, fb_config.nodes)
        plan = OverrunFaultPlan(endpoint.plan, fb_config.nodes)
        endpoint.plan = plan
        if paced:
            precompute_schedules((endpoint,), n_cycles, settings.overrun_policy == "lost_frame")
        lost_policy = settings.overrun_policy == "lost_frame"
        bar = ProgressBar(stop_time, f"{ctx.scenario.name} {label} (split)", enabled=not ctx.quiet and not paced)
        nodes = fb_config.nodes
        pipe_open = [True]

        def send(data: bytes) -> None:
            if pipe_open[0]:
                try:
                    conn.send_bytes(data)
                except (BrokenPipeError, OSError):  # the drive process is gone: the bus counters will tell
                    pipe_open[0] = False
        t0 = fb_config.start_time_s
        setpoints = controller_port.setpoints
        missing_seen = 0
        # both sides ask for SCHED_FIFO ([realtime] scheduling) even unpaced: each cycle hands
        # over twice between the processes and on a loaded machine every wake-up otherwise
        # waits for a time slice (measured at load 6.6: 6.2 ms per cycle normal, 1.5 ms FIFO)
        scheduling = settings.scheduling
        with realtime_scheduling(scheduling, settings.fifo_priority, settings.cpu if paced else None) as granted, \
                no_cyclic_gc():
            for k in range(n_cycles):
                t = t0 + k * period
                late = pacer.wait(k) if pacer is not None else False
                flags = 0
                if late and lost_policy:
                    plan.mark_lost(k)
                    flags = LOST
                offer = client.offer(k) if k >= client.next_cycle else None
                owed = offer is not None or client.awaiting
                send(pack_marker(k, flags, offer))
                endpoint.send_setpoints(k, gate.send(setpoints, late))
                observed = endpoint.collect_actuals(k)
                if owed:
                    frames = client.outcome(k, *_async_outcome(conn, k, options.receive_timeout_s))
                    if frames and endpoint.recorder is not None:
                        endpoint.recorder.add_many(frames)
                if not pres_expected(plan.for_cycle(k), nodes) and not _acknowledged(conn, k, options.receive_timeout_s):
                    session.drive_exit_code = process.exitcode if not process.is_alive() else None
                try:
                    setpoints = controller_port.step(k, t, observed, late and not lost_policy, late and lost_policy)
                except ControllerFailure as exc:
                    session.cycle = k
                    failure = SimulationError("controller", exc.time_s, exc.reason)
                    if k + 1 < n_cycles:
                        send(pack_marker(k + 1, END))
                    break
                session.cycle = k
                stopped_at = controller_port.stopped_at_s
                if stopped_at is not None and session.controller_stop_cycle is None:
                    session.controller_stop_cycle = k
                if endpoint.frames_missing != missing_seen:
                    missing_seen = endpoint.frames_missing
                    if not process.is_alive():
                        session.drive_exit_code = process.exitcode
                if on_cycle is not None:
                    on_cycle(k, session)
                if stopped_at is not None:
                    reason = controller_port.stop_reason
                    if session.drive_exit_code is not None:
                        failure = SimulationError(
                            "split drive side", t, f"drive process ended (exit code {session.drive_exit_code}); "
                            f"the controller stopped at t = {stopped_at:.6g} s: {reason}")
                        break
                    if t - stopped_at >= stop_grace_s - 1e-12:
                        failure = SimulationError("controller", stopped_at, f"motion stopped: {reason}")
                        if k + 1 < n_cycles:
                            send(pack_marker(k + 1, END))
                        break
                if k % 250 == 0:
                    bar.update(t - t0)
        info["loop_wall_s"] = time.perf_counter() - loop_t0
        bar.update(session.cycle * period, force=True)
        bar.close()
        if process.is_alive() or conn.poll(0):
            try:
                child = _receive(conn, process, 120.0, "done")
            except RuntimeError as error:
                info["drive_side_error"] = str(error)
    except KeyboardInterrupt as exc:  # SIGINT/SIGTERM: end the drive side, keep its rows, then re-raise
        interrupted = exc
        if hasattr(ctx, "note_position"):
            ctx.note_position(label, fb_config.start_time_s + max(session.cycle, 0) * period,
                              max(session.cycle, 0) * period)
        if process.is_alive():
            try:
                conn.send_bytes(pack_marker(session.cycle + 1, END))
                child = _receive(conn, process, 5.0, "done")
            except (OSError, RuntimeError, EOFError):
                pass
    finally:
        controller_port.close()
        endpoint.close()
        if process.is_alive():
            process.join(timeout=10)
        if process.is_alive():
            process.kill()
            process.join(timeout=5)
        conn.close()
    wall = time.perf_counter() - wall0
    cpu = time.process_time() - cpu0
    columns = ready.get("columns") or ["time", *signals]
    memory.open(columns, ready.get("kinds") or ["Real"] * len(columns))
    rows = read_raw_rows(raw, len(columns))
    if rows.size:
        memory.write(rows)
    raw.unlink(missing_ok=True)
    raw.parent.rmdir()
    record_file = ctx.series_name(record_file)
    write_recording(memory, ctx.series_sink(record_file))
    controller_file = None
    if command_log is not None:
        controller_file = ctx.series_name(controller_record_name(cell))
        command_log.close(ctx.series_sink(controller_file, command_log.units))
    if interrupted is not None:
        raise interrupted
    cycles = session.cycle + 1
    mn_summary = network_summary(endpoint.config, endpoint.events, endpoint, None, endpoint.recorder, cycles)
    fieldbus_summary = _merge_fieldbus(mn_summary, child["fieldbus"] if child else None)
    if session.asynchronous is not None:
        fieldbus_summary["asynchronous"] = merged_summary(session.asynchronous.summary(), (child or {}).get(
            "fieldbus", {}).get("asynchronous_nodes"))
    fieldbus_summary.pop("asynchronous_nodes", None)
    if failure is None and child and child.get("failure"):
        f = child["failure"]
        failure = SimulationError(f["component"], f["time"], f["reason"], f["messages"])
    reached = child["reached_s"] if child else t0 + (rows[-1, 0] if rows.size else 0.0)
    info.update(drive_process_exit_code=process.exitcode, controller_stop_cycle=session.controller_stop_cycle,
                drive_exit_seen_at_cycle=session.cycle if session.drive_exit_code is not None else None,
                drive_side_wall_s=child["wall_s"] if child else None, cycles=cycles,
                frames_missing_controller_side=endpoint.frames_missing,
                frames_missing_drive_side=child["frames_missing"] if child else None,
                lost_cycles_drive_side=len(child["lost_cycles"]) if child else None,
                drive_side_scheduling=child.get("scheduling") if child else None, controller_side_scheduling=granted,
                realtime_factor=(cycles * period) / wall if wall > 0 else None,
                loop_realtime_factor=(cycles * period) / info["loop_wall_s"] if info.get("loop_wall_s") else None)
    ctx.sim_time_s += cycles * period
    return CellRun(label, ctx.path(record_file), int(rows.shape[0]), reached, fieldbus_summary, wall,
                   ready.get("engine", ""), memory, failure, loop_cpu_time_s=cpu, pacer=pacer, scheduling=granted,
                   split=info, controller_timing=controller_port.timing(),
                   port_overhead=controller_port.overhead(), controller_close_error=controller_port.close_error,
                   controller_record=ctx.path(controller_file) if controller_file else None)


def _async_outcome(conn, cycle: int, timeout_s: float) -> tuple[str | None, bytes | None]:
    """The drive side's ``("async", cycle, kind, answer)`` of the asynchronous slot of ``cycle``
    ((None, None) when it does not come within ``timeout_s``: the drive process is gone)."""
    if not conn.poll(max(timeout_s, 5.0)):
        return None, None
    try:
        message = conn.recv()
    except (EOFError, OSError):
        return None, None
    if message[0] != "async" or message[1] != cycle:
        raise RuntimeError(f"split run: expected the asynchronous slot of cycle {cycle} from the drive side, "
                           f"got {message[:2]!r}")
    return message[2], message[3]


def _acknowledged(conn, cycle: int, timeout_s: float) -> bool:
    """Wait for the drive side's ``("ack", cycle)``; False when none came (process gone)."""
    try:
        if not conn.poll(timeout_s):
            return False
        kind, payload = conn.recv()
    except (EOFError, OSError):
        return False
    if kind != "ack" or payload != cycle:
        raise RuntimeError(f"split drive process sent {kind!r} {payload!r}, expected the ack of cycle {cycle}")
    return True


def _receive(conn, process, timeout_s: float, expected: str) -> dict[str, Any]:
    """The drive process's next message, which must be ``expected``."""
    deadline = time.monotonic() + timeout_s
    while not conn.poll(0.05):
        if not process.is_alive() and not conn.poll(0):
            raise RuntimeError(f"split drive process exited with code {process.exitcode} before '{expected}'")
        if time.monotonic() > deadline:
            raise RuntimeError(f"split drive process sent no '{expected}' within {timeout_s} s")
    try:
        kind, payload = conn.recv()
    except (EOFError, OSError):
        raise RuntimeError(f"split drive process exited with code {process.exitcode} before '{expected}'") from None
    if kind == "error":
        raise RuntimeError(f"split drive process failed:\n{payload}")
    if kind != expected:
        raise RuntimeError(f"split drive process sent '{kind}', expected '{expected}'")
    return payload
