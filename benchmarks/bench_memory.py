"""Memory of a long run stays flat: peak RSS of the same streaming run at two lengths.

The plain-FMU job (the plant FMU, 18 signals recorded every 1 ms, 1 ms macro step) runs
once for ``--short`` and once for ``--long`` simulated seconds (default 60 s and 600 s),
each in a fresh interpreter (`python -m cosim run`), and prints each run's peak
resident memory (``ru_maxrss`` of the child), the rows written and the ratio long/short.
The time series streams through :class:`cosim.results.timeseries.ParquetSink` (bounded
buffer, row groups written as the run goes), so the ratio should stay within 1.10.
Run: python benchmarks/bench_memory.py [--short 60] [--long 600] [--timeseries parquet|csv]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
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


def peak_rss_mib(seconds: float, folder: Path, fmt: str) -> tuple[float, int, float]:
    """Run the scenario for ``seconds`` in a child; (peak RSS MiB, rows, wall s)."""
    path = folder / f"memory_{int(seconds)}.toml"
    path.write_text(SCENARIO.format(seconds=seconds), encoding="utf-8")
    out = folder / f"out_{int(seconds)}"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    child = subprocess.Popen([sys.executable, "-m", "cosim", "run", str(path), "--out", str(out), "--quiet",
                              "--timeseries", fmt, "--ignore-budget"], env=env, cwd=folder)
    _, status, usage = os.wait4(child.pid, 0)
    if status != 0:
        raise SystemExit(f"run of {seconds} s failed (status {status})")
    summary = json.loads((out / "summary.json").read_text())
    return usage.ru_maxrss / 1024.0, int(summary["rows_recorded"]), float(summary.get("wall_time_s") or 0.0)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--short", type=float, default=60.0)
    parser.add_argument("--long", type=float, default=600.0)
    parser.add_argument("--timeseries", choices=("parquet", "csv"), default="parquet")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        short = peak_rss_mib(args.short, Path(tmp), args.timeseries)
        long = peak_rss_mib(args.long, Path(tmp), args.timeseries)
    result = {"short_s": args.short, "long_s": args.long, "short_peak_rss_mib": short[0], "long_peak_rss_mib": long[0],
              "short_rows": short[1], "long_rows": long[1], "ratio": long[0] / short[0],
              "load_average": os.getloadavg(), "format": args.timeseries}
    print(f"peak RSS: {args.short:g} s run {short[0]:.1f} MiB ({short[1]} rows), {args.long:g} s run "
          f"{long[0]:.1f} MiB ({long[1]} rows): ratio {result['ratio']:.3f} "
          f"({args.timeseries}; load average {result['load_average'][0]:.2f})")
    return result


if __name__ == "__main__":
    main()
