"""Closed-loop speed: plant + six drives + POWERLINK bus + 400 us controller (IK + eq. 7
feed-forward) + 1 ms laser tracker + 1 ms recorder, on the co-simulation master.

Target: at least 3x faster than real time on one core (median of 5 runs of
2 simulated seconds of the ISO 9283 path, model-based mode); controller compute p99
<= 100 us.

Each run builds the cell of ``scenarios/iso9283_rigid.toml`` (the main job on the rigid plant,
the suite's closed_loop section of benchmarks/RESULTS.md; ``--scenario scenarios/iso9283.toml``:
the main job itself, elastic plant) (true robot, macro step, plant
parameters, drive gains and the mode's drive speed feed-forward, fieldbus defaults)
exactly as ``python -m cosim run`` does (``cosim.execution.mode_runs.prepare`` and ``mode_cell``
as ``run_mode`` uses them, ``cosim.execution.run_cell``), with ``stop_time`` = 2 s, into a
temporary results folder; the CAN log is off unless ``--can-log`` (its BLF encoding is
file output, not loop work), and the time-series CSV is written after the loop.

Printed per run and as medians:

* real-time factor = simulated time / wall time of the loop (``CellRun.loop_wall_time_s``:
  fieldbus set-up, master initialization and stepping; no post-processing), and the same
  with the loop's CPU time of this process (``CellRun.loop_cpu_time_s``, process_time) -
  the machine is shared, so the wall figure depends on what else runs; the load average
  (1 min) before and after each run is printed with it;
* the controller's compute time per cycle, wall clock (perf_counter_ns) and thread CPU
  time (thread_time_ns), p50 / p99 / max, and the cycles over the 100 us budget.

``--breakdown`` adds one more run in which the loop's parts are wrapped with a thread
CPU-time clock (fieldbus ``run_cycle``, ``Controller.step``, the stepping kernel
``advance`` = the seven FMUs, the tracker task, the recorder's ``sample``/``flush``; the
rest of ``Master.run`` is the master's own Python and the fieldbus task's glue). Each
wrapper costs two ``thread_time_ns`` calls (about 1-2 us per wrapper at load 0.6-0.9),
so the parts
add up to more than an unwrapped run. Each part is exclusive of the other parts nested
in it (the recorder's flush inside its sample). Shown per 400 us controller cycle.

Usage::

    python benchmarks/bench_closed_loop.py [--runs 5] [--sim-time 2.0] [--mode model_based] [--can-log] [--breakdown]
        [--scenario scenarios/iso9283.toml]   # the main job: elastic plant (modes incl. model_based_elastic)
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_REALTIME = 3.0
TARGET_P99_US = 100.0


SCENARIO = ROOT / "scenarios" / "iso9283_rigid.toml"
"""The default cell: the main job's path, robot and drives on the rigid plant (the figures of
the suite's closed_loop, closed_loop_split and paced sections)."""
ELASTIC_SCENARIO = ROOT / "scenarios" / "iso9283.toml"
"""The main job: the elastic plant (the suite's closed_loop_elastic section)."""


def build(sim_time: float, mode: str, can_log: Path | None = None, scenario_path: Path | None = None):
    """Scenario, cell description and built-in controller of one run:
    ``cosim.execution.mode_runs.prepare`` and ``mode_cell`` (as ``run_mode``); ``scenario_path``
    defaults to :data:`SCENARIO`."""
    import dataclasses

    from cosim.execution.mode_runs import mode_cell, prepare
    from cosim.scenario import load_scenario

    scenario = load_scenario(scenario_path or SCENARIO)
    doc = scenario.data
    doc["simulation"]["stop_time"] = sim_time
    doc["controller"]["modes"] = [mode]
    setup = prepare(doc, str(scenario.path))
    cell, controller = mode_cell(setup, mode)
    return scenario, dataclasses.replace(cell, can_log=can_log), controller


def one_run(sim_time: float, mode: str, can_log: bool, out_dir: Path,
            scenario_path: Path | None = None) -> dict[str, float]:
    """One closed-loop run; real-time factors, controller timing, load average."""
    from cosim.execution import run_cell
    from cosim.scenario import RunContext

    scenario, cell, controller = build(sim_time, mode, out_dir / "can.blf" if can_log else None, scenario_path)
    ctx = RunContext(scenario, out_dir, quiet=True)
    load_before = os.getloadavg()[0]
    cell = run_cell(cell, controller, ctx, mode="in_process")
    load_after = os.getloadavg()[0]
    if cell.failure is not None:
        raise cell.failure
    timing = controller.timing()
    return {"realtime": cell.reached_s / cell.loop_wall_time_s, "cpu_realtime": cell.reached_s / cell.loop_cpu_time_s,
            "p50": timing.p50_us, "p99": timing.p99_us, "max": timing.max_us, "misses": timing.deadline_misses,
            "cpu_p50": timing.cpu_p50_us, "cpu_p99": timing.cpu_p99_us, "cpu_max": timing.cpu_max_us,
            "cycles": timing.cycles, "engine": cell.engine, "load_before": load_before, "load_after": load_after}


class _PartClock:
    """Wraps methods so each call's thread CPU time is added to a named part, exclusive
    of the wrapped calls nested in it (e.g. the recorder's flush inside its sample)."""

    def __init__(self) -> None:
        self.ns: dict[str, int] = {}
        self.calls: dict[str, int] = {}
        self._restore: list[tuple[type, str, Callable]] = []
        self._nested = [0]

    def wrap(self, cls: type, name: str, part: str) -> None:
        original = getattr(cls, name)
        self.ns.setdefault(part, 0)
        self.calls.setdefault(part, 0)
        clock, ns, calls, nested = time.thread_time_ns, self.ns, self.calls, self._nested

        def timed(obj, *args, **kwargs):
            nested.append(0)
            t0 = clock()
            try:
                return original(obj, *args, **kwargs)
            finally:
                spent = clock() - t0
                ns[part] += spent - nested.pop()
                nested[-1] += spent
                calls[part] += 1

        setattr(cls, name, timed)
        self._restore.append((cls, name, original))

    def restore(self) -> None:
        for cls, name, original in reversed(self._restore):
            setattr(cls, name, original)
        self._restore.clear()


def breakdown(sim_time: float, mode: str, out_dir: Path) -> tuple[dict[str, tuple[float, float]], int]:
    """Thread CPU time per part of the loop, µs per controller cycle and per call."""
    from controller import Controller
    from cosim.tracking.laser_tracker import LaserTracker
    from cosim.master import engines, master, recorder
    from fieldbus import PowerlinkNetwork

    clock = _PartClock()
    clock.wrap(master.Master, "run", "total (Master.run)")
    clock.wrap(PowerlinkNetwork, "run_cycle", "fieldbus run_cycle")
    clock.wrap(Controller, "step", "controller step")
    clock.wrap(engines.NativeEngine, "advance", "FMUs (stepping kernel)")
    clock.wrap(engines.PythonEngine, "advance", "FMUs (stepping kernel)")
    clock.wrap(LaserTracker, "__call__", "laser tracker task")
    clock.wrap(recorder.Recorder, "sample", "recorder sample")
    clock.wrap(recorder.Recorder, "flush", "recorder flush (sinks)")
    try:
        r = one_run(sim_time, mode, False, out_dir)
    finally:
        clock.restore()
    cycles = sim_time / 4e-4
    rest = clock.ns.pop("total (Master.run)")
    clock.calls.pop("total (Master.run)")
    parts = {k: (v * 1e-3 / cycles, v * 1e-3 / max(clock.calls[k], 1)) for k, v in clock.ns.items()}
    parts["master + task glue (rest)"] = (rest * 1e-3 / cycles, float("nan"))
    parts["total (Master.run)"] = ((rest + sum(clock.ns.values())) * 1e-3 / cycles, float("nan"))
    return parts, r["load_after"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--sim-time", type=float, default=2.0, help="simulated seconds per run")
    parser.add_argument("--mode", default="model_based",
                        choices=("standard", "standard_speed_ff", "model_based", "model_based_elastic"))
    parser.add_argument("--scenario", type=Path, default=SCENARIO,
                        help="an iso9283-job scenario (default: scenarios/iso9283_rigid.toml, the rigid plant; "
                             "scenarios/iso9283.toml: the main job, elastic plant)")
    parser.add_argument("--can-log", action="store_true", help="also write the CAN log (BLF)")
    parser.add_argument("--breakdown", action="store_true", help="one more run with a CPU-time breakdown per part")
    args = parser.parse_args()
    globals()["SCENARIO"] = args.scenario.resolve()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_closed_loop-") as tmp:
        one_run(0.05, args.mode, False, Path(tmp) / "warm-up")  # builds kernels/FMUs if needed, warms caches
        for k in range(args.runs):
            r = one_run(args.sim_time, args.mode, args.can_log, Path(tmp) / f"run{k}")
            rows.append(r)
            print(f"run {k + 1}: {r['realtime']:.2f}x real time (wall), {r['cpu_realtime']:.2f}x (CPU time); "
                  f"controller p50 {r['p50']:.1f} us, p99 {r['p99']:.1f} us, max {r['max']:.0f} us "
                  f"(CPU p50 {r['cpu_p50']:.1f}, p99 {r['cpu_p99']:.1f}, max {r['cpu_max']:.0f}), "
                  f"{r['misses']} of {r['cycles']} cycles over budget; load average {r['load_before']:.1f} -> "
                  f"{r['load_after']:.1f}; engine {r['engine']}", flush=True)
        parts = breakdown(args.sim_time, args.mode, Path(tmp) / "breakdown") if args.breakdown else None
    med = {k: statistics.median(r[k] for r in rows)
           for k in ("realtime", "cpu_realtime", "p50", "p99", "max", "cpu_p50", "cpu_p99", "cpu_max", "misses",
                     "load_before", "load_after")}
    cycles = rows[0]["cycles"]
    print(f"\nclosed loop ({args.scenario.name}, {args.mode}, {args.sim_time:g} s simulated, median of {args.runs}; "
          f"load average {med['load_before']:.1f} -> {med['load_after']:.1f} on {os.cpu_count()} cores):")
    print(f"  real-time factor        {med['realtime']:.2f}x (wall)   {med['cpu_realtime']:.2f}x (CPU time)"
          f"   target >= {TARGET_REALTIME:g}x: wall {'MET' if med['realtime'] >= TARGET_REALTIME else 'MISSED'}, "
          f"CPU {'MET' if med['cpu_realtime'] >= TARGET_REALTIME else 'MISSED'}")
    print(f"  controller wall time    p50 {med['p50']:.1f} us   p99 {med['p99']:.1f} us   max {med['max']:.0f} us"
          f"   target p99 <= {TARGET_P99_US:g} us: {'MET' if med['p99'] <= TARGET_P99_US else 'MISSED'}"
          f" ({med['misses']:.0f} of {cycles} cycles over budget)")
    print(f"  controller CPU time     p50 {med['cpu_p50']:.1f} us   p99 {med['cpu_p99']:.1f} us   "
          f"max {med['cpu_max']:.0f} us (thread_time_ns)"
          f"   p99 <= {TARGET_P99_US:g} us: {'MET' if med['cpu_p99'] <= TARGET_P99_US else 'MISSED'}")
    if parts is not None:
        table, load = parts
        print(f"\nthread CPU time per 400 us cycle (one instrumented run, load average {load:.1f}):")
        for name, (per_cycle, per_call) in table.items():
            call = f"   ({per_call:.1f} us per call)" if per_call == per_call else ""
            print(f"  {name:28s} {per_cycle:7.1f} us{call}")
        print(f"  budget for 3x real time     {400.0 / TARGET_REALTIME:7.1f} us")


if __name__ == "__main__":
    main()
