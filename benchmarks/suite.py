"""The performance suite behind ``python -m cosim bench [--out DIR] [--quick]``.

Every figure of the project's performance claims, measured in one run on the machine it runs on,
each a median over repeated runs, with the machine described and the ratios against
the baselines computed from the same run. The timing code is the benchmarks' own
(``bench_closed_loop``, ``bench_fieldbus``, ``bench_fmu``, ``bench_planners_cp``,
``bench_calibration.selection_problem``, ``bench_identification``); this module only
chooses the problem sizes and repetitions, collects the numbers, writes ``bench.json``
and prints a table.

Sections (keys of ``bench.json["figures"]``):

=====================  ==================================================================
closed_loop            in-process cell (ISO 9283 path, model-based, rigid plant): wall/CPU
                       real-time factor, controller compute p50/p99 (wall, µs)
closed_loop_elastic    the main job's cell (elastic plant, true geometry), modes model_based
                       and model_based_elastic: the same figures per mode
closed_loop_split      the same cell split over two processes (udp_multicast): RTF of the
                       cycles (without process start-up), start-up time
paced                  the in-process cell paced at 400 µs (10 s runs): overrun fraction,
                       lateness p99
controller_port        the user-controller contract: its overhead per cycle for a plain-Python
                       controller (isolated, 20 µs of own work), and the closed loop with the
                       built-in vs a user controller (real-time factors)
bus                    one POWERLINK cycle with six nodes (simbus, no recording): µs
fmu                    plant and drive doStep (fast path, 100 µs and 400 µs steps): µs; the
                       plant also as the main job runs it (elastic joints, 100 µs sub-steps)
planners               own CP vs TOPP-RA (paper line, 200 intervals), own PtP vs Ruckig
                       (plain and torque-feasible) between the line's end poses: solve
                       times and trajectory durations
calibration            selecting 32 of the campaign's visible candidates (min eigenvalue)
identification         base regressor + weighted least squares on a record
hil                    the paced cell side and a following controller in two processes over
                       udpcycle at 400 µs: overruns, lateness, frame round trip, lost cycles;
                       a deliberately late controller against cosim serve (expected vs
                       observed counters); ISO 9283 model-based TCP error, paced split vs
                       in process (drives holding / extrapolating a missing set-point)
memory                 peak RSS of a short and a 10x longer run, each in a fresh process and
                       measured in that process (VmHWM), not inherited from the suite:
                       the plain-FMU job and the robot cell (ISO path, then holding;
                       benchmarks/bench_memory.py): ratio long/short (target <= 1.10)
cli                    ``python -m cosim --help`` in fresh processes: wall and CPU time of the
                       whole process (the import cost every command pays)
main_job               ``python -m cosim run scenarios/iso9283.toml`` end to end, fresh
                       processes (benchmarks/bench_main_job.py): summary.json's real-time
                       factor (from the process start), the whole process's, its CPU time
output                 the main job's files (benchmarks/bench_output.py): size of each, the
                       total and its ratio to the 128 MB CSV output; write CPU per mode
                       (CAN log columnar vs BLF, time series compact vs plain) and of the
                       run's report.html
report                 report.html of a synthesized 600 s run at 1 ms (benchmarks/bench_report.py):
                       its size, cosim view's time, and in headless Chromium the time to
                       interactive (target < 5 s), to the 3D view, and of a zoom to every sample
=====================  ==================================================================

``ratios``: own CP / TOPP-RA solve time and duration, own PtP / ruckig_feasible
duration and solve time, in-process / split real-time factor.

The results page: :func:`results_page` writes every figure of ``bench.json`` as Markdown (the
machine, its load average before and after, the date and git commit, each section's
description from the table above and its figures with units, the ratios);
``python -m cosim bench`` writes it beside ``bench.json`` and, for a full run of every section,
to ``benchmarks/RESULTS.md`` (the "Benchmark results" page of the docs site).

BLAS runs single-threaded during the suite (threadpoolctl). Wall times on a shared
machine depend on its load: ``machine.load_average`` (before) and
``load_average_after`` say how busy it was; CPU times are given where the benchmark
measures them.
"""
from __future__ import annotations

import json
import math
import os
import platform
import statistics
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

BENCH_DIR = Path(__file__).resolve().parent
ROOT = BENCH_DIR.parent
if str(BENCH_DIR) not in sys.path:
    sys.path.insert(0, str(BENCH_DIR))
os.environ.setdefault("MPLBACKEND", "Agg")


@dataclass(frozen=True)
class Sizes:
    """Problem sizes and repetitions of one suite run."""

    repeats: int
    closed_loop_sim_s: float
    split_sim_s: float
    paced_sim_s: float
    bus_cycles: int
    fmu_batches: int
    cp_intervals: int
    ptp_intervals: int
    calibration_candidates: int | None
    calibration_grid: int | None
    calibration_restarts: int
    identification_samples: int
    hil_seconds: float = 10.0
    hil_runs: int = 5
    hil_late_seconds: float = 2.5
    main_job_runs: int = 3
    main_job_stop_time: str | None = None  # None: the scenario's own (12.6 s per mode)
    hil_late_cycles: tuple[int, ...] = (1500, 2500, 3500, 4500, 4501)
    hil_iso_runs: int = 5
    hil_iso_stop_time_s: float | None = None  # the whole ISO 9283 path (12.6 s)
    hil_iso_without_lookahead: bool = True  # also the runs without the set-point look-ahead (for comparison)
    memory_short_s: float = 60.0
    memory_long_s: float = 600.0
    report_seconds: float = 600.0
    report_runs: int = 5


FULL = Sizes(repeats=3, closed_loop_sim_s=2.0, split_sim_s=0.4, paced_sim_s=10.0, bus_cycles=5000, fmu_batches=60,
             cp_intervals=200, ptp_intervals=100, calibration_candidates=None, calibration_grid=None, calibration_restarts=5,
             identification_samples=5000)
QUICK = Sizes(repeats=1, closed_loop_sim_s=0.1, split_sim_s=0.04, paced_sim_s=0.1, bus_cycles=300, fmu_batches=3,
              cp_intervals=30, ptp_intervals=20, calibration_candidates=300, calibration_grid=7, calibration_restarts=1,
              identification_samples=300, hil_seconds=0.3, hil_runs=1, hil_late_seconds=1.2,
              hil_late_cycles=(500, 1200, 1201), hil_iso_runs=1, hil_iso_stop_time_s=0.6, memory_short_s=1.0,
              memory_long_s=3.0, main_job_runs=1,
              main_job_stop_time="0.3 s", report_seconds=10.0, report_runs=1)


def _median(values: list[float]) -> float:
    return float(statistics.median(values))


# ------------------------------------------------------------------------------------ machine
def machine() -> dict[str, Any]:
    """CPU model, cores, OS, Python and library versions, load average now."""
    import can
    import casadi
    import fmpy
    import numpy
    import pinocchio
    import scipy

    model = platform.processor() or "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    return {"cpu_model": model, "logical_cpus": os.cpu_count(), "cpus_usable": affinity,
            "platform": platform.platform(), "python": platform.python_version(), "numpy": numpy.__version__,
            "scipy": scipy.__version__, "pinocchio": pinocchio.__version__, "casadi": casadi.__version__,
            "fmpy": fmpy.__version__, "python_can": can.__version__,
            "load_average": [round(x, 2) for x in os.getloadavg()]}


def git_state() -> dict[str, Any]:
    """The commit of the checkout the suite runs from and whether tracked files differ from it
    (None values when it is not a git checkout)."""
    import subprocess

    def git(*args: str) -> str | None:
        try:
            done = subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True, timeout=30)
        except (OSError, subprocess.SubprocessError):
            return None
        return done.stdout.strip() if done.returncode == 0 else None

    commit = git("rev-parse", "HEAD")
    status = git("status", "--porcelain", "--untracked-files=no") if commit else None
    return {"commit": commit, "dirty": None if status is None else bool(status)}


# ------------------------------------------------------------------------------------ sections
def closed_loop(sizes: Sizes, work: Path) -> dict[str, Any]:
    """bench_closed_loop.one_run, median over runs."""
    import bench_closed_loop

    runs = [bench_closed_loop.one_run(sizes.closed_loop_sim_s, "model_based", False, work / f"cl{k}")
            for k in range(sizes.repeats)]
    return {"sim_time_s": sizes.closed_loop_sim_s, "runs": sizes.repeats,
            "realtime_factor": _median([r["realtime"] for r in runs]),
            "cpu_realtime_factor": _median([r["cpu_realtime"] for r in runs]),
            "controller_compute_p50_us": _median([r["p50"] for r in runs]),
            "controller_compute_p99_us": _median([r["p99"] for r in runs]),
            "controller_cpu_p99_us": _median([r["cpu_p99"] for r in runs]),
            "engine": runs[0]["engine"]}


def closed_loop_elastic(sizes: Sizes, work: Path) -> dict[str, Any]:
    """bench_closed_loop.one_run on the main job's cell (scenarios/iso9283.toml: elastic plant),
    modes model_based and model_based_elastic, median over runs each."""
    import bench_closed_loop

    out: dict[str, Any] = {"sim_time_s": sizes.closed_loop_sim_s, "runs": sizes.repeats,
                           "scenario": bench_closed_loop.ELASTIC_SCENARIO.name}
    for mode in ("model_based", "model_based_elastic"):
        runs = [bench_closed_loop.one_run(sizes.closed_loop_sim_s, mode, False, work / f"{mode}{k}",
                                          bench_closed_loop.ELASTIC_SCENARIO) for k in range(sizes.repeats)]
        out[f"{mode}_realtime_factor"] = _median([r["realtime"] for r in runs])
        out[f"{mode}_cpu_realtime_factor"] = _median([r["cpu_realtime"] for r in runs])
        out[f"{mode}_controller_compute_p50_us"] = _median([r["p50"] for r in runs])
        out[f"{mode}_controller_compute_p99_us"] = _median([r["p99"] for r in runs])
    return out


def closed_loop_split(sizes: Sizes, work: Path) -> dict[str, Any]:
    """The bench_closed_loop cell split over two processes (cosim.execution.split), unpaced."""
    import bench_closed_loop

    from cosim.execution.config import ExecutionOptions
    from cosim.scenario import RunContext
    from cosim.execution import run_cell

    rtf, startup = [], []
    for k in range(sizes.repeats):
        scenario, cell, controller = bench_closed_loop.build(sizes.split_sim_s, "model_based")
        ctx = RunContext(scenario, work / f"split{k}", quiet=True)
        cell = run_cell(cell, controller, ctx, mode="split", options=ExecutionOptions(mode="split"))
        info = cell.split
        if cell.failure is not None:
            raise cell.failure
        rtf.append(info["loop_realtime_factor"])
        startup.append(cell.loop_wall_time_s - info["loop_wall_s"])
    return {"sim_time_s": sizes.split_sim_s, "runs": sizes.repeats, "realtime_factor": _median(rtf),
            "cycle_wall_us": 400.0 / _median(rtf), "startup_s": _median(startup), "interface": "udp_multicast"}


def paced(sizes: Sizes, work: Path) -> dict[str, Any]:
    """Paced in-process runs (400 µs, hold policy, SCHED_FIFO and one pinned CPU when granted):
    medians over runs of the overrun fraction and the lateness p99, and every run's figures."""
    import bench_closed_loop

    from cosim.execution import run_cell
    from cosim.execution.config import ExecutionOptions, RealtimeSettings
    from cosim.execution.timing.stats import lateness_summary, load_average
    from cosim.scenario import RunContext

    runs = []
    for k in range(sizes.repeats):
        scenario, cell, controller = bench_closed_loop.build(sizes.paced_sim_s, "model_based")
        ctx = RunContext(scenario, work / f"paced{k}", quiet=True)
        load = load_average()
        cell = run_cell(cell, controller, ctx, mode="paced",
                        options=ExecutionOptions(realtime=True, settings=RealtimeSettings()))
        pacer, granted = cell.pacer, cell.scheduling
        s = lateness_summary(pacer.log, pacer.thresholds)
        runs.append({"cycles": s["cycles"], "overruns": s["overruns"], "overrun_fraction": s["overrun_fraction"],
                     "late_fraction": s["late_fraction"], "thresholds_us": s["thresholds_us"],
                     "missed_ticks": s["missed_ticks"], "lateness_p50_us": s["lateness"]["p50_us"],
                     "lateness_p99_us": s["lateness"]["p99_us"], "lateness_max_us": s["lateness"]["max_us"],
                     "cycle_work_p50_us": s["cycle_work"]["p50_us"], "cycle_work_p99_us": s["cycle_work"]["p99_us"],
                     "scheduling": granted, "load_average_before": load, "completed": cell.failure is None})
    return {"sim_time_s": sizes.paced_sim_s, "policy": "hold", "runs": runs, "cycles": runs[0]["cycles"],
            "overrun_fraction": _median([r["overrun_fraction"] for r in runs]),
            "lateness_p50_us": _median([r["lateness_p50_us"] for r in runs]),
            "lateness_p99_us": _median([r["lateness_p99_us"] for r in runs]),
            "cycle_work_p50_us": _median([r["cycle_work_p50_us"] for r in runs]),
            "scheduling": runs[0]["scheduling"]}


def controller_port(sizes: Sizes, work: Path) -> dict[str, Any]:
    """bench_controller_port: the contract's overhead per cycle for a plain-Python user controller
    (isolated, 20 us of its own work), and the closed loop with the built-in vs a user controller."""
    import bench_controller_port

    iso = bench_controller_port.port_overhead(cycles=sizes.bus_cycles * 4, work_us=20.0)
    cells = bench_controller_port.closed_loop(sizes.closed_loop_sim_s)
    builtin, user = cells["builtin_model_based"], cells["user_python_pd"]
    return {"overhead_p50_us": iso["overhead_p50_us"], "overhead_p99_us": iso["overhead_p99_us"],
            "user_own_p50_us": iso["controller_own_p50_us"], "port_step_p50_us": iso["port_step_p50_us"],
            "builtin_realtime_factor": builtin["realtime_factor"], "user_realtime_factor": user["realtime_factor"],
            "builtin_wall_us_per_cycle": builtin["wall_us_per_cycle"],
            "user_wall_us_per_cycle": user["wall_us_per_cycle"],
            "user_controller_own_mean_us": user["controller_own_mean_us"],
            "user_overhead_in_cell_us": user["overhead_in_cell_us"],
            "user_port_overhead_in_cell_p50_us": user["port_overhead_in_cell_p50_us"]}


def bus(sizes: Sizes, work: Path) -> dict[str, Any]:
    """bench_fieldbus.measure: one six-node cycle on simbus without recording, median of runs."""
    import bench_fieldbus

    runs = [bench_fieldbus.measure({}, None, sizes.bus_cycles) for _ in range(sizes.repeats)]
    slot = bench_fieldbus.asynchronous_slot(sizes.bus_cycles, sizes.repeats)
    return {"cycles": sizes.bus_cycles, "cycle_median_us": _median([r["median"] for r in runs]),
            "cycle_p90_us": _median([r["p90"] for r in runs]), "cycle_cpu_us": _median([r["cpu"] for r in runs]),
            # the asynchronous slot (fieldbus.asynchronous): idle vs an SDO in flight every cycle, same bus
            "cycle_without_od_median_us": slot["without"], "cycle_async_idle_median_us": slot["idle"],
            "cycle_sdo_in_flight_median_us": slot["in_flight"],
            "async_load_average": [round(slot["load_before"], 2), round(slot["load_after"], 2)]}


def fmu(sizes: Sizes, work: Path) -> dict[str, Any]:
    """bench_fmu.bench_plant / bench_drive: doStep of the fast path (and fmpy for reference), µs."""
    import bench_fmu

    from fmus.build import ensure_fmus

    paths = ensure_fmus()
    out: dict[str, Any] = {"batches": sizes.fmu_batches}
    for name, fn, path in (("plant", bench_fmu.bench_plant, paths["rx130l_plant"]),
                           ("drive", bench_fmu.bench_drive, paths["servo_drive"])):
        rows = [fn(path, sizes.fmu_batches) for _ in range(sizes.repeats)]
        for h in (100, 400):
            label = f"{name} doStep {h} us"
            fast = _median([dict((r[0], r[2]) for r in run)[label] for run in rows])
            slow = _median([dict((r[0], r[1]) for r in run)[label] for run in rows])
            out[f"{name}_step_{h}us_us"] = fast
            out[f"{name}_step_{h}us_fmpy_us"] = slow
    rows = [bench_fmu.bench_plant(paths["rx130l_plant"], sizes.fmu_batches, bench_fmu.ELASTIC_PLANT)
            for _ in range(sizes.repeats)]
    for h in (100, 400):  # the main job's plant: elastic joints, 100 us RK4 sub-steps
        out[f"plant_elastic_step_{h}us_us"] = _median([dict((r[0], r[2]) for r in run)[f"plant doStep {h} us"]
                                                       for run in rows])
    return out


def planners(sizes: Sizes, work: Path) -> dict[str, Any]:
    """Own CP vs TOPP-RA on the paper line (bench_planners_cp._median_runs); own PtP vs Ruckig
    between the line's end poses."""
    import bench_planners_cp

    from planners.base import JointLimits, PtPProblem
    from planners.cp_optimal import OwnCPPlanner
    from planners.paper_line import paper_cp_problem, paper_line_configurations
    from planners.ptp_optimal import OptimalPtPPlanner
    from planners.ruckig_baseline import FeasibleRuckigPlanner, RuckigPlanner
    from planners.toppra_baseline import ToppraPlanner
    from robot.dynamics import RobotDynamics

    dyn = RobotDynamics()
    out: dict[str, Any] = {"cp_intervals": sizes.cp_intervals, "ptp_intervals": sizes.ptp_intervals}
    cp = paper_cp_problem(dynamics=dyn, friction="full", kinematic_only_limits=True, n_intervals=sizes.cp_intervals)
    for key, planner in (("own_cp", OwnCPPlanner()), ("toppra", ToppraPlanner())):
        result, solve, build = bench_planners_cp._median_runs(planner, cp, sizes.repeats)
        out[f"{key}_solve_s"] = solve
        out[f"{key}_build_s"] = build
        out[f"{key}_duration_s"] = result.trajectory.duration
        out[f"{key}_status"] = result.status.name.lower()
    q0, qe = paper_line_configurations()
    ptp = PtPProblem(q0, qe, JointLimits.from_robot(), dynamics=dyn, n_intervals=sizes.ptp_intervals)
    own_ptp = OptimalPtPPlanner(compile_code=sizes.ptp_intervals >= 50)  # tiny problems: no gcc compile
    for key, planner in (("own_ptp", own_ptp), ("ruckig", RuckigPlanner()),
                         ("ruckig_feasible", FeasibleRuckigPlanner())):
        result, solve, build = bench_planners_cp._median_runs(planner, ptp, sizes.repeats)
        out[f"{key}_solve_s"] = solve
        out[f"{key}_duration_s"] = result.trajectory.duration
        out[f"{key}_status"] = result.status.name.lower()
    return out


def calibration(sizes: Sizes, work: Path) -> dict[str, Any]:
    """bench_calibration.selection_problem (the campaign's candidates), then
    ``select_configurations`` of 32 (min eigenvalue) timed per run, median."""
    import inspect

    import bench_calibration

    from calibration.config_selection import select_configurations
    from calibration.optical_tracker import TrackerSetup

    grid = {}
    if sizes.calibration_grid is not None and "values_per_axis" in inspect.signature(
            bench_calibration.selection_problem).parameters:
        grid["values_per_axis"] = sizes.calibration_grid
    _, theta = bench_calibration.selection_problem(TrackerSetup(), sizes.calibration_candidates, **grid)
    walls, cpus = [], []
    for seed in range(sizes.repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        select_configurations(theta, 32, index="min_eigenvalue", restarts=sizes.calibration_restarts, seed=seed)
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    return {"candidates": int(theta.shape[0]), "selected": 32, "restarts": sizes.calibration_restarts,
            "selection_s": _median(walls), "selection_cpu_s": _median(cpus)}


def identification(sizes: Sizes, work: Path) -> dict[str, Any]:
    """bench_identification.bench_identify: base regressor + WLS."""
    import bench_identification

    return bench_identification.bench_identify(sizes.identification_samples, max(sizes.repeats, 1))


def hil(sizes: Sizes, work: Path) -> dict[str, Any]:
    """Paced cell side + following controller in two processes over udpcycle at 400 µs
    (benchmarks/bench_hil.py): medians over runs of the overrun fraction, the lateness p99,
    the frame round trip p50/p99 and the lost cycles; every run's figures with its load.
    Then a deliberately late controller against ``cosim serve`` (FMUs, CAN log): per late
    cycle the expected and observed lost frames and threshold counters."""
    import bench_hil

    probe = bench_hil.stall_probe(min(sizes.hil_seconds, 8.0))  # the machine's own stalls, for context
    out = bench_hil.run(sizes.hil_seconds, sizes.hil_runs)
    m = out["median"]
    late = bench_hil.late_run(work / "late", sizes.hil_late_seconds, sizes.hil_late_cycles)
    # the ISO comparison in the HIL configuration of scenarios/hil.toml: drives extrapolating a
    # missing set-point, our controller sending the set-point look-ahead (docs/explanation/timing.md)
    lookahead, buffer = bench_hil.hil_lookahead(), bench_hil.hil_buffer()
    iso = bench_hil.iso_split(work / "iso", sizes.hil_iso_runs, sizes.hil_iso_stop_time_s, "extrapolate", lookahead,
                              buffer)
    extra: dict[str, Any] = {"iso_setpoint_lookahead": lookahead, "iso_setpoint_buffer": buffer}
    if sizes.hil_iso_without_lookahead and lookahead:
        plain = bench_hil.iso_split(work / "iso_no_lookahead", sizes.hil_iso_runs, sizes.hil_iso_stop_time_s,
                                    "extrapolate", 0)
        extra.update({"iso_no_lookahead_tcp_error_max_mm_split": plain["tcp_error_max_mm_split"],
                      "iso_no_lookahead_tcp_error_ratio": plain["tcp_error_ratio"],
                      "iso_no_lookahead_lost_fraction": plain["lost_fraction"], "iso_no_lookahead": plain})
    m_iso = iso["tcp_error_ratio"]
    # the HIL targets (meant for a quiet machine): <= 1 % overruns, round trip p99
    # <= 100 us, ISO error within 10 %
    targets = {"overruns_at_most_1_percent": m["overrun_fraction"] is not None and m["overrun_fraction"] <= 0.01,
               "round_trip_p99_at_most_100_us": m["round_trip_p99_us"] is not None and m["round_trip_p99_us"] <= 100.0,
               "iso_tcp_error_within_10_percent": m_iso is not None and abs(m_iso - 1.0) <= 0.10}
    return {"seconds": sizes.hil_seconds, "runs": out["runs"], "overrun_fraction": m["overrun_fraction"],
            "longest_overrun_run": m["longest_overrun_run"], "lateness_p99_us": m["lateness_p99_us"],
            "round_trip_p50_us": m["round_trip_p50_us"], "round_trip_p99_us": m["round_trip_p99_us"],
            "lost_cycles": m["lost_cycles"],
            "late_planned_cycles": len(late["per_cycle"]), "late_judged_cycles": late["judged"],
            "late_exact_cycles": late["planned_exact"], "late_exact_fraction": late["judged_exact_fraction"],
            "late_unplanned_lost_cycles": len(late["unplanned_lost_cycles"]), "late": late,
            "iso_tcp_error_max_mm_in_process": iso["tcp_error_max_mm_in_process"],
            "iso_tcp_error_max_mm_split": iso["tcp_error_max_mm_split"], "iso_tcp_error_ratio": iso["tcp_error_ratio"],
            "iso_overrun_fraction": iso["overrun_fraction"], "iso_lost_fraction": iso["lost_fraction"],
            "iso_round_trip_p99_us": iso["round_trip_p99_us"], "iso_steal_ms_per_s": iso["steal_ms_per_s"],
            "iso_controller_compute_p99_us": iso.get("controller_compute_p99_us"),
            "iso_lost_cycle_causes": iso.get("lost_cycle_causes_total"),
            "issue_targets_met": targets, **extra,
            "probe_gaps_over_1ms_per_s": probe["gaps_over_1ms"] / probe["seconds"],
            "probe_gap_ms_per_s": probe["gap_total_ms"] / probe["seconds"], "stall_probe": probe, "iso_completed_runs": iso["completed_runs"], "iso": iso}


def memory(sizes: Sizes, work: Path) -> dict[str, Any]:
    """bench_memory.measure: peak RSS (MiB) of the plain-FMU job, of the robot cell and of the
    identification job's ISO validation run (its fieldbus recording included) at
    ``memory_short_s`` and ``memory_long_s`` simulated seconds, each run in a fresh
    interpreter and measured in its own process (VmHWM: not the suite's pages, which the
    child's ``ru_maxrss`` carries, reported beside it), and the ratios long/short
    (everything streams: ``*_within_target`` when <= 1.10; ``targets_met``)."""
    import bench_memory

    work.mkdir(parents=True, exist_ok=True)
    out: dict[str, Any] = {"short_s": sizes.memory_short_s, "long_s": sizes.memory_long_s}
    # --quick: the cell only (each run is a fresh interpreter; the plain-FMU and identification figures
    # are the full suite's)
    for job in ("fmus", "cell", "identification") if sizes.repeats > 1 else ("cell",):
        r = bench_memory.measure(sizes.memory_short_s, sizes.memory_long_s, job=job, folder=work)
        out.update({f"{job}_short_peak_rss_mib": r["short_peak_rss_mib"],
                    f"{job}_long_peak_rss_mib": r["long_peak_rss_mib"], f"{job}_ratio": r["ratio"],
                    f"{job}_within_target": r["within_target"], f"{job}_long_wall_s": r["long_wall_s"],
                    f"{job}_short_ru_maxrss_mib": r["short_ru_maxrss_mib"],
                    f"{job}_long_ru_maxrss_mib": r["long_ru_maxrss_mib"]})
    out["ratio_target"] = bench_memory.RATIO_TARGET
    out["targets_met"] = all(v for k, v in out.items() if k.endswith("_within_target"))
    return out


def main_job(sizes: Sizes, work: Path) -> dict[str, Any]:
    """bench_main_job.run: the main job end to end in fresh processes, medians over runs."""
    import bench_main_job

    scenario = bench_main_job.SCENARIO
    if sizes.main_job_stop_time is not None:
        text = scenario.read_text(encoding="utf-8")
        old = 'stop_time = "12.6 s"'
        if old not in text:
            raise RuntimeError(f"{scenario}: no {old!r} to shorten")
        work.mkdir(parents=True, exist_ok=True)
        scenario = work / "iso9283_short.toml"
        scenario.write_text(text.replace(old, f'stop_time = "{sizes.main_job_stop_time}"', 1), encoding="utf-8")
    out = bench_main_job.run(sizes.main_job_runs, None, scenario)
    m = out["median"]
    return {"runs": sizes.main_job_runs, "sim_time_s": out["sim_time_s"], "realtime_factor": m["realtime_factor"],
            "process_realtime_factor": m["process_realtime_factor"], "wall_time_s": m["wall_time_s"],
            "process_wall_s": m["process_wall_s"], "cpu_s": m["cpu_s"], "mode_processes": out["mode_processes"],
            "tcp_error_max_mm": out["tcp_error_max_mm"], "load_before": m["load_before"],
            "load_after": m["load_after"]}


def output(sizes: Sizes, work: Path) -> dict[str, Any]:
    """bench_output.measure: the main job's files, their total against the 128 MB CSV output,
    the write CPU per mode (medians over the modes)."""
    import bench_output

    work.mkdir(parents=True, exist_ok=True)
    out = bench_output.measure(repeats=sizes.repeats, stop_time=sizes.main_job_stop_time)
    modes = out["modes"].values()

    def med(group: str, key: str) -> float:
        return _median([m[group][key] for m in modes])
    return {"total_mb": out["total_mb"], "ratio_to_csv_128mb": out["ratio_to_csv_128mb"],
            "can_columnar_cpu_s": med("can", "columnar_cpu_s"), "can_blf_cpu_s": med("can", "blf_cpu_s"),
            "series_cpu_s": med("series", "cpu_s"), "report_cpu_s": out["report_cpu_s"],
            "files": out["files"], "load_average": list(out["load_average"])}


def report(sizes: Sizes, work: Path) -> dict[str, Any]:
    """bench_report.measure: report.html of a synthesized run of ``report_seconds`` at 1 ms opened
    ``report_runs`` times in headless Chromium (medians)."""
    import bench_report

    out = bench_report.measure(sizes.report_seconds, sizes.report_runs)
    return {key: out[key] for key in ("seconds", "runs", "report_mb", "view_wall_s", "view_cpu_s",
                                      "interactive_s_median", "interactive_first_s", "scene_s_median",
                                      "zoom_s_median", "target_s",
                                      "load_average_before", "load_average_after")}


def cli(sizes: Sizes, work: Path) -> dict[str, Any]:
    """``python -m cosim --help`` in fresh processes (the interpreter itself, no PATH shim): the
    median wall and CPU time of the whole process over 10 runs per repeat, and the load average."""
    import resource
    import subprocess

    walls, cpus = [], []
    load_before = os.getloadavg()[0]
    for _ in range(10 * sizes.repeats):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "cosim", "--help"], check=True, capture_output=True)
        walls.append(time.perf_counter() - t0)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return {"help_wall_s": _median(walls), "help_wall_max_s": max(walls), "help_cpu_s": _median(cpus),
            "runs": len(walls), "load_before": load_before, "load_after": os.getloadavg()[0]}


SECTIONS: dict[str, Callable[[Sizes, Path], dict[str, Any]]] = {
    "closed_loop": closed_loop, "closed_loop_elastic": closed_loop_elastic, "closed_loop_split": closed_loop_split,
    "paced": paced,
    "controller_port": controller_port, "bus": bus, "fmu": fmu,
    "planners": planners, "calibration": calibration, "identification": identification, "hil": hil,
    "memory": memory,
    "main_job": main_job,
    "cli": cli,
    "output": output,
    "report": report,
}

#: The figures bench.json must hold (section -> keys), checked by the test and by run_suite.
REQUIRED: dict[str, tuple[str, ...]] = {
    "closed_loop": ("realtime_factor", "cpu_realtime_factor", "controller_compute_p50_us",
                    "controller_compute_p99_us"),
    "closed_loop_elastic": ("model_based_realtime_factor", "model_based_cpu_realtime_factor",
                            "model_based_elastic_realtime_factor", "model_based_elastic_cpu_realtime_factor"),
    "closed_loop_split": ("realtime_factor", "startup_s"),
    "paced": ("overrun_fraction", "lateness_p99_us"),
    "controller_port": ("overhead_p50_us", "builtin_realtime_factor", "user_realtime_factor"),
    "bus": ("cycle_median_us",),
    "fmu": ("plant_step_100us_us", "plant_step_400us_us", "plant_elastic_step_100us_us", "drive_step_100us_us",
            "drive_step_400us_us"),
    "planners": ("own_cp_solve_s", "toppra_solve_s", "own_cp_duration_s", "toppra_duration_s", "own_ptp_solve_s",
                 "ruckig_solve_s", "ruckig_feasible_solve_s", "own_ptp_duration_s", "ruckig_feasible_duration_s"),
    "calibration": ("selection_s",),
    "identification": ("identification_s",),
    "hil": ("overrun_fraction", "lateness_p99_us", "round_trip_p99_us", "late_judged_cycles", "late_exact_cycles",
            "iso_tcp_error_ratio"),
    "memory": ("cell_ratio", "cell_short_peak_rss_mib", "cell_long_peak_rss_mib"),
    "main_job": ("realtime_factor", "process_realtime_factor", "cpu_s"),
    "cli": ("help_wall_s", "help_cpu_s"),
    "output": ("total_mb", "ratio_to_csv_128mb", "can_columnar_cpu_s", "can_blf_cpu_s", "series_cpu_s",
               "report_cpu_s"),
    "report": ("report_mb", "view_cpu_s", "interactive_s_median", "scene_s_median", "zoom_s_median"),
}
RATIOS = ("own_cp_vs_toppra_solve_time", "own_cp_vs_toppra_duration", "own_ptp_vs_ruckig_feasible_duration",
          "own_ptp_vs_ruckig_feasible_solve_time", "in_process_vs_split_realtime_factor")


def ratios(figures: dict[str, dict[str, Any]]) -> dict[str, float | None]:
    """Ratios against the baselines, from this run's figures (None when a figure is missing)."""
    def get(section: str, key: str) -> float | None:
        value = figures.get(section, {}).get(key)
        return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None

    def ratio(a: float | None, b: float | None) -> float | None:
        return a / b if a is not None and b else None

    return {
        "own_cp_vs_toppra_solve_time": ratio(get("planners", "own_cp_solve_s"), get("planners", "toppra_solve_s")),
        "own_cp_vs_toppra_duration": ratio(get("planners", "own_cp_duration_s"), get("planners", "toppra_duration_s")),
        "own_ptp_vs_ruckig_feasible_duration": ratio(get("planners", "own_ptp_duration_s"),
                                                     get("planners", "ruckig_feasible_duration_s")),
        "own_ptp_vs_ruckig_feasible_solve_time": ratio(get("planners", "own_ptp_solve_s"),
                                                       get("planners", "ruckig_feasible_solve_s")),
        "in_process_vs_split_realtime_factor": ratio(get("closed_loop", "realtime_factor"),
                                                     get("closed_loop_split", "realtime_factor")),
    }


def missing_figures(result: dict[str, Any]) -> list[str]:
    """'section.key' of every required figure that is absent or not a finite number."""
    out = []
    for section, keys in REQUIRED.items():
        for key in keys:
            value = result.get("figures", {}).get(section, {}).get(key)
            if not (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)):
                out.append(f"{section}.{key}")
    for key in RATIOS:
        value = result.get("ratios", {}).get(key)
        if not (isinstance(value, (int, float)) and math.isfinite(value)):
            out.append(f"ratios.{key}")
    return out


def run_suite(out_dir: str | Path, quick: bool = False, sections: list[str] | None = None,
              log: Callable[[str], None] = print) -> dict[str, Any]:
    """Run the suite (all sections or ``sections``), write ``out_dir/bench.json``, return its content."""
    sizes = QUICK if quick else FULL
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    result: dict[str, Any] = {"suite": "cosim bench", "quick": quick, "started_at": time.strftime(
        "%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "sizes": sizes.__dict__, "machine": machine(), "figures": {},
        "section_wall_s": {}, "errors": {}, "git": git_state()}
    t_start = time.perf_counter()
    from threadpoolctl import threadpool_limits

    # single-threaded BLAS: the problems are small, and on a shared 2-core machine BLAS
    # threads spinning against other processes multiply wall times (seen: 36 s vs 1.1 s)
    with tempfile.TemporaryDirectory(prefix="cosim-bench-") as tmp, threadpool_limits(1):
        for name, fn in SECTIONS.items():
            if sections and name not in sections:
                continue
            log(f"[bench] {name} ...")
            t0 = time.perf_counter()
            try:
                result["figures"][name] = fn(sizes, Path(tmp) / name)
            except Exception as exc:  # one broken section must not hide the others' figures
                result["errors"][name] = f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=4)}"
                log(f"[bench] {name} FAILED: {type(exc).__name__}: {exc}")
            result["section_wall_s"][name] = time.perf_counter() - t0
    result["ratios"] = ratios(result["figures"])
    result["wall_time_s"] = time.perf_counter() - t_start
    result["machine"]["load_average_after"] = [round(x, 2) for x in os.getloadavg()]
    result["missing"] = missing_figures(result) if not sections else []
    (out_dir / "bench.json").write_text(json.dumps(result, indent=2, default=str) + "\n")
    return result


# ------------------------------------------------------------------------------------ table
ROWS: tuple[tuple[str, str, str, str], ...] = (
    ("closed_loop", "realtime_factor", "closed-loop real-time factor, in-process (wall)", "x"),
    ("closed_loop", "cpu_realtime_factor", "closed-loop real-time factor, in-process (CPU time)", "x"),
    ("closed_loop_elastic", "model_based_realtime_factor", "elastic plant, model_based: real-time factor (wall)", "x"),
    ("closed_loop_elastic", "model_based_cpu_realtime_factor", "elastic plant, model_based: (CPU time)", "x"),
    ("closed_loop_elastic", "model_based_elastic_realtime_factor",
     "elastic plant, model_based_elastic: real-time factor (wall)", "x"),
    ("closed_loop_elastic", "model_based_elastic_cpu_realtime_factor", "elastic plant, model_based_elastic: (CPU time)",
     "x"),
    ("closed_loop_split", "realtime_factor", "closed-loop real-time factor, split (cycles only)", "x"),
    ("closed_loop_split", "startup_s", "split: drive process start-up", "s"),
    ("closed_loop", "controller_compute_p50_us", "controller compute p50 (wall)", "us"),
    ("closed_loop", "controller_compute_p99_us", "controller compute p99 (wall)", "us"),
    ("paced", "overrun_fraction", "paced 400 us in-process: overrun fraction", ""),
    ("paced", "lateness_p99_us", "paced 400 us in-process: lateness p99", "us"),
    ("bus", "cycle_median_us", "POWERLINK cycle, 6 nodes (simbus)", "us"),
    ("bus", "cycle_async_idle_median_us", "POWERLINK cycle, idle asynchronous slot (SDO/NMT)", "us"),
    ("bus", "cycle_sdo_in_flight_median_us", "POWERLINK cycle, an SDO in flight every cycle", "us"),
    ("fmu", "plant_step_100us_us", "plant FMU doStep 100 us", "us"),
    ("fmu", "plant_step_400us_us", "plant FMU doStep 400 us", "us"),
    ("fmu", "plant_elastic_step_100us_us", "plant FMU doStep 100 us, elastic (main job)", "us"),
    ("fmu", "drive_step_100us_us", "drive FMU doStep 100 us", "us"),
    ("fmu", "drive_step_400us_us", "drive FMU doStep 400 us", "us"),
    ("planners", "own_cp_solve_s", "own CP solve (paper line)", "s"),
    ("planners", "toppra_solve_s", "TOPP-RA solve (paper line)", "s"),
    ("planners", "own_ptp_solve_s", "own PtP solve", "s"),
    ("planners", "ruckig_solve_s", "Ruckig solve", "s"),
    ("planners", "ruckig_feasible_solve_s", "Ruckig torque-feasible solve", "s"),
    ("planners", "own_cp_duration_s", "own CP trajectory duration", "s"),
    ("planners", "toppra_duration_s", "TOPP-RA trajectory duration", "s"),
    ("planners", "own_ptp_duration_s", "own PtP trajectory duration", "s"),
    ("planners", "ruckig_feasible_duration_s", "Ruckig torque-feasible duration", "s"),
    ("calibration", "selection_s", "calibration: select 32 configurations", "s"),
    ("identification", "identification_s", "identification: regressor + WLS", "s"),
    ("memory", "fmus_ratio", "peak RSS long/short run, plain-FMU job", "x"),
    ("memory", "cell_ratio", "peak RSS long/short run, robot cell", "x"),
    ("memory", "cell_long_peak_rss_mib", "peak RSS of the long robot-cell run", "MiB"),
    ("main_job", "realtime_factor", "main job end to end (summary.json, from process start)", "x"),
    ("main_job", "process_realtime_factor", "main job, whole process wall time", "x"),
    ("main_job", "cpu_s", "main job CPU time (all processes)", "s"),
    ("cli", "help_wall_s", "python -m cosim --help, whole process (median)", "s"),
    ("cli", "help_cpu_s", "python -m cosim --help, CPU time (median)", "s"),
    ("output", "total_mb", "main job output, all files", "MB"),
    ("output", "ratio_to_csv_128mb", "main job output: 128 MB CSV / total", "x"),
    ("output", "can_columnar_cpu_s", "CAN log write CPU per mode, columnar", "s"),
    ("output", "can_blf_cpu_s", "CAN log write CPU per mode, BLF", "s"),
    ("output", "series_cpu_s", "time series write CPU per mode", "s"),
    ("output", "report_cpu_s", "the run's report.html (all modes): write CPU time", "s"),
    ("report", "report_mb", "report.html of a 600 s run at 1 ms (synthesized)", "MB"),
    ("report", "view_cpu_s", "cosim view of it, CPU time", "s"),
    ("report", "interactive_s_median", "its report in headless Chromium: open to interactive (target < 5 s)", "s"),
    ("report", "interactive_first_s", "its report: the first open of a just-started browser, to interactive", "s"),
    ("report", "scene_s_median", "its report: open to the 3D view built (WebGL; software-rendered headless)", "s"),
    ("report", "zoom_s_median", "its report: zoom to 2 s at every sample", "s"),
    ("hil", "probe_gap_ms_per_s", "hil: machine stalls of a bare SCHED_FIFO loop (probe)", "ms/s"),
    ("hil", "probe_gaps_over_1ms_per_s", "hil: probe gaps over 1 ms", "1/s"),
    ("hil", "overrun_fraction", "hil: paced split 400 us, cell overrun fraction", ""),
    ("hil", "lateness_p99_us", "hil: cell cycle lateness p99", "us"),
    ("hil", "round_trip_p50_us", "hil: frame round trip p50", "us"),
    ("hil", "round_trip_p99_us", "hil: frame round trip p99", "us"),
    ("hil", "lost_cycles", "hil: lost cycles per run", ""),
    ("hil", "late_exact_fraction", "hil: late controller, planned cycles exactly as specified", ""),
    ("hil", "late_unplanned_lost_cycles", "hil: late controller, unplanned lost cycles", ""),
    ("hil", "iso_overrun_fraction", "hil: ISO 9283 paced split, cell overrun fraction", ""),
    ("hil", "iso_lost_fraction", "hil: ISO 9283 paced split, lost cycles fraction", ""),
    ("hil", "iso_round_trip_p99_us", "hil: ISO 9283 paced split, frame round trip p99", "us"),
    ("hil", "iso_steal_ms_per_s", "hil: ISO 9283 paced split, CPU time stolen by the hypervisor", "ms/s"),
    ("hil", "iso_tcp_error_max_mm_in_process", "hil: ISO 9283 model-based max TCP error, in process", "mm"),
    ("hil", "iso_tcp_error_max_mm_split", "hil: ISO 9283 model-based max TCP error, paced split", "mm"),
    ("hil", "iso_tcp_error_ratio", "hil: ISO 9283 max TCP error, split / in process", "x"),
    ("hil", "iso_no_lookahead_tcp_error_ratio", "hil: the same without the set-point look-ahead", "x"),
)


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return "-" if value is None else str(value)


def format_table(result: dict[str, Any]) -> str:
    """The figures and ratios as an aligned text table, machine first."""
    m = result["machine"]
    lines = [f"machine: {m['cpu_model']}, {m['cpus_usable']} usable of {m['logical_cpus']} CPUs, "
             f"Python {m['python']}, numpy {m['numpy']}, load average {m['load_average']} -> "
             f"{m.get('load_average_after')}",
             f"{'figure':58s} {'median':>12s}  unit"]
    for section, key, label, unit in ROWS:
        lines.append(f"{label:58s} {_fmt(result['figures'].get(section, {}).get(key)):>12s}  {unit}")
    lines.append("ratios (same run):")
    for key, value in result["ratios"].items():
        lines.append(f"  {key:56s} {_fmt(value):>12s}")
    targets = result["figures"].get("hil", {}).get("issue_targets_met")
    if targets:
        lines.append("hil targets (meant for a quiet machine): " + ", ".join(
            f"{key} {'yes' if ok else 'NO'}" for key, ok in targets.items()))
    for name, error in result["errors"].items():
        lines.append(f"ERROR in {name}: {error.splitlines()[0]}")
    lines.append(f"suite wall time {result['wall_time_s']:.1f} s ({'quick' if result['quick'] else 'full'}); "
                 f"repetitions {result['sizes']['repeats']}")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------ results page
#: The page ``cosim bench`` writes for a full run of every section (the docs site's "Benchmark results").
RESULTS_PAGE = BENCH_DIR / "RESULTS.md"
RATIO_LABELS = {
    "own_cp_vs_toppra_solve_time": "own CP / TOPP-RA, solve time",
    "own_cp_vs_toppra_duration": "own CP / TOPP-RA, trajectory duration",
    "own_ptp_vs_ruckig_feasible_duration": "own PtP / Ruckig torque-feasible, trajectory duration",
    "own_ptp_vs_ruckig_feasible_solve_time": "own PtP / Ruckig torque-feasible, solve time",
    "in_process_vs_split_realtime_factor": "in-process / split real-time factor",
}
#: Units of figures without a row in :data:`ROWS`, by the end of their key (first match).
UNIT_SUFFIXES = (("_ms_per_s", "ms/s"), ("_per_s", "1/s"), ("_us", "µs"), ("_ms", "ms"), ("_mib", "MiB"),
                 ("_mb", "MB"), ("_mm", "mm"), ("_rad", "rad"), ("_hz", "Hz"), ("realtime_factor", "x"),
                 ("_ratio", "x"), ("ratio_target", "x"), ("_s", "s"), ("seconds", "s"))


def section_descriptions() -> dict[str, str]:
    """Each section's description: the table of this module's docstring (one text per section)."""
    out: dict[str, str] = {}
    lines = __doc__.splitlines()
    rules = [k for k, line in enumerate(lines) if line.strip() and set(line.strip()) <= {"=", " "}]
    name = None
    for line in lines[rules[0] + 1:rules[-1]]:
        if not line.strip():
            continue
        if not line.startswith(" "):
            name, _, text = line.partition(" ")
            out[name] = text.strip()
        elif name:
            out[name] += " " + line.strip()
    return {k: v.replace("``", "`") for k, v in out.items()}


def _leaves(value: Any, prefix: str = "") -> list[tuple[str, Any]]:
    """(dotted key, value) of every scalar or list of scalars in ``value``; the objects of a list
    (e.g. each run's figures) as ``key[i].name``."""
    if isinstance(value, dict):
        return [leaf for k, v in value.items() for leaf in _leaves(v, f"{prefix}.{k}" if prefix else str(k))]
    if isinstance(value, (list, tuple)) and any(isinstance(v, (dict, list, tuple)) for v in value):
        return [leaf for i, v in enumerate(value) for leaf in _leaves(v, f"{prefix}[{i}]")]
    return [(prefix, value)]


def page_value(value: Any) -> str:
    """A figure as the page shows it: numbers to 4 significant digits (integers whole), lists of
    numbers in brackets, text on one line."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return f"{value:.4g}" if math.isfinite(value) else str(value)
    if value is None:
        return "-"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(page_value(v) for v in value) + "]"
    text = str(value).strip().splitlines()
    text = text[-1] if text else ""
    return (text[:77] + "...") if len(text) > 80 else text


def _unit(section: str, key: str) -> str:
    row = next((r for r in ROWS if r[0] == section and r[1] == key), None)
    if row is not None:
        return "µs" if row[3] == "us" else row[3]
    if key.split(".")[-2:-1] == ["files"]:
        return "bytes"
    last = key.split(".")[-1].lower()
    return next((unit for suffix, unit in UNIT_SUFFIXES if last.endswith(suffix)), "")


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def results_page(result: dict[str, Any]) -> str:
    """The results page of one suite run (``bench.json``'s content) as Markdown: the machine and
    load, the date and commit, the ratios, then each section's description and every figure."""
    m = result.get("machine", {})
    git = result.get("git") or {}
    sizes = result.get("sizes", {})
    load0, load1 = m.get("load_average"), m.get("load_average_after")
    usable = m.get("cpus_usable") or m.get("logical_cpus")
    lines = [
        "# Benchmark results", "",
        "<!-- written by `python -m cosim bench` from its bench.json (benchmarks/suite.py, results_page); "
        "do not edit: run the suite again -->", "",
        "What `python -m cosim bench` measured in one run on one machine: every figure of its `bench.json`, "
        "each a median over the section's repeated runs unless its key says otherwise. Wall-clock figures "
        "depend on how busy the machine was: the load average before and after the run is given below, "
        "CPU-time figures less so. Run `python -m cosim bench` to measure your machine; "
        "`python -m cosim bench --page-from results/bench/bench.json` writes this page again from a "
        "`bench.json`.", ""]
    if result.get("quick"):
        lines += ["**A `--quick` run**: tiny problems, one repetition each. It shows that every figure is "
                  "produced; its numbers are not the project's performance.", ""]
    busy = [x for x in (load0, load1) if isinstance(x, list) and x and usable and x[0] > usable]
    if busy:
        lines += [f"**A busy machine**: the 1-minute load average was above its {usable} usable CPUs "
                  f"({page_value(load0)} before, {page_value(load1)} after): wall-clock figures are slower "
                  f"than on a quiet machine.", ""]
    commit = git.get("commit")
    rows = [("date (UTC)", result.get("started_at", "-")),
            ("git commit", (f"`{commit}`" + (" (with uncommitted changes)" if git.get("dirty") else ""))
             if commit else "not recorded"),
            ("CPU", m.get("cpu_model", "-")),
            ("cores", f"{m.get('cpus_usable', '-')} usable of {m.get('logical_cpus', '-')} logical CPUs"),
            ("platform", m.get("platform", "-")),
            ("software", ", ".join(f"{k} {m[k]}" for k in ("python", "numpy", "scipy", "pinocchio", "casadi",
                                                           "fmpy", "python_can") if k in m)),
            ("load average before (1, 5, 15 min)", page_value(load0)),
            ("load average after (1, 5, 15 min)", page_value(load1)),
            ("suite", f"{'quick' if result.get('quick') else 'full'}, repetitions: {sizes.get('repeats', '-')}, "
                      f"{page_value(result.get('wall_time_s'))} s wall time"),
            ("sections run", ", ".join(result.get("figures", {})) or "none")]
    lines += ["## Machine and run", "", "| | |", "|---|---|"]
    lines += [f"| {name} | {_cell(str(value))} |" for name, value in rows]
    lines += ["", "## Ratios (same run)", "", "| ratio | key | value |", "|---|---|---:|"]
    for key, value in (result.get("ratios") or {}).items():
        lines.append(f"| {RATIO_LABELS.get(key, key)} | `ratios.{key}` | {page_value(value)} |")
    problems = [f"section `{name}` failed: {_cell(page_value(error.splitlines()[0]))}"
                for name, error in (result.get("errors") or {}).items()]
    problems += [f"missing figure `{key}`" for key in result.get("missing") or []]
    if problems:
        lines += ["", "## Not measured", ""] + [f"- {p}" for p in problems]
    descriptions = section_descriptions()
    for section, figures in (result.get("figures") or {}).items():
        wall = (result.get("section_wall_s") or {}).get(section)
        lines += ["", f"## {section}", "", descriptions.get(section, "(no description)")
                  + (f" The section took {page_value(wall)} s." if isinstance(wall, (int, float)) else ""), "",
                  "| figure | key | value | unit |", "|---|---|---:|---|"]
        leaves = dict(_leaves(figures))
        labelled = [(r[1], r[2]) for r in ROWS if r[0] == section and r[1] in leaves]
        order = labelled + [(k, "") for k in leaves if k not in dict(labelled)]
        for key, label in order:
            lines.append(f"| {_cell(label)} | `{section}.{key}` | {_cell(page_value(leaves[key]))} | "
                         f"{_unit(section, key)} |")
    return "\n".join(lines) + "\n"


def write_results_page(result: dict[str, Any], path: str | Path) -> Path:
    """Write :func:`results_page` of ``result`` to ``path``; return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(results_page(result), encoding="utf-8")
    return path


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results") / "bench")
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    print(format_table(run_suite(args.out, args.quick)))
