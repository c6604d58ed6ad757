"""The main job end to end: ``python -m cosim run scenarios/iso9283.toml``, the README's first
command after the install, as a user runs it.

Target: at least 6x faster than real time end to end on a quiet machine with two
cores, the tracking figures unchanged to the last digit.

Each run is a fresh ``python -m cosim run`` process (``sys.executable``) into a temporary
results folder. Per run it reports the real-time factor summary.json gives (simulated time
over the wall time from the start of the command's process to its final status:
interpreter start, imports, set-up, the modes, writing, evaluation and figures;
``wall_time_from = "process start"``), the wall time of the whole process as this script
saw it (until the process has exited), the CPU time of the process and its children
(``os.wait4``), the number of mode worker processes (``mode_processes``), the load average
(1 min) before and after, and each mode's ``tcp_error_max_mm``, which must be the same in
every run. Medians over the runs are printed last (``--json`` also writes them).

``--processes N`` sets ``$COSIM_MODE_PROCESSES`` (0: the modes one after another in one
process, the way the job ran before; default: the job's own choice), so the two can be
compared back to back on the same load. ``--env NAME=VALUE`` (repeatable) sets an environment
variable for the runs, e.g. ``COSIM_FIGURE_PROCESS=0`` (figures drawn by the job's own process,
not by the process forked at the command's start) or ``COSIM_MODE_NICENESS=0`` (the main job's
workers all at the same priority), for such comparisons.

Usage::

    python benchmarks/bench_main_job.py [--runs 3] [--processes N] [--scenario scenarios/iso9283.toml]
        [--env NAME=VALUE ...] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "scenarios" / "iso9283.toml"


def one_run(scenario: Path, out: Path, processes: int | None = None,
            extra_env: dict[str, str] | None = None) -> dict[str, Any]:
    """One ``python -m cosim run`` process; its figures (see the module docstring)."""
    env = {**os.environ, "MPLBACKEND": "Agg", **(extra_env or {})}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
    if processes is not None:
        env["COSIM_MODE_PROCESSES"] = str(processes)
    load_before = os.getloadavg()[0]
    started = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "cosim", "run", str(scenario), "--out", str(out), "--quiet"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(proc.pid, 0)
    elapsed = time.perf_counter() - started
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read() if proc.stderr else ""
    if proc.returncode != 0:
        raise RuntimeError(f"cosim run exited with {proc.returncode}: {err.strip()[-2000:]}")
    summary = json.loads((out / "summary.json").read_text())
    return {"realtime_factor": summary["realtime_factor"], "wall_time_s": summary["wall_time_s"],
            "wall_time_from": summary.get("wall_time_from"), "process_wall_s": elapsed,
            "process_realtime_factor": summary["sim_time_s"] / elapsed, "sim_time_s": summary["sim_time_s"],
            "cpu_s": usage.ru_utime + usage.ru_stime, "mode_processes": summary.get("mode_processes"),
            "tcp_error_max_mm": {m: e.get("tcp_error_max_mm") for m, e in summary["modes"].items()},
            "load_before": load_before, "load_after": os.getloadavg()[0]}


def run(runs: int = 3, processes: int | None = None, scenario: Path = SCENARIO,
        extra_env: dict[str, str] | None = None) -> dict[str, Any]:
    """``runs`` runs; per-run figures and medians (raises if the tracking figures differ between runs)."""
    results = []
    with tempfile.TemporaryDirectory(prefix="bench-main-job-") as work:
        for k in range(runs):
            results.append(one_run(Path(scenario), Path(work) / f"run{k}", processes, extra_env))
    figures = {json.dumps(r["tcp_error_max_mm"], sort_keys=True) for r in results}
    if len(figures) != 1:
        raise RuntimeError(f"the tracking figures differ between runs: {figures}")

    def median(key: str) -> float:
        return float(statistics.median(r[key] for r in results))

    return {"runs": results, "median": {key: median(key) for key in (
        "realtime_factor", "wall_time_s", "process_wall_s", "process_realtime_factor", "cpu_s", "load_before",
        "load_after")}, "sim_time_s": results[0]["sim_time_s"], "mode_processes": results[0]["mode_processes"],
        "tcp_error_max_mm": results[0]["tcp_error_max_mm"]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--processes", type=int, default=None, help="$COSIM_MODE_PROCESSES for the runs")
    parser.add_argument("--scenario", type=Path, default=SCENARIO)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--env", action="append", default=[], metavar="NAME=VALUE",
                        help="an environment variable for the runs, e.g. COSIM_FIGURE_PROCESS=0 or "
                             "COSIM_MODE_NICENESS=0 (repeatable)")
    args = parser.parse_args(argv)
    extra_env = {}
    for item in args.env:
        name, sep, value = item.partition("=")
        if not sep or not name:
            parser.error(f"--env {item!r}: expected NAME=VALUE")
        extra_env[name] = value
    out = run(args.runs, args.processes, args.scenario, extra_env)
    print(f"main job ({args.scenario.name}, {out['sim_time_s']:.4g} s simulated, mode processes "
          f"{out['mode_processes']}):")
    print(f"{'run':>4} {'RTF':>6} {'wall':>7} {'process':>8} {'CPU':>7} {'load':>11}")
    for k, r in enumerate(out["runs"]):
        print(f"{k:4d} {r['realtime_factor']:6.2f} {r['wall_time_s']:6.2f}s {r['process_wall_s']:7.2f}s "
              f"{r['cpu_s']:6.2f}s {r['load_before']:5.2f}-{r['load_after']:<5.2f}")
    m = out["median"]
    print(f"median: realtime_factor {m['realtime_factor']:.2f} (summary.json, from the process start to the final "
          f"status), {m['process_realtime_factor']:.2f} by the whole process's wall time ({m['process_wall_s']:.2f} s); "
          f"CPU {m['cpu_s']:.2f} s; load average {m['load_before']:.2f} before, {m['load_after']:.2f} after")
    print("tcp_error_max_mm: " + ", ".join(f"{k} {v!r}" for k, v in out["tcp_error_max_mm"].items()))
    if args.json:
        args.json.write_text(json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
