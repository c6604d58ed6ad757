"""Closed-loop speed: plant + six drives + POWERLINK bus + 400 us controller (IK + eq. 7
feed-forward) + 1 ms laser tracker + 1 ms recorder, on the co-simulation master.

Target (issue 5): at least 3x faster than real time on one core (median of 5 runs of
2 simulated seconds of the ISO 9283 path, model-based mode); controller compute p99
<= 100 us.

Each run builds the cell of ``scenarios/iso9283.toml`` (true robot, 100 us macro step,
drive gains, fieldbus defaults) exactly as ``python -m cosim run`` does
(``cosim.jobs.robot_cell.run_cell``), with ``stop_time`` = 2 s, into a temporary
results folder; the CAN log is off unless ``--can-log`` (its BLF encoding is file
output, not loop work). The real-time factor is simulated time / wall time of the
master run (``CellRun.loop_wall_time_s``: initialization + stepping, no
post-processing); the CPU-time factor (process_time) is printed too because the
machine may be shared. Usage::

    python benchmarks/bench_closed_loop.py [--runs 5] [--sim-time 2.0] [--mode model_based] [--can-log]
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TARGET_REALTIME = 3.0
TARGET_P99_US = 100.0


def one_run(sim_time: float, mode: str, can_log: bool, out_dir: Path) -> dict[str, float]:
    from controller import Controller, ControllerConfig, TcpTrajectory
    from cosim.jobs import iso9283, robot_cell
    from cosim.jobs.laser_tracker import TrackerConfig
    from cosim.scenario import RunContext, load_scenario
    from fieldbus import FieldbusConfig
    from planners.iso9283 import ISO_Q_HINT, iso9283_test_path

    scenario = load_scenario(ROOT / "scenarios" / "iso9283.toml")
    doc = scenario.data
    doc["simulation"]["stop_time"] = sim_time
    ctrl_t = doc["controller"]
    period = ctrl_t["period"]
    true_robot = iso9283.make_true_robot(doc["true_robot"])
    path = iso9283_test_path(speed=doc["path"]["speed"], acceleration=doc["path"]["acceleration"])
    reference = TcpTrajectory.from_reference(path.reference, path.duration, period)
    kin, dyn, _, _ = iso9283.controller_models(ctrl_t, true_robot)
    fb = FieldbusConfig.from_dict(doc["fieldbus"])
    config = ControllerConfig(mode=mode, period_s=period, lead_cycles=1 + fb.dead_time_cycles,
                              compute_budget_s=ctrl_t["compute_budget"], settle_time_s=ctrl_t["settle_time"])
    drive_model = robot_cell.drive_loop_model(doc["fmus"], period)
    controller = Controller(reference, config, kinematic_model=kin, dynamics=dyn, q_hint=np.array(ISO_Q_HINT),
                            drive_model=drive_model, capacity=int(sim_time / period) + 16)
    tracker = TrackerConfig(doc["tracker"]["period"], doc["tracker"]["noise_sigma"], doc["tracker"]["seed"])
    ctx = RunContext(scenario, out_dir, quiet=True)
    cpu0 = time.process_time()
    cell = robot_cell.run_cell(doc, controller, true_robot, ctx, label=mode, stop_time=sim_time, fieldbus=fb,
                               tracker=tracker, record_file="timeseries.csv",
                               can_log=out_dir / "can.blf" if can_log else None)
    cpu = time.process_time() - cpu0
    if cell.failure is not None:
        raise cell.failure
    timing = controller.timing()
    return {"realtime": cell.reached_s / cell.loop_wall_time_s, "cpu_realtime": cell.reached_s / cpu,
            "p50": timing.p50_us, "p99": timing.p99_us, "max": timing.max_us, "misses": timing.deadline_misses,
            "cpu_p50": timing.cpu_p50_us, "cpu_p99": timing.cpu_p99_us,
            "cycles": timing.cycles, "engine": cell.engine}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--sim-time", type=float, default=2.0, help="simulated seconds per run")
    parser.add_argument("--mode", default="model_based", choices=("standard", "model_based"))
    parser.add_argument("--can-log", action="store_true", help="also write the CAN log (BLF)")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_closed_loop-") as tmp:
        for k in range(args.runs):
            r = one_run(args.sim_time, args.mode, args.can_log, Path(tmp) / f"run{k}")
            rows.append(r)
            print(f"run {k + 1}: {r['realtime']:.2f}x real time (wall), {r['cpu_realtime']:.2f}x (CPU time); "
                  f"controller p50 {r['p50']:.1f} us, p99 {r['p99']:.1f} us, max {r['max']:.0f} us "
                  f"(CPU p50 {r['cpu_p50']:.1f}, p99 {r['cpu_p99']:.1f}), "
                  f"{r['misses']} of {r['cycles']} cycles over budget; engine {r['engine']}")
    med = {k: statistics.median(r[k] for r in rows)
           for k in ("realtime", "cpu_realtime", "p50", "p99", "cpu_p50", "cpu_p99")}
    print(f"\nclosed loop ({args.mode}, {args.sim_time:g} s simulated, median of {args.runs}):")
    print(f"  real-time factor      {med['realtime']:.2f}x (wall)   {med['cpu_realtime']:.2f}x (CPU time)"
          f"   target >= {TARGET_REALTIME:g}x: {'MET' if med['realtime'] >= TARGET_REALTIME else 'MISSED'}")
    print(f"  controller compute    p50 {med['p50']:.1f} us   p99 {med['p99']:.1f} us"
          f"   target p99 <= {TARGET_P99_US:g} us: {'MET' if med['p99'] <= TARGET_P99_US else 'MISSED'}")
    print(f"  controller CPU time   p50 {med['cpu_p50']:.1f} us   p99 {med['cpu_p99']:.1f} us (thread_time_ns)")


if __name__ == "__main__":
    main()
