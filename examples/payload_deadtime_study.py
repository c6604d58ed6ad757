"""A study written as a Python script: payload x fieldbus dead time x control mode on the
EN ISO 9283 path, run as a sweep on a local Dask cluster, printed as a table and plotted.

    python examples/payload_deadtime_study.py [--out DIR] [--workers N] [--stop-time "0.5 s"]

It uses only the public API (``import cosim``; docs/how-to/scripting.md): the main job's path and
robot on the rigid plant, ``scenarios/iso9283_rigid.toml`` (eq. 7 then removes the lag down to
micrometres, so the payload and the dead time are what the table shows; on the main job's
elastic plant the gear deflection would dominate), is loaded with overrides that shorten it (the first 0.3 s of the
path after enabling and settling, no CAN log, no per-run figures), and the study varies
three keys with the sweep-axis syntax:

* ``true_robot.payload_mass``: 0 kg and 10 kg on the flange (the controller's model knows it);
* ``fieldbus.dead_time_cycles``: 1 and 3 POWERLINK cycles (400 us each) from the cycle whose
  PReq carries a set-point to the SoC at which the drive applies it;
* ``controller.modes``: the drives' standard cascade or the model-based feed-forward (eq. 7).

Results in ``--out`` (default ``results/payload_deadtime_study/``): ``table.csv`` (the table
printed, full precision), ``payload_deadtime_study.png`` and the sweep's own files
(``sweep.csv``, one folder per variant). The same 8 variants run through
``python -m cosim sweep`` give the same numbers to the last digit (tests/examples/test_study.py).
"""
from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import cosim

ROOT = Path(__file__).resolve().parents[1]
BASE = ROOT / "scenarios" / "iso9283_rigid.toml"

PAYLOADS = ["0 kg", "10 kg"]
DEAD_TIMES = [1, 3]                              # POWERLINK cycles
MODES = [["standard"], ["model_based"]]          # one mode per variant
#: summary.json leaves shown (each variant has the one mode it ran: the glob picks it)
METRICS = {"tcp_error_max_mm": "modes.*.tcp_error_max_mm",
           "tcp_error_rms_mm": "modes.*.tcp_error_rms_mm",
           "path_accuracy_AT_mm": "modes.*.path_accuracy_AT_mm"}
COLUMNS = ["payload_kg", "dead_time_cycles", "mode", *METRICS]


def build_study(stop_time: str = "0.5 s"):
    """The study as a validated sweep (every variant checked by the iso9283 job; nothing runs)."""
    base = cosim.load_scenario(BASE, overrides={
        "simulation.stop_time": stop_time,     # enable + 0.2 s settle + the start of the path
        "results.can_log": False,
        "results.figures": False,
    })
    return cosim.build_sweep(
        base, name="payload_deadtime_study",
        axes={"true_robot.payload_mass": PAYLOADS,
              "fieldbus.dead_time_cycles": DEAD_TIMES,
              "controller.modes": MODES},
        metrics=list(METRICS.values()),
        description="ISO 9283 path: payload x fieldbus dead time x control mode -> TCP tracking error")


def table(result) -> list[dict]:
    """One dict per variant: the three parameters and the metrics (full precision)."""
    rows = []
    for row in result.rows:
        if row["status"] != "ok":
            raise SystemExit(f"variant {row['variant']} failed: {row['reason']}")
        mode = row["values"]["controller.modes"][0]
        rows.append({"payload_kg": row["values"]["true_robot.payload_mass"],
                     "dead_time_cycles": row["values"]["fieldbus.dead_time_cycles"],
                     "mode": mode,
                     **{name: row["metrics"][glob.replace("*", mode)] for name, glob in METRICS.items()}})
    return rows


def print_table(rows: list[dict]) -> None:
    print(f"{'payload':>8} {'dead time':>10} {'mode':<12} {'max TCP err':>12} {'RMS TCP err':>12} {'AT':>10}")
    for r in rows:
        print(f"{r['payload_kg']:>6g} kg {r['dead_time_cycles']:>5d} cyc. {r['mode']:<12} "
              f"{r['tcp_error_max_mm']:>9.4f} mm {r['tcp_error_rms_mm']:>9.4f} mm {r['path_accuracy_AT_mm']:>7.4f} mm")


def write_table(rows: list[dict], path: Path) -> None:
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, COLUMNS)
        writer.writeheader()
        for r in rows:
            writer.writerow({k: repr(v) if isinstance(v, float) else v for k, v in r.items()})


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.8), dpi=110, sharey=False)
    for ax, mode in zip(axes, [m[0] for m in MODES]):
        for payload in sorted({r["payload_kg"] for r in rows}):
            pts = sorted((r["dead_time_cycles"], r["tcp_error_max_mm"]) for r in rows
                         if r["mode"] == mode and r["payload_kg"] == payload)
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=f"{payload:g} kg")
        ax.set_title(mode)
        ax.set_xlabel("fieldbus dead time [cycles of 400 us]")
        ax.set_xticks(DEAD_TIMES)
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("max TCP error [mm]")
    axes[1].legend(title="payload")
    fig.suptitle("ISO 9283 path, first 0.3 s: max TCP error vs dead time and payload")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("results") / "payload_deadtime_study")
    parser.add_argument("--workers", type=int, default=2, help="worker processes of the local Dask cluster")
    parser.add_argument("--stop-time", default="0.5 s", help="simulated time per variant (default 0.5 s)")
    args = parser.parse_args(argv)

    study = build_study(args.stop_time)
    print(f"{len(study.variants)} variants of {BASE.name}: {', '.join(study.parameters)}", file=sys.stderr)
    result = cosim.run_sweep(study, args.out, workers=args.workers)
    rows = table(result)
    print_table(rows)
    write_table(rows, args.out / "table.csv")
    plot(rows, args.out / "payload_deadtime_study.png")
    print(f"{result.ok} variants in {result.wall_time_s:.1f} s; table {args.out / 'table.csv'}, "
          f"figure {args.out / 'payload_deadtime_study.png'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
