"""Hardware-in-the-loop timing: the paced cell side and a following controller in two
processes over the ``udpcycle`` interface.

``python benchmarks/bench_hil.py [--seconds 10] [--runs 5]`` runs, per run, a cell-side
process (the POWERLINK controlled nodes of ``fieldbus.DriveEndpoint.run_cycle_paced``,
paced at 400 µs by ``cosim.realtime.pacer.Pacer``) and a controller-side process
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


def _config(channel: str, peer: str, poll: float) -> dict:
    return {"bus": {"interface": "udpcycle", "channel": channel, "receive_timeout_s": 0.05,
                    "options": {"peer": peer, "latency_samples": 1 << 20, "busy_poll_s": poll}}}


def _scaling():
    from fieldbus import JointScaling

    return JointScaling([100.0, 100.0, 80.0, 60.0, 60.0, 50.0], 65536, [350.0, 500.0, 220.0, 35.0, 30.0, 17.0])


def cell_side(seconds: float, ports: tuple[int, int], window_s: float, queue) -> None:
    from cosim.realtime.pacer import Pacer, no_cyclic_gc
    from fieldbus import DriveActuals, DriveEndpoint

    cell, ctrl = ports
    endpoint = DriveEndpoint(_config(f"127.0.0.1:{cell}", f"127.0.0.1:{ctrl}", 0.0), _scaling())
    period = endpoint.config.cycle_time_s
    cycles = int(round(seconds / period))
    pacer = Pacer(period, 150e-6, period - window_s, capacity=cycles + 16)
    actuals = DriveActuals.zeros(6)
    actuals.statusword[:] = 0x27
    queue.put("ready")
    import select

    select.select([endpoint.bus.fileno()], [], [], 120.0)  # start with the controller's first datagram
    from cosim.realtime.pacer import realtime_scheduling

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
    setpoints = Setpoints.zeros(6)
    setpoints.controlword[:] = 0x0F
    endpoint.send_following(setpoints)  # announce: the cell answers with PRes every cycle anyway
    end = time.monotonic() + seconds + 1.0
    skipped = 0
    last = -1
    from cosim.realtime.pacer import no_cyclic_gc, realtime_scheduling

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
    cell = ctx.Process(target=cell_side, args=(seconds, ports, window_s, q_cell))
    cell.start()
    assert q_cell.get(timeout=60) == "ready"
    ctrl = ctx.Process(target=controller_side, args=(seconds, ports, q_ctrl))
    ctrl.start()
    c = q_cell.get(timeout=seconds + 120)
    k = q_ctrl.get(timeout=30)
    cell.join(10)
    ctrl.join(10)
    lateness = np.asarray(c["lateness_us"])
    overrun = np.asarray(c["overrun"], dtype=bool)
    from cosim.hil.cell_side import longest_run

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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    out = run(args.seconds, args.runs)
    for i, r in enumerate(out["runs"]):
        print(f"run {i}: {r['cycles']} cycles, overruns {r['overruns']} ({100 * r['overrun_fraction']:.3f} %), "
              f"longest run {r['longest_overrun_run']}, lateness p50/p99/p99.9/max "
              f"{r['lateness_us']['p50']:.1f}/{r['lateness_us']['p99']:.1f}/{r['lateness_us']['p99_9']:.1f}/"
              f"{r['lateness_us']['max']:.1f} us, round trip p50/p99/max {r['round_trip_us'].get('p50', 0):.1f}/"
              f"{r['round_trip_us'].get('p99', 0):.1f}/{r['round_trip_us'].get('max', 0):.1f} us, "
              f"lost cycles {r['lost_cycles']}, late frames {r['frames_late']}, "
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
