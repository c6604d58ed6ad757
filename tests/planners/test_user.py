"""User planners through the Planner contract: named in [planners] run as 'file.py:Class' or
'module:Class', run next to the built-in ones; every mistake a clear ScenarioError at its key."""
from __future__ import annotations

from pathlib import Path

import pytest

from cosim.scenario import ScenarioError, load_scenario
from planners.base import Planner
from planners.trajectory import Trajectory
from scenario_files import run_scenario, write_variant

ROOT = Path(__file__).resolve().parents[2]
PTP_TEXT = (ROOT / "scenarios" / "ptp_line.toml").read_text(encoding="utf-8")
EXAMPLE = ROOT / "examples" / "quintic_planner.py"
RUN = 'run = ["own_cp", "own_ptp", "ruckig", "ruckig_feasible"]'
EXEC = 'execute = true\nexecute_only = ["own_ptp", "ruckig", "ruckig_feasible"]'


def _variant(tmp_path: Path, run_line: str, extra: str = "", name: str = "v.toml") -> Path:
    return write_variant(PTP_TEXT, tmp_path / name, [(RUN, run_line), (EXEC, "execute = false"),
                                                     ("figures = true", "figures = true" + extra)])


def test_example_planner_satisfies_the_protocol():
    import importlib.util

    spec = importlib.util.spec_from_file_location("quintic_planner_example", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert isinstance(module.QuinticPtP(), Planner)


def test_user_planner_file_runs_next_to_ruckig_and_is_executed(tmp_path):
    entry = f"{EXAMPLE}:QuinticPtP"
    path = write_variant(PTP_TEXT, tmp_path / "v.toml", [
        (RUN, f'run = ["ruckig", "{entry}"]'), (EXEC, f'execute = true\nexecute_only = ["{entry}"]'),
        ("figures = true", f'figures = true\n[planners.parameters."{entry}"]\nspeed_factor = 0.8'),
        ('settle_time = "0.2 s"', 'settle_time = "0.05 s"')])
    code, summary = run_scenario(path, tmp_path / "out")
    assert code == 0 and summary["status"] == "ok", summary.get("reason")
    mine = summary["planners"]["quintic_ptp"]
    assert mine["class"] == entry and mine["kind"] == "ptp" and mine["status"] == "feasible"
    # the velocity limit (eq. 40 has no acceleration limit) binds at 0.8, checked at 1 ms by the job
    assert 0.799 < mine["constraint_ratios"]["velocity"] <= 0.8 + 1e-9
    assert mine["max_constraint_ratio"] == mine["constraint_ratios"]["velocity"]
    assert mine["duration_s"] > summary["planners"]["ruckig"]["duration_s"]
    # executed on the cell like the built-in planners (model_based, true robot)
    execution = mine["execution"]
    assert execution["status"] == "ok" and execution["path_completed"]
    assert 0.0 < mine["tcp_error_max_mm"] == execution["tcp_error_max_mm"] < 0.1
    assert "execution" not in summary["planners"]["ruckig"]
    traj = Trajectory.read_csv(tmp_path / "out" / "trajectory_quintic_ptp.csv")
    assert traj.duration == pytest.approx(mine["duration_s"])


def test_user_planner_by_module_name(tmp_path, monkeypatch):
    (tmp_path / "my_planners.py").write_text(
        "from planners.base import PlanResult, PlanStatus\n"
        "class Refuses:\n    name = 'refuses'\n    kind = 'cp'\n"
        "    def plan(self, problem):\n        return PlanResult(self.name, PlanStatus.INFEASIBLE, None, 0.0, "
        "message='never')\n"
        "class Raises:\n    name = 'raises'\n    kind = 'cp'\n"
        "    def plan(self, problem):\n        raise RuntimeError('boom')\n", encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    path = _variant(tmp_path, 'run = ["my_planners:Refuses", "my_planners:Raises"]')
    code, summary = run_scenario(path, tmp_path / "out")
    assert code == 0, summary.get("reason")
    assert summary["planners"]["refuses"]["status"] == "infeasible"
    assert summary["planners"]["raises"]["status"] == "failed"
    assert "RuntimeError: boom" in summary["planners"]["raises"]["message"]


BAD_PLANNERS = {
    "noplan.py": "class P:\n    name = 'p'\n    kind = 'cp'\n",
    "badkind.py": "class P:\n    name = 'p'\n    kind = 'joint'\n    def plan(self, problem):\n        pass\n",
    "clash.py": "class P:\n    name = 'ruckig'\n    kind = 'ptp'\n    def plan(self, problem):\n        pass\n",
    "broken.py": "import numpy\nclass P(:\n",
    "needs.py": "class P:\n    name = 'p'\n    kind = 'cp'\n    def __init__(self, gain):\n        pass\n"
                "    def plan(self, problem):\n        pass\n",
}


@pytest.mark.parametrize("run_line, match", [
    ('run = ["ruckig", "nothere.py:P"]', r"planners.run\[1\]: file .*nothere.py' does not exist"),
    ('run = ["ruckig", "noplan.py:Q"]', r"planners.run\[1\]: .*has no 'Q' \(its classes: \['P'\]\)"),
    ('run = ["ruckig", "noplan.py:P"]', r"planners.run\[1\]: P lacks \['plan'\]"),
    ('run = ["ruckig", "badkind.py:P"]', r"planners.run\[1\]: kind = 'joint'; expected a planner whose kind is"),
    ('run = ["ruckig", "clash.py:P"]', r"planners.run\[1\]: name 'ruckig' is also 'ruckig'"),
    ('run = ["ruckig", "broken.py:P"]', r"planners.run\[1\]: importing .*broken.py' failed: SyntaxError"),
    ('run = ["ruckig", "needs.py:P"]', r"planners.parameters.\"needs.py:P\": P\(\*\*parameters\) failed: TypeError"),
    ('run = ["ruckig", "no_such_module_xyz:P"]', r"planners.run\[1\]: no module named 'no_such_module_xyz'"),
    ('run = ["ruckig", "magic"]', r"planners.run\[1\]: expected one of 'own_cp'.* or a planner class"),
])
def test_bad_user_planners_are_refused_before_running(tmp_path, run_line, match):
    for name, text in BAD_PLANNERS.items():
        (tmp_path / name).write_text(text, encoding="utf-8")
    with pytest.raises(ScenarioError, match=match):
        load_scenario(_variant(tmp_path, run_line))


def test_parameters_for_an_unknown_entry(tmp_path):
    path = _variant(tmp_path, 'run = ["ruckig"]', '\n[planners.parameters."x.py:P"]\na = 1')
    with pytest.raises(ScenarioError, match=r"planners.parameters.\"x.py:P\": no such user planner in run"):
        load_scenario(path)
