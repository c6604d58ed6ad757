"""The cycle's numerics as one compiled C function (CasADi code generation, gcc, ctypes).

Same mathematics as :class:`controller.joint_reference.CartesianToJoint` (one NumericIK
Newton step from the predicted seed, consistent ``qd``/``qdd``) followed by
:class:`controller.feedforward.FeedForward` (eq. 7 with rotor inertia and friction), written
once as a CasADi SX expression of the controller's kinematic model and dynamic model
(numbers baked in as constants), generated as C, compiled with the system C compiler
and called through ctypes with prepared argument arrays: one foreign call per cycle
instead of a dozen pinocchio/LAPACK calls and numpy temporaries, which matters most when
the FMUs and the fieldbus have evicted the interpreter's caches between two cycles. With the
whole cycle around it in C too (``fast_cycle.c``) the controller step of the closed loop takes
21 us thread CPU per 400 us cycle (``benchmarks/bench_closed_loop.py --breakdown``, load
0.6-0.9).

Kernel ``f(state[18], ref[24], h)`` returns ``state_out[18], tau[6], info[3]``:
``state = (q, qd, qdd)`` of the previous cycle (rad, rad/s, rad/s^2), ``ref`` the desired
flange motion (``TcpTrajectory.packed`` layout: rotation column-major, position,
twist, acceleration), ``h`` the time since the previous cycle (s);
``info = (|e|^2, |dq|^2, hadamard)``:

* ``seed = q + qd h + qdd h^2 / 2`` (the warm start), ``e = log6(M(seed)^-1 M_target)`` (pinocchio's SE(3) log: angle from the trace, series
  below 1e-5 rad), ``dq = J_local(seed)^-1 e``, ``q = seed + dq``;
* ``J = J_LWA(q)``, ``qd = J^-1 [v; w]``, ``qdd = J^-1 ([a; dw] - Jdot qd)`` with
  ``Jdot qd = d(J(q) v)/dq . v`` at ``v = qd`` (forward-mode AD);
* ``tau = RNEA(q, qd, qdd) + friction`` (:func:`robot.symbolic.inverse_dynamics_expression`);
* ``hadamard = |det J| / prod_i |J[:, i]|`` (0 singular, 1 orthogonal columns).

The caller accepts the result only when ``|e|^2`` and ``|dq|^2`` are below NumericIK's
acceptance bound (then NumericIK's tolerance holds, see
``NumericIK._acceptance_bound``), ``q`` is inside the limits and the Jacobian is not
singular; otherwise it takes the Python path (NumericIK with its fallbacks). The
generated library is built and cached by the project's native layer (:mod:`native`,
keyed by the SHA-256 of its generated C source, compiler, flags and Python version).

The same library holds ``fast_cycle_run`` (``controller/fast_cycle.c``): the whole
compiled-path cycle around the kernel (stop check, acceptance, drive set-point
shaping, set-points, log row) in one foreign call, bound once by
:meth:`CompiledCycle.bind_fast_cycle`; Python numpy operations on 6-vectors cost about
1-2 µs each (timeit minimum: ``a + b`` 1.1 µs, ``a * 2.0`` 1.7 µs, numpy 2.4, 2-core AMD
EPYC VM), a dozen of them per cycle cost more than the kernel.
"""
from __future__ import annotations

import ctypes
import hashlib
import tempfile
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np
import pinocchio as pin

import native
from native.calls import address_of, load_calls

from robot.dynamics import RobotDynamics
from robot.symbolic import chain_structure, inverse_dynamics_expression
from robot.joints import N_JOINTS

if TYPE_CHECKING:
    from controller.drive_compensation import SetpointShaper
    from fieldbus import Setpoints

FUNCTION_NAME = "controller_cycle"
CFLAGS = ("-O2", "-fPIC", "-shared", "-std=c99", "-ffp-contract=off")
FAST_CYCLE_SOURCE = Path(__file__).with_name("fast_cycle.c")
#: what fast_cycle.c and elastic_cycle.c share (the arrays a cycle writes and reads, shaping, log row)
CYCLE_OUTPUTS_HEADER = Path(__file__).with_name("cycle_outputs.h")
FAST_STOP_CHECK, FAST_REJECTED = 2, -1
"""``fast_cycle_run`` results besides 0/1 (accepted, IK steps): a drive is not in
Operation enabled or a node is faulted (the Python path decides), the kernel's result
failed a check (the Python path redoes the cycle)."""
_SMALL_ANGLE = 1e-5


class CompiledCycleError(native.NativeBuildError):
    """Generating or compiling the cycle kernel failed (message holds the compiler output)."""


def _rodrigues(axis: np.ndarray, angle: ca.SX) -> ca.SX:
    k = ca.DM([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return ca.DM.eye(3) + ca.sin(angle) * k + (1.0 - ca.cos(angle)) * (k @ k)


def _forward_kinematics(structure, q: ca.SX) -> tuple[ca.SX, ca.SX, list, list]:
    """Flange rotation, position, joint origins and world joint axes at q (base_link)."""
    rot = ca.SX.eye(3)
    pos = ca.SX.zeros(3)
    origins, axes = [], []
    for i in range(N_JOINTS):
        pos = pos + rot @ ca.DM(structure.translations[i])
        rot = rot @ ca.DM(structure.rotations[i])
        origins.append(pos)
        axes.append(rot @ ca.DM(structure.axes[i]))
        rot = rot @ _rodrigues(structure.axes[i], q[i])
    return rot @ ca.DM(structure.flange_rotation), pos + rot @ ca.DM(structure.flange_translation), origins, axes


def _world_jacobian(p: ca.SX, origins: list, axes: list) -> ca.SX:
    """Geometric Jacobian at the flange origin, base-frame axes (pinocchio LOCAL_WORLD_ALIGNED)."""
    return ca.horzcat(*[ca.vertcat(ca.cross(z, p - o), z) for z, o in zip(axes, origins)])


def _log6(rot: ca.SX, pos: ca.SX) -> ca.SX:
    """pinocchio.log6 of (rot, pos): [v; w] with w = log3(rot), v = V(w)^-1 pos."""
    cos_theta = ca.fmin(ca.fmax((ca.trace(rot) - 1.0) / 2.0, -1.0), 1.0)
    theta = ca.acos(cos_theta)
    vee = ca.vertcat(rot[2, 1] - rot[1, 2], rot[0, 2] - rot[2, 0], rot[1, 0] - rot[0, 1])
    small = theta < _SMALL_ANGLE
    factor = ca.if_else(small, 0.5 * (1.0 + theta * theta / 6.0), theta / (2.0 * ca.sin(theta)))
    w = factor * vee
    wx = ca.skew(w)
    alpha = ca.if_else(small, 1.0 / 12.0 + theta * theta / 720.0,
                       (1.0 - theta * ca.sin(theta) / (2.0 * (1.0 - ca.cos(theta)))) / (theta * theta))
    v_inv = ca.SX.eye(3) - 0.5 * wx + alpha * (wx @ wx)
    return ca.vertcat(v_inv @ pos, w)


def cycle_function(kinematic_model: pin.Model, dynamics: RobotDynamics | None) -> ca.Function:
    """The SX kernel of the module docstring (tau = 0 when ``dynamics`` is None)."""
    kin = chain_structure(kinematic_model)
    state, ref, h = ca.SX.sym("state", 18), ca.SX.sym("ref", 24), ca.SX.sym("h")
    seed = state[0:6] + h * state[6:12] + 0.5 * h * h * state[12:18]
    r_t = ca.reshape(ref[0:9], 3, 3)
    p_t, twist, acc = ref[9:12], ref[12:18], ref[18:24]
    rot, pos, origins, axes = _forward_kinematics(kin, seed)
    err = _log6(rot.T @ r_t, rot.T @ (p_t - pos))
    j_world = _world_jacobian(pos, origins, axes)
    j_local = ca.vertcat(ca.horzcat(rot.T, ca.SX.zeros(3, 3)), ca.horzcat(ca.SX.zeros(3, 3), rot.T)) @ j_world
    dq = ca.solve(j_local, err)
    q = seed + dq

    qs, vs = ca.SX.sym("qs", 6), ca.SX.sym("vs", 6)
    _, pos_s, origins_s, axes_s = _forward_kinematics(kin, qs)
    jac_s = _world_jacobian(pos_s, origins_s, axes_s)
    drift_fn = ca.Function("jacobian_drift", [qs, vs], [ca.jtimes(jac_s @ vs, qs, vs)])
    jac_fn = ca.Function("world_jacobian", [qs], [jac_s])

    jac = jac_fn(q)
    qd = ca.solve(jac, twist)
    qdd = ca.solve(jac, acc - drift_fn(q, qd))
    norms = [ca.norm_2(jac[:, i]) for i in range(N_JOINTS)]
    hadamard = ca.fabs(ca.det(jac)) / (norms[0] * norms[1] * norms[2] * norms[3] * norms[4] * norms[5])
    if dynamics is not None:
        dyn = chain_structure(dynamics.model, dynamics.parameters)
        tau = ca.vertcat(*inverse_dynamics_expression(dyn, q, qd, qdd, dynamics.parameter_vector().tolist(),
                                                      dynamics.payload.tolist()))
    else:
        tau = ca.SX.zeros(6)
    info = ca.vertcat(ca.dot(err, err), ca.dot(dq, dq), hadamard)
    return ca.Function(FUNCTION_NAME, [state, ref, h], [ca.vertcat(q, qd, qdd), tau, info],
                       ["state", "ref", "h"], ["state_out", "tau", "info"], {"cse": True})


def _generate_c(function: ca.Function) -> str:
    generator = ca.CodeGenerator(f"{FUNCTION_NAME}.c", {"with_header": False, "casadi_int": "long long int"})
    generator.add(function)
    with tempfile.TemporaryDirectory() as tmp:
        generator.generate(tmp + "/")
        return (Path(tmp) / f"{FUNCTION_NAME}.c").read_text()


def build_library(function: ca.Function) -> Path:
    """Generate, compile (once per cache key, :func:`native.build`) and return the shared
    library's path (the generated kernel and ``fast_cycle.c``)."""
    source = _generate_c(function)

    def generate(folder: Path) -> list[Path]:
        c_file = folder / f"{FUNCTION_NAME}.c"
        c_file.write_text(source)
        return [c_file]

    try:
        return native.build("controller_cycle", [FAST_CYCLE_SOURCE], headers=[CYCLE_OUTPUTS_HEADER],
                            generate=generate, key=hashlib.sha256(source.encode()).digest(), cflags=CFLAGS)
    except native.NativeBuildError as exc:
        raise CompiledCycleError(f"controller kernel: {exc}") from None


class CycleOutputs(ctypes.Structure):
    """Mirror of ``cycle_outputs`` in cycle_outputs.h (shaping, what a compiled cycle writes
    and reads); bound by :func:`bind_outputs` and :func:`bind_observed`."""

    _fields_ = [
        ("shape", ctypes.c_longlong),
        ("lead", ctypes.c_double * N_JOINTS), ("g_over_t", ctypes.c_double * N_JOINTS),
        ("denominator", ctypes.c_double * N_JOINTS),
        *((name, ctypes.c_void_p) for name in ("shaper_delta", "shaper_q_prev", "shaper_target", "q_d", "qd_d",
                                               "qdd_d", "sp_position", "sp_torque", "sp_controlword")),
        ("enable_operation", ctypes.c_longlong),
        *((name, ctypes.c_void_p) for name in ("statusword", "node_fault", "q_obs")),
    ]


def bind_outputs(out: CycleOutputs, shaper: "SetpointShaper | None",
                 desired: tuple[np.ndarray, np.ndarray, np.ndarray], setpoints: "Setpoints",
                 enable_operation: int) -> list:
    """Point ``out`` at the set-point shaper's arrays (updated in place) or none, the
    controller's desired-motion arrays (q_d, qd_d, qdd_d) and set-points, with the
    controlword of a computing cycle; returns the objects the caller must keep alive."""
    out.shape = int(shaper is not None)
    if shaper is not None:
        out.lead[:] = np.broadcast_to(shaper._lead, (N_JOINTS,)).tolist()
        out.g_over_t[:] = np.broadcast_to(shaper._g_over_t, (N_JOINTS,)).tolist()
        out.denominator[:] = np.broadcast_to(shaper._denominator, (N_JOINTS,)).tolist()
        out.shaper_delta = _address(shaper._delta, np.float64, "shaper delta")
        out.shaper_q_prev = _address(shaper._q_prev, np.float64, "shaper q_prev")
        out.shaper_target = _address(shaper.target, np.float64, "shaper target")
    q_d, qd_d, qdd_d = desired
    out.q_d = _address(q_d, np.float64, "q_d")
    out.qd_d = _address(qd_d, np.float64, "qd_d")
    out.qdd_d = _address(qdd_d, np.float64, "qdd_d")
    out.sp_position = _address(setpoints.position, np.float64, "setpoints.position")
    out.sp_torque = _address(setpoints.torque_offset, np.float64, "setpoints.torque_offset")
    out.sp_controlword = _address(setpoints.controlword, np.int64, "setpoints.controlword")
    out.enable_operation = int(enable_operation)
    return [shaper, q_d, qd_d, qdd_d, setpoints.position, setpoints.torque_offset, setpoints.controlword]


def bind_observed(out: CycleOutputs, statusword: np.ndarray, node_fault: np.ndarray,
                  position: np.ndarray) -> tuple:
    """Point ``out`` at the arrays a cycle reads (int64 statuswords, bool node faults, float64
    positions, (6,) each; ValueError when they do not have that layout); returns them (keep
    them alive)."""
    out.statusword = _address(statusword, np.int64, "observed.statusword")
    out.node_fault = _address(node_fault, np.bool_, "observed.node_fault")
    out.q_obs = _address(position, np.float64, "observed.position")
    return statusword, node_fault, position


class FastPlan(ctypes.Structure):
    """Mirror of ``fast_plan`` in fast_cycle.c (pointers and constants of one controller)."""

    _fields_ = [
        ("arg", ctypes.c_void_p), ("res", ctypes.c_void_p), ("iw", ctypes.c_void_p), ("w", ctypes.c_void_p),
        ("state", ctypes.c_void_p), ("result", ctypes.c_void_p), ("tau", ctypes.c_void_p),
        ("info", ctypes.c_void_p),
        ("accept2", ctypes.c_double), ("tol2", ctypes.c_double), ("singular_tol", ctypes.c_double),
        ("lower", ctypes.c_double * N_JOINTS), ("upper", ctypes.c_double * N_JOINTS),
        ("model_based", ctypes.c_longlong), ("out", CycleOutputs),
    ]


def _address(array: np.ndarray, dtype: type, what: str) -> int:
    """Data address of a C-contiguous (6,) array of ``dtype`` (ValueError otherwise)."""
    if not (isinstance(array, np.ndarray) and array.dtype == dtype and array.shape == (N_JOINTS,)
            and array.flags.c_contiguous):
        raise ValueError(f"fast cycle: {what} must be a contiguous ({N_JOINTS},) {np.dtype(dtype).name} array, "
                         f"got {getattr(array, 'dtype', type(array).__name__)} {getattr(array, 'shape', '')}")
    return int(array.ctypes.data)


class CompiledCycle:
    """The compiled kernel with prepared ctypes argument arrays.

    ``state`` (18,) holds (q, qd, qdd) of the last accepted cycle; :meth:`run` evaluates
    the kernel from it into ``result`` (18,), ``tau`` (6,) and ``info`` (3,); :meth:`accept`
    copies ``result`` into the state; :meth:`reset` sets the state at rest. The arrays keep
    their memory for the object's life (the fast cycle holds their addresses).
    """

    def __init__(self, kinematic_model: pin.Model, dynamics: RobotDynamics | None) -> None:
        function = cycle_function(kinematic_model, dynamics)
        self.library_path = build_library(function)
        try:
            self._lib = native.load_ctypes(self.library_path)
        except native.NativeBuildError as exc:
            raise CompiledCycleError(f"controller kernel: {exc}") from None
        fn = getattr(self._lib, FUNCTION_NAME)
        fn.restype = ctypes.c_int
        fn.argtypes = [ctypes.c_void_p] * 4 + [ctypes.c_int]
        self._fn = fn
        sizes = [ctypes.c_longlong() for _ in range(4)]
        work = getattr(self._lib, f"{FUNCTION_NAME}_work")
        work.argtypes = [ctypes.POINTER(ctypes.c_longlong)] * 4
        if work(*(ctypes.byref(x) for x in sizes)) != 0:
            raise CompiledCycleError("controller kernel: the work-size query failed")
        n_arg, n_res, n_iw, n_w = (int(x.value) for x in sizes)
        self.state = np.zeros(18)
        self.result = np.zeros(18)
        self.h = np.zeros(1)
        self.tau = np.zeros(6)
        self.info = np.zeros(3)
        self._iw = (ctypes.c_longlong * max(n_iw, 1))()
        self._w = (ctypes.c_double * max(n_w, 1))()
        self._arg = (ctypes.c_void_p * max(n_arg, 3))(self.state.ctypes.data, 0, self.h.ctypes.data)
        self._res = (ctypes.c_void_p * max(n_res, 3))(self.result.ctypes.data, self.tau.ctypes.data,
                                                     self.info.ctypes.data)
        self._call = (ctypes.cast(self._arg, ctypes.c_void_p), ctypes.cast(self._res, ctypes.c_void_p),
                      ctypes.cast(self._iw, ctypes.c_void_p), ctypes.cast(self._w, ctypes.c_void_p), 0)
        fast = self._lib.fast_cycle_run
        fast.restype = ctypes.c_int
        fast.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
        self._fast = fast
        self.plan: FastPlan | None = None
        self._plan_ref = None
        self._keep: list = []

    def reset(self, q: np.ndarray) -> None:
        """State at rest at ``q`` (6,) rad."""
        self.state[:] = 0.0
        self.state[:6] = q

    def run(self, ref_address: int, h: float) -> None:
        """Evaluate from ``state`` for the packed reference row (24 doubles) at memory address
        ``ref_address`` (e.g. ``TcpTrajectory.packed`` row k: ``packed.ctypes.data + 192 k``)
        and the step ``h`` (s)."""
        self._arg[1] = ref_address
        self.h[0] = h
        if self._fn(*self._call) != 0:
            raise CompiledCycleError("controller kernel returned an error")

    def accept(self) -> None:
        """Make the last result the state (after checking ``info``)."""
        self.state[:] = self.result

    def set_state(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> None:
        """Overwrite the state (after a cycle solved by another path)."""
        self.state[:6] = q
        self.state[6:12] = qd
        self.state[12:] = qdd

    # ------------------------------------------------------------------ whole cycle
    def bind_fast_cycle(self, *, h: float, accept2: float, tol2: float, singular_tol: float,
                        lower: np.ndarray, upper: np.ndarray, model_based: bool,
                        shaper: "SetpointShaper | None", desired: tuple[np.ndarray, np.ndarray, np.ndarray],
                        setpoints: "Setpoints", enable_operation: int) -> None:
        """Prepare :meth:`fast_cycle` for one controller: step ``h`` (s), the acceptance
        bounds (squared norms, Hadamard ratio, joint limits in rad incl. tolerance), the
        torque offset choice, the set-point shaper (its arrays are updated in place) or
        None, the controller's desired-motion arrays (q_d, qd_d, qdd_d) and set-points
        (written on acceptance) and the controlword of a computing cycle."""
        plan = FastPlan()
        plan.arg = ctypes.cast(self._arg, ctypes.c_void_p)
        plan.res = ctypes.cast(self._res, ctypes.c_void_p)
        plan.iw = ctypes.cast(self._iw, ctypes.c_void_p)
        plan.w = ctypes.cast(self._w, ctypes.c_void_p)
        plan.state, plan.result = self.state.ctypes.data, self.result.ctypes.data
        plan.tau, plan.info = self.tau.ctypes.data, self.info.ctypes.data
        self.h[0] = h
        plan.accept2, plan.tol2, plan.singular_tol = accept2, tol2, singular_tol
        plan.lower[:] = [float(x) for x in lower]
        plan.upper[:] = [float(x) for x in upper]
        plan.model_based = int(bool(model_based))
        self._keep = bind_outputs(plan.out, shaper, desired, setpoints, enable_operation)
        self.plan = plan
        self._plan_ref = ctypes.byref(plan)
        calls = load_calls()
        if calls is not None:  # called by address: the same call without ctypes' conversions
            self.fast_cycle = partial(calls.int_p_p_p, address_of(self._fast), ctypes.addressof(plan))

    def bind_observed(self, statusword: np.ndarray, node_fault: np.ndarray, position: np.ndarray) -> None:
        """Point the fast cycle at the arrays it reads (int64 statuswords, bool node faults,
        float64 positions, (6,) each); ValueError when they do not have that layout."""
        self._keep_observed = bind_observed(self.plan.out, statusword, node_fault, position)

    def fast_cycle(self, ref_address: int, log_row_address: int) -> int:
        """The whole compiled-path cycle (fast_cycle.c) for the packed reference row at
        ``ref_address``, writing the log row (36 doubles) at ``log_row_address`` (0: none).
        Returns 0 or 1 (accepted; IK steps), FAST_STOP_CHECK or FAST_REJECTED."""
        return self._fast(self._plan_ref, ref_address, log_row_address)
