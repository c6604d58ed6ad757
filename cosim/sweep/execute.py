"""Run a sweep's variants as independent tasks on Dask (``dask.distributed``).

By default an embedded ``LocalCluster`` of worker PROCESSES is started on the local machine
(``n_workers = workers`` (default: CPU count), one thread each, so an FMU instance never
meets a second thread); with ``scheduler = "tcp://host:8786"`` the same tasks go to an
existing cluster, whose workers need this project installed (``pip install -e .``) and
the same paths (shared file system) for the results folders.

Fault handling: a variant whose scenario fails or raises is a ``failed`` row with the
runner's reason, and the sweep goes on. A task whose worker process dies is
rescheduled by the scheduler on another (or the restarted) worker, up to
``retries`` times for the embedded cluster (``distributed.scheduler.allowed-failures``;
an external scheduler uses its own setting); a task that raises outside the runner
(e.g. the folder cannot be written) is re-run up to ``retries`` times (Dask's
``retries=``). When that is exhausted the row is ``failed`` with the reason.

Results in ``out_dir`` (default ``results/<sweep name>/``): ``sweep.csv`` (one row per
variant, cosim/sweep/table.py), ``variants/<id>-<hash8>/`` (each variant's scenario.toml,
summary.json, run.log and the job's own files), ``sweep.json`` (the definition, counts
and timing) and the ``[report]`` figure. Re-running skips variants whose folder holds a
finished run (``ok`` or ``failed``) of the same variant hash.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import sys
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from tqdm import tqdm

from cosim.results.summary import replace_text
from cosim.scenario.keypath import referenced_files
from cosim.sweep.loader import Sweep
from cosim.sweep.table import write_table
from cosim.sweep.task import (ShippedResult, VariantTask, make_row, receive_shipped, reuse_finished,
                              run_shipped_variant, run_variant, worker_name)

TABLE_FILE = "sweep.csv"
SWEEP_FILE = "sweep.json"
VARIANTS_DIR = "variants"
#: Wall-time interval between rewrites of the table while the sweep runs, s.
TABLE_INTERVAL_S = 2.0
#: How variants get their inputs and return their results (run_sweep's ``transfer``).
TRANSFERS = ("auto", "ship", "shared")


@dataclass
class SweepResult:
    """What ``run_sweep`` did.

    Attributes:
        out_dir: the sweep's results folder.
        table: path of sweep.csv.
        figure: path of the [report] figure (None without [report] or without data to plot).
        rows: one dict per variant (cosim.sweep.task.make_row), in variant order.
        ran, reused: variants run now / taken from finished folders of an earlier run.
        ok, failed: rows by status.
        workers: Dask workers when the sweep started (0 when nothing had to run).
        wall_time_s: wall time of run_sweep, s.
        scheduler: address of the scheduler used ("" when nothing had to run).
        notes: remarks for the user (e.g. variants the figure left out).
    """

    out_dir: Path
    table: Path
    figure: Path | None
    rows: list[dict[str, Any]]
    ran: int
    reused: int
    workers: int
    wall_time_s: float
    scheduler: str = ""
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> int:
        """Rows with status ok."""
        return sum(r["status"] == "ok" for r in self.rows)

    @property
    def failed(self) -> int:
        """Rows with status failed."""
        return sum(r["status"] != "ok" for r in self.rows)

    parameters: list[str] = field(default_factory=list)
    transfer: str = "shared"

    def records(self) -> list[dict[str, Any]]:
        """The table as flat dicts, one per variant in order (the columns of sweep.csv, values typed)."""
        from cosim.sweep.table import table_records

        return table_records(self.rows, self.parameters)[1]

    def variant(self, index: int):
        """A :class:`cosim.api.RunResult` of variant ``index``'s folder (summary, time series, figures)."""
        from cosim.runs.result import RunResult

        return RunResult(self.rows[index]["folder"])


def default_out_dir(sweep: Sweep) -> Path:
    """``results/<sweep name>/`` (relative to the working directory)."""
    return Path("results") / sweep.name


def variant_tasks(sweep: Sweep, out_dir: Path) -> list[VariantTask]:
    """The tasks of every variant, with their folders under ``out_dir/variants/``."""
    variants_dir = (out_dir / VARIANTS_DIR).resolve()
    metrics = tuple(sweep.metrics) if sweep.metrics else None
    anchor = str(sweep.base.where.base_dir)
    return [VariantTask(v.index, v.id, v.hash, str(variants_dir / f"{v.id}-{v.hash[:8]}"), v.document, v.values,
                        metrics, f"{VARIANTS_DIR}/{v.id}-{v.hash[:8]}", (), tuple(sweep.collect), sweep.store,
                        anchor) for v in sweep.variants]


def with_inputs(sweep: Sweep, tasks: list[VariantTask]) -> list[VariantTask]:
    """``tasks`` listing the files their documents refer to (``task.inputs``: key path, SHA-256,
    file name), so that the files travel with the tasks (each file is read once)."""
    digests: dict[str, str] = {}
    out = []
    for task in tasks:
        inputs = []
        for path, text in referenced_files(sweep.base.job.schema, task.document):
            file = _client_file(task, text)
            inputs.append((tuple(path), digests.setdefault(file, _sha256(file)), Path(file).name,
                           "" if Path(text).expanduser().is_absolute() else text))
        out.append(replace(task, inputs=tuple(inputs)))
    return out


def _client_file(task: VariantTask, text: str) -> str:
    """The client's path of a file reference (relative ones are relative to the task's anchor)."""
    path = Path(text).expanduser()
    return str(path if path.is_absolute() else Path(task.anchor) / path)


def _sha256(path: str) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def input_files(sweep: Sweep, tasks: list[VariantTask]) -> dict[str, str]:
    """SHA-256 -> client path of every file the ``tasks`` ship."""
    out: dict[str, str] = {}
    for task in tasks:
        refs = dict(referenced_files(sweep.base.job.schema, task.document))
        for path, digest, _, _ in task.inputs:
            out.setdefault(digest, _client_file(task, refs[tuple(path)]))
    return out


def _identity(data: bytes) -> bytes:
    """A shipped input file's content, held on a worker as the result of a task."""
    return data


def resolve_transfer(transfer: str, scheduler: str | None, client: Any) -> str:
    """``"ship"`` or ``"shared"`` for ``transfer`` = ship/shared/auto (auto: shared only on a LocalCluster)."""
    if transfer not in TRANSFERS:
        raise ValueError(f"transfer: expected one of {', '.join(TRANSFERS)}, got {transfer!r}")
    if transfer != "auto":
        return transfer
    if scheduler:
        return "ship"
    if client is None:
        return "shared"
    from dask.distributed import LocalCluster

    return "shared" if isinstance(getattr(client, "cluster", None), LocalCluster) else "ship"


#: How long to wait for an existing Dask scheduler (--scheduler) to answer, s.
SCHEDULER_CONNECT_TIMEOUT_S = 5.0


class SchedulerUnreachable(ConnectionError):
    """The --scheduler address did not answer (message names it and the timeout)."""


def probe_scheduler(address: str, timeout_s: float = SCHEDULER_CONNECT_TIMEOUT_S) -> None:
    """Connect to ``address``, do Dask's handshake and ask its ``identity`` within ``timeout_s`` (s) in
    all: returns when a Dask scheduler answered, raises TimeoutError (a peer that accepts the
    connection and never answers: ``dask.distributed.Client`` would wait for its handshake for
    ever), OSError (refused, unknown host) or ValueError (a bad address, or a peer that is not a
    Dask scheduler)."""
    import asyncio

    from distributed.comm import connect

    stage = ["connecting"]

    async def ask() -> Any:
        comm = await connect(address, timeout=timeout_s)  # TCP connection, then Dask's handshake
        stage[0] = "identity"
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    async def bounded() -> Any:
        return await asyncio.wait_for(ask(), timeout_s)

    try:
        reply = asyncio.run(bounded())
    except asyncio.TimeoutError:
        what = "no answer" if stage[0] == "identity" else "no connection and handshake"
        raise TimeoutError(f"{what} within {timeout_s:g} s (a peer that accepts the connection and never "
                           "answers, or a firewall that drops it)") from None
    kind = reply.get("type") if isinstance(reply, dict) else None
    if kind != "Scheduler":
        raise ValueError(f"the peer is not a Dask scheduler (identity type {kind!r})")


@contextlib.contextmanager
def _children_ignore_interrupts() -> Iterator[None]:
    """Processes started inside ignore SIGINT/SIGTERM (they inherit the disposition across exec):
    Ctrl-C reaches the whole process group, and the workers must stay up until this process
    has cancelled the sweep and closes the cluster in order. Restored afterwards."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler if handler is not None else signal.SIG_DFL)


@contextlib.contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None, retries: int = 2) -> Iterator[Any]:
    """A ``dask.distributed.Client``: on ``scheduler`` if given, else on a new embedded LocalCluster of
    ``workers`` single-threaded worker processes (closed on exit)."""
    import dask
    from dask.distributed import Client, LocalCluster

    if scheduler:
        try:
            probe_scheduler(scheduler)  # bounded: Client() itself may wait for ever on a silent peer
            client = Client(scheduler, timeout=SCHEDULER_CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError, ValueError, TypeError) as exc:
            raise SchedulerUnreachable(f"--scheduler {scheduler!r}: no Dask scheduler answered within "
                                       f"{SCHEDULER_CONNECT_TIMEOUT_S:g} s ({type(exc).__name__}: "
                                       f"{str(exc).splitlines()[0] if str(exc) else ''}); expected the address "
                                       f"of a running scheduler such as tcp://host:8786") from None
        with client:
            yield client
        return
    with dask.config.set({"distributed.scheduler.allowed-failures": retries}), _children_ignore_interrupts():
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                               dashboard_address=":0", silence_logs=logging.ERROR)
    with cluster, Client(cluster) as client:
        from cosim.sweep.worker_plugin import QuietHeartbeatAtClose

        client.register_plugin(QuietHeartbeatAtClose(), name="cosim-quiet-heartbeat-at-close")
        yield client




def _failure_reason(exc: BaseException, retries: int) -> str:
    from distributed import KilledWorker

    if isinstance(exc, KilledWorker):
        return (f"worker process died while running this variant ({exc.allowed_failures + 1} attempts, "
                f"last on {exc.last_worker.address}): dask KilledWorker")
    return f"task raised {type(exc).__name__}: {exc} (after {retries} retries)"


def _write_definition(sweep: Sweep, out_dir: Path, state: dict[str, Any]) -> None:
    data = {
        "sweep": sweep.name,
        "file": str(sweep.path),
        "description": sweep.description,
        "base": str(sweep.base.path),
        "job": sweep.job,
        "axes": [{"key": a.key, "kind": a.kind, "values": list(a.values)} for a in sweep.axes],
        "overrides": sweep.overrides,
        "variants": len(sweep.variants),
        **state,
    }
    replace_text(out_dir / SWEEP_FILE, json.dumps(data, indent=2, default=str) + "\n")
    # what the supervisor writes if this process dies now (cosim/commands/supervisor.py): sweep.json and the
    # variants still running failed, with how the process ended
    from cosim.results import lastwords

    if data.get("status") == "running":
        lastwords.publish(out_dir / SWEEP_FILE, json.loads(json.dumps(data, default=str)),
                          also=(f"{VARIANTS_DIR}/*/summary.json",))
    else:
        lastwords.retract(out_dir / SWEEP_FILE)


def _mark_interrupted(todo: list[VariantTask], rows: dict[int, dict[str, Any]], exc: BaseException) -> None:
    """Variants that were running when the sweep was interrupted (their workers are gone): their
    summary.json from ``running`` to ``interrupted`` with the signal and the progress they had reached."""
    name = getattr(exc, "signal_name", "SIGINT")
    for task in todo:
        if task.index in rows:
            continue
        path = Path(task.folder) / "summary.json"
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if data.get("status") != "running":
            continue
        data.update(status="interrupted", signal=name, reason=f"sweep interrupted by {name}",
                    stopped_at_s=data.get("sim_time_s"))
        try:
            replace_text(path, json.dumps(data, indent=2) + "\n")
        except OSError:
            pass


def run_sweep(sweep: Sweep, out_dir: str | Path | None = None, *, workers: int | None = None,
              scheduler: str | None = None, client: Any = None, progress: bool = True,
              resume: bool = True, transfer: str = "auto") -> SweepResult:
    """Run every variant of ``sweep`` not already finished on Dask; write the table, figure and sweep.json.

    Args:
        sweep: from ``load_sweep`` (already validated).
        out_dir: results folder (default ``results/<sweep name>/``).
        workers: worker processes of the embedded LocalCluster (default: CPU count).
        scheduler: address of an existing Dask scheduler instead of the embedded cluster.
        client: an existing ``dask.distributed.Client`` to use (then workers/scheduler are ignored).
        progress: show a tqdm bar over the variants on stderr.
        resume: reuse finished variant folders of the same hash (False: run everything again).
        transfer: ``"shared"``: workers read the scenario's files and write the variant folders at the
            client's paths (a shared file system); ``"ship"``: each task carries its document and
            the files it refers to, runs in the worker's temporary folder and brings back its row,
            summary.json, run.log and the ``[sweep] collect`` files (or writes them to ``[sweep]
            store``); ``"auto"``: shared on the embedded cluster (or a ``client`` of a LocalCluster),
            ship on an external ``scheduler``.
    """
    start = time.perf_counter()
    mode = resolve_transfer(transfer, scheduler, client)
    out_dir = Path(out_dir) if out_dir is not None else default_out_dir(sweep)
    (out_dir / VARIANTS_DIR).mkdir(parents=True, exist_ok=True)
    tasks = variant_tasks(sweep, out_dir)
    rows: dict[int, dict[str, Any]] = {}
    if resume:
        for task in tasks:
            row = reuse_finished(task, out_dir / VARIANTS_DIR)
            if row is not None:
                rows[task.index] = row
    todo = [t for t in tasks if t.index not in rows]
    if mode == "ship":   # only the variants that run read their input files
        todo = with_inputs(sweep, todo)
    reused = len(rows)
    started_at = datetime.now(timezone.utc).isoformat(timespec="seconds")
    _write_definition(sweep, out_dir, {"status": "running", "started_at": started_at, "reused": reused})
    table_path = out_dir / TABLE_FILE
    write_table(table_path, list(rows.values()), sweep.parameters)
    workers_seen, where = 0, ""
    if todo:
        context = contextlib.nullcontext(client) if client is not None else \
            dask_client(workers, scheduler, sweep.retries)
        try:
            with context as dask_client_:
                workers_seen = len(dask_client_.scheduler_info().get("workers", {}))
                where = scheduler or getattr(dask_client_.scheduler, "address", "")
                _run_tasks(dask_client_, sweep, todo, rows, table_path, len(tasks), reused, progress,
                           mode == "ship")
                workers_seen = max(workers_seen, len(dask_client_.scheduler_info().get("workers", {})))
        except KeyboardInterrupt as exc:  # the cluster is closed: say so in every unfinished variant and sweep.json
            _mark_interrupted(todo, rows, exc)
            _write_definition(sweep, out_dir, {"status": "interrupted", "started_at": started_at, "reused": reused,
                                               "signal": getattr(exc, "signal_name", "SIGINT"),
                                               "finished": len(rows)})
            raise
        except Exception as exc:  # the scheduler did not answer, the cluster failed: sweep.json must not stay running
            reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            _write_definition(sweep, out_dir, {"status": "failed", "reason": reason, "started_at": started_at,
                                               "reused": reused, "finished": len(rows)})
            raise
    ordered = [rows[t.index] for t in tasks]
    write_table(table_path, ordered, sweep.parameters)
    figure = None
    notes: list[str] = []
    if sweep.report is not None:
        from cosim.sweep.report import plot_report

        figure, note = plot_report(ordered, sweep.report, out_dir / sweep.report.file, sweep.name)
        if note:
            notes.append(note)
    result = SweepResult(out_dir, table_path, figure, ordered, len(todo), reused, workers_seen,
                         time.perf_counter() - start, where, notes, list(sweep.parameters), mode)
    _write_definition(sweep, out_dir, {
        "status": "finished", "started_at": started_at, "wall_time_s": result.wall_time_s, "ran": result.ran,
        "reused": reused, "ok": result.ok, "failed": result.failed, "workers": workers_seen,
        "scheduler": where, "client": worker_name(), "table": TABLE_FILE, "transfer": mode, "store": sweep.store,
        "figure": None if figure is None else figure.name})
    return result


def _run_tasks(client: Any, sweep: Sweep, todo: list[VariantTask], rows: dict[int, dict[str, Any]],
               table_path: Path, total: int, reused: int, progress: bool, ship: bool = False) -> None:
    """Submit ``todo``, collect rows as they complete (progress bar, table rewritten every few seconds).

    ``ship``: each input file is submitted once (a task returning its content, held on a worker
    and fetched by the variants that need it), read here at submission and never again.
    """
    from dask.distributed import as_completed

    token = uuid.uuid4().hex[:8]
    if ship:
        blobs = {digest: client.submit(_identity, Path(path).read_bytes(), key=f"cosim-input-{digest[:32]}-{token}",
                                       pure=False)
                 for digest, path in input_files(sweep, todo).items()}
        futures = {client.submit(run_shipped_variant, task, *(blobs[d] for _, d, _, _ in task.inputs),
                                 key=f"{sweep.name}-{task.id}-{token}", retries=sweep.retries, pure=False): task
                   for task in todo}
    else:
        blobs = {}
        futures = {client.submit(run_variant, task, key=f"{sweep.name}-{task.id}-{token}", retries=sweep.retries,
                                 pure=False): task for task in todo}
    bar = tqdm(total=total, initial=reused, desc=f"sweep {sweep.name}", unit="variant", file=sys.stderr,
               disable=not progress, dynamic_ncols=True)
    last_write = time.perf_counter()
    try:
        for future in as_completed(list(futures)):
            task = futures.pop(future)
            try:
                row = future.result()
                if isinstance(row, ShippedResult):
                    row = receive_shipped(task, row)
            except Exception as exc:  # KilledWorker, or the task raised after its retries
                row = make_row(task, None, None, float("nan"), "", reason=_failure_reason(exc, sweep.retries))
            # release the result at once: a worker dying later must not make the scheduler recompute it
            future.release()
            del future
            rows[task.index] = row
            bar.update(1)
            bar.set_postfix(failed=sum(r["status"] != "ok" for r in rows.values()), refresh=False)
            if time.perf_counter() - last_write > TABLE_INTERVAL_S:
                write_table(table_path, list(rows.values()), sweep.parameters)
                last_write = time.perf_counter()
    except BaseException:
        client.cancel(list(futures))
        write_table(table_path, list(rows.values()), sweep.parameters)
        raise
    finally:
        bar.close()
        for blob in blobs.values():
            blob.release()


__all__ = ["SCHEDULER_CONNECT_TIMEOUT_S", "SWEEP_FILE", "SchedulerUnreachable", "SweepResult", "TABLE_FILE",
           "TRANSFERS", "VARIANTS_DIR", "dask_client", "default_out_dir", "input_files", "resolve_transfer",
           "run_sweep", "variant_tasks", "with_inputs"]
