"""Sweeps on a two-process Dask LocalCluster: every row equals running the same variant alone
with ``python -m cosim run``; a worker killed in the middle of a variant has its task retried
and the sweep completes; a failing variant is recorded with its reason; a second run skips
the variants that finished."""
from __future__ import annotations

import csv
import json
import os
import textwrap
from pathlib import Path

import pytest

from cosim.cli import main as cosim_main
from cosim.results import read_series
from cosim.sweep import dask_client, load_sweep, run_sweep
from cosim_fmu_models import build_test_fmu

ROOT = Path(__file__).resolve().parents[3]

#: A pythonfmu model that SIGKILLs the process running it, once (marker file), when its
#: offset equals kill_at: y = offset + t.
KILLER_MODEL = '''
import os
import signal
from pathlib import Path

from pythonfmu.fmi2slave import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real, String


class Killer(Fmi2Slave):
    author = "rx130l-cosim tests"
    description = "kills its process once"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.offset = 0.0
        self.kill_at = -1.0
        self.marker = ""
        self.y = 0.0
        self.register_variable(Real("offset", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable))
        self.register_variable(Real("kill_at", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable))
        self.register_variable(String("marker", causality=Fmi2Causality.parameter,
                                      variability=Fmi2Variability.tunable))
        self.register_variable(Real("y", causality=Fmi2Causality.output, initial=Fmi2Initial.exact))

    def do_step(self, current_time, step_size):
        self.y = self.offset + current_time + step_size
        if self.offset == self.kill_at and self.marker and not Path(self.marker).exists():
            Path(self.marker).write_text(str(os.getpid()))
            os.kill(os.getpid(), signal.SIGKILL)
        return True
'''

PLANT_BASE = """
connections = []

[scenario]
name = "drop"
job = "fmus"

[simulation]
stop_time = 0.1
macro_step = "200 us"

[[fmus]]
name = "plant"
builtin = "rx130l_plant"
[fmus.parameters]
"q0[2]" = -0.3
"q0[3]" = 1.2

[record]
period = "1 ms"
signals = ["plant.q[*]", "plant.qd[2]"]
"""


@pytest.fixture(scope="module")
def client():
    """One embedded cluster of two single-threaded worker processes for the module's tests."""
    with dask_client(workers=2, retries=3) as c:
        yield c


def read_table(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def test_rows_equal_serial_runs_of_the_same_variants(tmp_path, client):
    (tmp_path / "base.toml").write_text(PLANT_BASE, encoding="utf-8")
    sweep_path = tmp_path / "sweep.toml"
    sweep_path.write_text(textwrap.dedent("""
        [sweep]
        name = "drop_sweep"
        base = "base.toml"

        [[axes]]
        key = 'fmus[0].parameters."q0[2]"'
        values = [-0.3, 0.4]

        [[axes]]
        key = "simulation.stop_time"
        values = ["0.1 s", "60 ms"]

        [report]
        metric = "rows_recorded"
        parameter = "simulation.stop_time"
        group = 'fmus[0].parameters."q0[2]"'
        """), encoding="utf-8")
    sweep = load_sweep(sweep_path)
    result = run_sweep(sweep, tmp_path / "out", client=client, progress=False)
    assert (result.ran, result.reused, result.ok, result.workers) == (4, 0, 4, 2)
    assert result.figure is not None and result.figure.stat().st_size > 10_000
    rows = read_table(result.table)
    assert [r["variant"] for r in rows] == ["v0000", "v0001", "v0002", "v0003"]
    assert len({r["worker"] for r in rows}) == 2          # both worker processes ran variants
    assert all(r["worker"].split(":")[1] != str(os.getpid()) for r in rows)

    # the same variants, one by one, in this process, from scenario files written here
    for q2, stop in [(-0.3, "0.1 s"), (-0.3, "60 ms"), (0.4, "0.1 s"), (0.4, "60 ms")]:
        row = next(r for r in rows if float(r['fmus[0].parameters."q0[2]"']) == q2
                   and abs(float(r["simulation.stop_time"]) - {"0.1 s": 0.1, "60 ms": 0.06}[stop]) < 1e-12)
        alone = tmp_path / f"alone_{q2}_{stop.replace(' ', '')}"
        alone.mkdir()
        text = PLANT_BASE.replace('"q0[2]" = -0.3', f'"q0[2]" = {q2}').replace("stop_time = 0.1",
                                                                                f'stop_time = "{stop}"')
        (alone / "s.toml").write_text(text, encoding="utf-8")
        assert cosim_main(["run", str(alone / "s.toml"), "--out", str(alone), "--quiet"]) == 0
        summary = json.loads((alone / "summary.json").read_text())
        assert row["status"] == "ok" and row["reason"] == ""
        assert float(row["sim_time_s"]) == summary["sim_time_s"]
        assert int(row["rows_recorded"]) == summary["rows_recorded"]
        variant_dir = result.out_dir / row["folder"]
        assert (variant_dir / "timeseries.parquet").read_bytes() == (alone / "timeseries.parquet").read_bytes()
        assert float(row["wall_time_s"]) > 0


def test_killed_worker_is_retried_and_failures_recorded(tmp_path, client):
    fmu = _build_killer(tmp_path)
    faulty = build_test_fmu("faulty", tmp_path)
    marker = tmp_path / "killed.pid"
    (tmp_path / "base.toml").write_text(textwrap.dedent(f"""
        connections = []

        [scenario]
        name = "killer"
        job = "fmus"

        [simulation]
        stop_time = 0.1
        macro_step = 0.01

        [[fmus]]
        name = "k"
        path = "{fmu.name}"
        [fmus.parameters]
        kill_at = 2.0
        marker = "{marker}"

        [[fmus]]
        name = "f"
        path = "{faulty.name}"
        [fmus.parameters]
        fail_time = 0.05
        mode = 1

        [record]
        period = 0.01
        signals = ["k.y"]
        """), encoding="utf-8")
    (tmp_path / "sweep.toml").write_text(textwrap.dedent("""
        [sweep]
        name = "kill"
        base = "base.toml"

        [[axes]]
        key = "fmus[0].parameters.offset"
        values = [1.0, 2.0, 3.0]

        [[axes]]
        key = "fmus[1].parameters.fail_time"       # 0.5 s: never fails within 0.1 s
        values = [0.5, 0.05]
        """), encoding="utf-8")
    result = run_sweep(load_sweep(tmp_path / "sweep.toml"), tmp_path / "out", client=client, progress=False)
    rows = {(float(r["fmus[0].parameters.offset"]), float(r["fmus[1].parameters.fail_time"])): r
            for r in read_table(result.table)}
    assert len(rows) == 6
    killed_pid = marker.read_text().strip()                 # the variant did kill its worker once
    killer_row = rows[(2.0, 0.5)]
    assert killer_row["status"] == "ok", killer_row["reason"]
    assert killer_row["worker"].split(":")[1] != killed_pid   # finished by another process
    columns, series = read_series(result.out_dir / killer_row["folder"] / "timeseries.parquet")
    assert float(series[-1, columns.index("k.y")]) == pytest.approx(2.0 + 0.1)
    for (offset, fail_time), row in rows.items():
        if fail_time == 0.5:
            assert row["status"] == "ok", row["reason"]
        else:   # the faulty FMU fails at 0.05 s: recorded with the runner's reason, the sweep went on
            assert row["status"] == "failed"
            assert row["reason"].startswith("f at t = 0.04 s: fmi2DoStep"), row["reason"]
            summary = json.loads((result.out_dir / row["folder"] / "summary.json").read_text())
            assert summary["status"] == "failed" and summary["reason"] == row["reason"]
    assert result.failed == 3 and result.ok == 3


def _build_killer(dest: Path) -> Path:
    from pythonfmu.builder import FmuBuilder

    script = dest / "killer.py"
    script.write_text(KILLER_MODEL, encoding="utf-8")
    return Path(FmuBuilder.build_FMU(script, dest=dest))


def test_second_run_skips_finished_variants(tmp_path, client):
    (tmp_path / "base.toml").write_text(PLANT_BASE, encoding="utf-8")
    sweep_text = textwrap.dedent("""
        [sweep]
        name = "resume"
        base = "base.toml"

        [[axes]]
        key = 'fmus[0].parameters."q0[3]"'
        values = [1.0, 1.2, 1.4]
        """)
    (tmp_path / "sweep.toml").write_text(sweep_text, encoding="utf-8")
    out = tmp_path / "out"
    first = run_sweep(load_sweep(tmp_path / "sweep.toml"), out, client=client, progress=False)
    assert (first.ran, first.reused, first.ok) == (3, 0, 3)
    stamps = {r["variant"]: (Path(r["folder"]) / "summary.json").stat().st_mtime_ns for r in first.rows}

    second = run_sweep(load_sweep(tmp_path / "sweep.toml"), out, client=client, progress=False)
    assert (second.ran, second.reused, second.ok) == (0, 3, 3)
    assert read_table(second.table) == read_table(first.table)
    assert {r["variant"]: (Path(r["folder"]) / "summary.json").stat().st_mtime_ns for r in second.rows} == stamps

    # an unfinished variant (summary says running) and a new axis value run; the rest are reused,
    # including v0001 that became v0002 once a value was inserted before it
    summary_path = Path(first.rows[0]["folder"]) / "summary.json"
    summary = json.loads(summary_path.read_text())
    summary_path.write_text(json.dumps({**summary, "status": "running"}))
    (tmp_path / "sweep.toml").write_text(sweep_text.replace("[1.0, 1.2, 1.4]", "[1.0, 1.1, 1.2, 1.4]"),
                                         encoding="utf-8")
    # (this time through the scheduler address, as with --scheduler: the same cluster, a new client)
    third = run_sweep(load_sweep(tmp_path / "sweep.toml"), out, scheduler=client.scheduler.address, progress=False)
    assert (third.ran, third.reused, third.ok) == (2, 2, 4)
    # the shared cluster's nanny may still be restarting a worker killed by an earlier test,
    # so the count seen at connection time is 1 or 2 (the same scheduler either way)
    assert third.workers in (1, 2)
    rows = read_table(third.table)
    assert [float(r['fmus[0].parameters."q0[3]"']) for r in rows] == [1.0, 1.1, 1.2, 1.4]
    moved = next(r for r in third.rows if r["variant"] == "v0002")
    assert (Path(moved["folder"]) / "summary.json").stat().st_mtime_ns == stamps["v0001"]


def test_local_cluster_ship_equals_shared(tmp_path, client):
    """transfer = "ship" on the embedded cluster gives the rows and files of the shared file system
    (tests/cosim/sweep/test_ship.py runs it on separate worker programs without the client's files)."""
    import cosim
    from sweep_files import client_files

    sweep = cosim.load_sweep(client_files(tmp_path / "client"))
    shipped = cosim.run_sweep(sweep, tmp_path / "ship", client=client, transfer="ship")
    shared = cosim.run_sweep(sweep, tmp_path / "shared", client=client)
    assert (shipped.transfer, shared.transfer) == ("ship", "shared")
    for a, b in zip(shipped.records(), shared.records()):
        for column in ("variant", "status", "reason", "hash", "rows_recorded", "sim_time_s"):
            assert a.get(column) == b.get(column)
        assert (Path(a["folder"]) / "timeseries.parquet").read_bytes() == \
            (Path(b["folder"]) / "timeseries.parquet").read_bytes()


def test_user_planner_file_relative_to_the_base_scenario(tmp_path, client):
    """A sweep over the planners job with a user's planner class named relative to the base
    scenario ('plans/quintic.py:QuinticPtP', parameters keyed by that text): each variant runs
    anchored at the base scenario's folder (shared) or at a worker-side copy of it (ship)."""
    import cosim
    from sweep_files import planner_files

    sweep = cosim.load_sweep(planner_files(tmp_path / "client"))
    shared = cosim.run_sweep(sweep, tmp_path / "shared", client=client)
    shipped = cosim.run_sweep(sweep, tmp_path / "ship", client=client, transfer="ship")
    assert shared.ok == shipped.ok == 2, [r["reason"] for r in shared.rows + shipped.rows]
    assert [r["metrics"] for r in shared.rows] == [r["metrics"] for r in shipped.rows]
    slow, fast = (r["metrics"]["planners.quintic_ptp.duration_s"] for r in shared.rows)
    assert slow > fast


def test_embedded_workers_drop_only_the_heartbeat_failure_of_a_closing_worker(client):
    """The embedded cluster's workers carry QuietHeartbeatAtClose: the heartbeat that fails while a
    worker closes (a Dask race, dask/distributed#7891) is not printed with its traceback; the same
    failure while the worker runs, and every other record, still is."""
    import logging
    from types import SimpleNamespace

    from distributed.core import Status

    from cosim.sweep.worker_plugin import HEARTBEAT_FAILED, QuietHeartbeatAtClose, _HeartbeatAtCloseFilter

    def installed(dask_worker):
        return [type(p).__name__ for p in dask_worker.plugins.values()]

    assert all("QuietHeartbeatAtClose" in names for names in client.run(installed).values())
    worker = SimpleNamespace(status=Status.running)
    keep = _HeartbeatAtCloseFilter(worker)
    record = logging.LogRecord("distributed.worker", logging.ERROR, __file__, 1, HEARTBEAT_FAILED + ".", None, None)
    other = logging.LogRecord("distributed.worker", logging.ERROR, __file__, 1, "Unexpected exception", None, None)
    assert keep.filter(record) and keep.filter(other)
    for status in (Status.closing, Status.closing_gracefully, Status.closed):
        worker.status = status
        assert not keep.filter(record) and keep.filter(other)
    assert QuietHeartbeatAtClose.idempotent
