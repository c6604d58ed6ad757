"""CiA 402 modes of operation of the servo-drive FMU: cyclic synchronous velocity (9) and
torque (10) following their set-points, the velocity offset in CSP (8), bumpless mode
switches at run time, the 0x6061 display, an unsupported mode request, and the outputs in
Initialization Mode with their declared InitialUnknowns dependencies."""
import math

import fmpy
import numpy as np
import pytest
from fmpy.fmi2 import FMU2Slave
from fmpy.validation import validate_fmu

from fmus.build import ensure_fmus
from fmus.errors import SimulationError
from fmus.fmu import Fmu
from fmus.servo_drive.params import drive_start_values

SHUTDOWN, ENABLE, QUICK_STOP_CMD = 0x06, 0x0F, 0x02
CSP, CSV, CST = 8, 9, 10
H = 50e-6  # communication step = one current sample
REAL_IN = ("target_position", "torque_offset", "q_meas", "qd_meas", "target_velocity", "velocity_offset",
           "target_torque")
REAL_OUT = ("tau_out", "position_actual", "velocity_actual", "torque_actual", "following_error", "brake_torque")
INT_OUT = ("statusword", "modes_of_operation_display", "unsupported_mode_requests", "error_code")


class Axis:
    """Drive FMU of ``axis`` on a rigid inertia with a constant external load torque,
    stepped 50 us at a time; set-points are plain attributes."""

    def __init__(self, axis=4, inertia=0.21, load=0.0, **overrides):
        values = dict(drive_start_values(axis))
        values.update(overrides)
        self.drive = Fmu(ensure_fmus()["servo_drive"], f"modes{axis}", values, real_inputs=REAL_IN,
                         real_outputs=REAL_OUT, integer_inputs=("controlword", "modes_of_operation"),
                         integer_outputs=INT_OUT).start()
        self.inertia, self.load = inertia, load
        self.q = self.qd = self.t = 0.0
        self.target = self.velocity = self.velocity_offset = self.torque = self.torque_offset = 0.0
        self.target_speed = 0.0  # rad/s: the CSP target moves at this speed
        self.mode = CSP
        self.controlword = SHUTDOWN
        self.tau_history: list[float] = []

    def run(self, seconds):
        for _ in range(int(round(seconds / H))):
            self.target += self.target_speed * H
            self.drive.set_integer_inputs((self.controlword, self.mode))
            self.drive.set_inputs((self.target, self.torque_offset, self.q, self.qd, self.velocity,
                                   self.velocity_offset, self.torque))
            self.drive.do_step(self.t, H)
            self.t += H
            tau = float(self.drive.get_outputs()[0])
            self.tau_history.append(tau)
            acc = (tau + self.load) / self.inertia
            self.q, self.qd = self.q + self.qd * H + 0.5 * acc * H * H, self.qd + acc * H
        return self

    def enable(self):
        self.controlword = SHUTDOWN
        self.run(4e-4)
        self.controlword = ENABLE
        self.run(8e-4)
        assert self.statusword & 0x6F == 0x27
        return self

    def out(self, name):
        return float(self.drive.get_outputs()[REAL_OUT.index(name)])

    def integer(self, name):
        return int(self.drive.get_integer_outputs()[INT_OUT.index(name)])

    @property
    def statusword(self):
        return self.integer("statusword")

    @property
    def display(self):
        return self.integer("modes_of_operation_display")


def test_csv_speed_step_reaches_the_speed():
    axis = Axis()
    axis.mode = CSV
    axis.enable()
    assert axis.display == CSV and axis.statusword & 0x1000  # drive follows the command value
    axis.velocity = 0.5
    axis.run(0.05)
    assert axis.out("velocity_actual") == pytest.approx(0.5, rel=1e-3)
    assert axis.qd == pytest.approx(0.5, rel=1e-3)
    assert axis.out("following_error") == 0.0  # no position loop in CSV
    # the velocity offset 0x60B1 adds to the target velocity 0x60FF
    axis.velocity, axis.velocity_offset = 0.3, 0.4
    axis.run(0.05)
    assert axis.qd == pytest.approx(0.7, rel=1e-3)


def test_csv_speed_demand_is_limited_to_the_velocity_limit():
    limit = drive_start_values(4)["velocity_limit"]
    axis = Axis()
    axis.mode = CSV
    axis.enable()
    axis.velocity = 3.0 * limit
    axis.run(0.3)
    assert axis.qd == pytest.approx(limit, rel=2e-3)


def test_cst_torque_passes_through_within_the_current_loop_bandwidth():
    axis = Axis(inertia=1e3)  # nearly at rest: the back-EMF stays negligible
    axis.mode = CST
    axis.enable()
    assert axis.display == CST
    start = len(axis.tau_history)
    axis.torque, axis.torque_offset = 8.0, 2.0  # target torque 0x6071 + torque offset 0x60B2
    axis.run(0.01)
    tau = np.array(axis.tau_history[start:])
    t = (np.arange(tau.size) + 1) * H
    assert tau[-1] == pytest.approx(10.0, rel=1e-3)
    assert axis.out("torque_actual") == pytest.approx(10.0, rel=1e-3) and axis.out("brake_torque") == 0.0
    # current loop tuned to the technical optimum: 90 % of the step within 1 ms, settled (2 %) within 2 ms
    assert t[np.argmax(tau >= 9.0)] <= 1e-3
    assert np.all(np.abs(tau[t >= 2e-3] - 10.0) <= 0.2)
    assert tau.max() < 10.0 * 1.06  # ~4 % overshoot of the current loop, no more


def test_cst_target_torque_is_clamped_to_the_torque_limit():
    limit = drive_start_values(4)["torque_limit"]
    axis = Axis(inertia=1e3)
    axis.mode = CST
    axis.enable()
    axis.torque = 5.0 * limit
    axis.run(0.01)
    assert axis.out("torque_actual") == pytest.approx(limit, rel=1e-3)
    assert axis.statusword & 0x0800  # internal limit active


def test_csp_velocity_offset_replaces_the_speed_feedforward():
    """CSP with the drive's own speed feed-forward off: the velocity offset 0x60B1 carries it."""
    kv = drive_start_values(4)["position_kv"]
    lags = {}
    for offset in (0.0, 1.0):
        axis = Axis(speed_feedforward_gain=0.0)
        axis.enable()
        axis.target_speed, axis.velocity_offset = 1.0, offset
        axis.run(0.3)
        lags[offset] = axis.target - axis.q
    assert lags[0.0] == pytest.approx(1.0 / kv, rel=0.02)  # the classic lag v / Kv
    assert abs(lags[1.0]) < 0.02 * lags[0.0]


def _jump(history, index, window=40):
    """Largest torque change from one 50 us sample to the next within ``window`` samples after ``index``."""
    seg = np.asarray(history[index - 1:index + window])
    return float(np.abs(np.diff(seg)).max())


def test_mode_switches_at_run_time_are_bumpless():
    """Axis 4 holding a 20 N m load in CSP; switch to CSV (target velocity 0), then to CST
    with the target torque the motor makes, then back to CSP at position actual: torque
    and position continue without a jump."""
    axis = Axis(load=-20.0)
    axis.enable()
    axis.run(0.1)  # settled: the speed integrator holds the load
    steady = _jump(axis.tau_history, len(axis.tau_history) - 40)
    assert axis.out("torque_actual") == pytest.approx(20.0, rel=1e-3)

    q_before = axis.q
    axis.mode = CSV
    index = len(axis.tau_history)
    axis.run(0.05)
    assert axis.display == CSV
    assert _jump(axis.tau_history, index) < 1e-3  # N m: no bump (the speed integrator is kept)
    assert abs(axis.q - q_before) < 1e-9  # held at zero speed

    axis.mode = CST
    axis.torque = axis.out("torque_actual")
    index = len(axis.tau_history)
    axis.run(0.01)
    assert axis.display == CST
    assert _jump(axis.tau_history, index) < 1e-3
    assert abs(axis.out("torque_actual") - 20.0) < 1e-3

    axis.mode = CSP
    axis.target = axis.out("position_actual")
    index = len(axis.tau_history)
    q_switch = axis.q
    axis.run(0.1)
    assert axis.display == CSP
    assert _jump(axis.tau_history, index) < max(1e-3, 10 * steady)  # speed integrator pre-loaded
    assert abs(axis.q - q_switch) < 1e-6
    assert axis.out("torque_actual") == pytest.approx(20.0, rel=1e-3)


def test_mode_switches_while_moving_are_bumpless():
    """Axis 4 at 1 rad/s against a 20 N m load in CSP, then CSV at the same speed, then CST
    with the load torque: no torque step beyond the ripple of steady motion."""
    axis = Axis(load=-20.0)
    axis.enable()
    axis.target_speed = 1.0
    axis.run(0.2)
    ripple = _jump(axis.tau_history, len(axis.tau_history) - 40)
    axis.mode, axis.velocity, axis.target_speed = CSV, 1.0, 0.0
    index = len(axis.tau_history)
    axis.run(0.05)
    assert _jump(axis.tau_history, index) < 2 * ripple
    assert axis.qd == pytest.approx(1.0, rel=1e-6)
    axis.mode, axis.torque = CST, 20.0
    index = len(axis.tau_history)
    axis.run(0.01)
    assert _jump(axis.tau_history, index) < 2 * ripple
    assert axis.qd == pytest.approx(1.0, rel=1e-4)


def test_mode_takes_effect_at_the_next_sync_and_not_during_quick_stop():
    axis = Axis()
    axis.enable()
    axis.run(H)  # now 50 us after a position sample (the sync)
    axis.mode = CSV
    axis.run(7 * H)
    assert axis.display == CSP
    axis.run(H)  # the next position sample
    assert axis.display == CSV
    axis.velocity = 0.5
    axis.run(0.05)
    axis.controlword = QUICK_STOP_CMD
    axis.run(4e-4)
    assert axis.statusword & 0x6F == 0x07  # quick stop active
    axis.mode = CST
    axis.run(0.01)
    assert axis.display == CSV  # deferred while the stop ramp runs
    axis.controlword = 0x00  # disable voltage: switch on disabled
    axis.run(8e-4)
    assert axis.statusword & 0x6F == 0x40 and axis.display == CST


def test_unsupported_mode_is_refused_reported_and_counted():
    axis = Axis()
    axis.mode = CSV
    axis.enable()
    axis.velocity = 0.2
    axis.run(0.02)
    axis.mode = 1  # profile position: not supported by this drive
    axis.run(0.01)
    assert axis.display == CSV and axis.qd == pytest.approx(0.2, rel=1e-3)  # keeps its mode
    assert axis.statusword & 0x0080  # warning bit while the request stands
    assert axis.statusword & 0x6F == 0x27  # still operation enabled, no fault
    assert axis.integer("unsupported_mode_requests") == 1  # once per request, not per sample
    warnings = [m for m in axis.drive.messages if m.startswith("[fmi2Warning]")]
    assert len(warnings) == 1 and "modes_of_operation (0x6060) = 1 is not supported" in warnings[0]
    axis.mode = -3
    axis.run(0.002)
    assert axis.integer("unsupported_mode_requests") == 2
    axis.mode = CSV
    axis.run(0.002)
    assert not axis.statusword & 0x0080 and axis.display == CSV
    with pytest.raises(SimulationError, match="modes_of_operation=300"):  # beyond INT8: fmi2SetInteger refuses
        axis.drive.set_integer_inputs((ENABLE, 300))


def _instance(path, name):
    md = fmpy.read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    unzipped = fmpy.extract(str(path))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier="servo_drive", instanceName=name)
    fmu.instantiate()
    return fmu, vr


def test_outputs_are_computed_in_initialization_mode():
    path = ensure_fmus()["servo_drive"]
    fmu, vr = _instance(path, "init")
    values = drive_start_values(2)
    fmu.setupExperiment(startTime=0.0)
    fmu.setReal([vr[k] for k in ("gear_ratio",)], [values["gear_ratio"]])
    fmu.enterInitializationMode()
    fmu.setReal([vr["q_meas"], vr["qd_meas"]], [0.3, -0.02])
    fmu.setInteger([vr["modes_of_operation"]], [CST])
    counts_per_rad = values["gear_ratio"] * 65536 / (2 * math.pi)
    expected = math.floor(0.3 * counts_per_rad) / counts_per_rad
    pos, vel, tau = fmu.getReal([vr["position_actual"], vr["velocity_actual"], vr["tau_out"]])
    status, display = fmu.getInteger([vr["statusword"], vr["modes_of_operation_display"]])
    assert pos == expected and vel == -0.02 and tau == 0.0
    assert status == 0x0240 and display == CST  # switch on disabled, remote
    fmu.setReal([vr["q_meas"]], [-0.1])  # the outputs follow the inputs set in Initialization Mode
    assert fmu.getReal([vr["position_actual"]])[0] == math.floor(-0.1 * counts_per_rad) / counts_per_rad
    fmu.exitInitializationMode()
    assert fmu.getReal([vr["position_actual"]])[0] == math.floor(-0.1 * counts_per_rad) / counts_per_rad
    assert fmu.getInteger([vr["modes_of_operation_display"]])[0] == CST
    fmu.terminate()
    fmu.freeInstance()


def test_initial_unknowns_declare_their_dependencies():
    md = fmpy.read_model_description(str(ensure_fmus()["servo_drive"]))
    deps = {u.variable.name: sorted(d.name for d in (u.dependencies or [])) for u in md.initialUnknowns}
    assert deps["position_actual"] == ["encoder_counts_per_rev", "gear_ratio", "q_meas"]
    assert deps["velocity_actual"] == ["qd_meas"]
    assert deps["modes_of_operation_display"] == ["modes_of_operation"]
    assert deps["tau_out"] == [] and deps["torque_actual"] == []
    assert {u.variable.name for u in md.outputs} == set(deps)
    assert all(not u.dependencies for u in md.outputs)  # no direct feed-through in a step
    assert validate_fmu(str(ensure_fmus()["servo_drive"])) == []
    assert "integer multiple of current_sample_time" in md.description


def test_value_references_of_the_original_variables_are_unchanged():
    md = fmpy.read_model_description(str(ensure_fmus()["servo_drive"]))
    vr = {(v.type, v.name): v.valueReference for v in md.modelVariables}
    assert vr[("Real", "target_position")] == 0 and vr[("Real", "torque_offset")] == 1
    assert vr[("Real", "tau_out")] == 4 and vr[("Real", "brake_torque")] == 38
    assert vr[("Integer", "controlword")] == 0 and vr[("Integer", "quick_stop_option_code")] == 5
    assert vr[("Real", "target_velocity")] == 39 and vr[("Real", "velocity_offset")] == 40
    assert vr[("Real", "target_torque")] == 41
    assert vr[("Integer", "modes_of_operation")] == 6 and vr[("Integer", "modes_of_operation_display")] == 7


def _quick_stop_from(mode):
    axis = Axis(load=-2.0)
    axis.mode = mode
    axis.enable()
    if mode == CST:  # accelerate to ~0.95 rad/s, then hold the speed against the load
        axis.torque = 2.0 + 0.21 * 5.0
        axis.run(0.19)
        axis.torque = 2.0
        axis.run(0.01)
    elif mode == CSV:
        axis.velocity = 0.95
        axis.run(0.2)
    else:
        axis.target_speed = 0.95
        axis.run(0.2)
    speed = axis.qd
    index = len(axis.tau_history)
    axis.controlword = QUICK_STOP_CMD
    axis.run(0.1)
    return speed, _jump(axis.tau_history, index), max(axis.tau_history[index:]), axis


def test_quick_stop_from_cst_and_csv_is_the_same_ramp_as_from_csp():
    """The stop ramp (position loop) takes over from the torque the motor makes: leaving CST
    the speed integrator is pre-loaded, so the transient equals the one from CSP."""
    speed, jump, peak, axis = _quick_stop_from(CSP)
    assert speed == pytest.approx(0.95, rel=0.01)
    for mode in (CSV, CST):
        s, j, p, other = _quick_stop_from(mode)
        assert s == pytest.approx(speed, rel=0.03)
        assert j == pytest.approx(jump, rel=0.05) and p == pytest.approx(peak, rel=0.05)
        assert other.statusword & 0x6F == 0x07 and abs(other.qd) < 1e-3  # stopped, holding in quick stop
        assert other.display == mode


@pytest.mark.parametrize("axis_number", [2, 4])
def test_modes_and_switches_are_bit_identical_to_the_python_oracle(axis_number):
    """CSP with a velocity offset, then CSV, CST and back to CSP, with changing set-points:
    the FMU's torque equals the oracle's (fmus/servo_drive/reference.py, written from
    docs/explanation/fmus.md) to the last bits."""
    from fmus.servo_drive.reference import DriveReference

    values = drive_start_values(axis_number)
    inertia = [20.0, 20.0, 10.0, 0.2, 0.2, 0.05][axis_number - 1]
    drive = Fmu(ensure_fmus()["servo_drive"], "oracle_modes", values, real_inputs=REAL_IN,
                real_outputs=REAL_OUT, integer_inputs=("controlword", "modes_of_operation"),
                integer_outputs=INT_OUT).start()
    oracle = DriveReference(dict(values))
    oracle.initialize(0.0, 0.0, 0.0)
    q = qd = current = 0.0
    worst, displays = 0.0, set()
    limit = values["torque_limit"]
    for k in range(8000):  # 0.4 s
        t = k * H
        cw = SHUTDOWN if t < 4e-4 else ENABLE
        mode = CSP if t < 0.1 else CSV if t < 0.2 else CST if t < 0.3 else CSP
        target = 0.1 * math.sin(2 * math.pi * t) if mode == CSP and t < 0.1 else q + 0.02 * (t - 0.3)
        offset = 0.02 * limit * math.sin(6 * math.pi * t)
        velocity, velocity_offset = 0.3 * math.cos(5 * t), 0.05 * math.sin(9 * t)
        torque = 0.1 * limit * math.sin(20 * t)
        drive.set_integer_inputs((cw, mode))
        drive.set_inputs((target, offset, q, qd, velocity, velocity_offset, torque))
        drive.do_step(t, H)
        tau = float(drive.get_outputs()[0])
        displays.add(int(drive.get_integer_outputs()[1]))
        u, powered = oracle.tick_voltage(q, qd, current, target, offset, cw, mode, velocity, velocity_offset, torque)
        current = oracle.advance_current(current, u, qd) if powered else 0.0
        worst = max(worst, abs(tau - oracle.torque(current)))
        acc = (tau - 0.05 * limit) / inertia
        q, qd = q + qd * H + 0.5 * acc * H * H, qd + acc * H
    drive.close()
    assert displays == {CSP, CSV, CST}
    assert worst == 0.0, worst  # same operations in the same order
