"""Modes of operation end to end: a controller selects CST and CSV through the telegrams
(0x6060 in the RPDO1), the drive FMU runs them, the PRes shows the mode (0x6061) and the
actual values; torque and speed set-points arrive quantised as the telegram carries them."""
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fieldbus import DriveActuals, EnableSequencer, JointScaling, PowerlinkNetwork, Setpoints, motion_enabled
from fmus.build import ensure_fmus
from fmus.fmu import Fmu
from fmus.servo_drive.params import drive_start_values

PARAMS = tomllib.loads((Path(__file__).resolve().parents[2] / "robot" / "rx130l_params.toml").read_text())
TRAIN = PARAMS["drive_train"]
AXIS = 4
REAL_IN = ("target_position", "torque_offset", "q_meas", "qd_meas", "target_velocity", "velocity_offset",
           "target_torque")
REAL_OUT = ("tau_out", "position_actual", "velocity_actual", "torque_actual")
INT_IN = ("controlword", "fault_code", "modes_of_operation")
INT_OUT = ("statusword", "error_code", "modes_of_operation_display")


class OneAxisCell:
    """One drive FMU (axis 4) on a rigid inertia behind a one-node POWERLINK network; the
    controller's set-points are ``self.setpoints`` (the enable sequence runs by itself)."""

    def __init__(self, inertia=0.5):
        a = AXIS - 1
        self.scaling = JointScaling([TRAIN["gear_ratio"]["value"][a]], TRAIN["encoder_counts_per_motor_rev"]["value"],
                                    [TRAIN["rated_torque"]["value"][a]])
        self.network = PowerlinkNetwork({"nodes": 1}, self.scaling)
        self.drive = Fmu(ensure_fmus()["servo_drive"], "bus_axis", drive_start_values(AXIS),
                         real_inputs=REAL_IN, real_outputs=REAL_OUT, integer_inputs=INT_IN,
                         integer_outputs=INT_OUT).start()
        self.setpoints, self.actuals = Setpoints.zeros(1), DriveActuals.zeros(1)
        self.sequencer = EnableSequencer()
        self.inertia, self.q, self.qd, self.t, self.cycle = inertia, 0.0, 0.0, 0.0, 0
        self.observed = None
        self.applied = None

    def run(self, seconds):
        h = 50e-6
        for _ in range(int(round(seconds / 400e-6))):
            out, ints = self.drive.get_outputs(), self.drive.get_integer_outputs()
            self.actuals.statusword[0], self.actuals.error_code[0] = ints[0], ints[1]
            self.actuals.modes_of_operation_display[0] = ints[2]
            self.actuals.position[0], self.actuals.velocity[0], self.actuals.torque[0] = out[1], out[2], out[3]
            result = self.network.run_cycle(self.cycle, self.setpoints, self.actuals)
            self.cycle += 1
            app, self.observed, self.applied = result.applied, result.observed, result.applied.copy()
            self.setpoints.controlword[0] = self.sequencer.next_controlword(int(self.observed.statusword[0]))
            if not motion_enabled(int(self.observed.statusword[0])):
                self.setpoints.position[0] = self.observed.position[0]
            self.drive.set_integer_inputs((app.controlword[0], app.fault_code[0], app.modes_of_operation[0]))
            for _ in range(8):
                self.drive.set_inputs((app.position[0], app.torque_offset[0], self.q, self.qd,
                                       app.target_velocity[0], app.velocity_offset[0], app.target_torque[0]))
                self.drive.do_step(self.t, h)
                self.t += h
                acc = self.drive.get_outputs()[0] / self.inertia
                self.q, self.qd = self.q + self.qd * h + 0.5 * acc * h * h, self.qd + acc * h
        return self

    def close(self):
        self.network.close()
        self.drive.close()


@pytest.fixture
def cell():
    c = OneAxisCell()
    yield c
    c.close()


def test_csp_to_cst_to_csv_through_the_telegrams(cell):
    cell.run(0.02)
    assert motion_enabled(int(cell.observed.statusword[0])) and cell.observed.modes_of_operation_display[0] == 8

    cell.setpoints.modes_of_operation[0] = 10
    cell.setpoints.target_torque[0] = 3.21  # N m; the telegram carries 0.1 % of the 35 N m rated torque
    cell.run(0.02)
    quantised = round(3.21 / 0.035) * 0.035
    assert cell.applied.modes_of_operation[0] == 10 and cell.applied.target_torque[0] == pytest.approx(quantised,
                                                                                                          abs=1e-12)
    assert cell.observed.modes_of_operation_display[0] == 10  # 0x6061 in the TPDO2
    assert cell.observed.torque[0] == pytest.approx(quantised, abs=0.036)  # torque actual, one telegram unit
    assert cell.qd > 0.1  # the torque accelerates the free inertia

    cell.setpoints.modes_of_operation[0] = 9
    cell.setpoints.target_velocity[0] = 0.4
    cell.setpoints.velocity_offset[0] = 0.1
    cell.run(0.05)
    assert cell.observed.modes_of_operation_display[0] == 9
    assert cell.qd == pytest.approx(0.5, rel=1e-3)
    assert cell.observed.velocity[0] == pytest.approx(0.5, rel=1e-3)
    count = cell.scaling.rad_per_count[0]  # the telegram carries counts/s
    assert cell.applied.target_velocity[0] == np.floor(0.4 / count + 0.5) * count
    assert cell.applied.velocity_offset[0] == np.floor(0.1 / count + 0.5) * count


def test_a_mode_the_network_carries_no_setpoints_for_is_refused(cell):
    cell.run(0.004)
    cell.setpoints.modes_of_operation[0] = 1  # profile position
    with pytest.raises(ValueError, match=r"setpoints.modes_of_operation\[0\] = 1: expected 8 .cyclic synchronous "
                                         r"position., 9 .cyclic synchronous velocity. or 10"):
        cell.run(0.0004)
