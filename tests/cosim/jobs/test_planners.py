"""Job 'planners', reduced: scenarios/cp_line.toml with one executed planner and a
short settle time, scenarios/ptp_line.toml with a coarse PtP grid and no execution; the
summary fields carry real values, the files are written, bad scenarios are refused."""
from __future__ import annotations

from pathlib import Path

import pytest

from cosim.scenario import ScenarioError, load_scenario
from planners.trajectory import Trajectory
from scenario_files import run_scenario, write_variant

ROOT = Path(__file__).resolve().parents[3]
CP_TEXT = (ROOT / "scenarios" / "cp_line.toml").read_text(encoding="utf-8")
PTP_TEXT = (ROOT / "scenarios" / "ptp_line.toml").read_text(encoding="utf-8")
FIELDS = ("status", "duration_s", "solve_time_s", "max_constraint_ratio", "energy")


def variant(tmp_path: Path, text: str, replacements: list[tuple[str, str]], name: str = "v.toml") -> Path:
    return write_variant(text, tmp_path / name, replacements)


def run(path: Path, out: Path) -> dict:
    code, summary = run_scenario(path, out)
    assert code == 0 and summary["status"] == "ok", summary.get("reason")
    return summary


@pytest.fixture(scope="module")
def cp_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cp")
    # 200 intervals (CPProblem.n_intervals' default): the dense 1 ms check then stays within 1.001
    path = variant(tmp, CP_TEXT, [('plant = "true"', 'plant = "true"\nexecute_only = ["own_cp"]'),
                                  ('settle_time = "0.2 s"', 'settle_time = "0.05 s"')])
    return run(path, tmp / "out"), tmp / "out"


@pytest.fixture(scope="module")
def ptp_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ptp")
    path = variant(tmp, PTP_TEXT, [("n_intervals = 200", "n_intervals = 100"),
                                   ("ptp_intervals = 100", "ptp_intervals = 40"),
                                   ("execute = true", "execute = false"),
                                   ('execute_only = ["own_ptp", "ruckig", "ruckig_feasible"]\n', "")])
    return run(path, tmp / "out"), tmp / "out"


def test_cp_line_own_cp_matches_toppra_within_limits_and_is_executed(cp_run):
    summary, out = cp_run
    own, top = summary["planners"]["own_cp"], summary["planners"]["toppra"]
    for entry in (own, top):
        assert all(entry[k] is not None for k in FIELDS)
    assert own["status"] == "optimal" and top["status"] == "feasible"
    assert 0.999 < own["max_constraint_ratio"] <= 1.001          # time-optimal: rides on its limits
    assert own["duration_s"] <= 1.001 * top["duration_s"]
    assert 0.9 < own["duration_s"] < 1.2                          # the paper: 1.04 s
    assert summary["ratios"]["own_cp_over_toppra"] == pytest.approx(own["duration_s"] / top["duration_s"])
    assert own["energy"] > 0.0
    # executed on the cell (true robot, model-based): sub-millimetre TCP error, no drive saturation
    ex = own["execution"]
    assert ex["status"] == "ok" and ex["path_completed"]
    assert 0.0 < own["tcp_error_max_mm"] == ex["tcp_error_max_mm"] < 2.0
    assert own["drive_saturated"] is False and max(ex["current_demand_peak_ratio"]) < 1.0
    assert "execution" not in top and "tcp_error_max_mm" not in top
    traj = Trajectory.read_csv(out / "trajectory_own_cp.csv")
    assert traj.duration == pytest.approx(own["duration_s"])
    for name in ("trajectory_toppra.csv", "timeseries_own_cp.parquet", "figure7_velocity_profile.png",
                 "figure8_active_constraints.png"):
        assert (out / name).stat().st_size > 0, name
    assert set(summary["figures"]) == {"figure7_velocity_profile.png", "figure8_active_constraints.png"}


def test_ptp_line_own_ptp_beats_cp_and_torque_feasible_ruckig(ptp_run):
    summary, out = ptp_run
    p = summary["planners"]
    for name in ("own_cp", "own_ptp", "ruckig", "ruckig_feasible"):
        assert all(p[name][k] is not None for k in FIELDS), name
        assert (out / f"trajectory_{name}.csv").is_file()
        assert "execution" not in p[name]
    assert p["own_ptp"]["status"] in ("optimal", "feasible")
    assert p["own_ptp"]["max_constraint_ratio"] <= 1.001
    assert p["ruckig_feasible"]["max_constraint_ratio"] <= 1.001
    assert p["ruckig"]["max_constraint_ratio"] > 0.99              # rides on its (kinematic) limits
    r = summary["ratios"]
    assert r["own_ptp_over_own_cp"] <= 0.7
    assert r["own_ptp_over_ruckig_feasible"] < 1.0
    assert (out / "figure9_ptp.png").stat().st_size > 0


@pytest.mark.parametrize("replacement, key", [
    (('run = ["own_cp", "toppra"]', 'run = ["own_cp", "magic"]'), "planners.run"),
    (("k2 = 0.0 ", "k2 = -1.0 "), "problem.k2"),
    (("k1 = 1.0 ", "k1 = 0.0 "), "problem.k2"),
    (('plant = "true"', 'plant = "true"\nexecute_only = ["own_ptp"]'), "planners.execute_only"),
    (("velocity = 1.0", "velocity = 1.5"), "problem.limit_scale.velocity"),
])
def test_bad_scenarios_are_refused_naming_the_key(tmp_path, replacement, key):
    path = variant(tmp_path, CP_TEXT, [replacement])
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert key in str(info.value)
