"""Memory of a long run stays flat: peak RSS of the same streaming run at two lengths.

Two jobs (``--job``):

``fmus`` (default)
    the plain-FMU job (the plant FMU, 18 signals recorded every 1 ms, 1 ms macro step);
``cell``
    the robot cell (scenarios/iso9283_rigid.toml, the main job on the rigid plant, one mode - ``model_based`` -
    through controller, POWERLINK-timed fieldbus, six drive FMUs and the plant FMU, laser
    tracker at 1 ms): the ISO 9283 path (12.2 s), then the arm holds its end pose under
    control until the stop time. Every series streams to disk (recording, controller log at
    400 us, TCP series) with bounded buffers and the evaluation reads them back in chunks
    (cosim.cell.evaluation). ``--can-log`` adds the BLF CAN log (its writer is another process,
    whose memory is not in the figure).
``identification``
    the identification job's ISO 9283 validation run (scenarios/identification.toml, nominal
    model, no campaign: ``cosim.jobs.identification.run_validation_path``): the cell run as
    above plus the controller PC's fieldbus recording of the validation (position and torque
    actual every 400 us), which holds the path's duration only, however long the stop time.

Each length runs once for ``--short`` and once for ``--long`` simulated seconds (default
60 s and 600 s) in a fresh interpreter (``python -m cosim run`` with ``COSIM_SUPERVISE=0``, so
that the run is that process and not a child of the supervisor; started by
:func:`run_measured`); the figure is each run's own peak resident memory: the ``VmHWM`` of
``/proc/self/status`` the run's process reads as it exits (the high-water mark of its own
address space, which starts at the ``exec`` of the fresh interpreter). The ``ru_maxrss`` that
``wait4`` gives for the child is not that figure: Linux carries the forking process's resident
size into it (the high-water mark of the address space the child had before its ``exec``), so
from a large parent (the suite) every run looked as large as the parent; it is reported as
``*_ru_maxrss_mib`` for comparison. With the rows written and the ratio long/short, which
must stay within :data:`RATIO_TARGET` (``*_within_target``).
Run: python benchmarks/bench_memory.py [--job fmus|cell|identification] [--short 60] [--long 600] [--timeseries parquet|csv]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RATIO_TARGET = 1.10
"""Peak memory of the long run over the short one: everything streams, so at most 10 % more."""
LAUNCHER = r"""
import atexit, runpy, sys

peak_file = sys.argv.pop(1)


def _own_peak():
    with open("/proc/self/status", encoding="ascii") as status:
        for line in status:
            if line.startswith("VmHWM:"):
                with open(peak_file, "w", encoding="ascii") as out:
                    out.write(line.split()[1])  # kB


atexit.register(_own_peak)
args = sys.argv[1:]
if args[0] == "-m":
    sys.argv = ["-m", *args[2:]]
    runpy.run_module(args[1], run_name="__main__", alter_sys=True)
elif args[0] == "-c":
    sys.argv = ["-c", *args[2:]]
    exec(compile(args[1], "<string>", "exec"), {"__name__": "__main__"})
else:
    sys.argv = list(args)
    runpy.run_path(args[0], run_name="__main__")
"""
"""Runs ``python -m MODULE ARGS``, ``-c CODE`` or ``SCRIPT ARGS`` in this interpreter and writes the
process's own peak resident memory (``VmHWM``, kB) to a file as it exits."""


def run_measured(args: list[str], env: dict | None = None, cwd: Path | None = None) -> tuple[int, float, float]:
    """Run ``python *args`` (``["-m", "cosim", ...]``, ``["-c", code]`` or ``[script, ...]``) in a fresh interpreter;
    returns (exit status, its own peak RSS in MiB from ``/proc/self/status`` VmHWM, the
    ``ru_maxrss`` MiB ``wait4`` reports for it - which includes the forking process's pages).
    ``python -m cosim run`` runs unsupervised here (``COSIM_SUPERVISE=0``): supervised, the
    command's first process only waits for the run, which is a forked child."""
    env = dict(os.environ if env is None else env, COSIM_SUPERVISE="0")
    with tempfile.TemporaryDirectory(prefix="bench-memory-") as tmp:
        peak_file = Path(tmp) / "vmhwm_kb"
        child = subprocess.Popen([sys.executable, "-c", LAUNCHER, str(peak_file), *args], env=env, cwd=cwd)
        _, status, usage = os.wait4(child.pid, 0)
        own = float(peak_file.read_text()) / 1024.0 if peak_file.exists() else float("nan")
    return os.waitstatus_to_exitcode(status), own, usage.ru_maxrss / 1024.0


def within_target(short_mib: float, long_mib: float, target: float = RATIO_TARGET) -> bool:
    """True when the long run's peak is at most ``target`` times the short one's."""
    return bool(short_mib > 0 and long_mib / short_mib <= target)
SCENARIO = """
connections = []
[scenario]
name = "memory_{seconds}"
job = "fmus"
[simulation]
stop_time = {seconds}
macro_step = "1 ms"
[[fmus]]
name = "plant"
builtin = "rx130l_plant"
[fmus.parameters]
"q0[2]" = -1.5708   # rad: the arm hangs down, so it stays at rest for any length of run
integration_step = 1e-3   # s
[record]
period = "1 ms"
signals = ["plant.q[*]", "plant.qd[*]", "plant.qdd[*]"]
"""


def cell_scenario(seconds: float, can_log: bool = False) -> str:
    """The main job's scenario with one mode (model_based), ``seconds`` of simulated time, no figures."""
    text = (ROOT / "scenarios" / "iso9283_rigid.toml").read_text(encoding="utf-8")
    replace = {'stop_time = "12.6 s"': f"stop_time = {seconds!r}",
               'modes = ["standard", "standard_speed_ff", "model_based"]': 'modes = ["model_based"]',
               "figures = true": "figures = false", 'name = "iso9283_rigid"': f'name = "cell_memory_{seconds:g}"'}
    if not can_log:
        replace["can_log = true"] = "can_log = false"
    for old, new in replace.items():
        if old not in text:
            raise SystemExit(f"scenarios/iso9283_rigid.toml: {old!r} not found (the benchmark edits it)")
        text = text.replace(old, new)
    return text


def identification_scenario(seconds: float) -> str:
    """scenarios/identification.toml with ``seconds`` of stop time for each ISO run, no figures."""
    text = (ROOT / "scenarios" / "identification.toml").read_text(encoding="utf-8")
    for old, new in {'stop_time = "12.6 s"': f"stop_time = {seconds!r}", "figures = true": "figures = false"}.items():
        if old not in text:
            raise SystemExit(f"scenarios/identification.toml: {old!r} not found (the benchmark edits it)")
        text = text.replace(old, new)
    return text


def identification_child(path: str, out: str) -> None:
    """In the child: the identification job's validation run only; its figures to ``out``/validation.json."""
    from cosim.jobs.identification import run_validation_path
    from cosim.scenario import load_scenario
    from cosim.scenario.context import RunContext

    scenario = load_scenario(path)
    ctx = RunContext(scenario, out, quiet=True)
    start = time.perf_counter()
    fields = run_validation_path(scenario, ctx)
    fields["wall_time_s"] = time.perf_counter() - start
    (Path(out) / "validation.json").write_text(json.dumps(fields, indent=2) + "\n")


def peak_rss_mib(seconds: float, folder: Path, fmt: str, job: str = "fmus", can_log: bool = False
                 ) -> tuple[float, int, float, float]:
    """Run the scenario for ``seconds`` in a child; (its own peak RSS MiB, rows, wall s, ru_maxrss MiB)."""
    path = folder / f"memory_{job}_{seconds:g}.toml"
    text = {"fmus": lambda: SCENARIO.format(seconds=seconds), "cell": lambda: cell_scenario(seconds, can_log),
            "identification": lambda: identification_scenario(seconds)}[job]()
    path.write_text(text, encoding="utf-8")
    out = folder / f"out_{job}_{seconds:g}"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    if job == "identification":
        command = [str(Path(__file__).resolve()), "--child", str(path), str(out)]
    else:
        command = ["-m", "cosim", "run", str(path), "--out", str(out), "--quiet", "--timeseries", fmt,
                   "--ignore-budget"]
    status, own, inherited = run_measured(command, env=env, cwd=folder)
    if status != 0:
        raise SystemExit(f"run of {seconds} s failed (status {status})")
    if job == "identification":
        fields = json.loads((out / "validation.json").read_text())
        return own, int(fields["recorder_rows"]), float(fields["wall_time_s"]), inherited
    summary = json.loads((out / "summary.json").read_text())
    if job == "fmus":
        rows = int(summary["rows_recorded"])
    else:
        from cosim.results.timeseries import series_rows

        rows = series_rows(out / "timeseries_model_based.parquet") if fmt == "parquet" else \
            sum(1 for _ in open(out / "timeseries_model_based.csv", encoding="utf-8")) - 1
    return own, rows, float(summary.get("wall_time_s") or 0.0), inherited


def main(argv: list[str] | None = None) -> dict | None:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        identification_child(*argv[1:3])
        return None
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--short", type=float, default=60.0)
    parser.add_argument("--long", type=float, default=600.0)
    parser.add_argument("--timeseries", choices=("parquet", "csv"), default="parquet")
    parser.add_argument("--job", choices=("fmus", "cell", "identification"), default="fmus")
    parser.add_argument("--can-log", action="store_true", help="cell: write the BLF CAN log too")
    args = parser.parse_args(argv)
    return measure(args.short, args.long, args.timeseries, args.job, args.can_log)


def measure(short_s: float, long_s: float, fmt: str = "parquet", job: str = "fmus", can_log: bool = False,
            folder: Path | None = None) -> dict:
    """Peak RSS of the ``job`` at ``short_s`` and ``long_s`` simulated seconds; prints and returns the figures."""
    with tempfile.TemporaryDirectory(dir=folder) as tmp:
        short = peak_rss_mib(short_s, Path(tmp), fmt, job, can_log)
        long = peak_rss_mib(long_s, Path(tmp), fmt, job, can_log)
    result = {"job": job, "short_s": short_s, "long_s": long_s, "short_peak_rss_mib": short[0],
              "long_peak_rss_mib": long[0], "short_rows": short[1], "long_rows": long[1],
              "short_wall_s": short[2], "long_wall_s": long[2], "ratio": long[0] / short[0],
              "within_target": within_target(short[0], long[0]), "ratio_target": RATIO_TARGET,
              "short_ru_maxrss_mib": short[3], "long_ru_maxrss_mib": long[3],
              "load_average": os.getloadavg(), "format": fmt, "can_log": can_log}
    print(f"peak RSS of the run's own process ({job}): {short_s:g} s run {short[0]:.1f} MiB ({short[1]} rows, "
          f"{short[2]:.0f} s wall), {long_s:g} s run {long[0]:.1f} MiB ({long[1]} rows, {long[2]:.0f} s wall): "
          f"ratio {result['ratio']:.3f} ({'within' if result['within_target'] else 'ABOVE'} the {RATIO_TARGET} target; "
          f"{fmt}; wait4 ru_maxrss {short[3]:.1f} / {long[3]:.1f} MiB; load average {result['load_average'][0]:.2f})")
    return result


if __name__ == "__main__":
    main()
