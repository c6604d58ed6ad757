"""The compiled elastic cycle (controller/elastic_cycle.c) against the Python path of
ElasticController: bit-identical set-points, shaper state and log, with and without drive
set-point shaping, through a drive fault (stop); a subclass that replaces a cycle method runs
the Python path."""
from __future__ import annotations

import numpy as np
import pytest

from controller import ControllerConfig, Phase
from controller.elastic import ELASTIC_MODE, ElasticController, load_elastic_cycle
from controller.reference import JointTrajectory
from controller_support import PERIOD, drive, drive_model, logged
from robot.dynamics import RobotDynamics

DYN = RobotDynamics(payload=[8.0, 0.0, 0.0, 0.08])
A = np.array([0.3, -0.5, 0.4, 0.8, -0.6, 1.0])
W = np.array([2.0, 3.0, 1.5, 4.0, 5.0, 3.5])
Q0 = np.array([0.2, -0.6, 1.2, 0.3, 0.8, -0.2])

pytestmark = pytest.mark.skipif(load_elastic_cycle() is None, reason="no C compiler (COSIM_NATIVE=require in CI)")


@pytest.fixture(scope="module")
def reference():
    t = np.arange(0.0, 0.06 + PERIOD / 2, PERIOD)
    q, qd, qdd = (np.array([A * W ** n * np.sin(W * s + n * np.pi / 2) + (Q0 if n == 0 else 0.0) for s in t])
                  for n in range(3))
    return JointTrajectory(t, q, qd, qdd, PERIOD)


def run(ref, fast: bool, cycles: int, shaped: bool = True, fault_at: int | None = None, cls=ElasticController):
    ctrl = cls(ref, ControllerConfig(mode=ELASTIC_MODE, settle_time_s=0.002, fast_cycle=fast), dynamics=DYN,
               drive_model=drive_model() if shaped else None)
    drive(ctrl, range(cycles), fault_at=fault_at, fault_node=4)
    return logged(ctrl), ctrl


@pytest.mark.parametrize("shaped", [True, False])
def test_elastic_cycle_is_bit_identical(reference, shaped):
    n = len(reference.q) + 40  # through the end of the reference (FINISHED), then a drive fault
    slow, c_slow = run(reference, False, n, shaped, fault_at=n - 20)
    fast, c_fast = run(reference, True, n, shaped, fault_at=n - 20)
    assert c_slow._fast is None and c_fast._fast is not None
    assert c_fast.phase is Phase.STOPPED and c_slow.phase is Phase.STOPPED
    assert c_fast.stop_reason == c_slow.stop_reason and "drive 5" in c_fast.stop_reason
    assert c_fast.kernel_cycles > len(reference.q) and c_slow.kernel_cycles == 0
    assert set(fast) == set(slow)
    for name, column in slow.items():
        np.testing.assert_array_equal(fast[name], column, err_msg=name)
    for a, b in ((c_fast.setpoints.position, c_slow.setpoints.position),
                 (c_fast.setpoints.torque_offset, c_slow.setpoints.torque_offset),
                 (c_fast.setpoints.controlword, c_slow.setpoints.controlword), (c_fast._q_d, c_slow._q_d)):
        np.testing.assert_array_equal(a, b)
    if shaped:
        for name in ("_delta", "_q_prev", "target"):
            np.testing.assert_array_equal(getattr(c_fast._shaper, name), getattr(c_slow._shaper, name))
    assert c_fast.timing().cycles == c_slow.timing().cycles


def test_a_subclass_replacing_a_cycle_method_runs_the_python_path(reference):
    class Traced(ElasticController):
        calls = 0

        def _shape(self, k):
            Traced.calls += 1
            return super()._shape(k)

    slow, _ = run(reference, False, 60)
    traced, ctrl = run(reference, True, 60, cls=Traced)
    assert ctrl._fast is None and Traced.calls > 40
    for name, column in slow.items():
        np.testing.assert_array_equal(traced[name], column, err_msg=name)
