"""Mode model_based_elastic: the flatness-based feed-forward for elastic gears
(controller/feedforward.py) against finite differences, pinocchio and the plant's own
equations (tests/elastic_reference.py); the reference derivatives; the controller."""
import numpy as np
import pytest

from controller import ControllerConfig, ControllerConfigError, Controller
from controller.elastic import ELASTIC_MODE, ElasticController, make_controller
from controller.feedforward import (GearModel, elastic_feedforward, gear_deflection, link_torque_derivatives,
                                    motor_friction)
from controller.reference import JointTrajectory, ReferenceError, higher_derivatives
from elastic_reference import ElasticArm
from robot.dynamics import COULOMB_SLICE, ROTOR_INERTIA_SLICE, VISCOUS_SLICE, RobotDynamics

DYN = RobotDynamics(payload=[8.0, 0.0, 0.0, 0.08])
GEAR = GearModel.from_parameters()
A = np.array([0.3, -0.5, 0.4, 0.8, -0.6, 1.0])
W = np.array([2.0, 3.0, 1.5, 4.0, 5.0, 3.5])
Q0 = np.array([0.2, -0.6, 1.2, 0.3, 0.8, -0.2])


def motion(t, n):
    """n-th time derivative of a smooth test motion at t (scalar) -> (6,)."""
    return A * W ** n * np.sin(W * t + n * np.pi / 2) + (Q0 if n == 0 else 0.0)


def derivatives(t):
    return [motion(t, n) for n in range(5)]


def test_link_torque_derivatives_match_finite_differences():
    h = 1e-4
    for t in (0.05, 0.2, 0.35):  # every joint speed >= 0.45 rad/s: away from the steep Coulomb tanh
        assert np.abs(motion(t, 1)).min() > 0.45
        tau, tau_d, tau_dd = (x[0] for x in link_torque_derivatives(DYN, GEAR, *derivatives(t)))
        plus = link_torque_derivatives(DYN, GEAR, *derivatives(t + h))[0][0]
        minus = link_torque_derivatives(DYN, GEAR, *derivatives(t - h))[0][0]
        assert np.abs((plus - minus) / (2 * h) - tau_d).max() < 1e-6 * np.abs(tau_d).max()
        assert np.abs((plus - 2 * tau + minus) / h ** 2 - tau_dd).max() < 1e-5 * np.abs(tau_dd).max()


def test_gear_torque_is_pinocchio_rnea_of_the_links_with_their_friction_share():
    p = DYN.parameter_vector().copy()
    p[ROTOR_INERTIA_SLICE] = 0.0
    p[VISCOUS_SLICE] *= 1 - GEAR.motor_friction_share
    p[COULOMB_SLICE] *= 1 - GEAR.motor_friction_share
    links = RobotDynamics(p, DYN.payload)
    for t in (0.0, 0.3, 0.77):
        d = derivatives(t)
        tau = link_torque_derivatives(DYN, GEAR, *d)[0][0]
        np.testing.assert_allclose(tau, links.inverse_dynamics(d[0], d[1], d[2]), rtol=0, atol=1e-9)


def test_motor_reference_is_consistent_and_inverts_the_gear():
    stiff_only = GearModel(GEAR.stiffness, GEAR.stiffness_cubic, np.zeros(6), GEAR.motor_friction_share,
                           GEAR.stribeck_torque, GEAR.stribeck_velocity, GEAR.coulomb_smoothing_velocity)
    h = 1e-5
    t = 0.25
    ref, plus, minus = (elastic_feedforward(DYN, stiff_only, *derivatives(s)) for s in (t, t + h, t - h))
    assert np.abs((plus.q - minus.q) / (2 * h) - ref.qd).max() < 1e-8
    assert np.abs((plus.qd - minus.qd) / (2 * h) - ref.qdd).max() < 1e-6 * np.abs(ref.qdd).max()
    np.testing.assert_allclose(stiff_only.stiffness * ref.deflection, ref.gear_torque, rtol=1e-12)
    ia = DYN.parameter_vector()[ROTOR_INERTIA_SLICE]
    np.testing.assert_allclose(ref.torque, ia * ref.qdd + motor_friction(DYN, stiff_only, ref.qd) + ref.gear_torque,
                               rtol=1e-12)
    # with damping and a stiffening gear: k d + k3 d^3 + c dd/dt = tau_g to second order in c/k
    gear = GearModel(GEAR.stiffness, np.full(6, 1e11), GEAR.damping, GEAR.motor_friction_share,
                     GEAR.stribeck_torque, GEAR.stribeck_velocity, GEAR.coulomb_smoothing_velocity)
    tau, tau_d, tau_dd = link_torque_derivatives(DYN, gear, *derivatives(t))
    d, d_d, _ = gear_deflection(gear, tau, tau_d, tau_dd)
    residual = gear.stiffness * d + gear.stiffness_cubic * d ** 3 + gear.damping * d_d - tau
    assert np.abs(residual).max() < 1e-3 * np.abs(tau).max()
    assert np.abs(gear.damping * d_d).max() > 10 * np.abs(residual).max()  # the correction matters


def test_feedforward_drives_the_plant_equations_along_the_reference():
    """Open loop: the motor torque of the inversion, held over 50 us, fed to the plant's
    equations (numpy + pinocchio, RK4 at 10 us) from the matching start state, keeps the
    links within 2e-6 rad of the reference over 0.1 s; the rigid eq. 7 torque does not."""
    p = DYN.parameter_vector()
    arm = ElasticArm(p, DYN.payload)
    gear = GearModel(arm.k, arm.k3, arm.c, arm.share, arm.fs, arm.vst, arm.vs)
    hold, sub = 50e-6, 5
    times = np.arange(0.0, 0.1, hold)
    mids = [derivatives(t + hold / 2) for t in times]
    ff = elastic_feedforward(DYN, gear, *(np.array([m[n] for m in mids]) for n in range(5)))
    rigid = np.array([DYN.inverse_dynamics(m[0], m[1], m[2]) for m in mids])
    start = elastic_feedforward(DYN, gear, *derivatives(0.0))
    errors = {}
    for name, torques in (("elastic", ff.torque), ("rigid", rigid)):
        d0 = derivatives(0.0)
        x = np.concatenate((d0[0], d0[1], start.q[0], start.qd[0]))
        worst = 0.0
        for k, tau in enumerate(torques):
            dt = hold / sub
            for _ in range(sub):
                k1 = arm.rhs(x, tau, np.zeros(6))
                k2 = arm.rhs(x + dt / 2 * k1, tau, np.zeros(6))
                k3 = arm.rhs(x + dt / 2 * k2, tau, np.zeros(6))
                k4 = arm.rhs(x + dt * k3, tau, np.zeros(6))
                x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            worst = max(worst, np.abs(x[:6] - motion(times[k] + hold, 0)).max())
        errors[name] = worst
    print("open-loop link error over 0.1 s (rad):", errors)
    assert errors["elastic"] < 2e-6, errors
    assert errors["rigid"] > 50 * errors["elastic"], errors


def test_higher_derivatives_converge_at_second_order():
    errors = []
    for dt in (4e-3, 2e-3, 1e-3):
        t = np.arange(0.0, 1.0 + dt / 2, dt)
        qdd = np.array([motion(s, 2) for s in t])
        jerk, snap = higher_derivatives(qdd, dt)
        exact_j = np.array([motion(s, 3) for s in t])
        exact_s = np.array([motion(s, 4) for s in t])
        errors.append((np.abs(jerk - exact_j).max(), np.abs(snap - exact_s)[1:-1].max()))
    for (j1, s1), (j2, s2) in zip(errors, errors[1:]):
        assert 3.5 < j1 / j2 < 4.5 and 3.5 < s1 / s2 < 4.5, errors
    with pytest.raises(ReferenceError, match="expected a grid step > 0 s"):
        higher_derivatives(np.zeros((5, 6)), 0.0)


def _joint_reference(dt=400e-6, duration=0.4):
    t = np.arange(0.0, duration + dt / 2, dt)
    return JointTrajectory(t, *(np.array([motion(s, n) for s in t]) for n in range(3)), dt)


def test_controller_sends_the_motor_reference_and_torque():
    ref = _joint_reference()
    ctrl = make_controller(ref, ControllerConfig(mode=ELASTIC_MODE, settle_time_s=0.0), dynamics=DYN)
    assert isinstance(ctrl, ElasticController)
    rest = elastic_feedforward(DYN, ctrl.gear, ref.q[0], *(np.zeros(6),) * 4)
    np.testing.assert_array_equal(ctrl.setpoints.position, rest.q[0])
    sp = ctrl.setpoints
    ctrl.phase = ctrl.phase.__class__.TRACKING
    ctrl._compute(40 * 400e-6, sp)
    np.testing.assert_allclose(sp.position, ctrl.motor_reference.q[40], rtol=0, atol=0)
    np.testing.assert_allclose(sp.torque_offset, ctrl.motor_reference.torque[40], rtol=0, atol=0)
    np.testing.assert_array_equal(ctrl._q_d, ref.q[40])  # the log keeps the link reference
    assert np.abs(ctrl.motor_reference.deflection).max() > 1e-4


def test_the_plain_controller_refuses_the_elastic_mode():
    with pytest.raises(ControllerConfigError, match="ElasticController"):
        Controller(_joint_reference(), ControllerConfig(mode=ELASTIC_MODE))
    with pytest.raises(ControllerConfigError, match="expected 'model_based_elastic'"):
        ElasticController(_joint_reference(), ControllerConfig(mode="model_based"))


def test_joint_reference_on_grid_is_the_knot_by_knot_ik_exactly():
    """The grid loop (stored knot samples, no lookup) gives bit for bit what solving each
    knot through ``reference.sample`` and ``CartesianToJoint`` gives (the main job's figures
    depend on it)."""
    from controller.controller import start_configuration
    from controller.elastic import joint_reference_on_grid
    from controller.joint_reference import CartesianToJoint
    from controller.reference import TcpTrajectory
    from planners.iso9283 import ISO_Q_HINT, iso9283_test_path
    from robot.kinematics import FlangeKinematics

    path = iso9283_test_path()
    ref = TcpTrajectory.from_reference(path.reference, 0.3, 400e-6)  # start and first corner
    model = FlangeKinematics().model
    q0 = start_configuration(ref, model, np.array(ISO_Q_HINT))
    ik = CartesianToJoint(model)
    ik.reset(q0)
    expected = np.empty((3, ref.grid.n, 6))
    for k, t in enumerate(ref.grid.times):
        sample = ref.sample(t)
        q, qd, qdd = ik.solve(sample.target, sample.twist, sample.acceleration, ref.grid.dt)
        ik.set_state(q, qd, qdd)
        expected[:, k] = q, qd, qdd
    got = joint_reference_on_grid(ref, model, q0)
    for x, y in zip(got, expected):
        np.testing.assert_array_equal(x, y)


def test_compiled_link_torque_is_the_casadi_expression_bit_for_bit(monkeypatch):
    """The compiled link torque (native layer) gives the CasADi virtual machine's numbers
    exactly; with COSIM_NATIVE=off the virtual machine runs (same numbers)."""
    from controller.feedforward import _compiled_link_torque_function, _link_torque_function
    from robot.symbolic import chain_structure

    structure = chain_structure(DYN.model)
    compiled = _compiled_link_torque_function(structure)
    assert compiled is not None and compiled.class_name() != "SXFunction"
    rng = np.random.default_rng(7)
    n = 200
    args = [rng.standard_normal((6, n)) for _ in range(5)]
    p = DYN.parameter_vector()
    rest = [p, np.asarray(DYN.payload, dtype=float), 0.4 * p[VISCOUS_SLICE], 0.4 * p[COULOMB_SLICE]]
    vm = _link_torque_function(structure).map(n)(*args, *rest)
    for a, b in zip(vm, compiled.map(n)(*args, *rest)):
        np.testing.assert_array_equal(np.array(a), np.array(b))
    t = np.linspace(0.0, 0.5, 50)
    d = [np.array([motion(s, k) for s in t]) for k in range(5)]
    fast = link_torque_derivatives(DYN, GEAR, *d)
    monkeypatch.setenv("COSIM_NATIVE", "off")
    assert _compiled_link_torque_function(structure) is None
    for a, b in zip(fast, link_torque_derivatives(DYN, GEAR, *d)):
        np.testing.assert_array_equal(a, b)


def test_link_torque_grid_call_is_the_compiled_map_exactly(monkeypatch):
    """link_torque_derivatives' one C call over the grid (elastic_link_torque_grid) gives the
    compiled function's CasADi map numbers bit for bit (random knots, a length that is not a
    multiple of MAP_BLOCK), and so does the map path in blocks it replaces; single knots (6,)
    too."""
    from controller import feedforward
    from robot.symbolic import chain_structure

    structure = chain_structure(DYN.model)
    assert feedforward._compiled_link_torque_grid(structure) is not None
    rng = np.random.default_rng(11)
    n = 2 * feedforward.MAP_BLOCK + 37
    d = [rng.standard_normal((n, 6)) for _ in range(5)]
    p = DYN.parameter_vector()
    share = GEAR.motor_friction_share
    rest = [p, np.asarray(DYN.payload, dtype=float), (1 - share) * p[VISCOUS_SLICE], (1 - share) * p[COULOMB_SLICE]]
    mapped = feedforward._compiled_link_torque_function(structure).map(n)(*(a.T for a in d), *rest)
    grid = link_torque_derivatives(DYN, GEAR, *d)
    single = link_torque_derivatives(DYN, GEAR, *(a[5] for a in d))
    monkeypatch.setattr(feedforward, "_compiled_link_torque_grid", lambda structure: None)
    blocks = link_torque_derivatives(DYN, GEAR, *d)
    for a, b, c, e in zip(grid, mapped, blocks, single):
        assert a.shape == (n, 6) and e.shape == (1, 6)
        np.testing.assert_array_equal(a, np.array(b).T)
        np.testing.assert_array_equal(c, a)
        np.testing.assert_array_equal(e[0], a[5])


def test_cached_link_torque_library_is_found_without_building_the_expression(monkeypatch):
    """The compiled link torque's cache key is the generator's identity (structure, CasADi
    version, the expression's source files): a process whose cache holds the library loads it
    without building the CasADi expression (~0.1 CPU-s of the elastic set-up); a changed source
    file changes the key."""
    from controller import feedforward
    from robot.symbolic import chain_structure

    structure = chain_structure(DYN.model)
    assert feedforward._compiled_link_torque(structure) is not None  # built (or found) once
    monkeypatch.setattr(feedforward, "_COMPILED_LINK_TORQUE", {})
    monkeypatch.setattr(feedforward, "_LINK_TORQUE_FUNCTIONS", {})

    def refuse(structure):
        raise AssertionError("the expression was built although the library is cached")

    monkeypatch.setattr(feedforward, "_build_link_torque_function", refuse)
    compiled, grid = feedforward._compiled_link_torque(structure)
    assert compiled.class_name() != "SXFunction" and grid is not None
    key = feedforward._structure_key(structure)
    assert feedforward._generator_key(key) == feedforward._generator_key(key)
    assert feedforward._generator_key(key) != feedforward._generator_key(key + b"x")


def test_link_torque_in_blocks_is_the_one_wide_map_exactly():
    """link_torque_derivatives evaluates MAP_BLOCK knots per CasADi call: the same numbers as
    one map over all knots (a length that is not a multiple of the block)."""
    from controller import feedforward
    from robot.symbolic import chain_structure

    t = np.linspace(0.0, 0.5, 2 * feedforward.MAP_BLOCK + 37)
    d = [np.array([motion(s, k) for s in t]) for k in range(5)]
    got = link_torque_derivatives(DYN, GEAR, *d)
    p = DYN.parameter_vector()
    share = GEAR.motor_friction_share
    wide = feedforward._link_torque_function(chain_structure(DYN.model)).map(t.size)(
        *(a.T for a in d), p, np.asarray(DYN.payload, dtype=float), (1 - share) * p[VISCOUS_SLICE],
        (1 - share) * p[COULOMB_SLICE])
    for a, b in zip(got, wide):
        np.testing.assert_array_equal(a, np.array(b).T)
