"""The servo drive's protection (docs/explanation/fmus.md "Protection"), one axis on a simple load, stepped by
the project's FMU wrapper: I2t derating to the rated current and back (0x2310), max motor speed
(fault 0x8400), software position limits (fault 0x8612), each with its fault reaction and its
bits in limit_status / limit_history."""
import pytest

from fmus.build import ensure_fmus
from fmus.fmu import Fmu
from fmus.servo_drive.params import drive_start_values
from fmus.servo_drive.spec import LIMIT_BITS

SHUTDOWN, ENABLE = 0x06, 0x0F
ENABLED, FAULT_REACTION, FAULT = 0x27, 0x0F, 0x08
CSP, CST = 8, 10
BIT = {kind: 1 << bit for kind, bit in LIMIT_BITS.items()}


class Axis:
    """Drive FMU of axis 4 on a rigid inertia (or a blocked rotor), stepped one position sample (400 us) at a time."""

    def __init__(self, blocked=False, **overrides):
        self.values = {**drive_start_values(4), **overrides}
        self.drive = Fmu(ensure_fmus()["servo_drive"], "protection", self.values,
                         real_inputs=("target_position", "q_meas", "qd_meas", "target_torque"),
                         real_outputs=("tau_out", "current_actual", "i2t_level"),
                         integer_inputs=("controlword", "modes_of_operation"),
                         integer_outputs=("statusword", "error_code", "limit_status", "limit_history")).start()
        self.blocked, self.inertia = blocked, 0.21
        self.q = self.qd = self.t = self.target = self.torque = 0.0
        self.mode = CSP

    def run(self, controlword=ENABLE, seconds=400e-6):
        h = 400e-6
        for _ in range(max(1, round(seconds / h))):
            self.drive.set_integer_inputs((controlword, self.mode))
            self.drive.set_inputs((self.target, self.q, self.qd, self.torque))
            self.drive.do_step(self.t, h)
            self.t += h
            if not self.blocked:
                acc = self.drive.get_outputs()[0] / self.inertia
                self.q, self.qd = self.q + self.qd * h + 0.5 * acc * h * h, self.qd + acc * h

    @property
    def state(self):
        return int(self.drive.get_integer_outputs()[0]) & 0x6F

    @property
    def ints(self):
        return [int(v) for v in self.drive.get_integer_outputs()]

    def enable(self):
        self.run(SHUTDOWN)
        self.run(ENABLE)
        assert self.state == ENABLED


def test_i2t_derates_to_the_rated_current_after_the_peak_time_and_recovers():
    """A blocked rotor in CST at 60 N m (1.82 A: between the rated 1.06 A and the peak 2.12 A):
    the integral of i^2 - I_rated^2 reaches (I_peak^2 - I_rated^2) * peak_current_time after
    (I_peak^2 - I_rated^2) * 2 s / (i^2 - I_rated^2) = 3.095 s; then the current is limited to
    the rated one, statusword bit 7 and 0x603F = 0x2310 warn; with no torque it cools at
    I_rated^2 per second down to i2t_release = 0.9 of the threshold: 0.6 s later the peak
    current is allowed again."""
    axis = Axis(blocked=True)
    v = axis.values
    n_kt = v["gear_ratio"] * v["torque_constant"]
    i_peak = min(v["current_limit"], v["torque_limit"] / n_kt)
    i_rated, i_cmd = v["rated_current"], 60.0 / n_kt
    threshold = (i_peak ** 2 - i_rated ** 2) * v["peak_current_time"]
    t_derate = threshold / (i_cmd ** 2 - i_rated ** 2)
    assert t_derate == pytest.approx(3.095, abs=1e-3)
    axis.enable()
    axis.mode, axis.torque = CST, 60.0
    t0 = axis.t
    while axis.ints[1] == 0 and axis.t - t0 < 5.0:
        axis.run()
    derated_after = axis.t - t0
    assert derated_after == pytest.approx(t_derate, abs=0.01)  # measured: within one sample plus the current rise
    axis.run(seconds=0.05)
    sw, code, status, history = axis.ints
    assert code == 0x2310 and sw & 0x80 and status & BIT["i2t"] and history & BIT["i2t"] and axis.state == ENABLED
    assert axis.drive.get_outputs()[1] == pytest.approx(i_rated, rel=1e-3)  # current at the rated value
    assert axis.drive.get_outputs()[2] == pytest.approx(1.0, abs=1e-3)
    axis.torque = 0.0
    t1 = axis.t
    while axis.ints[1] == 0x2310 and axis.t - t1 < 2.0:
        axis.run()
    assert axis.t - t1 == pytest.approx(0.1 * threshold / i_rated ** 2, abs=0.01)
    axis.run()  # the step of the release still shows the bit
    assert axis.ints[1] == 0 and not axis.ints[2] & BIT["i2t"] and axis.ints[3] & BIT["i2t"]
    assert any("I2t" in m for m in axis.drive.messages)


def test_max_motor_speed_raises_fault_8400_and_stops_the_axis():
    """CST at 20 N m on a free 0.21 kg m^2 axis: beyond max_motor_speed (0x6080, 1.3x the URDF
    speed) the drive raises 0x8400, stops on its fault-reaction ramp and ends in Fault."""
    axis = Axis()
    axis.enable()
    axis.mode, axis.torque = CST, 20.0
    while axis.state == ENABLED and axis.t < 1.0:
        axis.run()
    vmax = axis.values["max_motor_speed"]
    assert axis.ints[1] == 0x8400 and axis.state == FAULT_REACTION
    assert 0.95 * vmax < abs(axis.qd) < 1.05 * vmax  # tripped at the limit (the ramp has begun in that sample)
    axis.run(seconds=1.0)
    assert axis.state == FAULT and abs(axis.qd) < 0.01
    assert axis.ints[3] & BIT["speed_limit"] and axis.ints[3] & (BIT["speed_limit"] << 8)
    assert axis.ints[2] & (BIT["speed_limit"] << 8)  # in Fault because of it
    assert any("0x6080" in m for m in axis.drive.messages)


def test_software_position_limit_raises_fault_8612():
    """CSP toward a target beyond position_limit_max (0x607D): the axis follows until its
    position actual passes the limit, then fault 0x8612, fault reaction, Fault."""
    axis = Axis(position_limit_max=0.05)
    axis.enable()
    while axis.state == ENABLED and axis.t < 1.0:
        axis.target = min(axis.target + 1.0 * 400e-6, 0.2)  # 1 rad/s ramp
        axis.run()
    assert axis.ints[1] == 0x8612 and axis.state == FAULT_REACTION
    assert 0.05 < axis.q < 0.05 + 0.01
    axis.run(seconds=0.5)
    assert axis.state == FAULT and axis.ints[3] & BIT["position_limit"] and axis.ints[3] & (BIT["position_limit"] << 8)
    assert any("software position limits" in m for m in axis.drive.messages)


def test_bad_protection_parameters_are_refused_by_the_fmu():
    axis_values = {**drive_start_values(4), "position_limit_min": 1.0, "position_limit_max": -1.0}
    with pytest.raises(Exception):
        Fmu(ensure_fmus()["servo_drive"], "bad", axis_values).start()
