"""Sweeps that ship their inputs and results: a Dask scheduler and two worker processes started
as separate programs (``sys.executable -m distributed.cli.dask_*``), each worker in its own
working directory and TMPDIR; the tasks are submitted before any worker exists and the client's
scenario folder is then renamed away, so no worker can read a file at the client's paths. The
client ends with every row, the collected time series (equal to a local run of the same
variant), the failed variants' reasons; a re-run resumes; a store URL receives the artifacts."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

import cosim
from sweep_files import client_files, planner_files

ROOT = Path(__file__).resolve().parents[3]
TESTS = Path(__file__).resolve().parents[2]

def _env(tmp: Path) -> dict[str, str]:
    env = dict(os.environ, TMPDIR=str(tmp), PYTHONPATH=os.pathsep.join([str(ROOT), str(TESTS)]),
               MPLBACKEND="Agg", PYTHONDONTWRITEBYTECODE="1")
    tmp.mkdir(parents=True, exist_ok=True)
    return env


@pytest.fixture
def scheduler(tmp_path):
    """A scheduler process with no workers yet; yields (address, start_worker(name) -> folder)."""
    home = tmp_path / "scheduler"
    home.mkdir()
    info = home / "scheduler.json"
    procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                               "--port", "0", "--no-dashboard", "--scheduler-file", str(info)],
                              cwd=home, env=_env(home / "tmp"), stdout=subprocess.DEVNULL,
                              stderr=open(home / "log", "w"))]
    deadline = time.monotonic() + 60
    while not info.is_file() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert info.is_file(), (home / "log").read_text()
    time.sleep(0.2)
    address = json.loads(info.read_text())["address"]

    def start_worker(name: str) -> Path:
        folder = tmp_path / name
        (folder / "cwd").mkdir(parents=True)
        procs.append(subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", address,
                                       "--nthreads", "1", "--no-nanny", "--no-dashboard",
                                       "--local-directory", str(folder / "dask")],
                                      cwd=folder / "cwd", env=_env(folder / "tmp"), stdout=subprocess.DEVNULL,
                                      stderr=open(folder / "log", "w")))
        return folder

    try:
        yield address, start_worker
    finally:
        for proc in reversed(procs):
            proc.terminate()
        for proc in reversed(procs):
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()


def _tasks_on_scheduler(address: str) -> int:
    from dask.distributed import Client

    with Client(address, timeout=30) as c:
        return c.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.tasks))


def test_sweep_on_workers_without_the_clients_files(tmp_path, scheduler):
    address, start_worker = scheduler
    client_dir = tmp_path / "client"
    sweep = cosim.load_sweep(client_files(client_dir))
    planner_sweep = cosim.load_sweep(planner_files(client_dir))
    out = tmp_path / "out"
    done: dict = {}
    runners = [threading.Thread(target=lambda: done.setdefault("result", cosim.run_sweep(
                   sweep, out, scheduler=address)), daemon=True),
               threading.Thread(target=lambda: done.setdefault("planners", cosim.run_sweep(
                   planner_sweep, tmp_path / "planners_out", scheduler=address)), daemon=True)]
    for runner in runners:
        runner.start()
    deadline = time.monotonic() + 60
    # 4 + 2 variants, 2 FMUs + the planner file: all submitted before any worker exists
    while _tasks_on_scheduler(address) < 4 + 2 + 2 + 1 and time.monotonic() < deadline:
        time.sleep(0.2)
    assert _tasks_on_scheduler(address) >= 9
    client_dir.rename(tmp_path / "client_gone")       # nothing at the client's paths any more
    workers = [start_worker("worker1"), start_worker("worker2")]
    for runner in runners:
        runner.join(timeout=240)
        assert not runner.is_alive(), "a sweep did not finish"
    result = done["result"]
    assert (result.transfer, result.ran, result.reused) == ("ship", 4, 0)

    rows = {(r["values"]["fmus[0].parameters.y0"], r["values"]["fmus[1].parameters.fail_time"]): r
            for r in result.rows}
    assert len(rows) == 4 and result.ok == 2 and result.failed == 2
    worker_pids = {r["worker"].split(":")[1] for r in result.rows}
    assert str(os.getpid()) not in worker_pids
    # each worker got the FMUs in its own TMPDIR (content-addressed cache), and left no run folder there
    used = [w for w in workers if (w / "tmp" / "cosim-inputs").is_dir()]
    assert used, "no worker cached the shipped inputs"
    for w in used:
        cached = sorted(p.name for p in (w / "tmp" / "cosim-inputs").rglob("*.fmu"))
        assert set(cached) <= {"Faulty.fmu", "Integrator.fmu"}
        assert not list((w / "tmp").glob("cosim-v*")) and not list((w / "cwd").iterdir())

    # the user's planner file was recreated next to a worker-side scenario folder (relative reference kept)
    assert any(list((w / "tmp" / "cosim-inputs" / "anchors").glob("*/scenario/plans/quintic.py")) for w in used)
    planners = done["planners"]
    assert planners.ok == 2, [r["reason"] for r in planners.rows]
    slow, fast = (r["metrics"]["planners.quintic_ptp.duration_s"] for r in planners.rows)
    assert slow > fast > planners.rows[0]["metrics"]["planners.ruckig.duration_s"]

    shutil.move(tmp_path / "client_gone", client_dir)   # back, to run the variants here for comparison
    local = cosim.run(client_dir / "ptp.toml", out=tmp_path / "local_planner")
    assert local.summary["planners.quintic_ptp.duration_s"] == fast     # speed_factor 0.8 in the file
    for (y0, fail_time), row in rows.items():
        folder = Path(row["folder"])
        assert folder.parent == out / "variants"
        names = sorted(p.name for p in folder.iterdir())
        assert names == ["run.log", "scenario.toml", "summary.json", "sweep_row.json", "timeseries.parquet"]
        assert row["artifacts"] == ["timeseries.parquet"]
        summary = json.loads((folder / "summary.json").read_text())
        local = cosim.run(client_dir / "base.toml", out=tmp_path / f"local_{y0}_{fail_time}", check=False,
                          overrides={"fmus[0].parameters.y0": y0, "fmus[1].parameters.fail_time": fail_time})
        assert summary["status"] == local.status == row["status"]
        assert (folder / "timeseries.parquet").read_bytes() == (local.out / "timeseries.parquet").read_bytes()
        # the variant's scenario.toml is the client's document (the client's paths), runnable here
        assert cosim.load_scenario(folder / "scenario.toml").data["fmus"][0]["path"] == \
            client_dir / "fmus" / "Integrator.fmu"
        if fail_time == 0.05:
            assert row["reason"].startswith("f at t = 0.04 s: fmi2DoStep"), row["reason"]
            assert summary["reason"] == row["reason"]
        else:
            assert row["status"] == "ok" and row["metrics"]["rows_recorded"] == 11
            assert cosim.RunResult.open(folder).timeseries("timeseries", kind="numpy")["i.y"][0] == y0

    # resume: a second run reuses every variant; with a store URL the workers write the artifacts there
    again = cosim.run_sweep(cosim.load_sweep(client_dir / "sweep.toml"), out, scheduler=address)
    assert (again.ran, again.reused, again.ok) == (0, 4, 2)
    store = tmp_path / "store"
    stored = cosim.build_sweep(client_dir / "base.toml", {"fmus[0].parameters.k": [5.0]}, name="stored",
                               collect=["timeseries"], store=f"file://{store}")
    res = cosim.run_sweep(stored, tmp_path / "out2", scheduler=address)
    row = res.rows[0]
    assert row["status"] == "ok" and row["store"] == f"file://{store}/{Path(row['folder']).parent.name}/" \
        f"{Path(row['folder']).name}"
    remote = store / "variants" / Path(row["folder"]).name
    assert sorted(p.name for p in remote.iterdir()) == ["run.log", "summary.json", "timeseries.parquet"]
    assert sorted(p.name for p in Path(row["folder"]).iterdir()) == ["run.log", "scenario.toml", "summary.json",
                                                                     "sweep_row.json"]


def test_collect_and_store_are_validated(tmp_path):
    sweep_path = client_files(tmp_path / "client")
    text = sweep_path.read_text()
    sweep_path.write_text(text.replace('collect = ["timeseries"]', 'collect = ["timeseries"]\nstore = "nosuch://x"'))
    with pytest.raises(cosim.ScenarioError) as info:
        cosim.load_sweep(sweep_path)
    assert info.value.key == "sweep.store" and "fsspec" in info.value.expected
    sweep_path.write_text(text.replace('collect = ["timeseries"]', 'collect = "timeseries"'))
    with pytest.raises(cosim.ScenarioError) as info:
        cosim.load_sweep(sweep_path)
    assert info.value.key == "sweep.collect"
    local = cosim.load_sweep(sweep_path.read_text().replace('collect = "timeseries"', 'store = "artifacts"')
                             .replace('base = "base.toml"', f'base = "{tmp_path / "client" / "base.toml"}"'))
    assert local.store == str(Path.cwd() / "artifacts")


def test_referenced_files_from_the_schema():
    """What a task ships: FilePath values, files of 'file.py:Class' in string fields, and what
    specs with referenced_file() name - found by walking the job's schema, nothing else."""
    from cosim.scenario.schema import AnyValue, Field, FilePath, List, String, Table
    from cosim.scenario.keypath import referenced_files, relocate_file

    schema = Table({
        "controller": Field(Table({"class": Field(String()), "fmu": Field(FilePath()),
                                   "label": Field(String())})),
        "fmus": Field(List(Table({"path": Field(FilePath()), "name": Field(String())}))),
        "free": Field(Table({}, extra=AnyValue())),
    })
    doc = {"controller": {"class": "ctrl/my.py:MyController", "fmu": "/abs/c.fmu", "label": "my_run"},
           "fmus": [{"path": "a.fmu", "name": "a"}, {"name": "builtin"}],
           "free": {"anything": "other.py:Class"}}   # AnyValue: the schema does not say it is a file
    found = referenced_files(schema, doc)
    assert found == [(("controller", "class"), "ctrl/my.py"), (("controller", "fmu"), "/abs/c.fmu"),
                     (("fmus", 0, "path"), "a.fmu")]
    assert relocate_file(String(), "ctrl/my.py:MyController", "/w/my.py") == "/w/my.py:MyController"
    assert referenced_files(schema, {"controller": {"class": "package.module:MyController"}}) == []
    from cosim.jobs.planners import PlannerEntry
    assert referenced_files(List(PlannerEntry()), ["ruckig", "p/q.py:P", "mod:P"]) == [((1,), "p/q.py")]
