"""Hardware-in-the-loop timing: the paced cell side and a following controller in two
processes over the ``udpcycle`` interface.

``python benchmarks/bench_hil.py [--seconds 10] [--runs 5]`` runs, per run, a cell-side
process (the POWERLINK controlled nodes of ``fieldbus.DriveEndpoint.run_cycle_paced``,
paced at 400 µs by ``cosim.execution.timing.pacer.Pacer``) and a controller-side process
(``ManagingNodeEndpoint.follow`` / ``send_following``), both on loopback, and prints per
run and as medians over runs: overrun fraction and longest run of consecutive overruns
of the cell's pacing, lateness p50/p99/p99.9/max, one-way datagram latency both ways
(kernel arrival minus the sender's send time) and their sum as the frame round trip,
lost cycles (the cell's loss-of-PReq count) and late frames, with the load average.
This is the transport and bus part of ``cosim serve``; ``cosim bench`` runs it as the
``hil`` section.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: both processes ask for SCHED_FIFO (granted to root; 'normal (...)' otherwise, reported per run)
SCHEDULING = "fifo"
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def steal_ms() -> float:
    """CPU time the hypervisor took from this (virtual) machine so far, ms, all CPUs (/proc/stat
    'steal'; 0 where not reported). A vCPU that is descheduled by the host stalls whatever runs
    on it, SCHED_FIFO or not: the stalls no setting inside the machine can prevent."""
    try:
        fields = Path("/proc/stat").read_text().splitlines()[0].split()
        return int(fields[8]) * 1000.0 / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def steal_ms_per_cpu() -> list[float]:
    """:func:`steal_ms` of each CPU (``/proc/stat`` cpuN lines), ms; [] where not reported."""
    try:
        lines = [line.split() for line in Path("/proc/stat").read_text().splitlines() if line.startswith("cpu")]
        return [int(f[8]) * 1000.0 / os.sysconf("SC_CLK_TCK") for f in lines[1:] if len(f) > 8]
    except (OSError, IndexError, ValueError):
        return []


def stall_probe(seconds: float = 8.0, period_s: float = 400e-6, work_s: float = 80e-6) -> dict:
    """The machine's own stalls, without our code: a SCHED_FIFO loop paced like the cell (sleep,
    spin to each 400 µs deadline, 80 µs of busy work) that watches the clock for gaps > 100 µs
    while spinning and working. A gap there is time the loop did not run although it was
    runnable at real-time priority: the OS or the hypervisor (compare ``steal_ms_per_s``). Run in
    a child process (its scheduling and affinity are its own)."""
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    process = ctx.Process(target=_stall_probe_child, args=(seconds, period_s, work_s, queue))
    process.start()
    out = queue.get(timeout=seconds + 60)
    process.join(10)
    return out


def _stall_probe_child(seconds: float, period_s: float, work_s: float, queue) -> None:
    from cosim.execution.timing.pacer import realtime_scheduling

    period, work, limit = int(period_s * 1e9), int(work_s * 1e9), 100_000
    gaps = []
    steal0 = steal_ms()
    with realtime_scheduling(SCHEDULING, 10) as granted:
        clock = time.perf_counter_ns
        origin = clock()
        end = origin + int(seconds * 1e9)
        k = 0
        while True:
            k += 1
            deadline = origin + k * period
            now = clock()
            if now >= end:
                break
            if deadline - now > 150_000:
                time.sleep((deadline - now - 150_000) * 1e-9)
            previous = clock()
            stop = max(deadline, previous) + work
            while previous < stop:  # spin to the deadline, then work; a gap is time not run
                now = clock()
                if now - previous > limit:
                    gaps.append(now - previous)
                previous = now
            if previous - deadline > period:
                origin += (previous - deadline) // period * period
    steal = (steal_ms() - steal0) / seconds
    g = np.asarray(gaps, dtype=float) * 1e-3
    queue.put({"seconds": seconds, "scheduling": granted, "gaps_over_100us": int(g.size),
               "gaps_over_1ms": int((g > 1000).sum()), "gap_total_ms": float(g.sum() * 1e-3),
               "gap_max_us": float(g.max()) if g.size else 0.0, "steal_ms_per_s": steal})


def _config(channel: str, peer: str, poll: float) -> dict:
    return {"bus": {"interface": "udpcycle", "channel": channel, "receive_timeout_s": 0.05,
                    "options": {"peer": peer, "latency_samples": 1 << 20, "busy_poll_s": poll}}}


def _scaling():
    from fieldbus import JointScaling

    return JointScaling([100.0, 100.0, 80.0, 60.0, 60.0, 50.0], 65536, [350.0, 500.0, 220.0, 35.0, 30.0, 17.0])


def cell_side(seconds: float, ports: tuple[int, int], window_s: float, queue) -> None:
    from cosim.execution.timing.pacer import Pacer, no_cyclic_gc
    from cosim.execution.timing.schedule import precompute_schedules
    from fieldbus import DriveActuals, DriveEndpoint

    cell, ctrl = ports
    endpoint = DriveEndpoint(_config(f"127.0.0.1:{cell}", f"127.0.0.1:{ctrl}", 0.0), _scaling())
    period = endpoint.config.cycle_time_s
    cycles = int(round(seconds / period))
    pacer = Pacer(period, 150e-6, period - window_s, capacity=cycles + 16)
    precompute_schedules((endpoint,), cycles + 1, False, compact=True)  # as cosim serve
    actuals = DriveActuals.zeros(6)
    actuals.statusword[:] = 0x27
    queue.put("ready")
    import select

    select.select([endpoint.bus.fileno()], [], [], 120.0)  # start with the controller's first datagram
    from cosim.execution.timing.pacer import realtime_scheduling

    with realtime_scheduling(SCHEDULING, 10) as granted, no_cyclic_gc():
        for k in range(cycles):
            pacer.wait(k)
            deadline = (pacer.deadline_ns(k) + int(window_s * 1e9)) * 1e-9
            actuals.position[:] = 1e-4 * k
            endpoint.run_cycle_paced(k, actuals, deadline, clock=lambda: time.perf_counter_ns() * 1e-9)
    log = pacer.log
    lost = sum(1 for e in endpoint.events.events if e.kind == "loss_of_preq" and e.event == "error" and e.node == 1)
    out = {"cycles": log.count, "scheduling": granted, "lateness_us": log.lateness_us.tolist(), "overrun": log.overrun[:log.count].tolist(),
           "lost_cycles": lost, "frames_late": endpoint.frames_late,
           "latency_in_us": [x * 1e-3 for x in endpoint.bus.latency_ns], "stats": endpoint.bus.stats.as_dict()}
    endpoint.close()
    queue.put(out)


def controller_side(seconds: float, ports: tuple[int, int], queue) -> None:
    from fieldbus import ManagingNodeEndpoint, Setpoints

    cell, ctrl = ports
    endpoint = ManagingNodeEndpoint(_config(f"127.0.0.1:{ctrl}", f"127.0.0.1:{cell}", 200e-6), _scaling())
    from cosim.execution.timing.schedule import precompute_schedules

    precompute_schedules((endpoint,), int(round(seconds / endpoint.config.cycle_time_s)) + 16, False, compact=True)
    setpoints = Setpoints.zeros(6)
    setpoints.controlword[:] = 0x0F
    endpoint.send_following(setpoints)  # announce: the cell answers with PRes every cycle anyway
    end = time.monotonic() + seconds + 1.0
    skipped = 0
    last = -1
    from cosim.execution.timing.pacer import no_cyclic_gc, realtime_scheduling

    with realtime_scheduling(SCHEDULING, 10), no_cyclic_gc():
        skipped, last = _follow(endpoint, setpoints, end)
    queue.put({"cycles_followed": last + 1, "cycles_skipped": skipped,
               "latency_in_us": [x * 1e-3 for x in endpoint.bus.latency_ns]})
    endpoint.close()


def _follow(endpoint, setpoints, end: float) -> tuple[int, int]:
    skipped, last = 0, -1
    while time.monotonic() < end:
        got = endpoint.follow(0.2)
        if got is None:
            break
        cycle, observed = got
        skipped += max(cycle - last - 1, 0) if last >= 0 else 0
        last = cycle
        setpoints.position[:] = observed.position + 1e-4
        endpoint.send_following(setpoints)
    return skipped, last


def run_once(seconds: float, base_port: int, window_s: float = 200e-6) -> dict:
    ctx = mp.get_context("spawn")
    q_cell, q_ctrl = ctx.Queue(), ctx.Queue()
    ports = (base_port, base_port + 1)
    load_before = os.getloadavg()
    steal0, wall0 = steal_ms(), time.monotonic()
    cell = ctx.Process(target=cell_side, args=(seconds, ports, window_s, q_cell))
    cell.start()
    assert q_cell.get(timeout=60) == "ready"
    ctrl = ctx.Process(target=controller_side, args=(seconds, ports, q_ctrl))
    ctrl.start()
    c = q_cell.get(timeout=seconds + 120)
    k = q_ctrl.get(timeout=30)
    cell.join(10)
    ctrl.join(10)
    steal = (steal_ms() - steal0) / (time.monotonic() - wall0)
    lateness = np.asarray(c["lateness_us"])
    overrun = np.asarray(c["overrun"], dtype=bool)
    from cosim.execution.cell_side import longest_run

    longest = longest_run(overrun)
    up = np.asarray(c["latency_in_us"])  # controller -> cell
    down = np.asarray(k["latency_in_us"])  # cell -> controller
    n = min(up.size, down.size)
    rtt = up[:n] + down[:n]
    return {"cycles": c["cycles"], "overruns": int(overrun.sum()), "overrun_fraction": float(overrun.mean()),
            "longest_overrun_run": longest,
            "lateness_us": {"p50": float(np.percentile(lateness, 50)), "p99": float(np.percentile(lateness, 99)),
                            "p99_9": float(np.percentile(lateness, 99.9)), "max": float(lateness.max())},
            "round_trip_us": {"p50": float(np.percentile(rtt, 50)), "p99": float(np.percentile(rtt, 99)),
                              "max": float(rtt.max())} if n else {"p50": None, "p99": None, "max": None},
            "lost_cycles": c["lost_cycles"], "frames_late": c["frames_late"],
            "controller_cycles_skipped": k["cycles_skipped"], "transport": c["stats"], "scheduling": c["scheduling"],
            "steal_ms_per_s": steal,
            "load_average_before": load_before, "load_average_after": os.getloadavg()}


def run(seconds: float = 10.0, runs: int = 5) -> dict:
    results = [run_once(seconds, 47000 + 4 * i + (os.getpid() % 500) * 20) for i in range(runs)]

    def med(path):
        values = [r for r in results]
        for key in path:
            values = [v[key] for v in values]
        values = [v for v in values if v is not None]
        return statistics.median(values) if values else None

    summary = {"runs": results, "seconds": seconds,
               "median": {"overrun_fraction": med(("overrun_fraction",)),
                          "longest_overrun_run": med(("longest_overrun_run",)),
                          "lateness_p99_us": med(("lateness_us", "p99")),
                          "lateness_max_us": med(("lateness_us", "max")),
                          "round_trip_p50_us": med(("round_trip_us", "p50")),
                          "round_trip_p99_us": med(("round_trip_us", "p99")),
                          "lost_cycles": med(("lost_cycles",))}}
    return summary


# ------------------------------------------------------------------ a deliberately late controller
#: Cycles (of the cell, counted from the first PRes the controller sees) in which the controller answers too late:
#: three single late cycles, then two in a row (the second trips the default threshold 15).
LATE_CYCLES = (1500, 2500, 3500, 4500, 4501)
#: the served run's wall time (the controller is up before the cell starts)
LATE_SECONDS = 2.5


def expected_counters(lost: list[int], cycles: int, increment: int = 8, decrement: int = 1,
                      threshold: int = 15) -> dict:
    """What POWERLINK specifies (EPSG DS 301 4.7.4.1) for a CN that misses the SoC and PReq of
    the cycles ``lost``: per lost cycle one loss-of-SoC and one loss-of-PReq error, each
    counter +``increment``, -``decrement`` per cycle without error (not below 0); the
    reaction in the cycle the counter reaches ``threshold``. -> {"errors": {cycle: counter},
    "trips": [cycles]} (the same for every node and for both counters)."""
    value, errors, trips, lost_set = 0, {}, [], set(lost)
    for k in range(cycles):
        if k in lost_set:
            before = value
            value += increment
            errors[k] = value
            if before < threshold <= value:
                trips.append(k)
        else:
            value = max(value - decrement, 0)
    return {"errors": errors, "trips": trips}


def late_controller(endpoint_file: str, late: tuple[int, ...], seconds: float, queue) -> None:
    """Follow the served cell until it stops, enable the drives, hold the start pose, and answer the PRes of
    the cycle before each ``late`` cycle only after that cycle's window has closed (a quarter of
    the way from the window's end to the next cycle, timed from that PRes's kernel arrival): the
    group arrives after its window,
    where the cell must drop it. Started before ``cosim serve``: it waits for ``endpoint_file``."""
    import logging

    from cosim.cell.wiring import joint_scaling
    from cosim.execution.timing.pacer import no_cyclic_gc, realtime_scheduling
    from cosim.execution.timing.schedule import precompute_schedules
    from fieldbus import EnableSequencer, ManagingNodeEndpoint, Setpoints

    logging.getLogger("fieldbus").setLevel(logging.ERROR)  # its own view of the skipped cycles: not needed here
    queue.put("ready")
    path = Path(endpoint_file)
    while not path.exists():
        time.sleep(0.001)
    desc = json.loads(path.read_text())
    period, window = desc["cycle_time_s"], desc["window_s"]
    # from the kernel arrival of the PRes of the cycle before (sent at the start of that cycle): a
    # quarter of the way from the late cycle's window end to the next cycle, so the group surely
    # misses its window and the next cycle's answer, sent right after, still has ~250 us to spare
    # (measured from this process's own wake-up instead, a late wake-up also cost the next cycle)
    delay_ns = int((period + window + (period - window) / 4) * 1e9)
    config = _config(desc["controller_channel"], desc["cell_channel"], 200e-6)
    config["cycle_time_us"] = round(period * 1e6, 6)
    endpoint = ManagingNodeEndpoint(config, joint_scaling())
    precompute_schedules((endpoint,), int(seconds / period) + 16, False, compact=True)
    setpoints = Setpoints.zeros(desc["nodes"])
    setpoints.position[:] = desc["q_start_rad"]
    sequencers = [EnableSequencer() for _ in range(desc["nodes"])]
    pending, sent_late, last, first = sorted(late), [], -1, None
    endpoint.send_following(setpoints)  # the cell takes it as the first group
    with realtime_scheduling(SCHEDULING, 10), no_cyclic_gc():
        while True:
            got = endpoint.follow(0.5 if first is not None else 120.0)  # the cell may take a while to start
            # the newest PRes's kernel arrival (wall ns): after a stall of this process several have
            # arrived, and timing from the oldest one made the 'late' group early enough to be taken
            arrived = endpoint.bus.newest_arrival_ns or time.time_ns()
            if got is None:
                break
            cycle, observed = got
            last = cycle
            # the cell's own cycle number, from the frame time it stamped on its PRes
            cell_cycle = int(endpoint.peer_time_s // period + 1e-9)
            first = cell_cycle if first is None else first
            for i, sequencer in enumerate(sequencers):
                setpoints.controlword[i] = sequencer.next_controlword(int(observed.statusword[i]))
            # the next planned cycle reached: ``follow`` digests every PRes that has arrived, so after a
            # stall (of the cell or of this process) it can jump over a planned cycle - take the next
            # cycle instead of skipping the plan (one per PRes: a pair stays a pair)
            if pending and cell_cycle + 1 - first >= pending[0]:
                pending.pop(0)
                while time.time_ns() - arrived < delay_ns:
                    pass
                sent_late.append(cell_cycle + 1)
            endpoint.send_following(setpoints)
    stats = endpoint.bus.stats.as_dict()
    endpoint.close()
    queue.put({"late_sent": sent_late, "first_cell_cycle": first, "cycles_followed": last + 1,
               "transport": stats})


def _late_scenario(work: Path, seconds: float) -> Path:
    """scenarios/hil.toml for ``seconds`` with POWERLINK's default loss-of-SoC/PReq thresholds (the
    late controller is about what POWERLINK specifies: 15 trips at the second lost cycle in a row;
    hil.toml sets those of a buffered drive)."""
    import re

    from fieldbus import FieldbusConfig

    text = (ROOT / "scenarios" / "hil.toml").read_text().replace('stop_time = "6 s"', f'stop_time = "{seconds} s"')
    defaults = FieldbusConfig.from_dict({}).thresholds
    for key in ("cn_loss_of_soc", "cn_loss_of_preq"):
        text = re.sub(rf"^{key} = \d+", f"{key} = {getattr(defaults, key)}", text, count=1, flags=re.MULTILINE)
    path = work / "hil_late.toml"
    path.write_text(text)
    return path


def _cell_cycles_in_can_log(path: Path, period: float) -> tuple[set[int], set[int]]:
    """Cycles with the cell's SoC taken, cycles with a PRes sent, from the cell's CAN log."""
    from fieldbus.canlog import open_log

    soc, pres = set(), set()
    for msg in open_log(path):
        k = int(msg.timestamp // period + 1e-9) if msg.arbitration_id != 0x080 else round(msg.timestamp / period)
        if msg.arbitration_id == 0x080:
            soc.add(k)
        elif msg.arbitration_id == 0x181:
            pres.add(k)
    return soc, pres


def late_run(work: Path, seconds: float = LATE_SECONDS, late: tuple[int, ...] = LATE_CYCLES,
             port: int | None = None) -> dict:
    """``cosim serve`` (scenarios/hil.toml at 400 µs, FMUs, CAN log) against :func:`late_controller`
    in another process: expected vs observed lost cycles and counter values per late cycle,
    observed from the cell's CAN log (cycles without SoC/PReqs) and its fieldbus events."""
    import subprocess

    from fieldbus import FieldbusConfig

    work.mkdir(parents=True, exist_ok=True)
    out = work / "served"
    port = port or 47700 + (os.getpid() % 300) * 2
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
           "MPLBACKEND": "Agg"}
    load_before = os.getloadavg()
    endpoint_file = out / "hil_endpoint.json"
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    controller = ctx.Process(target=late_controller, args=(str(endpoint_file), tuple(late), seconds, queue))
    controller.start()
    if queue.get(timeout=180) != "ready":
        raise RuntimeError("the late controller did not start")
    serve = subprocess.Popen([sys.executable, "-m", "cosim", "serve", str(_late_scenario(work, seconds)), "--out",
                              str(out), "--quiet", "--channel", f"127.0.0.1:{port}", "--scheduling", SCHEDULING],
                             env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ctrl = queue.get(timeout=seconds + 120)
    finally:
        controller.join(10)
        _, err = serve.communicate(timeout=seconds + 180)
    summary = json.loads((out / "summary.json").read_text())
    hil = summary["hil"]["model_based"]
    desc = json.loads(endpoint_file.read_text())
    period = desc["cycle_time_s"]
    first = hil["controller"]["first_cycle"]
    cycles = hil["cycles"]
    planned = list(ctrl["late_sent"])  # cell cycles (the controller read them from the cell's PRes)
    threshold = FieldbusConfig.from_dict({}).thresholds.cn_loss_of_preq  # _late_scenario: the default
    observed = {row["cycle"]: row["counters"] for row in hil["lost_cycles"]}
    trips: dict[int, set[int]] = {}
    for f in hil["fault_reactions"]:
        if f["event"] == "fault_reaction" and f["kind"] in ("loss_of_soc", "loss_of_preq"):
            trips.setdefault(f["cycle"], set()).add(f["node"])
    soc, pres = _cell_cycles_in_can_log(out / "can_model_based.parquet", period)
    judged = range(first, min(first + ctrl["cycles_followed"], cycles))
    missing_soc = sorted(k for k in judged if k not in soc)
    cell_late = {int(c): x for c, x in hil.get("overrun_cycles", [])}
    faulted = {k for a, b in hil.get("all_nodes_faulted_cycles", []) for k in range(a, b + 1)}
    per_cycle = judge_late_cycles(planned, observed, trips, soc, pres, cell_late, threshold, faulted=faulted)
    unplanned = sorted(k for k in set(observed) - set(planned) if k in judged)
    n_judged = sum(not r["status"].startswith("not judged") for r in per_cycle)
    reasons = {}
    for r in per_cycle:
        if r["status"].startswith("not judged"):
            reasons[r["status"]] = reasons.get(r["status"], 0) + 1
    exact = sum(r["status"] == "exact" for r in per_cycle)
    return {"seconds": seconds, "cycles": cycles, "first_cycle": first, "late_controller_cycles": list(late),
            "late_cell_cycles": planned, "per_cycle": per_cycle, "observed_lost_cycles": sorted(observed),
            "missing_soc_in_can_log": missing_soc, "unplanned_lost_cycles": unplanned,
            "planned": len(per_cycle), "judged": n_judged, "not_judged": reasons,
            "planned_exact": exact, "judged_exact_fraction": exact / n_judged if n_judged else None,
            "frames_late": hil["frames_late"], "overruns": hil["overruns"], "cycles_served": cycles,
            "overrun_causes": {k: hil["overrun_causes"][k] for k in ("stalled", "own_work", "other")},
            "longest_overrun_run": hil["longest_overrun_run"],
            "serve_exit": serve.returncode, "serve_stderr_tail": err[-500:] if serve.returncode else "",
            "load_average_before": load_before, "load_average_after": os.getloadavg()}


#: status of a planned late cycle the cell itself started late (or started the cycle before late)
NOT_JUDGED = "not judged: cell late"
#: ... one whose cycle before had no group taken (the cell had dropped the controller's groups: a stall
#: of the controller, or its SoC counter out of step until the cell re-aligns), so k's loss is not k's alone
NOT_JUDGED_NO_GROUP = "not judged: no group taken the cycle before"
#: ... one in which every node's communication fault was latched (the cell counts no missing group then)
NOT_JUDGED_FAULTED = "not judged: drives in fault reaction"


def judge_late_cycles(planned: list[int], observed: dict[int, dict], trips: dict[int, set[int]], soc: set[int],
                      pres: set[int], cell_late: dict[int, float], threshold: int, nodes: int = 6,
                      faulted: set[int] = frozenset()) -> list[dict]:
    """Per planned late cycle k: what POWERLINK specifies against what the served cell did.

    ``observed``: cycle -> {"loss_of_preq"/"loss_of_soc": counter per node} (summary ``hil.lost_cycles``);
    ``trips``: cycle -> nodes whose loss-of-SoC/PReq fault reaction fired; ``soc``/``pres``: cycles with
    the cell's SoC taken / a PRes sent in the CAN log; ``cell_late``: the cell's own overrun cycles ->
    lateness (µs). The expected counter at k follows from the cycles actually lost before k (the
    planned ones and any stall: +8 per lost cycle, -1 per good one) and k itself. A cycle k the cell
    started late (k or k-1 an overrun) is not judged: its window opened late, so a group sent after
    the nominal window may still be in time for it - the controller was not late *for that cell*.
    Nor is a cycle k whose cycle before had no SoC taken (in ``soc``) unless planned too
    (:data:`NOT_JUDGED_NO_GROUP`), or
    one in ``faulted`` (every node's communication fault latched: :data:`NOT_JUDGED_FAULTED`).
    -> rows with ``status`` 'exact', 'DIFFERS' or one of the NOT_JUDGED* reasons."""
    rows = []
    for k in planned:
        history = sorted({c for c in observed if c < k} | {k})
        expected = expected_counters(history, k + 1, threshold=threshold)
        row = observed.get(k, {})
        r = {"cycle": k, "expected_counter": expected["errors"][k],
             "observed_loss_of_preq_counters": row.get("loss_of_preq"),
             "observed_loss_of_soc_counters": row.get("loss_of_soc"),
             "soc_in_can_log": k in soc, "pres_in_can_log": k in pres,
             "expected_trip": k in expected["trips"], "observed_trip_nodes": sorted(trips.get(k, ())),
             "cell_lateness_us": [cell_late.get(k - 1), cell_late.get(k)]}
        exact = (r["observed_loss_of_preq_counters"] == [r["expected_counter"]] * nodes
                 and r["observed_loss_of_soc_counters"] == [r["expected_counter"]] * nodes
                 and not r["soc_in_can_log"] and r["pres_in_can_log"]
                 and r["expected_trip"] == (r["observed_trip_nodes"] == list(range(1, nodes + 1))))
        if k in cell_late or k - 1 in cell_late:
            r["status"] = NOT_JUDGED
        elif k - 1 not in soc and k - 1 not in planned:  # (a planned cycle before: a pair, lost by design)
            r["status"] = NOT_JUDGED_NO_GROUP
        elif k in faulted:
            r["status"] = NOT_JUDGED_FAULTED
        else:
            r["status"] = "exact" if exact else "DIFFERS"
        rows.append(r)
    return rows


def print_late(r: dict) -> None:
    print(f"late controller against cosim serve, {r['cycles']} cycles (first group in cell cycle "
          f"{r['first_cycle']}), load {r['load_average_before'][0]:.2f} -> {r['load_average_after'][0]:.2f}:")
    for row in r["per_cycle"]:
        before, at = (f"{x:.0f} us" if x is not None else "-" for x in row["cell_lateness_us"])
        print(f"  cell cycle {row['cycle']}: counters expected {row['expected_counter']}, observed loss of PReq "
              f"{row['observed_loss_of_preq_counters']}, loss of SoC {row['observed_loss_of_soc_counters']},"
              f" SoC in CAN log {row['soc_in_can_log']}, PRes {row['pres_in_can_log']}, trip expected "
              f"{row['expected_trip']} observed nodes {row['observed_trip_nodes']}; cell overrun before/at "
              f"{before}/{at}: {row['status']}")
    c = r["overrun_causes"]
    print(f"  planned {r['planned']} (of {len(r['late_controller_cycles'])}), judged {r['judged']}, exactly as "
          f"POWERLINK specifies {r['planned_exact']} of {r['judged']} judged; not judged {r['not_judged'] or 0}")
    print(f"  the cell's own overruns: {r['overruns']} in {r['cycles_served']} cycles "
          f"({100 * r['overruns'] / max(r['cycles_served'], 1):.1f} %, longest run {r['longest_overrun_run']}; "
          f"stalled {c['stalled']}, own work {c['own_work']}, other {c['other']}); unplanned lost cycles "
          f"{r['unplanned_lost_cycles']} (stalls); cycles without SoC in the CAN log {len(r['missing_soc_in_can_log'])}"
          f"; late frames dropped {r['frames_late']}")


# ------------------------------------------------------------------ ISO 9283, paced split vs in process
#: The loss-of-SoC/PReq counters off (threshold 0: errors are still counted and logged), so the
#: paced split run completes whatever it loses and its TCP error can be compared (the default
#: 15 trips at two lost cycles in a row; on the loaded machine even 200 tripped on a stall).
ISO_THRESHOLD = 0


#: The ISO 9283 job compared: the rigid-plant variant, whose model_based mode the split-vs-in-process
#: comparison is about (0.0103 mm in process); the main job's elastic plant is scenarios/iso9283.toml.
ISO_SCENARIO = "iso9283_rigid.toml"


def hil_lookahead() -> int:
    """``[fieldbus] setpoint_lookahead`` of scenarios/hil.toml: the set-point look-ahead of the HIL
    configuration (0 when the scenario sets none)."""
    import tomllib

    document = tomllib.loads((ROOT / "scenarios" / "hil.toml").read_text())
    return int(document.get("fieldbus", {}).get("setpoint_lookahead", 0))


def hil_buffer() -> int:
    """``[fieldbus] setpoint_buffer`` of scenarios/hil.toml: the drives' set-point buffer depth of
    the HIL configuration (0 when the scenario sets none)."""
    import tomllib

    document = tomllib.loads((ROOT / "scenarios" / "hil.toml").read_text())
    return int(document.get("fieldbus", {}).get("setpoint_buffer", 0))


def iso_scenario(work: Path, stop_time_s: float | None = None, missing_setpoint: str = "hold",
                 name: str = "iso", lookahead: int = 0, buffer: int = 0) -> Path:
    """scenarios/``ISO_SCENARIO``, model_based mode only, no figures, loss counters at
    ``ISO_THRESHOLD``, the drives' reaction to a missing set-point ``missing_setpoint``
    ('hold' or 'extrapolate'), ``lookahead`` cycles of set-point look-ahead in each PReq,
    a set-point buffer of ``buffer`` cycles in the drives."""
    text = (ROOT / "scenarios" / ISO_SCENARIO).read_text()

    def replace(text: str, pattern: str, new: str) -> str:
        import re

        out, count = re.subn(pattern, new, text, count=1, flags=re.MULTILINE)
        if count != 1:
            raise RuntimeError(f"scenarios/{ISO_SCENARIO}: no line matching {pattern!r} to change")
        return out

    text = replace(text, r"^modes = \[.*$", 'modes = ["model_based"]')
    if stop_time_s is not None:
        text = replace(text, r'^stop_time = ".*"', f'stop_time = "{stop_time_s} s"')
    text = replace(text, r"^figures = true", "figures = false")
    fieldbus = (f"cycle_time_us = 400\nsetpoint_lookahead = {lookahead}\nsetpoint_buffer = {buffer}\n[fieldbus.thresholds]\n"
                f"cn_loss_of_soc = {ISO_THRESHOLD}\ncn_loss_of_preq = {ISO_THRESHOLD}\n[fieldbus.reaction]\n"
                f'missing_setpoint = "{missing_setpoint}"')
    import re

    if re.search(r"^cycle_time_us = 400.*$", text, flags=re.MULTILINE):
        text = replace(text, r"^cycle_time_us = 400.*$", fieldbus)
    else:  # the scenario extends the cell (scenarios/cell.toml: a 400 us cycle) and has no [fieldbus] keys of its own
        text = text.rstrip("\n") + "\n\n[fieldbus]\n" + fieldbus + "\n"
    work.mkdir(parents=True, exist_ok=True)
    path = work / f"{name}.toml"
    path.write_text(text)
    return path


def _run_cosim(args: list[str], timeout: float) -> int:
    """Exit code of ``python -m cosim ARGS --quiet``: 0, or 3 (the run failed, its summary says
    why); anything else raises."""
    import subprocess

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
           "MPLBACKEND": "Agg"}
    done = subprocess.run([sys.executable, "-m", "cosim", *args, "--quiet"], env=env, capture_output=True,
                          text=True, timeout=timeout)
    if done.returncode not in (0, 3):
        raise RuntimeError(f"cosim {' '.join(args)} exited with {done.returncode}: {done.stderr[-1500:]}")
    return done.returncode


def iso_split_run(scenario: Path, out: Path, split: bool) -> dict:
    """One ISO 9283 model_based run, in process (unpaced) or paced split; its TCP errors and,
    split, the timing of both sides and where the lost cycles came from."""
    load_before = os.getloadavg()
    steal0, wall0, per_cpu0 = steal_ms(), time.monotonic(), steal_ms_per_cpu()
    _run_cosim(["run", str(scenario), "--out", str(out)] + (["--split", "--realtime"] if split else []), 900)
    elapsed = time.monotonic() - wall0
    steal = (steal_ms() - steal0) / elapsed
    per_cpu = [(b - a) / elapsed for a, b in zip(per_cpu0, steal_ms_per_cpu())]
    summary = json.loads((out / "summary.json").read_text())
    mode = (summary.get("modes") or {}).get("model_based") or {}
    ok = summary["status"] == "ok"  # a run whose counters tripped has no comparable TCP error
    row = {"tcp_error_max_mm": mode.get("tcp_error_max_mm") if ok else None,
           "tcp_error_rms_mm": mode.get("tcp_error_rms_mm") if ok else None,
           "status": summary["status"], "reason": summary.get("reason"), "steal_ms_per_s": steal,
           "steal_ms_per_s_per_cpu": per_cpu,
           "load_average_before": load_before, "load_average_after": os.getloadavg()}
    if split:
        hil = summary["hil_split"]["model_based"]
        cell = hil["cell_side"] or {}
        if not cell:
            return row
        lost = cell.get("lost_cycles", [])
        lost_cycles = [r["cycle"] for r in lost]
        # a lost cycle the cell started late (its own stall) vs one it started in time (the controller was late)
        overrun_cycles = set(summary.get("realtime", {}).get("overrun_cycles", []))
        cell_side_stall = sum(1 for k in lost_cycles if k in overrun_cycles or k - 1 in overrun_cycles)
        row.update({"cycles": cell["cycles"], "overrun_fraction": cell["overrun_fraction"],
                    "overruns": cell["overruns"], "longest_overrun_run": cell["longest_overrun_run"],
                    "lateness": cell["lateness"], "round_trip_us": hil["round_trip"],
                    "lost_cycles": sum(cell["frames_lost_per_node"].values()) // 6,
                    "lost_fraction": sum(cell["frames_lost_per_node"].values()) / 6 / max(cell["cycles"], 1),
                    "lost_after_cell_overrun": cell_side_stall,
                    "lost_with_cell_in_time": len(lost_cycles) - cell_side_stall,
                    "controller_cycles_skipped": hil["controller_side"]["cycles_skipped"],
                    "controller_cycles_caught_up": hil["controller_side"].get("cycles_caught_up", 0),
                    "controller_stalls_over_one_cycle": hil["controller_side"].get("stalls_over_one_cycle"),
                    "controller_compute_over_one_cycle": hil["controller_side"].get("compute_over_one_cycle"),
                    "cell_overrun_causes": {k: v for k, v in cell.get("overrun_causes", {}).items()
                                            if k in ("stalled", "own_work", "other")},
                    "controller_compute_us": hil["controller_side"]["compute"],
                    "controller_compute_step_us": hil["controller_side"].get("compute_step"),
                    "controller_compute_send_us": hil["controller_side"].get("compute_send"),
                    "controller_wakeup_after_pres_us": hil["controller_side"].get("wakeup_after_pres"),
                    # each lost cycle's cause as the controller side attributes it (cosim.execution.split.paced)
                    "lost_cycle_causes": {k: v for k, v in (hil.get("lost_cycle_causes") or {}).items()
                                          if k != "examples"},
                    "frames_late": cell["frames_late"], "scheduling": hil["controller_side"]["scheduling"],
                    # lost PReqs whose set-point the drives took from the look-ahead, and cycles held
                    "cycles_covered": (cell.get("setpoint_lookahead") or {}).get("cycles_covered", 0),
                    "cycles_held": sum(cell.get("cycles_held_per_node", {}).values()),
                    "lost_runs": _run_lengths(lost_cycles)})
    return row


def _run_lengths(cycles: list[int]) -> dict[str, int]:
    """{length: how many runs of consecutive lost cycles of that length} (the first 1000 listed)."""
    runs: dict[int, int] = {}
    length = 0
    for i, cycle in enumerate(cycles):
        length = length + 1 if i and cycle == cycles[i - 1] + 1 else 1
        if i + 1 == len(cycles) or cycles[i + 1] != cycle + 1:
            runs[length] = runs.get(length, 0) + 1
    return {str(k): v for k, v in sorted(runs.items())}


def iso_split(work: Path, runs: int = 5, stop_time_s: float | None = None, missing_setpoint: str = "hold",
              lookahead: int = 0, buffer: int = 0) -> dict:
    """The HIL comparison figure: ISO 9283 model-based TCP error of the paced split run (our controller
    in this process, ``cosim serve``'s cell in another, 400 µs) against the in-process run;
    ``runs`` split runs, medians."""
    scenario = iso_scenario(work, stop_time_s, missing_setpoint, lookahead=lookahead, buffer=buffer)
    reference = iso_split_run(scenario, work / "in_process", split=False)
    split = [iso_split_run(scenario, work / f"split_{i}", split=True) for i in range(runs)]

    def med(key):
        values = [r[key] for r in split if r.get(key) is not None]
        return statistics.median(values) if values else None

    tcp = med("tcp_error_max_mm")
    completed = sum(1 for r in split if r["status"] == "ok")
    return {"runs": runs, "completed_runs": completed,"stop_time_s": stop_time_s, "missing_setpoint": missing_setpoint, "setpoint_lookahead": lookahead,
            "setpoint_buffer": buffer, "threshold": ISO_THRESHOLD,
            "in_process": reference, "split_runs": split,
            "tcp_error_max_mm_in_process": reference["tcp_error_max_mm"], "tcp_error_max_mm_split": tcp,
            "tcp_error_rms_mm_in_process": reference["tcp_error_rms_mm"], "tcp_error_rms_mm_split": med("tcp_error_rms_mm"),
            "tcp_error_ratio": tcp / reference["tcp_error_max_mm"] if tcp is not None else None,
            "overrun_fraction": med("overrun_fraction"), "lost_fraction": med("lost_fraction"),
            "steal_ms_per_s": med("steal_ms_per_s"),
            "controller_compute_p99_us": statistics.median([r["controller_compute_us"]["p99_us"] for r in split
                                                            if (r.get("controller_compute_us") or {}).get("p99_us")
                                                            is not None] or [float("nan")]),
            "lost_cycle_causes_total": {k: sum((r.get("lost_cycle_causes") or {}).get(k, 0) for r in split)
                                        for k in ("cell_late", "controller_stalled", "controller_compute",
                                                  "transport")},
            "round_trip_p99_us": statistics.median([r["round_trip_us"]["p99_us"] for r in split
                                                    if (r.get("round_trip_us") or {}).get("p99_us") is not None]
                                                   or [float("nan")])}


def print_iso(r: dict) -> None:
    ref = r["in_process"]
    print(f"ISO 9283 model_based, missing set-point '{r['missing_setpoint']}', look-ahead "
          f"{r.get('setpoint_lookahead', 0)} cycles, set-point buffer {r.get('setpoint_buffer', 0)} cycles, "
          f"thresholds {r['threshold']}: "
          f"in process max/RMS TCP error {ref['tcp_error_max_mm']:.4f}/{ref['tcp_error_rms_mm']:.4f} mm")
    for i, x in enumerate(r["split_runs"]):
        if x["status"] != "ok" or "cycles" not in x:
            print(f"  split {i}: {x['status']}: {x.get('reason')}")
            continue
        print(f"  split {i}: max/RMS {x['tcp_error_max_mm']:.4f}/{x['tcp_error_rms_mm']:.4f} mm, {x['cycles']} cycles, "
              f"overruns {100 * x['overrun_fraction']:.3f} %, lost {x['lost_cycles']} ({100 * x['lost_fraction']:.3f} %: "
              f"{x['lost_after_cell_overrun']} after a cell overrun, {x['lost_with_cell_in_time']} with the cell in "
              f"time; controller: PRes waiting > 1 cycle {x['controller_stalls_over_one_cycle']}, steps > 1 cycle "
              f"{x['controller_compute_over_one_cycle']}; causes {x.get('lost_cycle_causes')}; cell overruns "
              f"{x['cell_overrun_causes']}; covered from the look-ahead {x.get('cycles_covered')} node-cycles, "
              f"held {x.get('cycles_held')}; runs of lost cycles by length {x.get('lost_runs')}; controller caught up "
              f"{x.get('controller_cycles_caught_up')} cycles), round trip p50/p99 "
              f"{x['round_trip_us']['p50_us']:.1f}/{x['round_trip_us']['p99_us']:.1f} us, controller compute p50/p99/max "
              f"{x['controller_compute_us']['p50_us']:.1f}/{x['controller_compute_us']['p99_us']:.1f}/"
              f"{x['controller_compute_us']['max_us']:.0f} us, steal {x['steal_ms_per_s']:.1f} ms/s, load "
              f"{x['load_average_before'][0]:.2f} -> {x['load_average_after'][0]:.2f}")
    if r["tcp_error_ratio"] is None:
        print(f"  no split run completed of {r['runs']}")
        return
    print(f"  median of {r['completed_runs']} completed runs of {r['runs']}: split max TCP error "
          f"{r['tcp_error_max_mm_split']:.4f} mm = {r['tcp_error_ratio']:.3g} x in process; "
          f"overruns {100 * r['overrun_fraction']:.3f} %, lost {100 * r['lost_fraction']:.3f} %, controller compute "
          f"p99 {r['controller_compute_p99_us']:.1f} us; lost cycles by cause (all runs) {r['lost_cycle_causes_total']}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--late", action="store_true",
                        help="only the deliberately late controller against cosim serve (LATE_CYCLES)")
    parser.add_argument("--probe", action="store_true",
                        help="only the stall probe: a bare SCHED_FIFO loop's gaps for --seconds (the machine's own stalls)")
    parser.add_argument("--iso", action="store_true",
                        help="only the ISO 9283 model-based TCP error, paced split (--runs) vs in process")
    parser.add_argument("--stop-time", type=float, default=None, help="--iso: seconds of the ISO path (default all)")
    parser.add_argument("--missing-setpoint", choices=("hold", "extrapolate"), default="hold",
                        help="--iso: the drives' reaction to a lost set-point")
    parser.add_argument("--lookahead", type=int, default=0,
                        help="--iso: [fieldbus] setpoint_lookahead, cycles of set-points each PReq carries ahead")
    parser.add_argument("--buffer", type=int, default=0,
                        help="--iso: [fieldbus] setpoint_buffer, the drives' set-point buffer depth in cycles "
                             "(needs --lookahead >= 1)")
    args = parser.parse_args(argv)
    if args.iso:
        import tempfile

        with tempfile.TemporaryDirectory(prefix="bench-hil-iso-") as tmp:
            iso = iso_split(Path(tmp), args.runs, args.stop_time, args.missing_setpoint, args.lookahead, args.buffer)
        print_iso(iso)
        if args.json:
            args.json.write_text(json.dumps(iso, indent=1))
        return 0
    if args.probe:
        print(json.dumps(stall_probe(args.seconds)))
        return 0
    if args.late:
        import tempfile

        with tempfile.TemporaryDirectory(prefix="bench-hil-late-") as tmp:
            late = late_run(Path(tmp))
        print_late(late)
        if args.json:
            args.json.write_text(json.dumps(late, indent=1))
        return 0
    out = run(args.seconds, args.runs)
    for i, r in enumerate(out["runs"]):
        print(f"run {i}: {r['cycles']} cycles, overruns {r['overruns']} ({100 * r['overrun_fraction']:.3f} %), "
              f"longest run {r['longest_overrun_run']}, lateness p50/p99/p99.9/max "
              f"{r['lateness_us']['p50']:.1f}/{r['lateness_us']['p99']:.1f}/{r['lateness_us']['p99_9']:.1f}/"
              f"{r['lateness_us']['max']:.1f} us, round trip p50/p99/max {r['round_trip_us'].get('p50', 0):.1f}/"
              f"{r['round_trip_us'].get('p99', 0):.1f}/{r['round_trip_us'].get('max', 0):.1f} us, "
              f"lost cycles {r['lost_cycles']}, late frames {r['frames_late']}, steal {r['steal_ms_per_s']:.1f} ms/s, "
              f"load {r['load_average_before'][0]:.2f} -> {r['load_average_after'][0]:.2f}")
    m = out["median"]
    print(f"median over {len(out['runs'])} runs: overrun {100 * m['overrun_fraction']:.3f} %, lateness p99 "
          f"{m['lateness_p99_us']:.1f} us, round trip p50/p99 {m['round_trip_p50_us']:.1f}/"
          f"{m['round_trip_p99_us']:.1f} us, lost cycles {m['lost_cycles']}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
