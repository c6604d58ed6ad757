"""Job 'compare': controllers x trajectories on one seeded robot, one ranked table.

One short comparison (2 built-in modes x the ISO 9283 path cut at 0.6 s, a user joint CSV
and a user planner) checked against the main job's model_based run on the same settings
(identical tcp_error_max_mm), plus the table, figures and the errors before running."""
from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from cosim.results import read_series
from cosim.scenario import ScenarioError, load_scenario
from scenario_files import run_scenario, write_variant

ROOT = Path(__file__).resolve().parents[3]
ISO_TEXT = (ROOT / "scenarios" / "iso9283_rigid.toml").read_text(encoding="utf-8")  # the rigid plant, as the compare example
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
LIMITED = {("ruckig_feasible", "model_based")}
"""(trajectory, controller) entries of the example that hit a drive limit (verdict limit, not ranked)."""
EXAMPLE_SHORT = [('stop_time = "12.6 s"', 'stop_time = "0.6 s"'), ('settle_time = "0.2 s"', 'settle_time = "0.1 s"')]
"""The example as a user runs it, with the ISO 9283 path cut at 0.6 s (the other trajectories run whole)."""


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """examples/compare.toml (shortened ISO path) and the main job on the same settings (model_based only)."""
    tmp = tmp_path_factory.mktemp("compare")
    path = write_variant(EXAMPLE.read_text(encoding="utf-8"),  # one file per process (xdist workers)
                         EXAMPLE.parent / f"_test_{os.getpid()}_{tmp.name}.toml", EXAMPLE_SHORT)
    try:
        code, summary = run_scenario(path, tmp / "out")
    finally:
        path.unlink()
    # eq. 7 on ruckig_feasible (scaled for the robot without the 10 kg payload) asks joint 1's drive for more
    # than its peak torque: that entry's verdict is limit, so is the command's (exit 4); all others are ok
    assert code == 4 and summary["status"] == "limit", summary.get("reason")
    assert {k for k, v in summary["verdicts"].items() if v["verdict"] != "ok"} == {f"{c}__{t}" for t, c in LIMITED}
    assert summary["reason"].startswith("model_based__ruckig_feasible: limit: torque_limit joint 1")
    # the main job on the rigid plant, scenarios/iso9283_rigid.toml, with the same two edits (ISO path cut at 0.6 s, settle 0.1 s)
    main = write_variant(ISO_TEXT, tmp / "main.toml", [
        *EXAMPLE_SHORT, ('modes = ["standard", "standard_speed_ff", "model_based"]', 'modes = ["model_based"]'),
        ("can_log = true", "can_log = false"), ("figures = true", "figures = false")])
    code, main_summary = run_scenario(main, tmp / "main_out")
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


def test_compare_report_overlays_the_entries_with_the_ranking(runs, browser):
    """report.html of the compare run in headless Chromium: every entry, the ranking table (docs/how-to/view_results.md)."""
    from browser_support import console_errors, open_report, report_state

    summary, out, _ = runs
    open_report(browser, out / "report.html")
    assert console_errors(browser) == []
    state = report_state(browser)
    assert state["runs"] == list(summary["entries"])
    assert state["ranking_rows"] == len(summary["table"])
    assert any(k.startswith("entries.") and k.endswith(".tcp_error_max_mm") for k in state["keys"])


TRAJECTORIES = ("iso9283", "pick_place_joint", "line", "ruckig_feasible", "quintic_ptp")
CONTROLLERS = ("standard", "standard_speed_ff", "model_based", "pd_gravity", "feedforward_fmu")


def test_table_ranks_the_ok_entries_and_is_written_as_csv_and_json(runs):
    summary, out, _ = runs
    rows = summary["table"]
    ranked = [r for r in rows if r["rank"] is not None]
    assert rows[:len(ranked)] == ranked  # the ranking first, the entries that are not ok below it
    assert [r["trajectory"] for r in ranked] == [t for t in TRAJECTORIES for c in CONTROLLERS if (t, c) not in LIMITED]
    unranked = rows[len(ranked):]
    assert [(r["trajectory"], r["controller"]) for r in unranked] == sorted(LIMITED)
    for r in unranked:  # listed with the verdict and why; metrics marked, never ranked
        assert r["status"] == "limit" and r["first_violation"].startswith("torque_limit joint 1 at t = ")
        assert r["tcp_error_max_mm"] is None and r["unranked_metrics"]["current_peak_ratio"] >= 1.0 - 1e-6
    for r in ranked:
        assert r["status"] == "ok" and r["rank"] in (1, 2, 3, 4, 5)
        for key in ("tcp_error_max_mm", "tcp_error_rms_mm", "path_accuracy_AT_mm", "joint_lag_max_mrad",
                    "current_peak_ratio", "energy_J", "tau_squared_integral", "duration_s"):
            assert r[key] is not None and r[key] > 0.0, (r["trajectory"], r["controller"], key)
        assert r["deadline_misses"] >= 0
        assert r["path_accuracy_AT_mm"] <= r["tcp_error_max_mm"] + 1e-9
    for traj in TRAJECTORIES:
        group = [r for r in ranked if r["trajectory"] == traj]
        assert [r["rank"] for r in group] == list(range(1, len(group) + 1))
        errors = [r["tcp_error_max_mm"] for r in group]
        assert errors == sorted(errors)
        # the drive cascade alone lags by far the most on every trajectory; the C controller FMU's
        # decoupled feed-forward beats the drives' own speed feed-forward and comes close to eq. 7
        assert group[-1]["controller"] == "standard" and errors[-1] > 5 * errors[0], traj
        order = [r["controller"] for r in group]
        assert order.index("feedforward_fmu") < order.index("standard_speed_ff"), (traj, order)
        # PD + gravity in torque mode (10) beats the bare cascade on every trajectory
        assert order.index("pd_gravity") < order.index("standard"), (traj, order)
    by = {(r["trajectory"], r["controller"]): r for r in rows}
    assert by[("pick_place_joint", "model_based")]["duration_s"] == pytest.approx(1.8)
    assert by[("line", "model_based")]["duration_s"] == pytest.approx(0.8)
    with open(out / "compare.csv", newline="") as handle:
        table = list(csv.DictReader(handle))
    assert len(table) == len(rows) and float(table[0]["tcp_error_max_mm"]) == rows[0]["tcp_error_max_mm"]
    data = json.loads((out / "compare.json").read_text())
    assert data["rank_by"] == "tcp_error_max_mm" and data["rows"] == rows
    for name in ("trajectory_pick_place_joint.csv", "trajectory_line.csv", "trajectory_quintic_ptp.csv",
                 "timeseries_standard__line.parquet", "tcp_model_based__quintic_ptp.parquet",
                 "controller_standard__iso9283.parquet"):
        assert (out / name).stat().st_size > 0, name
    # the PD + gravity class runs its drives in cyclic synchronous torque, the built-in modes in position
    for ctrl, mode in (("pd_gravity", 10), ("model_based", 8)):
        columns, data = read_series(out / f"timeseries_{ctrl}__line.parquet")
        modes = {float(v) for j in range(1, 7) for v in data[300:, columns.index(f"drive{j}.modes_of_operation_display")]}
        assert modes == {mode}, (ctrl, modes)
    trajs = summary["trajectories"]
    assert trajs["pick_place_joint"]["kind"] == "joint" and trajs["line"]["kind"] == "cartesian"
    assert trajs["quintic_ptp"]["planner"] == "quintic_planner.py:QuinticPtP"


def test_figures_show_every_entry(runs):
    summary, out, _ = runs
    from cosim.jobs.compare_figures import axis_scale

    assert summary["figures"] == ["compare_metrics.png", "compare_tcp_error.png"]
    for name in summary["figures"]:
        assert (out / name).stat().st_size > 30_000
    errors = [r["tcp_error_max_mm"] for r in summary["table"] if r["rank"] is not None]
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
    (tmp_path / "ctrl.py").write_text("class NoStep:\n    def setup(self, info): pass\n    def close(self): pass\n")
    with pytest.raises(ScenarioError, match=r"compare.controllers\[1\].class: .*NoStep: no method step\(\)"):
        load_scenario(_compare_toml(tmp_path, '["model_based", "ctrl.py:NoStep"]', '["iso9283"]'))
    with pytest.raises(ScenarioError, match=r"compare.controllers\[1\].fmu: .*no such file"):
        load_scenario(_compare_toml(tmp_path, '["model_based", "nothere.fmu"]', '["iso9283"]'))
    source = ROOT / "examples" / "fmus" / "feedforward_controller"
    with pytest.raises(ScenarioError, match=r"compare.controllers\[0\].*q_nope\[1\]"):
        load_scenario(_compare_toml(tmp_path, f'[{{ fmu_source = "{source}", fmu_inputs = {{ "q_nope[1]" = '
                                               '"position[1]" } }]', '["iso9283"]'))


def test_a_failing_user_controller_is_a_failed_entry_and_the_others_run(tmp_path):
    """A user controller that raises mid-run stops its own run cleanly (status failed, the reason,
    its time series so far on disk); the comparison goes on and ranks the entries that ended ok; the
    command exits 3 (its most severe verdict, failed)."""
    _joint_csv(tmp_path / "wave.csv")
    (tmp_path / "flaky.py").write_text(
        "from controller import ControllerOutput\n"
        "from controller.tracking_clock import TrackingClock\n"
        "class Flaky:\n"
        "    def setup(self, info):\n"
        "        self.clock = TrackingClock(info, settle_time_s=0.05)\n"
        "        self.out = ControllerOutput.zeros(info.n_joints)\n"
        "    def step(self, inputs):\n"
        "        tau = self.clock.update(inputs, self.out.controlword)\n"
        "        if inputs.time_s > 0.15:\n"
        "            raise RuntimeError('sensor model diverged')\n"
        "        self.out.target_position[:] = self.clock.reference(tau)[0]\n"
        "        return self.out\n"
        "    def close(self):\n"
        "        pass\n", encoding="utf-8")
    path = _compare_toml(tmp_path, '["model_based", "flaky.py:Flaky"]', '["wave.csv"]',
                         [("figures = true", "figures = false")])
    code, summary = run_scenario(path, tmp_path / "out")
    assert code == 3 and summary["status"] == "failed", summary.get("reason")  # not ok: exit non-zero
    assert summary["reason"].startswith("Flaky__wave: failed: failure at t = 0.15")
    rows = {r["controller"]: r for r in summary["table"]}
    assert rows["model_based"]["status"] == "ok" and rows["model_based"]["rank"] == 1
    assert rows["Flaky"]["status"] == "failed" and rows["Flaky"]["rank"] is None
    entry = summary["entries"]["Flaky__wave"]
    assert "sensor model diverged" in entry["failure"] and summary["failed_entries"] == ["Flaky__wave"]
    columns, data = read_series(tmp_path / "out" / "timeseries_Flaky__wave.parquet")
    times = data[:, columns.index("time")].tolist()
    assert 0.14 < times[-1] < 0.2


def test_split_execution_gives_the_in_process_numbers(tmp_path):
    """cosim run --split: controller and drives in two processes over UDP; same table as in process."""
    import json

    from cosim.cli import main

    _joint_csv(tmp_path / "wave.csv")
    path = _compare_toml(tmp_path, '["model_based"]', '["wave.csv"]', [("figures = true", "figures = false")])
    tables = []
    for extra in ([], ["--split"]):
        out = tmp_path / ("split" if extra else "in_process")
        assert main(["run", str(path), "--out", str(out), "--quiet", *extra]) == 0
        tables.append(json.loads((out / "summary.json").read_text())["table"])
    assert tables[0][0]["status"] == tables[1][0]["status"] == "ok"
    assert tables[1][0]["tcp_error_max_mm"] == tables[0][0]["tcp_error_max_mm"]


def test_model_based_elastic_runs_on_joint_and_cartesian_files(tmp_path):
    """The flatness-based feed-forward for elastic gears is computed for any joint reference (jerk and
    snap from its accelerations on the controller grid, controller/elastic.py), not only the ISO path:
    on the elastic plant it beats eq. 7's rigid model on a joint CSV and on a Cartesian CSV."""
    elastic = (ROOT / "scenarios" / "iso9283.toml").read_text(encoding="utf-8")
    _joint_csv(tmp_path / "wave.csv")
    line = ROOT / "examples" / "trajectories" / "line_cartesian.csv"
    path = write_variant(elastic, tmp_path / "compare.toml", [
        ('job = "iso9283"', 'job = "compare"'), *SHORT, ("figures = true", "figures = false"),
        ("[results]", '[compare]\ncontrollers = ["model_based", "model_based_elastic"]\n'
                      f'trajectories = ["wave.csv", {{ file = "{line}", name = "line", '
                      'q_seed = [0.0, 0.4, 1.8, 0.0, 0.9, 3.1416] }]\n\n[results]')])
    code, summary = run_scenario(path, tmp_path / "out")
    assert code == 0 and summary["status"] == "ok", summary.get("reason")
    rows = {(r["trajectory"], r["controller"]): r for r in summary["table"]}
    for traj in ("wave", "line"):
        flat, rigid = rows[(traj, "model_based_elastic")], rows[(traj, "model_based")]
        assert flat["status"] == rigid["status"] == "ok" and flat["rank"] == 1, traj
        assert flat["tcp_error_max_mm"] < rigid["tcp_error_max_mm"] / 5, traj
        entry = summary["entries"][f"model_based_elastic__{traj}"]
        assert entry["path_completed"] and entry["files"]["controller"] == f"controller_model_based_elastic__{traj}.parquet"


def test_compare_elastic_example_pd_gains_for_elastic_gears(tmp_path):
    """examples/compare_elastic.toml (the comparison on the main job's elastic plant) on its Cartesian line:
    the PD + gravity class with the rigid plant's 10 Hz gains drives the currents to their clamp and lags
    by millimetres; with the gains for elastic gears (3 Hz + model feed-forward) it stays well inside
    the clamp and is several times better; the flatness-based feed-forward is the best entry."""
    example = ROOT / "examples" / "compare_elastic.toml"
    text = example.read_text(encoding="utf-8")
    start = text.index("trajectories = [")
    end = text.index("]\n", text.index("quintic_planner.py")) + 2
    path = write_variant(text, example.parent / f"_test_{tmp_path.name}.toml", [
        (text[start:end], 'trajectories = [{ file = "trajectories/line_cartesian.csv", name = "line", '
                          'q_seed = [0.0, 0.4, 1.8, 0.0, 0.9, 3.1416] }]\n')])
    try:
        code, summary = run_scenario(path, tmp_path / "out")
    finally:
        path.unlink()
    rows = {r["controller"]: r for r in summary["table"]}
    assert set(rows) == {"standard", "model_based", "model_based_elastic", "pd_gravity_10hz", "pd_gravity"}
    assert rows["model_based_elastic"]["rank"] == 1
    rigid_gains, elastic_gains = rows["pd_gravity_10hz"], rows["pd_gravity"]
    assert rigid_gains["current_peak_ratio"] > 0.99 and elastic_gains["current_peak_ratio"] < 0.8
    assert elastic_gains["tcp_error_max_mm"] < rigid_gains["tcp_error_max_mm"] / 3
    assert elastic_gains["status"] == "ok", elastic_gains
