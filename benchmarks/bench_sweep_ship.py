"""What shipping costs: the same sweep with ``transfer = "shared"`` and ``"ship"`` on one cluster.

The variants are the main job's ISO 9283 scenario shortened to ``--stop-time`` (one mode per
variant, no CAN log, no figures), over payload mass. ``ship`` sends each task its document
(the builtin FMUs are built on the worker) and brings back the row, summary.json, run.log and
the ``--collect`` files (default the time series) through Dask; ``shared`` lets the workers
write the client's folders. One embedded LocalCluster of ``--workers`` processes runs both,
interleaved over ``--repeats`` rounds, every variant anew (``resume=False``); printed: the
median wall time of each mode, their ratio, and the bytes brought back per variant.

    python benchmarks/bench_sweep_ship.py [--variants 4] [--stop-time "0.5 s"] [--repeats 2] [--workers 2]
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def folder_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--variants", type=int, default=4)
    parser.add_argument("--stop-time", default="0.5 s")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--collect", default="timeseries", help="comma-separated [sweep] collect items")
    args = parser.parse_args()

    import cosim
    from cosim.sweep import dask_client

    base = cosim.load_scenario(ROOT / "scenarios" / "iso9283.toml", overrides={
        "simulation.stop_time": args.stop_time, "results.can_log": False, "results.figures": False,
        "controller.modes": ["model_based"]})
    payloads = [f"{10.0 * i / max(1, args.variants - 1):.3f} kg" for i in range(args.variants)]
    sweep = cosim.build_sweep(base, {"true_robot.payload_mass": payloads}, name="bench_ship",
                              collect=[c for c in args.collect.split(",") if c], metrics=["sim_time_s"])
    times: dict[str, list[float]] = {"shared": [], "ship": []}
    sizes: dict[str, int] = {}
    with tempfile.TemporaryDirectory(prefix="bench-ship-") as tmp, dask_client(workers=args.workers) as client:
        cosim.run_sweep(sweep, Path(tmp) / "warm", client=client)               # FMU builds, imports
        for round_ in range(args.repeats):
            for mode in ("shared", "ship"):
                out = Path(tmp) / f"{mode}{round_}"
                result = cosim.run_sweep(sweep, out, client=client, transfer=mode, resume=False)
                assert result.ok == args.variants, [r["reason"] for r in result.rows]
                times[mode].append(result.wall_time_s)
                if mode == "ship":
                    sizes["ship"] = folder_bytes(out / "variants") // args.variants
                else:
                    sizes["shared"] = folder_bytes(out / "variants") // args.variants
                print(f"round {round_ + 1} {mode:>6}: {result.wall_time_s:6.2f} s for {args.variants} variants",
                      flush=True)
    shared, ship = statistics.median(times["shared"]), statistics.median(times["ship"])
    print(f"median wall time: shared {shared:.2f} s, ship {ship:.2f} s, ratio ship/shared {ship / shared:.3f}; "
          f"per variant: {sizes['ship'] / 1e6:.2f} MB brought back (collect={args.collect!r}), "
          f"{sizes['shared'] / 1e6:.2f} MB written in place; load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
