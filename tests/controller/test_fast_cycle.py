"""The compiled whole cycle (controller/fast_cycle.c) against the Python code around the
kernel: bit-identical set-points, state and log in both modes, with drive set-point
shaping, through a drive fault (stop), and when the kernel's results are rejected."""
from __future__ import annotations

import numpy as np
import pytest

from controller import Controller, ControllerConfig, Phase, TcpTrajectory
from controller_support import PERIOD, drive, drive_model, logged
from fieldbus import ObservedActuals
from planners.iso9283 import ISO_Q_HINT, iso9283_test_path
from robot.dynamics import RobotDynamics


@pytest.fixture(scope="module")
def tcp_ref():
    path = iso9283_test_path()
    return TcpTrajectory.from_reference(path.reference, path.duration, PERIOD)


def run(ref, mode: str, fast: bool, cycles: int, fault_at: int | None = None, reject: bool = False):
    """Controller on six CiA 402 state machines whose position follows the target with a
    small lag; returns the log columns (compute times dropped) and the controller."""
    ctrl = Controller(ref, ControllerConfig(mode=mode, settle_time_s=0.002, fast_cycle=fast),
                      dynamics=RobotDynamics(), q_hint=np.array(ISO_Q_HINT), drive_model=drive_model())
    if reject:  # every kernel result fails the acceptance check: the Python path solves each cycle
        ctrl._accept2 = 0.0
        if ctrl._fast is not None:
            ctrl._fast.plan.accept2 = 0.0
    drive(ctrl, range(cycles), fault_at=fault_at, fault_node=2)
    return logged(ctrl), ctrl


@pytest.mark.parametrize("mode", ["model_based", "standard"])
def test_fast_cycle_is_bit_identical(tcp_ref, mode):
    slow, c_slow = run(tcp_ref, mode, False, 120, fault_at=90)
    fast, c_fast = run(tcp_ref, mode, True, 120, fault_at=90)
    assert c_fast.phase is Phase.STOPPED and c_slow.phase is Phase.STOPPED
    assert c_fast.stop_reason == c_slow.stop_reason and "drive 3" in c_fast.stop_reason
    assert c_fast.kernel_cycles == c_slow.kernel_cycles > 70
    for name, column in slow.items():
        np.testing.assert_array_equal(fast[name], column, err_msg=name)
    np.testing.assert_array_equal(c_fast.setpoints.position, c_slow.setpoints.position)
    assert c_fast.timing().cycles == c_slow.timing().cycles


def test_fast_cycle_hands_rejected_results_to_the_python_path(tcp_ref):
    slow, c_slow = run(tcp_ref, "model_based", False, 40, reject=True)
    fast, c_fast = run(tcp_ref, "model_based", True, 40, reject=True)
    assert c_fast.kernel_cycles == 0 and c_fast.fallback_cycles == c_slow.fallback_cycles > 20
    for name, column in slow.items():
        np.testing.assert_array_equal(fast[name], column, err_msg=name)


def test_fast_cycle_refuses_unusual_observed_arrays(tcp_ref):
    """Observed arrays of another layout: the Python path takes the cycle, same result."""
    ref_log, _ = run(tcp_ref, "model_based", False, 30)
    ctrl = Controller(tcp_ref, ControllerConfig(mode="model_based", settle_time_s=0.002), dynamics=RobotDynamics(),
                      q_hint=np.array(ISO_Q_HINT), drive_model=drive_model())
    obs = ObservedActuals.zeros(6)
    obs.statusword = obs.statusword.astype(np.int32)
    drive(ctrl, range(30), observed=obs)
    log = ctrl.log.columns()
    assert ctrl.kernel_cycles > 15
    np.testing.assert_array_equal(log["target3"], ref_log["target3"])
