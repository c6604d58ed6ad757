"""The controller contract (controller.contract) and the port that drives it from the fieldbus
(controller.port): the built-in controller satisfies it and goes through it, a subclass is
never bypassed by the compiled paths, a user controller's output reaches the bus, and a
controller that raises or returns NaN / an unknown mode of operation is a ControllerFailure."""
from __future__ import annotations

import numpy as np
import pytest

from controller import (MODE_CSP, CellController, Controller, ControllerConfig, ControllerInfo, ControllerInput,
                        ControllerOutput, TcpTrajectory, contract_problems)
from controller.port import ControllerFailure, ControllerPort, bus_carriers
from fieldbus import Cia402DriveModel, ObservedActuals
from planners.iso9283 import ISO_Q_HINT, iso9283_test_path
from robot.dynamics import RobotDynamics

PERIOD = 400e-6


@pytest.fixture(scope="module")
def tcp_ref():
    path = iso9283_test_path()
    return TcpTrajectory.from_reference(path.reference, path.duration, PERIOD)


class Offset(Controller):
    """A user's subclass of the built-in controller: adds 1 mrad to every target."""

    def _set_outputs(self, sp, q, qd, qdd, torque):
        super()._set_outputs(sp, q, qd, qdd, torque)
        sp.position[:] += 1e-3


def closed_loop(controller, cycles: int = 60):
    """Drive ``controller`` through a ControllerPort against six CiA 402 state machines
    whose position follows the target with a lag; returns the targets sent per cycle."""
    port = ControllerPort(controller, 6, q_start=getattr(controller, "q_start", np.zeros(6)))
    port.setup(ControllerInfo(period_s=PERIOD, dead_time_cycles=1, q_start=np.zeros(6)))
    drives = [Cia402DriveModel() for _ in range(6)]
    obs = ObservedActuals.zeros(6)
    obs.fresh[:] = True
    obs.position[:] = port.setpoints.position
    obs.statusword[:] = [d.statusword for d in drives]
    targets = []
    for k in range(cycles):
        sp = port.step(k, k * PERIOD, obs)
        targets.append(sp.position.copy())
        for i, d in enumerate(drives):
            d.step(int(sp.controlword[i]))
        obs.statusword[:] = [d.statusword for d in drives]
        obs.position[:] = 0.5 * (obs.position + sp.position)
    port.close()
    return np.array(targets)


def test_builtin_controller_satisfies_the_contract(tcp_ref):
    ctrl = Controller(tcp_ref, ControllerConfig(mode="standard", settle_time_s=0.002), q_hint=np.array(ISO_Q_HINT))
    assert isinstance(ctrl, CellController) and contract_problems(Controller) == []
    # its contract output aliases the set-points the bus carries: the port hands them over as they are
    assert ctrl.output.target_position is ctrl.setpoints.position
    assert ctrl.output.torque_offset is ctrl.setpoints.torque_offset
    assert (ctrl.output.modes_of_operation == MODE_CSP).all()
    port = ControllerPort(ctrl)
    assert port.setpoints is ctrl.setpoints
    with pytest.raises(ControllerFailure, match="differs from the cell's bus cycle"):
        port.setup(ControllerInfo(period_s=1e-3))


def test_a_subclass_is_never_bypassed_by_the_compiled_path(tcp_ref):
    kwargs = dict(dynamics=RobotDynamics(), q_hint=np.array(ISO_Q_HINT))
    config = ControllerConfig(mode="model_based", settle_time_s=0.002)
    plain, offset = Controller(tcp_ref, config, **kwargs), Offset(tcp_ref, config, **kwargs)
    assert plain._fast is not None          # the built-in class keeps its whole-cycle C path
    assert offset._fast is None and "overrides _set_outputs" in offset.kernel_note
    base, shifted = closed_loop(plain), closed_loop(offset)
    enabled = offset.enabled_at_s
    assert enabled is not None and offset.kernel_cycles > 20  # the kernel still does the numerics
    moved = np.abs(shifted - base).max(axis=1)
    # every cycle after enabling carries the subclass's +1 mrad (within the loop's own drift)
    after = slice(int(round(enabled / PERIOD)) + 1, None)
    assert np.all(moved[after] > 0.5e-3), moved


class Hold:
    """A tiny user controller: enables the drives and holds the start pose, with a torque offset."""

    def __init__(self, offset: float = 0.0, fail_at: int | None = None, nan_at: int | None = None,
                 mode: int = MODE_CSP) -> None:
        self.offset, self.fail_at, self.nan_at, self.mode = offset, fail_at, nan_at, mode
        self.closed = False

    def setup(self, info: ControllerInfo) -> None:
        self.out = ControllerOutput.zeros(info.n_joints)
        self.out.target_position[:] = info.q_start

    def step(self, inputs: ControllerInput) -> ControllerOutput:
        from fieldbus import EnableSequencer  # noqa: F401 - what a user would use for the enable sequence
        if inputs.cycle == self.fail_at:
            raise RuntimeError("boom")
        self.out.controlword[:] = 0x000F
        self.out.torque_offset[:] = self.offset
        self.out.modes_of_operation[:] = self.mode if inputs.cycle >= 2 else MODE_CSP
        if inputs.cycle == self.nan_at:
            self.out.torque_offset[2] = np.nan
        return self.out

    def close(self) -> None:
        self.closed = True


def _observed() -> ObservedActuals:
    obs = ObservedActuals.zeros(6)
    obs.fresh[:] = True
    return obs


def test_user_controller_output_reaches_the_setpoints():
    ctrl = Hold(offset=2.5)
    assert isinstance(ctrl, CellController)
    port = ControllerPort(ctrl, 6)
    port.setup(ControllerInfo(period_s=PERIOD, q_start=np.linspace(0.1, 0.6, 6)))
    obs = _observed()
    obs.position[:] = 0.25
    sp = port.step(3, 3 * PERIOD, obs, late=True)
    assert port.inputs.cycle == 3 and port.inputs.previous_output_late and not port.inputs.previous_output_lost
    assert port.inputs.position is obs.position  # bound, not copied
    assert (port.inputs.modes_of_operation_display == MODE_CSP).all()
    np.testing.assert_array_equal(sp.position, np.linspace(0.1, 0.6, 6))
    np.testing.assert_array_equal(sp.torque_offset, 2.5)
    np.testing.assert_array_equal(sp.controlword, 0x000F)
    port.close()
    assert ctrl.closed


@pytest.mark.parametrize("kwargs, message", [
    ({"fail_at": 2}, r"Hold.step\(\) raised RuntimeError: boom"),
    ({"nan_at": 2}, r"torque_offset = .*nan.* at t = 0.0008 s \(cycle 2\): expected finite numbers"),
    ({"mode": 7}, r"modes_of_operation of joint 1 = 7: expected one of \(8, 9, 10\)"),
])
def test_a_failing_user_controller_is_a_controller_failure(kwargs, message):
    port = ControllerPort(Hold(**kwargs), 6)
    port.setup(ControllerInfo(period_s=PERIOD, q_start=np.zeros(6)))
    obs = _observed()
    port.step(0, 0.0, obs)
    port.step(1, PERIOD, obs)
    with pytest.raises(ControllerFailure, match=message) as info:
        port.step(2, 2 * PERIOD, obs)
    assert info.value.cycle == 2 and info.value.time_s == pytest.approx(2 * PERIOD)


def test_torque_mode_needs_a_bus_that_carries_it():
    carriers = bus_carriers()
    port = ControllerPort(Hold(mode=10), 6)
    port.setup(ControllerInfo(period_s=PERIOD, q_start=np.zeros(6)))
    if carriers["modes_of_operation"] is None:
        with pytest.raises(ControllerFailure, match="carries no modes_of_operation yet: expected 8"):
            port.step(2, 0.0, _observed())
    else:
        sp = port.step(2, 0.0, _observed())
        np.testing.assert_array_equal(getattr(sp, carriers["modes_of_operation"]), 10)


def test_contract_problems_name_the_missing_methods():
    class Half:
        def step(self, inputs):
            return None

    assert contract_problems(Half) == ["no method setup()", "no method close()"]
    assert not isinstance(Half(), CellController)
