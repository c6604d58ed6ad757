"""Job 'compare': controllers x trajectories on one seeded robot, one ranked table.

One short comparison (2 built-in modes x the ISO 9283 path cut at 0.6 s, a user joint CSV
and a user planner) checked against the main job's model_based run on the same settings
(identical tcp_error_max_mm), plus the table, figures and the errors before running."""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from cosim.scenario import ScenarioError, load_scenario
from scenario_files import run_scenario, write_variant

ROOT = Path(__file__).resolve().parents[1]
ISO_TEXT = (ROOT / "scenarios" / "iso9283.toml").read_text(encoding="utf-8")
SHORT = [('stop_time = "12.6 s"', 'stop_time = "0.6 s"'), ("can_log = true", "can_log = false"),
         ('settle_time = "0.2 s"', 'settle_time = "0.1 s"')]
Q0 = np.array([0.0, 0.4, 1.8, 0.0, 0.9, math.pi])


def _joint_csv(path: Path, duration: float = 0.4, dq=(0.05, 0.03, -0.04, 0.06, -0.05, 0.08)) -> Path:
    t = np.linspace(0.0, duration, 41)
    s = t / duration
    q = Q0 + np.outer(10 * s**3 - 15 * s**4 + 6 * s**5, dq)
    lines = ["# a user trajectory: t in s, joint angles in degrees", "t, " + ", ".join(f"q{j} [deg]" for j in
                                                                                          range(1, 7))]
    lines += [",".join(repr(float(v)) for v in (t[k], *np.degrees(q[k]))) for k in range(t.size)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _compare_toml(tmp_path: Path, controllers: str, trajectories: str, extra: list[tuple[str, str]] = ()) -> Path:
    return write_variant(ISO_TEXT, tmp_path / "compare.toml", [
        ('job = "iso9283"', 'job = "compare"'), *SHORT,
        ("[results]", f"[compare]\ncontrollers = {controllers}\ntrajectories = {trajectories}\n\n[results]"),
        *extra])


EXAMPLE = ROOT / "examples" / "compare.toml"
EXAMPLE_SHORT = [('stop_time = "12.6 s"', 'stop_time = "0.6 s"'), ('settle_time = "0.2 s"', 'settle_time = "0.1 s"')]
"""The example as a user runs it, with the ISO 9283 path cut at 0.6 s (the other trajectories run whole)."""


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """examples/compare.toml (shortened ISO path) and the main job on the same settings (model_based only)."""
    tmp = tmp_path_factory.mktemp("compare")
    path = write_variant(EXAMPLE.read_text(encoding="utf-8"), EXAMPLE.parent / f"_test_{tmp.name}.toml",
                         EXAMPLE_SHORT)
    try:
        code, summary = run_scenario(path, tmp / "out")
    finally:
        path.unlink()
    assert code == 0 and summary["status"] == "ok", summary.get("reason")
    # the main job on the same scenario settings: the example with job = "iso9283", model_based only
    text = EXAMPLE.read_text(encoding="utf-8")
    text = text[:text.index("\n[compare]\n")] + text[text.index("\n[results]\n"):]
    main = write_variant(text, EXAMPLE.parent / f"_test_{tmp.name}_main.toml", [
        *EXAMPLE_SHORT, ('job = "compare"', 'job = "iso9283"'),
        ('period = "400 us"            # paper section 2.3.2', 'modes = ["model_based"]\nperiod = "400 us"'),
        ("figures = true", "figures = false")])
    try:
        code, main_summary = run_scenario(main, tmp / "main_out")
    finally:
        main.unlink()
    assert code == 0, main_summary.get("reason")
    return summary, tmp / "out", main_summary


def test_model_based_entry_equals_the_main_job(runs):
    summary, _, main = runs
    mine = summary["entries"]["model_based__iso9283"]
    ref = main["modes"]["model_based"]
    assert mine["tcp_error_max_mm"] == ref["tcp_error_max_mm"]          # to the last digit
    for key in ("tcp_error_rms_mm", "path_accuracy_AT_mm", "joint_lag_max_rad"):
        assert mine[key] == ref[key], key
    assert summary["true_robot"] == main["true_robot"]


TRAJECTORIES = ("iso9283", "pick_place_joint", "line", "ruckig_feasible", "quintic_ptp")
CONTROLLERS = ("standard", "standard_speed_ff", "model_based")


def test_table_ranks_every_entry_and_is_written_as_csv_and_json(runs):
    summary, out, _ = runs
    rows = summary["table"]
    assert [r["trajectory"] for r in rows] == [t for t in TRAJECTORIES for _ in CONTROLLERS]
    for r in rows:
        assert r["status"] == "ok" and r["rank"] in (1, 2, 3)
        for key in ("tcp_error_max_mm", "tcp_error_rms_mm", "path_accuracy_AT_mm", "joint_lag_max_mrad",
                    "current_peak_ratio", "energy_J", "tau_squared_integral", "duration_s"):
            assert r[key] is not None and r[key] > 0.0, (r["trajectory"], r["controller"], key)
        assert r["deadline_misses"] >= 0
        assert r["path_accuracy_AT_mm"] <= r["tcp_error_max_mm"] + 1e-9
    for traj in TRAJECTORIES:
        group = [r for r in rows if r["trajectory"] == traj]
        assert [r["rank"] for r in group] == [1, 2, 3]
        errors = [r["tcp_error_max_mm"] for r in group]
        assert errors == sorted(errors)
        # the drive cascade alone lags by far the most on every trajectory
        assert group[-1]["controller"] == "standard" and errors[-1] > 5 * errors[0], traj
    by = {(r["trajectory"], r["controller"]): r for r in rows}
    assert by[("pick_place_joint", "model_based")]["duration_s"] == pytest.approx(1.8)
    assert by[("line", "model_based")]["duration_s"] == pytest.approx(0.8)
    with open(out / "compare.csv", newline="") as handle:
        table = list(csv.DictReader(handle))
    assert len(table) == len(rows) and float(table[0]["tcp_error_max_mm"]) == rows[0]["tcp_error_max_mm"]
    data = json.loads((out / "compare.json").read_text())
    assert data["rank_by"] == "tcp_error_max_mm" and data["rows"] == rows
    for name in ("trajectory_pick_place_joint.csv", "trajectory_line.csv", "trajectory_quintic_ptp.csv",
                 "timeseries_standard__line.csv", "tcp_model_based__quintic_ptp.csv",
                 "controller_standard__iso9283.csv"):
        assert (out / name).stat().st_size > 0, name
    # the payload FMU (built from C) hangs 3 kg on the flange from t = 0.5 s, through the plant's tau_ext
    with open(out / "timeseries_model_based__pick_place_joint.csv", newline="") as handle:
        series = list(csv.DictReader(handle))
    mass = {round(float(r["time"]), 4): float(r["payload.load_mass"]) for r in series}
    assert mass[0.499] == 0.0 and mass[0.502] == 3.0 and mass[1.0] == 3.0
    assert abs(float(series[600]["payload.tau[2]"])) > 5.0
    trajs = summary["trajectories"]
    assert trajs["pick_place_joint"]["kind"] == "joint" and trajs["line"]["kind"] == "cartesian"
    assert trajs["quintic_ptp"]["planner"] == "quintic_planner.py:QuinticPtP"


def test_figures_show_every_entry(runs):
    summary, out, _ = runs
    from cosim.jobs.compare_figures import axis_scale

    assert summary["figures"] == ["compare_metrics.png", "compare_tcp_error.png"]
    for name in summary["figures"]:
        assert (out / name).stat().st_size > 30_000
    errors = [r["tcp_error_max_mm"] for r in summary["table"]]
    assert max(errors) / min(errors) > 30 and axis_scale(errors) == "log"
    assert axis_scale([0.0, 1.0, 100.0]) == "symlog" and axis_scale([1.0, 2.0]) == "linear"


def test_bad_entries_are_refused_before_running(tmp_path):
    bad = _joint_csv(tmp_path / "toofast.csv", duration=0.05, dq=(0.3, 0, 0, 0, 0, 0))
    with pytest.raises(ScenarioError, match=r"compare.trajectories\[1\].file: .*toofast.csv', line \d+, column "
                                            r"'qd?d?1'.*exceeds the (velocity|acceleration) limit"):
        load_scenario(_compare_toml(tmp_path, '["model_based"]', f'["iso9283", "{bad.name}"]'))
    with pytest.raises(ScenarioError, match=r"compare.trajectories\[1\]: .*name 'iso9283' twice"):
        load_scenario(_compare_toml(tmp_path, '["model_based"]', '["iso9283", {path = "iso9283"}]'))
    with pytest.raises(ScenarioError, match=r"compare.controllers\[0\]: expected a built-in mode"):
        load_scenario(_compare_toml(tmp_path, '["fancy"]', '["iso9283"]'))
    with pytest.raises(ScenarioError, match=r"compare.trajectories\[0\].planner: file .*nope.py' does not exist"):
        load_scenario(_compare_toml(tmp_path, '["model_based"]', '["nope.py:P"]'))
    with pytest.raises(ScenarioError, match=r"compare.trajectories\[0\].file: .*missing.csv.*no such file"):
        load_scenario(_compare_toml(tmp_path, '["model_based"]', '["missing.csv"]'))
