"""--realtime and --split apply to every job that runs the robot cell: each such job runs its
cells through cosim.execution.run_cell (which hands them to the execution) - directly, through
cosim.execution.mode_runs.run_mode, or through cosim.execution.mode_pool.run_modes (which runs run_mode
in its workers, or in this process under --realtime/--split) - and a job other than
the main one - the fieldbus fault job - runs split over two processes with the same reaction."""
from __future__ import annotations

import ast
import json
from pathlib import Path

from cosim.cli import main
from cosim.execution.cell_execution import CELL_JOBS
from scenario_files import write_variant

ROOT = Path(__file__).resolve().parents[3]


def test_every_job_that_runs_the_cell_honours_the_execution_options():
    runs_cell = set()
    for path in (ROOT / "cosim" / "jobs").glob("*.py"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        calls = {n.func.id for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
        names = [n.value.value for n in ast.walk(tree) if isinstance(n, ast.Assign)
                 and any(isinstance(t, ast.Name) and t.id == "JOB_NAME" for t in n.targets)]
        if calls & {"run_cell", "run_mode", "run_modes"}:
            runs_cell.update(names)
    assert runs_cell == {"iso9283", "fieldbus_fault", "identification", "planners", "compare"}
    assert runs_cell <= CELL_JOBS


def test_fieldbus_fault_job_runs_split(tmp_path):
    path = write_variant((ROOT / "scenarios" / "fieldbus_loss.toml").read_text(), tmp_path / "loss.toml", [
        ('stop_time = "3 s"', 'stop_time = "1 s"'), ('settle_time = "0.2 s"', 'settle_time = "10 ms"'),
        ("start_cycle = 2500", "start_cycle = 100")])
    text = path.read_text().replace("figures = true", "figures = false")
    path.write_text(text)
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out), "--quiet", "--split"]) == 5  # verdict fault (exits.py)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "fault" and summary["execution"]["mode"] == "split"
    split = summary["execution"]["split"]["model_based"]
    assert split["drive_process_exit_code"] == 0
    assert all(e["tripped_as_expected"] for e in summary["expected_trips"])
    assert summary["controller"]["stopped_at_cycle"] == 101 and summary["rest"]["at_rest"]
