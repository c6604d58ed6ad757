"""Controller references: interpolation exact at knots, consistent derivatives between them;
IK stage: pose reproduced, J qd = twist, qdd against finite differences of qd;
feed-forward: equals M(q) qdd + C qd + g + friction of the given model (pinocchio, independent)."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from controller import (CartesianToJoint, FeedForward, JointTrajectory, ReferenceError, SingularConfigurationError,
                        TcpTrajectory, quintic_hermite, start_configuration)
from planners.iso9283 import ISO_Q_HINT, iso9283_test_path
from planners.trajectory import Trajectory
from robot.description import load_model
from robot.dynamics import RobotDynamics
from robot.kinematics import FlangeKinematics
from robot.true_robot import make_true_robot

PERIOD = 400e-6


@pytest.fixture(scope="module")
def iso_path():
    return iso9283_test_path()


@pytest.fixture(scope="module")
def tcp_ref(iso_path):
    return TcpTrajectory.from_reference(iso_path.reference, iso_path.duration, PERIOD)


def test_quintic_hermite_matches_end_conditions_and_derivatives():
    rng = np.random.default_rng(3)
    p0, v0, a0, p1, v1, a1 = rng.normal(size=(6, 4))
    h = 0.37
    for s, (p, v, a) in ((0.0, (p0, v0, a0)), (1.0, (p1, v1, a1))):
        pos, vel, acc = quintic_hermite(p0, v0, a0, p1, v1, a1, h, s)
        np.testing.assert_allclose(pos, p, atol=1e-13)
        np.testing.assert_allclose(vel, v, atol=1e-12)
        np.testing.assert_allclose(acc, a, atol=1e-11)
    # the returned derivatives are those of the returned position (central differences in time)
    s, ds = 0.41, 1e-5
    plus, minus = (quintic_hermite(p0, v0, a0, p1, v1, a1, h, s + d)[0] for d in (ds, -ds))
    _, vel, acc = quintic_hermite(p0, v0, a0, p1, v1, a1, h, s)
    np.testing.assert_allclose((plus - minus) / (2 * ds * h), vel, rtol=1e-7)
    v_plus, v_minus = (quintic_hermite(p0, v0, a0, p1, v1, a1, h, s + d)[1] for d in (ds, -ds))
    np.testing.assert_allclose((v_plus - v_minus) / (2 * ds * h), acc, rtol=1e-6)


def test_tcp_trajectory_exact_at_knots_and_smooth_between(iso_path, tcp_ref):
    t = 2.0  # a knot (multiple of the period)
    sample = tcp_ref.sample(t)
    ref = iso_path.reference(np.array([t]))
    np.testing.assert_allclose(sample.target.translation, ref.position[0], atol=1e-15)
    np.testing.assert_allclose(sample.twist[:3], ref.velocity[0], atol=1e-15)
    np.testing.assert_allclose(sample.acceleration[:3], ref.acceleration[0], atol=1e-15)
    # between knots: the interpolation agrees with the planner's analytic time law
    for t in (2.0 + 0.37 * PERIOD, 7.9 + 0.81 * PERIOD):
        sample = tcp_ref.sample(t)
        ref = iso_path.reference(np.array([t]))
        assert np.linalg.norm(sample.target.translation - ref.position[0]) < 1e-9  # m
        assert np.linalg.norm(sample.twist[:3] - ref.velocity[0]) < 1e-6  # m/s
        assert np.linalg.norm(sample.acceleration[:3] - ref.acceleration[0]) < 5e-3  # m/s^2
        np.testing.assert_allclose(sample.target.rotation, ref.rotation[0], atol=1e-12)
    # the vectorised positions equal the per-sample interpolation
    times = np.array([0.0, 2.0 + 0.37 * PERIOD, 5.5, tcp_ref.duration + 1.0])
    np.testing.assert_allclose(tcp_ref.positions(times),
                               [tcp_ref.sample(x).target.translation for x in times], atol=1e-13)
    # clamped before the start and after the end: at rest
    assert np.all(tcp_ref.sample(-1.0).twist == 0.0)
    assert np.allclose(tcp_ref.sample(1e3).twist, 0.0, atol=1e-12)


def test_tcp_trajectory_rejects_malformed_reference():
    class Bad:
        def __init__(self, n):
            self.position = np.zeros((n, 3))
            self.rotation = np.tile(np.eye(3), (n, 1, 1)) * 2.0
            self.velocity = self.angular_velocity = self.acceleration = self.angular_acceleration = np.zeros((n, 3))

    with pytest.raises(ReferenceError, match="orthonormal"):
        TcpTrajectory.from_reference(lambda t: Bad(t.size), 0.01, PERIOD)
    with pytest.raises(ReferenceError, match="dt"):
        TcpTrajectory.from_reference(lambda t: Bad(t.size), 0.01, 0.0)
    with pytest.raises(ReferenceError, match="t_end"):
        TcpTrajectory.from_reference(lambda t: Bad(t.size), -1.0, PERIOD)


def test_joint_trajectory_from_planner_trajectory():
    t = np.linspace(1.0, 2.0, 101)
    w = 2 * np.pi
    q = np.column_stack([0.1 * k * np.sin(w * t) for k in range(1, 7)])
    qd = np.column_stack([0.1 * k * w * np.cos(w * t) for k in range(1, 7)])
    qdd = np.column_stack([-0.1 * k * w * w * np.sin(w * t) for k in range(1, 7)])
    traj = Trajectory(t, q, qd, qdd, np.zeros_like(q))
    ref = JointTrajectory.from_planner_trajectory(traj, PERIOD)
    assert ref.duration == pytest.approx(1.0, abs=PERIOD)
    s = ref.sample(0.5)  # planner time 1.5 s
    np.testing.assert_allclose(s.q, [0.1 * k * np.sin(w * 1.5) for k in range(1, 7)], atol=1e-8)
    np.testing.assert_allclose(s.qd, [0.1 * k * w * np.cos(w * 1.5) for k in range(1, 7)], atol=1e-5)


def _ik_run(model, tcp_ref, t0: float, n: int):
    q0 = start_configuration(tcp_ref, model, np.array(ISO_Q_HINT))
    c2j = CartesianToJoint(model)
    c2j.reset(q0)
    # walk from the start to t0 at rest-free warm start: solve every cycle
    rows = []
    for k in range(int(round((t0 + n * PERIOD) / PERIOD)) + 1):
        s = tcp_ref.sample(k * PERIOD)
        q, qd, qdd = c2j.solve(s.target, s.twist, s.acceleration, PERIOD)
        if k * PERIOD >= t0 - 1e-12:
            rows.append((s, q.copy(), qd.copy(), qdd.copy(), c2j.last_iterations))
    return rows


@pytest.mark.parametrize("kind", ["nominal", "error_model"])
def test_ik_stage_pose_velocity_acceleration_consistent(tcp_ref, kind):
    model = load_model() if kind == "nominal" else make_true_robot(4).kinematic_model()
    kin = FlangeKinematics(model)
    rows = _ik_run(model, tcp_ref, t0=7.7, n=60)  # on the large circle: all derivatives non-zero
    assert max(r[4] for r in rows) <= 1  # warm start: at most one Newton step
    for s, q, qd, qdd, _ in rows:
        placement = kin.placement(q)
        assert np.linalg.norm(placement.translation - s.target.translation) < 1e-10
        assert np.linalg.norm(pin.log3(placement.rotation.T @ s.target.rotation)) < 1e-10
        np.testing.assert_allclose(kin.jacobian(q) @ qd, s.twist, atol=1e-10)
    # qdd is the time derivative of qd (central differences over two cycles)
    for k in range(1, len(rows) - 1):
        fd = (rows[k + 1][2] - rows[k - 1][2]) / (2 * PERIOD)
        np.testing.assert_allclose(rows[k][3], fd, atol=2e-4 * max(1.0, np.abs(fd).max()))
        fd_q = (rows[k + 1][1] - rows[k - 1][1]) / (2 * PERIOD)
        np.testing.assert_allclose(rows[k][2], fd_q, atol=1e-5)


def test_ik_stage_singular_jacobian_raises():
    model = load_model()
    kin = FlangeKinematics(model)
    q = np.array([0.0, 0.3, 1.2, 0.0, 0.0, 0.2])  # q5 = 0: wrist singularity (axes 4 and 6 aligned)
    c2j = CartesianToJoint(model)
    c2j.reset(q)
    with pytest.raises(SingularConfigurationError, match="singular"):
        c2j.solve(kin.placement(q), np.zeros(6), np.zeros(6), PERIOD)


@pytest.mark.parametrize("which", ["nominal", "true_with_payload"])
def test_feedforward_is_eq7_of_the_given_model(which):
    if which == "nominal":
        dyn = RobotDynamics()
    else:
        true = make_true_robot(2, payload=[8.0, 0.0, 0.0, 0.08])
        dyn = true.dynamics()
    ff = FeedForward(dyn)
    rng = np.random.default_rng(11)
    for _ in range(5):
        q, qd, qdd = rng.uniform(-1.5, 1.5, 6), rng.uniform(-1.0, 1.0, 6), rng.uniform(-5, 5, 6)
        expected = dyn.mass_matrix(q) @ qdd + dyn.nonlinear_effects(q, qd)  # M qdd + C qd + g + friction
        np.testing.assert_allclose(ff.torque(q, qd, qdd), expected, rtol=1e-10, atol=1e-9)


def test_compiled_kernel_equals_the_python_path(tcp_ref):
    """The generated C kernel (Newton step, qd, qdd, eq. 7 torque) against CartesianToJoint +
    FeedForward along 2 s of the path: same results to the IK tolerance."""
    from controller.compiled_cycle import CompiledCycle

    model = load_model()
    dyn = RobotDynamics(payload=[8.0, 0.0, 0.0, 0.08])
    kernel = CompiledCycle(model, dyn)
    q0 = start_configuration(tcp_ref, model, np.array(ISO_Q_HINT))
    c2j, ff = CartesianToJoint(model), FeedForward(dyn)
    c2j.reset(q0)
    kernel.reset(q0)
    worst = np.zeros(4)
    base = tcp_ref.packed.ctypes.data
    for k in range(0, 5000):
        s = tcp_ref.sample(k * PERIOD)
        kernel.run(base + 192 * k, PERIOD)
        assert kernel.info[0] <= c2j.ik._accept2 and kernel.info[1] <= c2j.ik._accept2
        assert kernel.info[2] > 1e-3  # far from singular on the ISO cube
        kernel.accept()
        q, qd, qdd = c2j.solve(s.target, s.twist, s.acceleration, PERIOD)
        tau = ff.torque(q, qd, qdd)
        st = kernel.state
        worst = np.maximum(worst, [np.abs(st[:6] - q).max(), np.abs(st[6:12] - qd).max(),
                                   np.abs(st[12:] - qdd).max(), np.abs(kernel.tau - tau).max()])
    assert worst[0] < 1e-9 and worst[1] < 1e-8 and worst[2] < 1e-6 and worst[3] < 1e-5, worst
    # a singular wrist is reported (hadamard ratio ~ 0), so the controller falls back to the Python path
    q = np.array([0.0, 0.3, 1.2, 0.0, 0.0, 0.2])
    kin = FlangeKinematics(model)
    placement = kin.placement(q)
    row = np.concatenate([placement.rotation.ravel(order="F"), placement.translation, np.zeros(12)])
    kernel.reset(q)
    kernel.run(row.ctypes.data, PERIOD)
    assert kernel.info[2] < 1e-9
