"""Verdicts of cell runs (cosim/cell/verdict.py, docs/reference/verdicts.md): a comparison with a failing,
a faulting, a refused and a good entry exits non-zero, ranks only the good one and says why for
each; close() exceptions and chronic budget overruns are reported; a user planner beyond the
robot's limits is refused before it runs; exit codes 4/5 of ``python -m cosim run``."""
from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cosim.cell.run import CellRun
from cosim.cell.verdict import MAX_VIOLATIONS, judge, most_severe
from cosim.master import SimulationError
from scenario_files import run_scenario, write_variant

ROOT = Path(__file__).resolve().parents[3]
ISO_TEXT = (ROOT / "scenarios" / "iso9283_rigid.toml").read_text(encoding="utf-8")
SHORT = [('stop_time = "12.6 s"', 'stop_time = "0.6 s"'), ("can_log = true", "can_log = false"),
         ('settle_time = "0.2 s"', 'settle_time = "0.1 s"'), ("figures = true", "figures = false")]
Q0 = np.array([0.0, 0.4, 1.8, 0.0, 0.9, math.pi])

CONTROLLERS = '''
import time
from controller import ControllerOutput
from controller.tracking_clock import TrackingClock


class _Tracking:
    def setup(self, info):
        self.clock = TrackingClock(info, settle_time_s=0.05)
        self.out = ControllerOutput.zeros(info.n_joints)

    def step(self, inputs):
        tau = self.clock.update(inputs, self.out.controlword)
        self.out.target_position[:] = self.clock.reference(tau)[0]
        return self.out

    def close(self):
        pass

    motion_start_s = property(lambda self: self.clock.motion_start_s)
    stop_reason = property(lambda self: self.clock.stop_reason)
    stopped_at_s = property(lambda self: self.clock.stopped_at_s)


class Flaky(_Tracking):
    """Raises in step() after 0.15 s: a failed run."""

    def step(self, inputs):
        if inputs.time_s > 0.15:
            raise RuntimeError("sensor model diverged")
        return super().step(inputs)


class Idle:
    """Never enables the drives (controlword 0): a fault."""

    def setup(self, info):
        self.out = ControllerOutput.zeros(info.n_joints)
        self.out.target_position[:] = info.q_start

    def step(self, inputs):
        return self.out

    def close(self):
        pass


class Closer(_Tracking):
    """Tracks, then raises in close(): a failed run (the motion is complete)."""

    def close(self):
        raise OSError("could not flush the controller's own log")


class Hog(_Tracking):
    """Tracks, but burns 300 us of CPU per cycle against the 100 us budget: a warning."""

    def step(self, inputs):
        end = time.thread_time_ns() + 300_000
        while time.thread_time_ns() < end:
            pass
        return super().step(inputs)
'''

NINE_X = '''
import numpy as np
from planners.base import PlanResult, PlanStatus
from planners.trajectory import Trajectory


class NineTimes:
    """A PtP plan whose fastest joint runs at 9 times its velocity limit (a rest-to-rest quintic)."""

    name = "nine_times"
    kind = "ptp"

    def plan(self, problem):
        dq = problem.qe - problem.q0
        duration = float(np.max(15.0 / 8.0 * np.abs(dq) / (9.0 * np.asarray(problem.limits.velocity))))
        t = np.linspace(0.0, duration, 201)
        u = t / duration
        s = 10 * u**3 - 15 * u**4 + 6 * u**5
        sd = (30 * u**2 - 60 * u**3 + 30 * u**4) / duration
        sdd = (60 * u - 180 * u**2 + 120 * u**3) / duration**2
        q = problem.q0 + np.outer(s, dq)
        traj = Trajectory(t, q, np.outer(sd, dq), np.outer(sdd, dq), np.zeros_like(q))
        return PlanResult(self.name, PlanStatus.FEASIBLE, traj, 0.0)


class Halfway(NineTimes):
    """A PtP plan that stops halfway (within every limit)."""

    name = "halfway"

    def plan(self, problem):
        dq = 0.5 * (problem.qe - problem.q0)
        duration = 2.0
        t = np.linspace(0.0, duration, 201)
        u = t / duration
        s = 10 * u**3 - 15 * u**4 + 6 * u**5
        sd = (30 * u**2 - 60 * u**3 + 30 * u**4) / duration
        sdd = (60 * u - 180 * u**2 + 120 * u**3) / duration**2
        q = problem.q0 + np.outer(s, dq)
        traj = Trajectory(t, q, np.outer(sd, dq), np.outer(sdd, dq), np.zeros_like(q))
        return PlanResult(self.name, PlanStatus.FEASIBLE, traj, 0.0)
'''


def _joint_csv(path: Path, duration: float = 0.4, dq=(0.05, 0.03, -0.04, 0.06, -0.05, 0.08)) -> Path:
    t = np.linspace(0.0, duration, 41)
    s = t / duration
    q = Q0 + np.outer(10 * s**3 - 15 * s**4 + 6 * s**5, dq)
    lines = ["t, " + ", ".join(f"q{j} [deg]" for j in range(1, 7))]
    lines += [",".join(repr(float(v)) for v in (t[k], *np.degrees(q[k]))) for k in range(t.size)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def comparison(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("verdicts")
    _joint_csv(tmp / "wave.csv")
    (tmp / "ctrls.py").write_text(CONTROLLERS, encoding="utf-8")
    (tmp / "nine.py").write_text(NINE_X, encoding="utf-8")
    controllers = ('["model_based", "ctrls.py:Flaky", "ctrls.py:Idle", "ctrls.py:Closer", "ctrls.py:Hog"]')
    path = write_variant(ISO_TEXT, tmp / "compare.toml", [
        ('job = "iso9283"', 'job = "compare"'), *SHORT,
        ("[results]", f'[compare]\ncontrollers = {controllers}\ntrajectories = ["wave.csv", "nine.py:NineTimes"]\n\n'
                      "[results]")])
    code, summary = run_scenario(path, tmp / "out")
    return code, summary, tmp / "out"


def test_compare_with_failing_and_faulting_entries_exits_non_zero_and_ranks_only_ok(comparison):
    code, summary, out = comparison
    assert code == 3 and summary["status"] == "failed"  # the most severe verdict: failed (Flaky, Closer)
    rows = {(r["controller"], r["trajectory"]): r for r in summary["table"]}
    good = rows[("model_based", "wave")]
    assert good["status"] == "ok" and good["rank"] == 1 and good["tcp_error_max_mm"] > 0
    hog = rows[("Hog", "wave")]  # ok, with a compute-budget warning: ranked
    ranked = [r for r in summary["table"] if r["rank"] is not None]
    assert ranked == sorted([good, hog], key=lambda r: r["rank"]) and summary["table"][:2] == ranked
    flaky, idle = rows[("Flaky", "wave")], rows[("Idle", "wave")]
    assert flaky["status"] == "failed" and "sensor model diverged" in flaky["first_violation"]
    assert idle["status"] == "fault" and "never reached Operation enabled" in idle["first_violation"]
    for r in (flaky, idle):  # metrics marked, never ranked
        assert r["rank"] is None and r["tcp_error_max_mm"] is None and "not ranked" in r["note"]
        assert "tcp_error_max_mm" in r["unranked_metrics"]
    entries = summary["entries"]
    assert entries["Idle__wave"]["verdict"] == "fault"
    assert entries["Idle__wave"]["first_violation"]["kind"] == "not_enabled"
    assert entries["Flaky__wave"]["first_violation"]["kind"] == "failure"
    assert summary["verdicts"]["Idle__wave"]["verdict"] == "fault"
    # the refused plan: every entry on it listed with the reason, nothing ran on it
    refused = rows[("model_based", "nine_times")]
    assert refused["status"] == "refused" and refused["rank"] is None
    assert "planner nine.py:NineTimes: joint " in refused["first_violation"] and " limit at t = " in \
        refused["first_violation"]
    assert not (out / "timeseries_model_based__nine_times.parquet").exists()
    assert summary["trajectories"]["nine_times"]["status"] == "refused"
    # compare.csv: the ranked row first, the others below with empty rank and metric cells
    with open(out / "compare.csv", newline="") as handle:
        table = list(csv.DictReader(handle))
    assert [r["rank"] for r in table[:2]] == ["1", "2"] and table[0]["tcp_error_max_mm"]
    assert all(r["rank"] == "" and r["tcp_error_max_mm"] == "" and r["first_violation"] for r in table[2:])
    data = json.loads((out / "compare.json").read_text())
    assert "only entries whose verdict is ok are ranked" in data["ranking_rule"]


def test_close_exception_is_a_failed_run(comparison):
    _, summary, _ = comparison
    entry = summary["entries"]["Closer__wave"]
    assert entry["verdict"] == "failed" and entry["path_completed"]
    assert entry["first_violation"]["kind"] == "close_error"
    assert "Closer.close() raised OSError: could not flush" in entry["close_error"]


def test_chronic_budget_overruns_are_a_warning(comparison):
    _, summary, _ = comparison
    entry = summary["entries"]["Hog__wave"]
    assert entry["verdict"] == "ok"
    (warning,) = entry["warnings"]
    assert warning["kind"] == "budget" and warning["value"] > 50.0
    assert entry["cycle_compute_cpu_us"]["p99"] > 100.0 if "cycle_compute_cpu_us" in entry else True


def test_console_names_every_verdict(tmp_path):
    """python -m cosim run prints one line per run that is not ok, the budget warning and the verdict."""
    _joint_csv(tmp_path / "wave.csv")
    (tmp_path / "ctrls.py").write_text(CONTROLLERS, encoding="utf-8")
    path = write_variant(ISO_TEXT, tmp_path / "compare.toml", [
        ('job = "iso9283"', 'job = "compare"'), *SHORT,
        ("[results]", '[compare]\ncontrollers = ["ctrls.py:Idle", "ctrls.py:Hog"]\ntrajectories = ["wave.csv"]\n\n'
                      "[results]")])
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-m", "cosim", "run", str(path), "--out", str(tmp_path / "out"), "--quiet"],
                          capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert done.returncode == 5, done.stderr  # fault (Idle) is the most severe verdict
    err = done.stderr
    assert "Idle__wave: fault: not_enabled" in err
    assert "warning: Hog__wave: compute budget: the controller overran its compute budget of 100 us" in err
    assert "iso9283_rigid: fault: Idle__wave: fault: not_enabled" in err and "exit code 5" in err
    assert "not ranked:" in err and "Idle / wave: fault:" in err
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["status"] == "fault" and summary["first_violation"]["kind"] == "not_enabled"


def test_planner_beyond_the_limits_is_refused_before_running(tmp_path):
    (tmp_path / "nine.py").write_text(NINE_X, encoding="utf-8")
    path = write_variant((ROOT / "scenarios" / "ptp_line.toml").read_text(encoding="utf-8"), tmp_path / "p.toml", [
        ('run = ["own_cp", "own_ptp", "ruckig", "ruckig_feasible"]', 'run = ["nine.py:NineTimes", "nine.py:Halfway"]'),
        ('execute_only = ["own_ptp", "ruckig", "ruckig_feasible"]\n', ""), ("figures = true", "figures = false")])
    code, summary = run_scenario(path, tmp_path / "out")
    assert code == 3 and summary["status"] == "failed"
    nine = summary["planners"]["nine_times"]
    assert nine["status"] == "refused" and "execution" not in nine
    assert nine["first_violation"]["kind"] == "refused"
    first = nine["first_violation"]
    assert abs(first["value"]) > first["limit"] and first["time_s"] >= 0.0
    assert nine["constraint_ratios"]["velocity"] == pytest.approx(9.0, rel=0.01)  # 9 x a joint's limit
    assert f"planner nine.py:NineTimes: joint {first['joint']} beyond its " in nine["refused"]
    assert f"limit at t = {first['time_s']:.6g} s" in nine["refused"]
    half = summary["planners"]["halfway"]
    assert half["status"] == "refused" and "does not reach the end of the motion" in half["refused"]
    assert not list((tmp_path / "out").glob("timeseries_*"))  # nothing ran
    assert (tmp_path / "out" / "trajectory_nine_times.csv").is_file()  # the plan itself is kept


def _run(**fields) -> CellRun:
    base = dict(label="x", record_path=None, rows_recorded=10, reached_s=1.0, fieldbus={"faults": []},
                loop_wall_time_s=1.0, engine="", recording=None)
    base.update(fields)
    return CellRun(**base)


def test_judge_rules():
    """judge() on CellRun records: limit events, bus faults, failures, controller stops, never enabled."""
    torque = {"kind": "torque_limit", "joint": 3, "time_s": 0.5, "error_code": "0x2310", "value": 1e6,
              "limit": 380.0, "unit": "N.m", "reaction": "none", "detail": "torque limit reached"}
    end_stop = {**torque, "kind": "end_stop", "time_s": 0.7, "error_code": None}
    assert judge(_run()).verdict == "ok"
    v = judge(_run(protection_events=[end_stop, torque]))
    assert v.verdict == "limit" and v.first_violation["kind"] == "torque_limit" and v.violations_total == 2
    v = judge(_run(protection_events=[torque], failure=SimulationError("controller", 0.8, "motion stopped: x")))
    assert v.verdict == "limit"  # the stop came from the limit's reaction
    bus = {"event": "fault_reaction", "side": "cn", "node": 2, "kind": "loss_of_preq", "time_s": 0.3, "cycle": 750,
           "counter": 16, "threshold": 15, "detail": "drive gets fault code"}
    v = judge(_run(fieldbus={"faults": [bus]}, protection_events=[torque]))
    assert v.verdict == "fault" and v.first_violation["kind"] == "fault_reaction" and v.first_violation["joint"] == 2
    v = judge(_run(failure=SimulationError("plant", 0.2, "NaN in q[1]"), protection_events=[torque]))
    assert v.verdict == "failed" and v.first_violation["kind"] == "failure"
    assert judge(_run(failure=SimulationError("controller", 0.2, "motion stopped: drive 1 reports Fault"))
                 ).verdict == "fault"
    assert judge(_run(drives_checked=True)).verdict == "fault"
    assert judge(_run(drives_checked=True, drives_enabled_at_s=0.01)).verdict == "ok"
    many = [{**torque, "time_s": 0.001 * k} for k in range(MAX_VIOLATIONS + 50)]
    fields = judge(_run(protection_events=many)).fields()
    assert len(fields["violations"]) == MAX_VIOLATIONS and fields["violations_total"] == MAX_VIOLATIONS + 50
    assert fields["violations_cut"] is True
    assert most_severe(["ok", "limit", "fault"]) == "fault" and most_severe([]) == "ok"
    assert most_severe(["limit", "interrupted", "failed"]) == "interrupted"


def test_exit_code_5_from_python_m_cosim_run(tmp_path):
    """A user controller that never enables the drives on the iso9283 job: status fault, exit 5."""
    (tmp_path / "ctrls.py").write_text(CONTROLLERS, encoding="utf-8")
    path = write_variant(ISO_TEXT, tmp_path / "idle.toml", [
        *SHORT, ('modes = ["standard", "standard_speed_ff", "model_based"]', 'modes = []\nclass = "ctrls.py:Idle"')])
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-m", "cosim", "run", str(path), "--out", str(tmp_path / "out"), "--quiet"],
                          capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert done.returncode == 5, done.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["status"] == "fault" and summary["modes"]["Idle"]["verdict"] == "fault"
    assert "never reached Operation enabled" in summary["reason"]


SLOW = CONTROLLERS + '''

class Slow(_Tracking):
    """Takes 1.5 ms of CPU per 400 us cycle: under --realtime every cycle overruns."""

    def setup(self, info):
        self.clock = TrackingClock(info, settle_time_s=0.05, enable_timeout_s=0.1)
        self.out = ControllerOutput.zeros(info.n_joints)

    def step(self, inputs):
        end = time.thread_time_ns() + 1_500_000
        while time.thread_time_ns() < end:
            pass
        return super().step(inputs)
'''


def test_realtime_run_that_fails_by_overruns_says_so(tmp_path):
    """cosim run --realtime with a controller slower than the bus cycle: the one-line verdict names the
    overruns as well as what they caused."""
    (tmp_path / "slow.py").write_text(SLOW, encoding="utf-8")
    path = write_variant(ISO_TEXT, tmp_path / "slow.toml", [
        *SHORT[1:], ('stop_time = "12.6 s"', 'stop_time = "0.4 s"'),
        ('modes = ["standard", "standard_speed_ff", "model_based"]', 'modes = []\nclass = "slow.py:Slow"'),
        ("[results]", '[realtime]\noverrun_policy = "skip"\nscheduling = "normal"\ncpu = "none"\n\n[results]')])
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-m", "cosim", "run", str(path), "--out", str(tmp_path / "out"), "--quiet",
                           "--realtime"], capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert done.returncode in (3, 5), done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert "Operation enabled" in last and "controller overran" in last and "% of cycles" in last, done.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert "controller overran" in summary["reason"]


BRUTE = '''
import numpy as np
from controller import ControllerOutput
from controller.contract import MODE_CST
from controller.tracking_clock import TrackingClock


class Brute:
    """Enables the drives, then commands 1e6 N.m on joint 3 in cyclic synchronous torque."""

    def setup(self, info):
        self.clock = TrackingClock(info, settle_time_s=0.02)
        self.out = ControllerOutput.zeros(info.n_joints, mode=MODE_CST)

    def step(self, inputs):
        tau = self.clock.update(inputs, self.out.controlword)
        self.out.target_torque[:] = 0.0
        if tau is not None:
            self.out.target_torque[2] = 1e6
        return self.out

    def close(self):
        pass

    motion_start_s = property(lambda self: self.clock.motion_start_s)
    stop_reason = property(lambda self: self.clock.stop_reason)
    stopped_at_s = property(lambda self: self.clock.stopped_at_s)
'''


def test_a_controller_commanding_1e6_nm_ends_with_verdict_limit(tmp_path):
    """python -m cosim run: the drives clamp the torque and stop the axis; verdict limit, exit 4."""
    (tmp_path / "brute.py").write_text(BRUTE, encoding="utf-8")
    path = write_variant(ISO_TEXT, tmp_path / "brute.toml", [
        *SHORT, ('modes = ["standard", "standard_speed_ff", "model_based"]', 'modes = []\nclass = "brute.py:Brute"')])
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-m", "cosim", "run", str(path), "--out", str(tmp_path / "out"), "--quiet"],
                          capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    assert done.returncode == 4, done.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    entry = summary["modes"]["Brute"]
    assert summary["status"] == "limit" and entry["verdict"] == "limit"
    kinds = {v["kind"] for v in entry["violations"]}
    assert "torque_limit" in kinds, entry["violations"]
    first = entry["first_violation"]
    assert first["kind"] == "torque_limit" and first["joint"] == 3
    assert "Brute: limit: torque_limit joint 3" in done.stderr and "exit code 4" in done.stderr
    # no joint beyond its end stop by more than the contact's deflection (the plant's end-stop record)
    from cosim.results import read_series

    columns, data = read_series(tmp_path / "out" / "timeseries_Brute.parquet")
    stops = [v for v in entry["violations"] if v["kind"] == "end_stop"]
    assert stops and {v["joint"] for v in stops} == {3}
    for stop in stops:
        q = data[:, columns.index(f"plant.q[{stop['joint']}]")]
        beyond = q.max() - stop["stop_rad"] if stop["stop_rad"] > 0 else stop["stop_rad"] - q.min()
        assert beyond <= stop["max_penetration_rad"] + 1e-9, stop
