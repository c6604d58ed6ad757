"""CiA 402 state machine of the servo-drive FMU: transitions, statuswords, power only
when enabled, quick-stop and fault-reaction ramps, fault reset, following-error fault,
holding brake while the power stage is off."""
import numpy as np
import pytest

from fmus.build import ensure_fmus
from fmus.fmu import Fmu
from fmus.servo_drive.params import drive_start_values

# statusword & 0x6F of each state (CiA 402 table)
SWITCH_ON_DISABLED, READY, SWITCHED_ON, ENABLED, QUICK_STOP, FAULT_REACTION, FAULT = (
    0x40, 0x21, 0x23, 0x27, 0x07, 0x0F, 0x08)
SHUTDOWN, SWITCH_ON, ENABLE, DISABLE_VOLTAGE, QUICK_STOP_CMD, FAULT_RESET = 0x06, 0x07, 0x0F, 0x00, 0x02, 0x80
TS_P = 400e-6  # one position sample = one state-machine evaluation
CLOSING = round(drive_start_values(4)["brake_closing_time"] / TS_P)  # samples the motor holds while the brake engages
FE_TIME = round(drive_start_values(4)["following_error_time"] / TS_P)  # samples beyond the window before 0x8611


class Axis:
    """Drive FMU of axis 4 on a rigid inertia, stepped one position sample at a time."""

    def __init__(self, **overrides):
        values = dict(drive_start_values(4))
        values.update(overrides)
        self.drive = Fmu(ensure_fmus()["servo_drive"], "cia402", values,
                         real_inputs=("target_position", "torque_offset", "q_meas", "qd_meas"),
                         real_outputs=("tau_out", "position_actual", "velocity_actual",
                                       "torque_actual", "brake_torque"),
                         integer_inputs=("controlword", "fault_code"),
                         integer_outputs=("statusword", "error_code", "limit_status", "limit_history")).start()
        self.inertia, self.q, self.qd, self.t, self.target = 0.21, 0.0, 0.0, 0.0, 0.0
        self.velocity = 0.0  # rad/s of the target ramp
        self.load = 0.0  # N m, external torque on the axis (e.g. gravity)

    def run(self, controlword, samples=1, fault_code=0):
        h = 50e-6
        for _ in range(samples * 8):
            self.target += self.velocity * h
            self.drive.set_integer_inputs((controlword, fault_code))
            self.drive.set_inputs((self.target, 0.0, self.q, self.qd))
            self.drive.do_step(self.t, h)
            self.t += h
            tau = self.drive.get_outputs()[0]
            acc = (tau + self.load) / self.inertia
            self.q, self.qd = self.q + self.qd * h + 0.5 * acc * h * h, self.qd + acc * h
        return self.state

    @property
    def state(self):
        return int(self.drive.get_integer_outputs()[0]) & 0x6F

    @property
    def statusword(self):
        return int(self.drive.get_integer_outputs()[0])

    @property
    def tau(self):
        return float(self.drive.get_outputs()[0])

    @property
    def motor_torque(self):
        return float(self.drive.get_outputs()[3])

    @property
    def brake_torque(self):
        return float(self.drive.get_outputs()[4])

    def enable(self):
        assert self.run(SHUTDOWN) == READY
        assert self.run(ENABLE) == ENABLED


def test_power_up_and_device_control_transitions():
    axis = Axis()
    assert axis.state == SWITCH_ON_DISABLED and axis.statusword & 0x0200  # remote
    assert axis.run(ENABLE) == SWITCH_ON_DISABLED  # needs shutdown first
    assert axis.tau == 0.0
    assert axis.run(SHUTDOWN) == READY                 # 2
    assert axis.statusword & 0x10                      # voltage enabled
    assert axis.run(SWITCH_ON) == SWITCHED_ON          # 3
    assert axis.run(ENABLE) == ENABLED                 # 4
    assert axis.statusword & 0x1000                    # CSP: drive follows the command value
    assert axis.run(SWITCH_ON) == SWITCHED_ON          # 5
    assert axis.run(SHUTDOWN) == READY                 # 6
    assert axis.run(ENABLE) == ENABLED                 # 3 + 4 in one telegram
    assert axis.run(SHUTDOWN) == READY                 # 8
    assert axis.run(DISABLE_VOLTAGE) == SWITCH_ON_DISABLED  # 7
    axis.enable()
    assert axis.run(DISABLE_VOLTAGE) == SWITCH_ON_DISABLED  # 9
    assert axis.run(SHUTDOWN) == READY
    assert axis.run(SWITCH_ON) == SWITCHED_ON
    assert axis.run(QUICK_STOP_CMD) == SWITCH_ON_DISABLED  # 10


def test_torque_only_when_enabled():
    axis = Axis()
    axis.target = 0.01
    for command, state in ((SHUTDOWN, READY), (SWITCH_ON, SWITCHED_ON)):
        assert axis.run(command, samples=5) == state
        assert axis.tau == 0.0 and axis.q == 0.0
    assert axis.run(ENABLE, samples=5) == ENABLED
    assert axis.tau != 0.0 and axis.q > 0.0 and axis.brake_torque == 0.0
    assert axis.run(SWITCH_ON) == SWITCHED_ON
    # power off: no motor torque; the holding brake closes on the moving axis and brakes it
    assert axis.motor_torque == 0.0
    assert axis.tau == axis.brake_torque and axis.brake_torque * axis.qd < 0.0


def _ramp_deceleration(axis, active_state, command, samples, **kw):
    speeds, states = [], []
    for _ in range(samples):
        states.append(axis.run(command, **kw))
        speeds.append(axis.qd)
    speeds = np.array(speeds)
    ramping = (np.array(states) == active_state) & (speeds > 0.2 * speeds[0]) & (speeds < 0.8 * speeds[0])
    times = np.arange(speeds.size) * TS_P
    slope = np.polyfit(times[ramping], speeds[ramping], 1)[0] if ramping.sum() > 3 else 0.0
    return states, speeds, slope


@pytest.mark.parametrize("option_code, final", [(6, QUICK_STOP), (2, SWITCH_ON_DISABLED)])
def test_quick_stop_ramp(option_code, final):
    values = drive_start_values(4)
    axis = Axis(quick_stop_option_code=option_code)
    axis.enable()
    axis.velocity = 2.0
    axis.run(ENABLE, samples=100)
    assert axis.qd == pytest.approx(2.0, rel=1e-3)
    axis.velocity = 0.0  # the master would freeze the target; the drive ignores it anyway
    states, speeds, slope = _ramp_deceleration(axis, QUICK_STOP, QUICK_STOP_CMD, 300 + CLOSING)
    assert states[0] == QUICK_STOP                     # 11
    assert slope == pytest.approx(-values["quick_stop_deceleration"], rel=0.05)
    assert states[-1] == final and abs(speeds[-1]) <= values["standstill_velocity"]
    if option_code == 6:
        held = axis.q
        axis.run(QUICK_STOP_CMD, samples=50)
        assert abs(axis.q - held) < 1e-5              # holds position
        axis.target = axis.q
        assert axis.run(ENABLE) == ENABLED             # 16
    else:
        assert axis.motor_torque == 0.0                # 12: power off (the brake holds)


def test_fault_reaction_fault_and_reset():
    values = drive_start_values(4)
    axis = Axis()
    axis.enable()
    axis.velocity = 2.0
    axis.run(ENABLE, samples=100)
    axis.velocity = 0.0
    states, speeds, slope = _ramp_deceleration(axis, FAULT_REACTION, ENABLE, 250 + CLOSING, fault_code=0x8130)
    assert states[0] == FAULT_REACTION                 # 13
    assert slope == pytest.approx(-values["fault_reaction_deceleration"], rel=0.05)
    assert states[-1] == FAULT                         # 14
    assert axis.motor_torque == 0.0                    # power off, the brake holds
    held = axis.q
    axis.load = -0.5 * values["brake_holding_torque"]
    axis.run(ENABLE, samples=500, fault_code=0x8130)  # 0.2 s
    assert axis.state == FAULT and abs(axis.qd) < 1e-4
    assert axis.q - held == pytest.approx(axis.load / values["brake_stiffness"], rel=0.05)  # the brake's sag
    axis.load = 0.0
    assert int(axis.drive.get_integer_outputs()[1]) == 0x8130
    # reset while the cause is still present: back into Fault
    axis.run(FAULT_RESET, fault_code=0x8130)
    assert axis.run(SHUTDOWN, samples=2, fault_code=0x8130) == FAULT
    # cause gone: the rising edge of bit 7 resets
    axis.run(0x00)
    assert axis.run(FAULT_RESET) == SWITCH_ON_DISABLED  # 15
    assert int(axis.drive.get_integer_outputs()[1]) == 0
    axis.enable()


def test_the_brake_takes_over_the_held_load_without_the_axis_moving():
    """A fault reaction under a static load: ramp to standstill, the motor holds the axis for the
    brake's closing time (still powered), then the closed brake takes over the motor's torque
    where the axis is: no sag onto the brake spring, no creep afterwards."""
    values = drive_start_values(4)
    axis = Axis()
    axis.load = 0.3 * values["brake_holding_torque"]
    axis.enable()
    axis.velocity = 1.0
    axis.run(ENABLE, samples=100)
    axis.velocity = 0.0
    axis.run(ENABLE, samples=200, fault_code=0x8130)  # ramp (20 ms), 10 ms standstill, 50 ms of the closing
    held, motor = axis.q, axis.motor_torque
    assert axis.state == FAULT_REACTION and motor == pytest.approx(-axis.load, rel=0.02)  # still holding
    axis.run(ENABLE, samples=CLOSING + 100, fault_code=0x8130)
    assert axis.state == FAULT and axis.motor_torque == 0.0
    assert axis.brake_torque == pytest.approx(-axis.load, rel=1e-3)
    sag = axis.load / values["brake_stiffness"]
    assert abs(axis.q - held) < 0.02 * abs(sag) and abs(axis.qd) < 1e-5


def test_fault_while_disabled_goes_straight_to_fault():
    axis = Axis()
    assert axis.run(SHUTDOWN, fault_code=0x8700) == FAULT


def test_following_error_window_raises_fault_8611():
    """A target jump of 10 mrad against a 1 mrad window (0x6065): the position loop (Kv = 307/s)
    needs about 8 ms to bring the error back inside, longer than the 2 ms time-out (0x6066)."""
    axis = Axis(following_error_window=1e-3, following_error_time=0.002)
    axis.enable()
    axis.target = 0.01  # a jump far beyond the window
    axis.run(ENABLE, samples=2)
    assert axis.statusword & 0x2000 and axis.state == ENABLED  # beyond the window, not yet for 2 ms
    axis.run(ENABLE, samples=100 + CLOSING)  # time-out, ramp from the actual speed, standstill, brake
    assert axis.state == FAULT
    assert int(axis.drive.get_integer_outputs()[1]) == 0x8611
    assert any("following error" in message for message in axis.drive.messages)
    history = int(axis.drive.get_integer_outputs()[3])
    assert history & 0x10 and history & (0x10 << 8)  # beyond the window; fault reaction caused by it


def test_following_error_shorter_than_its_time_out_is_no_fault():
    """The same jump with the default 10 ms time-out: the error is back inside the window in
    time, the drive stays enabled; the excursion shows in limit_history (bit 4) without a fault."""
    axis = Axis(following_error_window=1e-3)
    assert FE_TIME == 25
    axis.enable()
    axis.target = 0.01
    axis.run(ENABLE, samples=100)
    assert axis.state == ENABLED and int(axis.drive.get_integer_outputs()[1]) == 0
    history = int(axis.drive.get_integer_outputs()[3])
    assert history & 0x10 and not history & (0x10 << 8)


def test_brake_holds_below_its_holding_torque_and_slips_above():
    """Power off (Switch on disabled from power-up): the closed brake holds a static load
    with the sag load / stiffness and settles; a load above the holding torque makes it
    slip with the acceleration (load - holding torque) / inertia."""
    values = drive_start_values(4)
    limit, stiffness = values["brake_holding_torque"], values["brake_stiffness"]
    axis = Axis()
    axis.load = 0.8 * limit
    axis.run(0x00, samples=500)  # 0.2 s
    assert axis.state == SWITCH_ON_DISABLED
    assert axis.q == pytest.approx(axis.load / stiffness, rel=1e-3) and abs(axis.qd) < 1e-6
    assert axis.brake_torque == pytest.approx(-axis.load, rel=1e-4) and axis.motor_torque == 0.0
    axis.load = 1.5 * limit
    axis.run(0x00, samples=50)
    qd0, t0 = axis.qd, axis.t
    axis.run(0x00, samples=50)
    assert axis.brake_torque == pytest.approx(-limit)
    assert (axis.qd - qd0) / (axis.t - t0) == pytest.approx((axis.load - limit) / axis.inertia, rel=1e-3)


def test_no_brake_when_holding_torque_is_zero():
    axis = Axis(brake_holding_torque=0.0)
    axis.load = 1.0
    axis.run(0x00, samples=25)
    assert axis.brake_torque == 0.0 and axis.tau == 0.0
    assert axis.qd == pytest.approx(axis.load / axis.inertia * axis.t, rel=1e-9)  # free fall
