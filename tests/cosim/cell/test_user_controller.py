"""A user's controller in the cell, named in a scenario: a Python class (``[controller] class``)
and an FMI 2.0 controller FMU (``[controller] fmu`` + name mapping), each run through the
controller contract on the short ISO 9283 cell; bad input is a clear error before anything
runs; a controller that raises or returns NaN mid-run ends the run cleanly with the time
series so far on disk."""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from cosim.cli import main
from cosim.results import read_series
from cosim.scenario import ScenarioError, load_scenario
from error_checks import assert_names_file_and_fragments
from realtime_support import short_scenario_text

FOLLOW = '''
import numpy as np
from controller import ControllerOutput
from controller.tracking_clock import TrackingClock


class Follow:
    """Joint reference as CSP target, a proportional torque offset; optionally fails."""

    def __init__(self, kp=0.0, fail_at_cycle=-1, nan_at_cycle=-1):
        self.kp, self.fail_at, self.nan_at = kp, fail_at_cycle, nan_at_cycle

    def setup(self, info):
        self.clock = TrackingClock(info, settle_time_s=0.01)
        self.out = ControllerOutput.zeros(info.n_joints)

    def step(self, inputs):
        if inputs.cycle == self.fail_at:
            raise ZeroDivisionError("division by zero in my law")
        tau = self.clock.update(inputs, self.out.controlword)
        q_d, _, _ = self.clock.reference(tau)
        self.out.target_position[:] = q_d
        self.out.torque_offset[:] = self.kp * (q_d - inputs.position)
        if inputs.cycle == self.nan_at:
            self.out.torque_offset[4] = float("nan")
        return self.out

    def close(self):
        pass

    motion_start_s = property(lambda self: self.clock.motion_start_s)
    stop_reason = property(lambda self: self.clock.stop_reason)
    stopped_at_s = property(lambda self: self.clock.stopped_at_s)


class HoldInTorqueMode:
    """Cyclic synchronous torque (mode 10) once the drives are enabled: gravity of the nominal
    model plus a joint PD around the start pose."""

    def __init__(self, kp=3000.0, kd=60.0):
        self.kp, self.kd = kp, kd

    def setup(self, info):
        self.info = info
        self.clock = TrackingClock(info, settle_time_s=0.005)
        self.out = ControllerOutput.zeros(info.n_joints)
        self.out.target_position[:] = info.q_start

    def step(self, inputs):
        tau = self.clock.update(inputs, self.out.controlword)
        q = inputs.position
        if self.clock.motion_start_s is not None:
            self.out.modes_of_operation[:] = 10
            self.out.target_torque[:] = (self.info.dynamics.gravity(q) + self.kp * (self.info.q_start - q)
                                         - self.kd * inputs.velocity)
        self.out.target_position[:] = q
        return self.out

    def close(self):
        pass

    motion_start_s = property(lambda self: self.clock.motion_start_s)


class NoStep:
    def setup(self, info):
        pass

    def close(self):
        pass
'''


def scenario(tmp_path: Path, controller_lines: str, stop_time: str = "60 ms", extra: str = "") -> Path:
    (tmp_path / "my_ctrl.py").write_text(FOLLOW)
    text = short_scenario_text(stop_time, name="user_ctrl", extra=extra)
    text, n = re.subn(r'modes = \["model_based"\]', controller_lines, text, count=1)
    assert n == 1
    text = text.replace("can_log = true", "can_log = false")
    path = tmp_path / "user_ctrl.toml"
    path.write_text(text)
    return path


def run(path: Path, out: Path) -> tuple[int, dict]:
    code = main(["run", str(path), "--out", str(out), "--quiet"])
    return code, json.loads((out / "summary.json").read_text())


def test_a_user_controller_class_runs_the_cell(tmp_path):
    path = scenario(tmp_path, 'class = "my_ctrl.py:Follow"\nlabel = "follow"',
                    extra="[controller.parameters]\nkp = 20.0\n")
    code, summary = run(path, tmp_path / "out")
    assert code == 0 and summary["status"] == "ok"
    entry = summary["modes"]["follow"]
    assert entry["user_controller"] and entry["controller"] == "Follow" and entry["status"] == "ok"
    assert entry["motion_start_s"] == pytest.approx(0.0144, abs=2e-3)   # enabled ~3.6 ms + settle 10 + lead 0.8
    assert 0.0 < entry["tcp_error_max_mm"] < 5.0                        # it tracks the path
    assert entry["controller_cycles_timed"] == 151 and entry["cycle_wall_us"]["p50"] > 0
    assert (tmp_path / "out" / "timeseries_follow.parquet").is_file() and (tmp_path / "out" / "tcp_follow.parquet").is_file()
    assert list(summary["modes"]) == ["follow"]  # a named controller without `modes` runs alone
    # the per-cycle command log, as the built-in modes have: one row per cycle, what went to the drives
    assert entry["files"]["controller"] == "controller_follow.parquet"
    log = _command_log(tmp_path / "out" / "controller_follow.parquet", 151)
    moving = log["t"] > entry["motion_start_s"] + 0.01
    assert moving.sum() > 50 and np.all(log["controlword1"][moving] == 0x0F) and np.all(log["mode1"] == 8)
    kp = 20.0  # the class's law, row by row: torque offset = kp (q_d - q_obs), target = q_d
    for j in range(1, 7):
        assert np.array_equal(log[f"tau_ff{j}"], kp * (log[f"target{j}"] - log[f"q_obs{j}"])), j
    assert np.all(log["compute_us"] > 0) and np.all(np.isfinite(log["compute_cpu_us"]))


def _command_log(path: Path, rows: int) -> dict:
    """A user controller's command log as columns (checked: its columns, one row per cycle, every 400 us)."""
    from controller.port import command_log_columns

    columns, data = read_series(path)
    assert columns == command_log_columns(6)[0] and data.shape[0] == rows
    log = {name: data[:, k] for k, name in enumerate(columns)}
    assert np.array_equal(log["cycle"], np.arange(rows)) and np.allclose(np.diff(log["t"]), 4e-4)
    return log


def test_a_named_controller_runs_alone_unless_modes_are_listed(pd_fmu):
    """``[controller] class`` (or fmu) without ``modes``: the user's controller alone; ``modes`` listed:
    those built-in modes too; neither: the default built-in modes."""
    from cosim.cell.parts import CONTROLLER_TABLE, DEFAULT_MODES
    from cosim.scenario.schema import Where

    at = Where(None) / "controller"
    assert CONTROLLER_TABLE.check({}, at)["modes"] == list(DEFAULT_MODES)
    assert CONTROLLER_TABLE.check({"class": "my_ctrl.py:Follow"}, at)["modes"] == []
    assert CONTROLLER_TABLE.check({"fmu": str(pd_fmu)}, at)["modes"] == []
    assert CONTROLLER_TABLE.check({"class": "my_ctrl.py:Follow", "modes": ["standard"]}, at)["modes"] == ["standard"]


@pytest.mark.parametrize("params, reason", [
    ("fail_at_cycle = 50", "Follow.step() raised ZeroDivisionError: division by zero in my law"),
    ("nan_at_cycle = 50", "torque_offset = "),
])
def test_a_user_controller_that_raises_or_returns_nan_stops_the_run_cleanly(tmp_path, params, reason):
    path = scenario(tmp_path, 'class = "my_ctrl.py:Follow"', extra=f"[controller.parameters]\n{params}\n")
    code, summary = run(path, tmp_path / "out")
    assert code != 0 and summary["status"] == "failed"
    assert reason in summary["reason"] and summary["failed_component"] == "controller"
    assert summary["stopped_at_s"] == pytest.approx(50 * 400e-6)
    entry = summary["modes"]["Follow"]
    assert entry["status"] == "failed" and entry["stopped_at_s"] == pytest.approx(0.02)
    _, data = read_series(tmp_path / "out" / "timeseries_Follow.parquet")
    # the time series up to the failing cycle is on disk (400 us rows: 0 .. 19.6 ms)
    assert data.shape[0] == 50 and float(data[-1, 0]) == pytest.approx(0.0196)


@pytest.mark.parametrize("lines, extra, fragments", [
    ('class = "my_ctrl.py:Missing"', "", ["controller.class", "no 'Missing'", "Follow"]),
    ('class = "nowhere.py:Follow"', "", ["controller.class", "does not exist"]),
    ('class = "my_ctrl.py:NoStep"', "", ["controller.class", "no method step()", "setup(info), step(inputs)"]),
    ('class = "my_ctrl.py:Follow"', "[controller.parameters]\ngain = 3.0\n",
     ["controller.parameters", "gain", "Follow"]),
])
def test_bad_controller_class_is_an_error_before_anything_runs(tmp_path, lines, extra, fragments):
    path = scenario(tmp_path, lines, extra=extra)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert_names_file_and_fragments(info.value, path, fragments)
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 2


@pytest.fixture(scope="module")
def pd_fmu(tmp_path_factory) -> Path:
    from cosim_fmu_models import build_test_fmu

    return build_test_fmu("pd_controller", tmp_path_factory.mktemp("controller_fmu"))


def fmu_lines(fmu: Path, inputs: str = "") -> tuple[str, str]:
    mapping = "[controller.fmu_inputs]\n" + "".join(
        f'q{i} = "position[{i}]"\nq_ref{i} = "reference_position[{i}]"\n' for i in range(1, 7)) + inputs
    mapping += "[controller.fmu_outputs]\n" + "".join(f'tau{i} = "torque_offset[{i}]"\n' for i in range(1, 7))
    return f'fmu = "{fmu}"\nlabel = "pd_fmu"', mapping


def test_a_controller_fmu_runs_the_cell(tmp_path, pd_fmu):
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(pd_fmu)) == []
    lines, mapping = fmu_lines(pd_fmu)
    path = scenario(tmp_path, lines, extra=mapping + "[controller.parameters]\nkp = 20.0\n")
    code, summary = run(path, tmp_path / "out")
    assert code == 0 and summary["status"] == "ok", summary.get("reason")
    entry = summary["modes"]["pd_fmu"]
    assert entry["controller"] == "FmuController" and 0.0 < entry["tcp_error_max_mm"] < 5.0
    assert entry["controller_cycles_timed"] == 151
    log = _command_log(tmp_path / "out" / "controller_pd_fmu.parquet", 151)
    assert np.any(log["tau_ff1"] != 0.0) and np.all(log["target_torque1"] == 0.0)
    assert np.all(log["compute_us"] > 0)


def test_a_failing_controller_fmu_stops_the_run_cleanly(tmp_path, pd_fmu):
    lines, mapping = fmu_lines(pd_fmu)
    path = scenario(tmp_path, lines, extra=mapping + "[controller.parameters]\nfail_after = 0.02\n")
    code, summary = run(path, tmp_path / "out")
    assert code != 0 and summary["status"] == "failed"
    # the step from t = 0.02 s (50 exact 400 us periods) is the first with current_time >= fail_after
    assert "fmi2DoStep(t=0.02 s, h=0.0004 s) returned fmi2Discard" in summary["reason"]
    assert summary["stopped_at_s"] == pytest.approx(0.02, abs=1e-3)
    assert (tmp_path / "out" / "timeseries_pd_fmu.parquet").is_file()


@pytest.mark.parametrize("inputs, extra, fragments", [
    ('speed1 = "velocity[1]"\n', "", ["controller.fmu_inputs.speed1", "Pd_controller.fmu has no variable 'speed1'"]),
    ('q1 = "acceleration[1]"\n', "", ["controller.fmu_inputs.q1", "unknown field 'acceleration'"]),
    ("", "[controller.parameters]\nki = 1.0\n", ["controller.parameters.ki", "no variable 'ki'"]),
])
def test_a_controller_fmu_lacking_a_mapped_variable_is_an_error(tmp_path, pd_fmu, inputs, extra, fragments):
    lines, mapping = fmu_lines(pd_fmu, inputs)
    if 'q1 = "acceleration[1]"' in inputs:  # replace the valid q1 mapping by a bad one
        mapping = mapping.replace('q1 = "position[1]"\n', "")
    path = scenario(tmp_path, lines, extra=mapping + extra)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert_names_file_and_fragments(info.value, path, fragments)


def test_a_user_controller_in_cyclic_synchronous_torque_mode_holds_the_arm(tmp_path):
    """Mode 10 through the whole cell: the drives switch to CST (0x6061 shows 10) and the
    controller's gravity + PD torque holds the arm at its start pose."""
    path = scenario(tmp_path, 'class = "my_ctrl.py:HoldInTorqueMode"\nlabel = "cst"')
    text = path.read_text().replace('signals = [', 'signals = ["drive*.modes_of_operation_display", ', 1)
    path.write_text(text)
    code, summary = run(path, tmp_path / "out")
    assert code == 0 and summary["status"] == "ok", summary.get("reason")
    columns, data = read_series(tmp_path / "out" / "timeseries_cst.parquet")
    rows = [dict(zip(columns, row)) for row in data]
    last = rows[-1]
    assert [int(float(last[f"drive{i}.modes_of_operation_display"])) for i in range(1, 7)] == [10] * 6
    first = rows[0]
    drift = max(abs(float(last[f"plant.q[{i}]"]) - float(first[f"plant.q[{i}]"])) for i in range(1, 7))
    assert drift < 2e-3, drift   # rad, held by the user's torque alone


def test_controller_table_defaults_are_the_controllers_own():
    """The ``[controller]`` keys shared by the cell jobs and identification are defined once,
    with the defaults of :class:`controller.ControllerConfig` / :class:`controller.ControllerInfo`."""
    import dataclasses

    from controller import ControllerConfig, ControllerInfo
    from cosim.cell.parts import CONTROLLER_CONFIG_FIELDS, CONTROLLER_TABLE
    from cosim.jobs.identification import CONTROLLER_TABLE as IDENTIFICATION_CONTROLLER_TABLE

    config = {f.name: f.default for f in dataclasses.fields(ControllerConfig)}
    info = {f.name: f.default for f in dataclasses.fields(ControllerInfo)}
    assert CONTROLLER_CONFIG_FIELDS["period"].default == config["period_s"]
    assert CONTROLLER_CONFIG_FIELDS["compute_budget"].default == config["compute_budget_s"] == info["compute_budget_s"]
    assert CONTROLLER_CONFIG_FIELDS["settle_time"].default == config["settle_time_s"]
    for table in (CONTROLLER_TABLE, IDENTIFICATION_CONTROLLER_TABLE):
        for key, field in CONTROLLER_CONFIG_FIELDS.items():
            assert table.fields[key] is field, key


def test_a_controller_fmu_exchanges_integers_and_booleans_through_the_fmu_class(tmp_path):
    """The cell opens a controller FMU as fmus.fmu.Fmu (preallocated arrays, no fmpy per-cycle calls):
    Integer, Boolean and Real inputs gathered from their fields, outputs scattered to theirs, the
    parameters set as start values; what the FMU does not map is the built-in controller's."""
    import numpy as np

    from controller import ControllerInfo, ControllerInput
    from controller.fmu_controller import ControllerFmu
    from cosim.cell.user_controller import make_controller_fmu
    from cosim_fmu_models import build_test_fmu
    from fmus.fmu import Fmu

    fmu = build_test_fmu("word_controller", tmp_path)
    ctl = make_controller_fmu(fmu, {"status": "statusword[2]", "ready": "fresh[3]", "t": "time_s"},
                              {"mode": "modes_of_operation[4]", "offset": "torque_offset[1]",
                               "flag": "controlword[6]"}, {"gain": 2.0}, settle_time_s=0.0)
    ctl.setup(ControllerInfo(period_s=4e-4, q_start=np.full(6, 0.1)))
    try:
        assert isinstance(ctl._fmu, Fmu) and isinstance(ctl._fmu, ControllerFmu)
        inputs = ControllerInput.zeros(6)
        inputs.statusword[:] = [0x21, 0x40, 0x21, 0x21, 0x21, 0x21]
        inputs.fresh[:] = [True, True, False, True, True, True]
        inputs.time_s = 0.5
        out = ctl.step(inputs)
        assert out.modes_of_operation.tolist() == [8, 8, 8, -1, 8, 8]  # not ready: -1
        assert out.torque_offset.tolist() == [1.0, 0, 0, 0, 0, 0] and out.controlword[5] == 0
        assert np.allclose(out.target_position, 0.1)  # unmapped: the start pose while enabling
        inputs.fresh[2] = True
        inputs.time_s = 0.5004
        out = ctl.step(inputs)
        assert out.modes_of_operation[3] == 0x40 + 1 and out.controlword[5] == 1
        assert out.torque_offset[0] == pytest.approx(1.0008, abs=1e-15) and ctl.time == pytest.approx(0.5008)
    finally:
        ctl.close()
