"""A controller that skips cycles (a split controller that fell behind the cell) solves the
jumped cycle on the compiled path: the IK seed is predicted over the time since its last
state, further Newton steps go through the kernel, and the Python-path IK (milliseconds
when cold) is not used; the result is the IK solution of the reference at that time."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from controller import Controller, ControllerConfig, Phase, TcpTrajectory
from controller_support import PERIOD, cycles_with_jumps, drive, drive_model
from planners.iso9283 import ISO_Q_HINT, iso9283_test_path
from robot.dynamics import RobotDynamics
from robot.inverse_kinematics import NumericIK


@pytest.fixture(scope="module")
def tcp_ref():
    path = iso9283_test_path()
    return TcpTrajectory.from_reference(path.reference, path.duration, PERIOD)


def make(ref, fast: bool = True) -> Controller:
    return Controller(ref, ControllerConfig(mode="model_based", settle_time_s=0.002, fast_cycle=fast),
                      dynamics=RobotDynamics(), q_hint=np.array(ISO_Q_HINT), drive_model=drive_model())


@pytest.mark.parametrize("fast", [True, False])
@pytest.mark.parametrize("gap", [2, 6, 40, 400])
def test_jumped_cycle_stays_on_the_compiled_path_and_solves_the_ik(tcp_ref, fast, gap):
    ctrl = make(tcp_ref, fast)
    ik = NumericIK(ctrl.kinematic_model, tolerance=1e-12)
    jumps = {1500: gap, 2200: gap}
    checked = []

    def check(c: Controller, k: int) -> None:
        if k - gap in jumps:  # the cycle after a jump: q_d is the IK solution of the reference there
            tau = (k - c.motion_start_cycle) * PERIOD
            sample = tcp_ref.sample(tcp_ref.t_start + tau)
            q = ik.solve(sample.target, c._q_d)
            assert np.max(np.abs(c._q_d - q)) < 1e-9
            # qd_d consistent with the flange twist at q_d
            jac = pin.computeFrameJacobian(c.kinematic_model, c.kinematic_model.createData(), c._q_d,
                                           ik.frame_id, pin.LOCAL_WORLD_ALIGNED)
            np.testing.assert_allclose(jac @ c._qd_d, sample.twist, atol=1e-9)
            checked.append(k)

    drive(ctrl, cycles_with_jumps(3200, jumps), half_way=False, check=check)
    assert ctrl.phase is Phase.TRACKING
    assert len(checked) == 2
    assert ctrl.fallback_cycles == 0  # never the Python-path IK
    assert ctrl.kernel is not None and ctrl.kernel_cycles > 2300
    assert ctrl.kernel.h[0] == PERIOD  # the whole-cycle path's step is restored


def test_without_jumps_the_cycle_is_unchanged(tcp_ref):
    """Consecutive cycles: set-points and log bit-identical between the two compiled paths
    (the seed step is the period, as before)."""
    logs = []
    for fast in (True, False):
        ctrl = make(tcp_ref, fast)
        drive(ctrl, range(300), half_way=False)
        log = ctrl.log.columns()
        log.pop("compute_us")
        logs.append(log)
        assert ctrl.fallback_cycles == 0
    for name, column in logs[0].items():
        np.testing.assert_array_equal(logs[1][name], column, err_msg=name)


def test_warm_up_leaves_the_controller_as_it_was(tcp_ref):
    """``warm_up`` runs the Python-path cycle once at set-up (its first call in a process costs
    milliseconds) and changes nothing the cycles compute."""
    plain, warmed = make(tcp_ref), make(tcp_ref)
    warmed.warm_up()
    assert warmed.fallback_cycles == 0 and warmed.kernel_cycles == 0
    for ctrl in (plain, warmed):
        drive(ctrl, range(400), half_way=False)
    a, b = plain.log.columns(), warmed.log.columns()
    a.pop("compute_us"), b.pop("compute_us")
    for name, column in a.items():
        np.testing.assert_array_equal(b[name], column, err_msg=name)
    np.testing.assert_array_equal(plain.setpoints.position, warmed.setpoints.position)
