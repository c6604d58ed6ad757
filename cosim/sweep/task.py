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
import hashlib
import json
import os
import shutil
import socket
import tempfile
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import tomli_w

from cosim.sweep.table import select_metrics

SCENARIO_FILE = "scenario.toml"
SUMMARY_FILE = "summary.json"
ROW_FILE = "sweep_row.json"
LOG_FILE = "run.log"
FINISHED = ("ok", "limit", "fault", "failed")
#: One variant at a time per process, even on a worker with several threads (an external
#: cluster started without ``--nthreads 1``): FMU instances and the redirected stdout/stderr
#: of a run are never shared between threads.
_ONE_AT_A_TIME = threading.Lock()
#: Exit codes of ``cosim run`` (cosim/commands/run.py) -> words for the reason column.
EXIT_WORDS = {2: "invalid scenario", 3: "run failed", 4: "a run hit a limit", 5: "a fault reaction",
              130: "interrupted"}


@dataclass(frozen=True)
class VariantTask:
    """Everything a worker needs to run one variant (picklable, no open resources).

    Attributes:
        index, id, hash: the variant's position, name and hash (cosim.sweep.loader.Variant).
        folder: its results folder (absolute path).
        document: the scenario document to write and run.
        values: axis key -> validated value (the parameter columns).
        metrics: metric globs of ``[sweep] metrics`` (None: every numeric leaf).
        relative_folder: ``variants/<id>-<hash8>`` (the folder under the sweep's results folder
            and under ``store``).
        inputs: the files the document refers to, shipped to the worker: ``(key path in the
            document, SHA-256 of the content, file name, the reference's text when relative to
            ``anchor`` else "")``; the content travels as the task's extra arguments
            (:func:`run_shipped_variant`).
        collect: globs of the files to bring back (shipped runs) or to copy to ``store``.
        store: an fsspec URL the worker writes the collected files to (None: none).
        anchor: the folder relative file references of the document are relative to (the base
            scenario's; FMU and other ``FilePath`` values are absolute already). A shipped task
            recreates the referenced files at the same relative places under a worker folder.
    """

    index: int
    id: str
    hash: str
    folder: str
    document: dict[str, Any]
    values: dict[str, Any]
    metrics: tuple[str, ...] | None = None
    relative_folder: str = ""
    inputs: tuple[tuple[tuple, str, str], ...] = ()
    collect: tuple[str, ...] = ()
    store: str | None = None
    anchor: str = ""


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
    verdict = (summary or {}).get("status")
    if exit_code in (4, 5) and verdict in ("limit", "fault"):  # completed, with that verdict (not ranked as ok)
        status = verdict
    if status != "ok" and reason is None:
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
        "reason": reason if status != "ok" else None,
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
    folder = Path(task.folder)
    folder.mkdir(parents=True, exist_ok=True)
    for stale in (ROW_FILE, SUMMARY_FILE):
        (folder / stale).unlink(missing_ok=True)
    write_scenario(task, folder)
    start, cpu_start = time.perf_counter(), time.process_time()
    with open(folder / LOG_FILE, "w", encoding="utf-8") as log, \
            contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
        code = run_document(task.document, folder, task.anchor or None)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    row = make_row(task, read_summary(folder), code, wall, worker_name(), cpu_time_s=cpu)
    if task.store:
        # shared file system: the run wrote the client's folder; copy what the sweep collects to the store
        names = collected_files(folder, task.collect) + [n for n in ALWAYS_BACK if (folder / n).is_file()]
        row["store"] = upload(folder, sorted(set(names)), task.store, task.relative_folder)
    write_row(folder, row)
    return row


def run_document(document: dict[str, Any], folder: Path, anchor: str | None) -> int:
    """Run a scenario document into ``folder`` with the public API (relative file references
    resolved against ``anchor``); messages to stdout/stderr; return ``cosim run``'s exit code
    (0 ok, 2 invalid scenario or results folder, 3 the run failed, 4/5 completed with verdict
    limit/fault)."""
    import sys
    import traceback

    from cosim.master import SimulationError
    from cosim.results.outdir import OutputFolderError
    from cosim.runs.execute import execute
    from cosim.runs.scenario import load_scenario
    from cosim.scenario.errors import ScenarioError

    try:
        result = execute(load_scenario(document, base_dir=anchor), folder, report=False)  # the sweep's table is its view
    except (ScenarioError, OutputFolderError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except SystemExit as exc:  # a job calling sys.exit
        return exc.code if isinstance(exc.code, int) else 3
    if result.ok:
        return 0
    if result.status in ("limit", "fault"):  # completed with that verdict: exit 4 / 5 as cosim run
        from cosim.cell.verdict import exit_code

        print(f"{result.status}: {result.summary.reason}", file=sys.stderr)
        return exit_code(result.status)
    print(f"error: run failed: {result.summary.reason}", file=sys.stderr)
    if result.error is not None and not isinstance(result.error, SimulationError):
        traceback.print_exception(result.error, file=sys.stderr)
    return 3


#: Files a shipped variant always brings back (besides its row); scenario.toml is written by the client.
ALWAYS_BACK = (SUMMARY_FILE, LOG_FILE)


@dataclass
class ShippedResult:
    """What a shipped variant returns: its row, and the files it brings back ``{relative path: bytes}``."""

    row: dict[str, Any]
    files: dict[str, bytes]


def _input_cache() -> Path:
    """The worker's cache of shipped input files (content-addressed, under its temporary folder)."""
    return Path(tempfile.gettempdir()) / "cosim-inputs"


def _write_once(target: Path, data: bytes) -> None:
    if not target.is_file():
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
        tmp.write_bytes(data)
        os.replace(tmp, target)


def _materialize(task: VariantTask, blobs: tuple[bytes, ...]) -> tuple[dict[str, Any], str | None]:
    """Write the shipped input files on the worker; return the document pointing at them and its anchor.

    Absolute references (FMU paths, ...) go to a content-addressed cache and the document is
    changed to point there; references relative to the scenario's folder are recreated at the
    same relative places under an anchor folder (named by their contents, so a worker imports a
    user's module file once), which the document is then run against.
    """
    from cosim.scenario import get_job
    from cosim.scenario.keypath import get_path, relocate_file, spec_at, with_value

    if len(blobs) != len(task.inputs):
        raise ValueError(f"variant {task.id}: {len(task.inputs)} input files expected, {len(blobs)} received")
    for (_, digest, name, _), data in zip(task.inputs, blobs):
        if hashlib.sha256(data).hexdigest() != digest:
            raise ValueError(f"variant {task.id}: input file {name} arrived damaged (SHA-256 differs)")
    job = get_job(task.document["scenario"]["job"])
    document = task.document
    relative = sorted({(rel, digest) for _, digest, _, rel in task.inputs if rel})
    anchor = None
    if relative:
        ups = max(os.path.normpath(rel).split(os.sep).count("..") for rel, _ in relative)
        key = hashlib.sha256(repr(relative).encode()).hexdigest()[:24]
        anchor_dir = _input_cache() / "anchors" / key / "scenario" / os.path.join(*(["up"] * ups or ["."]))
        anchor = str(anchor_dir.resolve())
    for (path, digest, name, rel), data in zip(task.inputs, blobs):
        if rel:
            _write_once(Path(os.path.normpath(Path(anchor) / rel)), data)
            continue
        target = _input_cache() / digest[:24] / name
        _write_once(target, data)
        spec = spec_at(job.schema, tuple(path), document) if job is not None else None
        old = get_path(document, tuple(path), None)
        document = with_value(document, tuple(path), relocate_file(spec, old, str(target)) if spec else str(target))
    return document, anchor


def collected_files(folder: Path, globs: tuple[str, ...]) -> list[str]:
    """Files under ``folder`` matching ``globs`` (relative POSIX paths, sorted; no temporary files)."""
    found: set[str] = set()
    for glob in globs:
        for path in folder.glob(glob):
            if path.is_file() and not path.name.endswith(".tmp"):
                found.add(path.relative_to(folder).as_posix())
    return sorted(found)


def upload(folder: Path, names: list[str], store: str, relative_folder: str) -> str:
    """Copy ``names`` (relative to ``folder``) to ``<store>/<relative_folder>/`` through fsspec; return that URL."""
    import fsspec

    fs, root = fsspec.core.url_to_fs(store)
    target = f"{root.rstrip('/')}/{relative_folder}"
    for name in names:
        remote = f"{target}/{name}"
        fs.makedirs(remote.rsplit("/", 1)[0], exist_ok=True)
        fs.put_file(str(folder / name), remote)
    return f"{store.rstrip('/')}/{relative_folder}"


def run_shipped_variant(task: VariantTask, *blobs: bytes) -> ShippedResult:
    """Run one variant on a worker that shares no files with the client.

    ``blobs`` are the contents of ``task.inputs`` (written to the worker's cache and put into the
    document); the run goes to a fresh folder under the worker's temporary folder, which is removed
    afterwards. Returns the row (its ``folder`` is the client's) and the files brought back:
    summary.json and run.log always, the ``collect`` globs unless ``store`` is set (then the worker
    writes them to the store and the row's ``store`` names the URL).
    """
    with _ONE_AT_A_TIME:
        work = Path(tempfile.mkdtemp(prefix=f"cosim-{task.id}-"))
        try:
            document, anchor = _materialize(task, blobs)
            local = replace(task, folder=str(work / "run"), document=document, store=None, anchor=anchor or "")
            row = _run_variant(local)
            run_dir = Path(local.folder)
            names = [n for n in collected_files(run_dir, task.collect) if n not in (SCENARIO_FILE, ROW_FILE)]
            back = list(ALWAYS_BACK)
            if task.store:
                row["store"] = upload(run_dir, sorted(set(names) | set(ALWAYS_BACK)), task.store,
                                      task.relative_folder)
            else:
                back += [n for n in names if n not in back]
            row.update(folder=task.folder, artifacts=names)
            files = {n: (run_dir / n).read_bytes() for n in back if (run_dir / n).is_file()}
            return ShippedResult(row, files)
        finally:
            shutil.rmtree(work, ignore_errors=True)


def receive_shipped(task: VariantTask, result: ShippedResult) -> dict[str, Any]:
    """On the client: write what a shipped variant brought back into its folder (the row last, so
    an interrupted write is run again by the next resume); return the row."""
    folder = Path(task.folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / ROW_FILE).unlink(missing_ok=True)
    write_scenario(task, folder)
    for name, data in result.files.items():
        target = (folder / name).resolve()
        if folder.resolve() not in target.parents:
            raise ValueError(f"variant {task.id}: refusing to write {name!r} outside its folder")
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(target.name + ".tmp")
        tmp.write_bytes(data)
        os.replace(tmp, target)
    row = dict(result.row, folder=task.folder)
    write_row(folder, row)
    return row


def write_scenario(task: VariantTask, folder: Path) -> Path:
    """Write the variant's document as ``<folder>/scenario.toml``."""
    path = folder / SCENARIO_FILE
    path.write_text(f"# variant {task.id} (hash {task.hash}) of a sweep; run by cosim.sweep\n"
                    + tomli_w.dumps(task.document), encoding="utf-8")
    return path


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


__all__ = ["ALWAYS_BACK", "FINISHED", "LOG_FILE", "ROW_FILE", "SCENARIO_FILE", "SUMMARY_FILE", "ShippedResult",
           "VariantTask", "collected_files", "finished_row", "make_row", "read_summary", "receive_shipped",
           "reuse_finished", "run_shipped_variant", "run_variant", "upload", "worker_name", "write_row",
           "write_scenario"]
