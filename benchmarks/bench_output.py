"""The main job's output: size of every file, the total against the 128 MB the job wrote as
CSV, and what writing it costs in CPU time per mode.

Runs ``scenarios/iso9283.toml`` into a temporary folder (or takes ``--results DIR``), lists
each file's size and the total, then replays one mode's data through the writers the job
uses - in this process, CPU time (``time.process_time``), median of ``--repeats``:

* CAN log: the recorder's sink (sorting, watermarks) into the columnar log
  (``fieldbus.canlog``) vs the BLF writer (``fieldbus.blf``, python-can's bytes);
* time series: ``cosim.results.ParquetSink`` streaming and closing each file (standard
  encodings: byte-stream-split or dictionary float64 columns, zstd);
* the run's ``report.html`` (all modes, :func:`cosim.results.report.write_report`): what the
  report adds to a run's CPU time (a run forks it beside its figures: the same work).

Run: python benchmarks/bench_output.py [--results results/iso9283] [--repeats 3]
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

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "scenarios" / "iso9283.toml"
CSV_BASELINE_MB = 128.0
"""The main job's output when it wrote CSV: 128 MB; the target is at least 5x below that."""
FLUSH_CYCLES = 250  # the recorder's hand-over period (fieldbus/powerlink_defaults.toml)


def run_job(out: Path, scenario: Path = SCENARIO, stop_time: str | None = None, plain: bool = False) -> Path:
    """Run the main job into ``out``; ``plain``: with the CAN log as BLF."""
    if stop_time is not None or plain:
        text = scenario.read_text(encoding="utf-8")
        if stop_time is not None:
            text = text.replace('stop_time = "12.6 s"', f'stop_time = "{stop_time}"', 1)
        if plain:
            text = text.replace("\n[results]\n", '\n[results]\ncan_log_format = "blf"\n', 1)
        scenario = out.parent / "iso_variant.toml"
        scenario.write_text(text, encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    subprocess.run([sys.executable, "-m", "cosim", "run", str(scenario), "--out", str(out), "--quiet"], cwd=ROOT,
                   env=env, check=True, stdout=subprocess.DEVNULL)
    return out


def file_sizes(folder: Path) -> dict[str, int]:
    return {p.name: p.stat().st_size for p in sorted(folder.iterdir()) if p.is_file() and not p.name.startswith(".")}


def _cpu(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return statistics.median(times)


def can_write_cpu(log: Path, work: Path, repeats: int) -> dict[str, float]:
    """CPU s to write one mode's frames as the columnar log and as BLF, through the recorder's sink."""
    from fieldbus.canlog import RECORD_DTYPE, read_frames
    from fieldbus.recorder import _BlfSink

    frames = read_frames(log)
    rec = np.zeros(frames.frames.size, dtype=RECORD_DTYPE)
    rec["t"] = frames.timestamps
    for name in ("id", "error", "length", "data"):
        rec[name] = frames.frames[name]
    sync = np.flatnonzero(rec["id"] == 0x080)
    cuts = sync[::FLUSH_CYCLES][1:]
    batches = np.split(rec, cuts)
    # each frame's cell cycle (as the recorder hands it over): the log's, else counted from the SoCs
    cycles = frames.cycles if frames.cycles is not None else np.cumsum(rec["id"] == 0x080) - 1
    cycle_batches = np.split(np.asarray(cycles, dtype=np.int64), cuts)

    def write(path: Path, columnar: bool) -> None:
        sink = _BlfSink(str(path), columnar=columnar)
        for b, c in zip(batches, cycle_batches):
            sink.feed(b.tobytes(), float(b["t"][-1]) if b.size else None, c)
        sink.close()

    out = {"frames": int(rec.size)}
    out["columnar_cpu_s"] = _cpu(lambda: write(work / "c.parquet", True), repeats)
    out["blf_cpu_s"] = _cpu(lambda: write(work / "c.blf", False), repeats)
    out["columnar_bytes"] = (work / "c.parquet").stat().st_size
    out["blf_bytes"] = (work / "c.blf").stat().st_size
    return out


def series_write_cpu(folder: Path, mode: str, work: Path, repeats: int) -> dict[str, float]:
    """CPU s to stream and close one mode's three time series (as the job writes them)."""
    from cosim.results.timeseries import ParquetSink, read_series, read_units

    jobs = []
    for stem in ("timeseries", "controller", "tcp"):
        path = folder / f"{stem}_{mode}.parquet"
        names, data = read_series(path)
        units = read_units(path)
        kinds = ["Integer" if n in ("phase", "ik_iterations", "segment") else "Real" for n in names]
        jobs.append((stem, names, kinds, data, units))

    def write() -> None:
        for stem, names, kinds, data, units in jobs:
            sink = ParquetSink(work / f"{stem}.parquet", units, flush_interval_s=1e9)
            sink.open(names, kinds)
            for start in range(0, len(data), 2048):  # the controller log's stream blocks
                sink.write(data[start:start + 2048])
            sink.close()

    return {"cpu_s": _cpu(write, repeats)}


def report_write_cpu(folder: Path, work: Path, repeats: int) -> dict[str, float]:
    """CPU s to write the folder's report.html (every mode), and its size."""
    from cosim.results.report import write_report

    out = work / "report.html"
    return {"cpu_s": _cpu(lambda: write_report([folder], out), repeats), "bytes": out.stat().st_size}


def measure(results: Path | None = None, repeats: int = 3, stop_time: str | None = None,
            work: Path | None = None) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-output-") as tmp:
        tmp = Path(tmp)
        folder = results if results is not None else run_job(tmp / "out", stop_time=stop_time)
        sizes = file_sizes(folder)
        total = sum(sizes.values())
        modes = sorted(p.stem[len("can_"):] for p in folder.glob("can_*.parquet"))
        per_mode = {}
        for mode in modes:
            per_mode[mode] = {"can": can_write_cpu(folder / f"can_{mode}.parquet", tmp, repeats),
                              "series": series_write_cpu(folder, mode, tmp, repeats)}
        html = report_write_cpu(folder, tmp, repeats)
        return {"files": sizes, "total_bytes": total, "total_mb": total / 1e6, "report_cpu_s": html["cpu_s"],
                "report_mb": html["bytes"] / 1e6,
                "ratio_to_csv_128mb": CSV_BASELINE_MB * 1e6 / total if total else None, "modes": per_mode,
                "load_average": os.getloadavg()}


def report(out: dict) -> str:
    lines = [f"{'file':42s} {'MB':>8s}"]
    lines += [f"{name:42s} {size / 1e6:8.3f}" for name, size in out["files"].items()]
    lines.append(f"{'total':42s} {out['total_mb']:8.3f}   ({out['ratio_to_csv_128mb']:.2f}x below the 128 MB CSV output)")
    lines.append("write CPU per mode (s, median)   CAN columnar / BLF      time series")
    for mode, m in out["modes"].items():
        c, s = m["can"], m["series"]
        lines.append(f"  {mode:28s} {c['columnar_cpu_s']:7.3f} / {c['blf_cpu_s']:7.3f}"
                     f"   {s['cpu_s']:7.3f}")
    lines.append(f"report.html (all modes): {out['report_mb']:.2f} MB, written in {out['report_cpu_s']:.2f} CPU-s")
    lines.append("load average: " + " ".join(f"{x:.2f}" for x in out["load_average"]))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", type=Path, default=None, help="a results folder of the main job (default: run it)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", type=Path, default=None, help="also write the figures as JSON")
    args = parser.parse_args(argv)
    out = measure(args.results, args.repeats)
    print(report(out))
    if args.json:
        args.json.write_text(json.dumps(out, indent=2), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
