"""One variant as a task: write its scenario, run it with the ordinary runner, return its table row.

``run_variant`` is what a Dask worker process executes (and what a serial loop would):
it writes the variant's scenario to ``<folder>/scenario.toml``, runs
``python -m cosim run scenario.toml --out <folder> --quiet`` in-process
(``cosim.cli.main``; its stdout/stderr go to ``<folder>/run.log``), reads the
``summary.json`` the runner wrote, and returns the row (also saved as
``<folder>/sweep_row.json``, which is what makes a sweep resumable). A scenario that
fails or raises gives a row with ``status = "failed"`` and the runner's reason; only
problems outside the runner (e.g. the folder cannot be written) raise, so Dask's
``retries`` re-run them.
"""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomli_w

from cosim.sweep.table import select_metrics

SCENARIO_FILE = "scenario.toml"
SUMMARY_FILE = "summary.json"
ROW_FILE = "sweep_row.json"
LOG_FILE = "run.log"
FINISHED = ("ok", "failed")
#: One variant at a time per process, even on a worker with several threads (an external
#: cluster started without ``--nthreads 1``): FMU instances and the redirected stdout/stderr
#: of a run are never shared between threads.
_ONE_AT_A_TIME = threading.Lock()
#: Exit codes of ``cosim run`` (cosim/commands/run.py) -> words for the reason column.
EXIT_WORDS = {1: "simulation failed", 2: "invalid scenario", 3: "internal error"}


@dataclass(frozen=True)
class VariantTask:
    """Everything a worker needs to run one variant (picklable, no open resources).

    Attributes:
        index, id, hash: the variant's position, name and hash (cosim.sweep.loader.Variant).
        folder: its results folder (absolute path).
        document: the scenario document to write and run.
        values: axis key -> validated value (the parameter columns).
        metrics: metric globs of ``[sweep] metrics`` (None: every numeric leaf).
    """

    index: int
    id: str
    hash: str
    folder: str
    document: dict[str, Any]
    values: dict[str, Any]
    metrics: tuple[str, ...] | None = None


def worker_name() -> str:
    """``host:pid`` of this process."""
    return f"{socket.gethostname()}:{os.getpid()}"


def _log_tail(path: Path, lines: int = 3) -> str:
    try:
        text = [line.strip() for line in path.read_text(encoding="utf-8", errors="replace").splitlines()]
    except OSError:
        return ""
    return " | ".join([line for line in text if line][-lines:])


def read_summary(folder: str | Path) -> dict[str, Any] | None:
    """The folder's summary.json (None when missing or unreadable)."""
    try:
        return json.loads((Path(folder) / SUMMARY_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def make_row(task: VariantTask, summary: dict[str, Any] | None, exit_code: int | None, wall_time_s: float,
             worker: str, reason: str | None = None, cpu_time_s: float | None = None) -> dict[str, Any]:
    """The table row of a finished variant (times in s; CPU time of the worker process during the run)."""
    status = "ok" if exit_code == 0 and summary is not None and summary.get("status") == "ok" else "failed"
    if status == "failed" and reason is None:
        if summary is not None and summary.get("reason"):
            reason = str(summary["reason"])
        else:
            reason = f"{EXIT_WORDS.get(exit_code, f'exit code {exit_code}')}: {_log_tail(Path(task.folder) / LOG_FILE)}"
    return {
        "index": task.index,
        "variant": task.id,
        "hash": task.hash,
        "folder": task.folder,
        "values": dict(task.values),
        "status": status,
        "reason": reason if status == "failed" else None,
        "wall_time_s": wall_time_s,
        "cpu_time_s": cpu_time_s,
        "worker": worker,
        "metrics": select_metrics(summary or {}, task.metrics),
    }


def run_variant(task: VariantTask) -> dict[str, Any]:
    """Run one variant with the ordinary scenario runner in this process; return its row."""
    with _ONE_AT_A_TIME:
        return _run_variant(task)


def _run_variant(task: VariantTask) -> dict[str, Any]:
    from cosim.cli import main as cosim_main

    folder = Path(task.folder)
    folder.mkdir(parents=True, exist_ok=True)
    for stale in (ROW_FILE, SUMMARY_FILE):
        (folder / stale).unlink(missing_ok=True)
    scenario_path = folder / SCENARIO_FILE
    scenario_path.write_text(f"# variant {task.id} (hash {task.hash}) of a sweep; run by cosim.sweep\n"
                             + tomli_w.dumps(task.document), encoding="utf-8")
    start, cpu_start = time.perf_counter(), time.process_time()
    with open(folder / LOG_FILE, "w", encoding="utf-8") as log, \
            contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
        try:
            code = cosim_main(["run", str(scenario_path), "--out", str(folder), "--quiet"])
        except SystemExit as exc:  # argparse or a job calling sys.exit
            code = exc.code if isinstance(exc.code, int) else 3
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    row = make_row(task, read_summary(folder), code, wall, worker_name(), cpu_time_s=cpu)
    write_row(folder, row)
    return row


def write_row(folder: str | Path, row: dict[str, Any]) -> None:
    """Save ``row`` as ``<folder>/sweep_row.json`` (atomically)."""
    path = Path(folder) / ROW_FILE
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(row, indent=1, default=str) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def finished_row(folder: str | Path, variant_hash: str) -> dict[str, Any] | None:
    """The saved row of a variant that finished in ``folder`` with this hash, else None."""
    try:
        row = json.loads((Path(folder) / ROW_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    summary = read_summary(folder)
    if row.get("hash") != variant_hash or summary is None or summary.get("status") not in FINISHED:
        return None
    return row


def reuse_finished(task: VariantTask, variants_dir: Path) -> dict[str, Any] | None:
    """The row of ``task`` when a finished run of the same hash exists under ``variants_dir``.

    Its own folder first; otherwise a folder of the same hash under another variant id
    (the axes were edited and the variants renumbered) is renamed to this variant's folder.
    """
    own = Path(task.folder)
    row = finished_row(own, task.hash)
    if row is None:
        for other in sorted(variants_dir.glob(f"*-{task.hash[:8]}")):
            if other != own and (row := finished_row(other, task.hash)) is not None:
                if own.exists():
                    shutil.rmtree(own)
                other.rename(own)
                break
    if row is None:
        return None
    row.update(index=task.index, variant=task.id, folder=task.folder, values=dict(task.values),
               metrics=select_metrics(read_summary(own) or {}, task.metrics))
    write_row(own, row)
    return row


__all__ = ["FINISHED", "LOG_FILE", "ROW_FILE", "SCENARIO_FILE", "SUMMARY_FILE", "VariantTask", "finished_row",
           "make_row", "read_summary", "reuse_finished", "run_variant", "worker_name", "write_row"]
