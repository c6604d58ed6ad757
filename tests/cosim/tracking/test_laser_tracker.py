"""The laser tracker's compiled sample (cosim/tracking/tracker_kernel.c) against pinocchio:
the true arm's flange to round-off on random joint angles, and the tracker task on a
falling plant FMU with and without the kernel (same noise, same readings)."""
from __future__ import annotations

import numpy as np
import pytest

from cosim.tracking import laser_tracker
from cosim.tracking.laser_tracker import TRACKER_VARIABLES, LaserTracker, TrackerConfig
from cosim.master import Master, MemorySink
from fmus.build import ensure_fmus
from robot.true_robot import make_true_robot


@pytest.fixture(scope="module")
def true_model():
    return make_true_robot(3, payload=[5.0, 0.0, 0.0, 0.05]).kinematic_model()


def run_tracker(true_model, compiled: bool, monkeypatch) -> tuple[np.ndarray, bool]:
    if not compiled:
        monkeypatch.setattr(laser_tracker, "load_library", lambda source, **kwargs: None)
    master = Master(base_step=1e-3)
    master.add_fmu("plant", ensure_fmus()["rx130l_plant"], start_values={"q0[2]": -0.4, "q0[3]": 0.9, "q0[5]": 0.6})
    for name in TRACKER_VARIABLES:
        master.add_variable(name, "Real", 0.0)
    tracker = LaserTracker(true_model, TrackerConfig(1e-3, 2e-6, 5))
    master.add_task(tracker, 1e-3, name="tracker", setup=tracker.setup)
    sink = MemorySink()
    master.add_recorder(list(TRACKER_VARIABLES) + [f"plant.q[{i}]" for i in range(1, 7)], 1e-3, sink)
    with master:
        master.initialize(0.3)
        master.run(0.3)
    monkeypatch.undo()
    return sink.data, tracker.compiled


def test_compiled_flange_equals_pinocchio(true_model):
    plan = laser_tracker.compiled_chain(true_model, true_model.getFrameId("tool0"))
    library = laser_tracker.load_library(laser_tracker.KERNEL_SOURCE)
    if library is None:
        pytest.skip("no C compiler")
    import ctypes
    fn = library.tracker_sample
    fn.argtypes, fn.restype = [ctypes.c_void_p, ctypes.c_void_p], None
    q, out = np.zeros(6), np.zeros(3)
    plan.q, plan.out = q.ctypes.data, out.ctypes.data
    tracker = LaserTracker(true_model)
    rng = np.random.default_rng(1)
    worst = 0.0
    for _ in range(500):
        q[:] = rng.uniform(-np.pi, np.pi, 6)
        fn(ctypes.byref(plan), None)
        worst = max(worst, float(np.abs(out - tracker.flange_position(q)).max()))
    assert worst < 1e-12, worst


def test_tracker_task_compiled_and_pinocchio_agree(true_model, monkeypatch):
    fast, compiled = run_tracker(true_model, True, monkeypatch)
    slow, fallback = run_tracker(true_model, False, monkeypatch)
    if not compiled:
        pytest.skip("no C compiler")
    assert not fallback
    assert np.array_equal(fast[:, 4:], slow[:, 4:])  # the same plant motion
    assert np.ptp(fast[:, 4:], axis=0).max() > 0.01  # the arm moved
    assert np.abs(fast[:, 1:4] - slow[:, 1:4]).max() < 1e-12  # same readings (noise included) to round-off
    assert 1e-7 < np.std(np.diff(fast[:20, 1])) < 1e-4  # noise is there


def test_reflector_off_the_flange(true_model):
    """A reflector on the tool (m in tool0): the compiled sample and pinocchio agree, it sees a
    turn of joint 6 (the flange centre does not), and a bad offset is named."""
    reflector = (0.12, -0.05, 0.08)
    tracker = LaserTracker(true_model, TrackerConfig(reflector=reflector))
    centre = LaserTracker(true_model)
    q = np.array([0.1, -0.4, 0.9, 0.2, 0.6, 0.3])
    turned = q + np.array([0, 0, 0, 0, 0, 1e-3])
    # the flange centre lies on axis 6 up to the true robot's geometric errors (< 1 mm here)
    assert np.linalg.norm(centre.flange_position(turned) - centre.flange_position(q)) < 1e-6
    moved = np.linalg.norm(tracker.flange_position(turned) - tracker.flange_position(q))
    assert moved == pytest.approx(1e-3 * np.hypot(0.12, 0.05), rel=0.02)
    library = laser_tracker.load_library(laser_tracker.KERNEL_SOURCE)
    if library is not None:
        import ctypes
        plan = laser_tracker.compiled_chain(true_model, true_model.getFrameId("tool0"), reflector)
        fn = library.tracker_sample
        fn.argtypes, fn.restype = [ctypes.c_void_p, ctypes.c_void_p], None
        qq, out = q.copy(), np.zeros(3)
        plan.q, plan.out = qq.ctypes.data, out.ctypes.data
        fn(ctypes.byref(plan), None)
        assert np.abs(out - tracker.flange_position(q)).max() < 1e-12
    with pytest.raises(laser_tracker.TrackerConfigError, match="reflector"):
        TrackerConfig(reflector=(0.1, 0.0))
    with pytest.raises(laser_tracker.TrackerConfigError, match="reflector"):
        TrackerConfig(reflector=(2.0, 0.0, 0.0))
