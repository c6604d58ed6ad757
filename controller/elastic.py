"""Mode ``model_based_elastic``: flatness-based feed-forward for an arm with elastic gears.

:class:`ElasticController` is the built-in :class:`controller.Controller` with its
cycle's set-points replaced: before motion it solves the controller model's inverse
kinematics on every knot of the reference grid (the same :class:`CartesianToJoint` the
cycle uses: q, qd, qdd of the model), takes jerk and snap from the exact accelerations
(:func:`controller.reference.higher_derivatives`) and inverts the flexible-joint model
(:func:`controller.feedforward.elastic_feedforward`). Each cycle then reads the knot of
its application time: the drives get the MOTOR reference ``q_m = q + d`` (their encoders
see the motor) as target, shaped for their speed feed-forward like mode ``model_based``,
and the motor torque ``tau_m = Ia qdd_m + f_m(qd_m) + tau_g`` as torque offset; the log's
desired motion stays the LINK reference (what the TCP is judged against).

Model: the controller's :class:`robot.dynamics.RobotDynamics` (links, rotor inertia,
friction) and :class:`controller.feedforward.GearModel` (stiffness, damping, friction
split; default the nominal ``[elastic]`` table of the parameter file).
"""
from __future__ import annotations

import ctypes
import dataclasses
from functools import lru_cache, partial
from pathlib import Path

import numpy as np
import pinocchio as pin

import native
from controller import compiled_cycle
from controller.compiled_cycle import CycleOutputs, bind_observed, bind_outputs
from controller.controller import _HOOKS, _JOINT_ROW_BYTES, Command, Controller, ControllerConfig, ControllerConfigError, Phase
from controller.drive_compensation import DriveLoopModel, SetpointShaper
from controller.feedforward import ElasticReference, GearModel, elastic_feedforward
from controller.joint_reference import CartesianToJoint
from controller.reference import JointTrajectory, TcpTrajectory, higher_derivatives
from fieldbus import Setpoints
from native.calls import address_of, load_calls
from robot.dynamics import RobotDynamics

ELASTIC_MODE = "model_based_elastic"

ELASTIC_CYCLE_SOURCE = Path(__file__).with_name("elastic_cycle.c")
_ELASTIC_CYCLE_CFLAGS = ("-O2", "-shared", "-fPIC", "-std=c99", "-ffp-contract=off")
_ELASTIC_PYTHON = 2  # elastic_cycle_run: the Python path takes this cycle
#: the cycle methods the compiled elastic cycle replaces: a subclass that overrides one runs the Python path
_ELASTIC_HOOKS = (*_HOOKS, "_shape")


class _ElasticPlan(ctypes.Structure):
    """Mirror of ``elastic_plan`` in elastic_cycle.c."""

    _fields_ = [("n_knots", ctypes.c_longlong),
                *((name, ctypes.c_void_p) for name in ("link_q", "link_qd", "link_qdd", "motor_q", "motor_qd",
                                                       "motor_qdd", "motor_torque")),
                ("out", CycleOutputs)]


@lru_cache(maxsize=1)
def load_elastic_cycle() -> ctypes.CDLL | None:
    """The compiled elastic cycle (``elastic_cycle.c``, built by :mod:`native`), or None (no compiler:
    the Python path runs every cycle, bit for bit the same)."""
    lib = native.load_library(ELASTIC_CYCLE_SOURCE, _ELASTIC_CYCLE_CFLAGS, what="elastic controller cycle",
                              headers=[compiled_cycle.CYCLE_OUTPUTS_HEADER])
    if lib is not None:
        lib.elastic_cycle_run.restype = ctypes.c_int
        lib.elastic_cycle_run.argtypes = [ctypes.c_void_p, ctypes.c_longlong, ctypes.c_void_p]
    return lib


def _rows(array: np.ndarray, n: int, what: str) -> np.ndarray:
    """``array`` as a C-contiguous (n, 6) float64 array (the same values; a copy only when needed)."""
    out = np.ascontiguousarray(array, dtype=np.float64)
    if out.shape != (n, 6):
        raise ValueError(f"elastic cycle: {what} has shape {out.shape}, expected ({n}, 6)")
    return out


class ElasticCycle:
    """The compiled computing cycle of an :class:`ElasticController` (``elastic_cycle.c``): bound
    once to the controller's references, shaper, desired-motion arrays and set-points."""

    def __init__(self, lib: ctypes.CDLL, ctrl: "ElasticController") -> None:
        link, m = ctrl.link_reference, ctrl.motor_reference
        n = len(link[0])
        self._keep = [_rows(a, n, name) for a, name in ((link[0], "link q"), (link[1], "link qd"),
                                                        (link[2], "link qdd"), (m.q, "motor q"),
                                                        (m.qd, "motor qd"), (m.qdd, "motor qdd"),
                                                        (m.torque, "motor torque"))]
        plan = _ElasticPlan()
        plan.n_knots = n
        (plan.link_q, plan.link_qd, plan.link_qdd, plan.motor_q, plan.motor_qd, plan.motor_qdd,
         plan.motor_torque) = (a.ctypes.data for a in self._keep)
        self._keep += bind_outputs(plan.out, ctrl._shaper, (ctrl._q_d, ctrl._qd_d, ctrl._qdd_d), ctrl.setpoints,
                                   Command.ENABLE_OPERATION)
        self.plan = plan
        self._plan_ref = ctypes.byref(plan)
        self._run = lib.elastic_cycle_run
        calls = load_calls()
        if calls is not None:  # called by address: the same call without ctypes' conversions
            self.run = partial(calls.int_p_ll_p, address_of(lib.elastic_cycle_run), ctypes.addressof(plan))
        self._observed: tuple = ()

    def bind_observed(self, statusword: np.ndarray, node_fault: np.ndarray, position: np.ndarray) -> None:
        """Point the cycle at the arrays it reads (int64 statuswords, bool node faults, float64
        positions, (6,) each); ValueError when they do not have that layout."""
        self._observed = bind_observed(self.plan.out, statusword, node_fault, position)

    def run(self, knot: int, log_row_address: int) -> int:
        """The cycle at ``knot``, writing the log row (36 doubles) at ``log_row_address`` (0: none);
        0 done, 2: the Python path must take the cycle (nothing changed)."""
        return self._run(self._plan_ref, knot, log_row_address)


def joint_reference_on_grid(reference: TcpTrajectory | JointTrajectory, model: pin.Model,
                            q_start: np.ndarray, compiled: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q, qd, qdd (each (n, 6)) of the reference on its own knots: the stored samples of a
    joint reference, or the model's IK with consistent derivatives along a flange reference
    (``compiled``: by :mod:`controller.ik_table` when it is built, the same numbers bit for
    bit; else, or with ``compiled=False``, knot by knot from Python)."""
    if isinstance(reference, JointTrajectory):
        return reference.q.copy(), reference.qd.copy(), reference.qdd.copy()
    ik = CartesianToJoint(model)
    ik.reset(q_start)
    n, h = reference.grid.n, reference.grid.dt
    out = np.empty((3, n, 6))
    if compiled:
        from controller.ik_table import solve_table

        if solve_table(ik, reference, out, build=False):  # built by `cosim build`, not in a run
            return out[0], out[1], out[2]
    # the stored knot samples (what reference.sample returns at a knot time, without the
    # lookup); solve() leaves its result as the next seed's state (set_state is a no-op copy)
    solve, targets, twist, acc = ik.solve, reference._placements, reference.twist, reference.acceleration
    q_out, qd_out, qdd_out = out[0], out[1], out[2]
    for k in range(n):
        q, qd, qdd = solve(targets[k], twist[k], acc[k], h)
        q_out[k], qd_out[k], qdd_out[k] = q, qd, qdd
    return q_out, qd_out, qdd_out


class ElasticController(Controller):
    """The built-in controller in mode ``model_based_elastic`` (see module docstring).

    Arguments as :class:`controller.Controller`, plus ``gear`` (the controller's gear
    model). The reference's grid step must equal the controller period (every cycle
    reads a knot).
    """

    _elastic_mode = True

    def __init__(self, reference: TcpTrajectory | JointTrajectory, config: ControllerConfig | None = None, *,
                 kinematic_model: pin.Model | None = None, dynamics: RobotDynamics | None = None,
                 q_hint: np.ndarray | None = None, drive_model: DriveLoopModel | None = None,
                 capacity: int = 65536, gear: GearModel | None = None) -> None:
        config = config or ControllerConfig(mode=ELASTIC_MODE)
        if config.mode != ELASTIC_MODE:
            raise ControllerConfigError(f"ElasticController: mode = {config.mode!r}, expected {ELASTIC_MODE!r}")
        # the set-points come from the table below: no per-cycle IK kernel
        super().__init__(reference, dataclasses.replace(config, compiled=False), kinematic_model=kinematic_model,
                         dynamics=dynamics if dynamics is not None else RobotDynamics(), q_hint=q_hint,
                         drive_model=None, capacity=capacity)
        if abs(reference.grid.dt - self.config.period_s) > 1e-12 * max(1.0, self.config.period_s):
            raise ControllerConfigError(f"{ELASTIC_MODE}: reference grid step {reference.grid.dt!r} s, expected the "
                                        f"controller period {self.config.period_s!r} s")
        self.gear = gear or GearModel.from_parameters()
        q, qd, qdd = joint_reference_on_grid(reference, self.kinematic_model, self.q_start)
        jerk, snap = higher_derivatives(qdd, reference.grid.dt)
        self.link_reference = (q, qd, qdd, jerk, snap)
        self.motor_reference: ElasticReference = elastic_feedforward(self.dynamics, self.gear, q, qd, qdd, jerk, snap)
        rest = elastic_feedforward(self.dynamics, self.gear, self.q_start, *(np.zeros(6),) * 4)
        self._motor_start = rest.q[0].copy()
        self._tau_rest[:] = rest.torque[0]
        self._shaper = SetpointShaper(drive_model) if drive_model is not None else None
        self._last_knot = -1
        if self._shaper is not None:
            if abs(drive_model.period_s - self.config.period_s) > 1e-12:
                raise ControllerConfigError(f"drive_model.period_s = {drive_model.period_s!r}: expected the "
                                            f"controller period {self.config.period_s!r} s")
            self._shaper.reset(self._motor_start)
            self._in_order = self._shaping_in_order()
            self._scratch = np.empty((2, 6))
        self.setpoints.position[:] = self._motor_start
        # the computing cycle in one C call (elastic_cycle.c), bit for bit the Python path below
        self._fast = None
        if config.compiled and config.fast_cycle and not any(
                getattr(type(self), name) is not getattr(ElasticController, name) for name in _ELASTIC_HOOKS):
            lib = load_elastic_cycle()
            if lib is not None:
                self._fast = ElasticCycle(lib, self)
                self._observed_bound = None
                self._ref_t_start = reference.t_start  # what the cycle reads of the reference
                self._ref_duration = reference.duration
                self.kernel_note = f"elastic cycle {lib._name}"

    def _fast_step(self, cycle: int, t: float, observed, started: int, cpu_started: int) -> bool:
        """A settling/tracking/finished cycle through the compiled elastic cycle: the same
        set-points, shaper state, log row and timing as :meth:`Controller.run_cycle` with
        :meth:`_compute`. False when the Python path must take this cycle (a drive not in
        Operation enabled or a node fault, unusual observed arrays); nothing has changed then."""
        bound = self._observed_bound
        if bound is None or observed.position is not bound[0] or observed.statusword is not bound[1] \
                or observed.node_fault is not bound[2]:
            if not self._bind_fast_observed(observed):
                return False
        phase = self.phase
        tau = 0.0 if phase is Phase.SETTLING else (cycle - self.motion_start_cycle) * self._period_s
        ref = self.reference
        k, _ = ref.grid.locate(self._ref_t_start + tau)
        fast = self._fast
        log = self.log
        row = log.rows  # the log row the compiled cycle writes (ControllerLog.next_joints_address)
        if row == log._capacity:
            log._grow()
            row = log.rows
        joints = log._joints_address + _JOINT_ROW_BYTES * row
        if self._shape_gap != 1 and self._shaper is not None:
            # a jump the bus interpolates: shape over the samples in between (drive_compensation)
            self._set_shaper_gains(fast.plan.out, self._shape_gap)
            status = fast.run(k, joints)
            self._set_shaper_gains(fast.plan.out, 1)
        else:
            status = fast.run(k, joints)
        if status != 0:
            return False
        self._last_knot = k
        self._fast_step_done(cycle, t, phase, tau, self._ref_duration, started, cpu_started, 0)
        return True

    def _enable(self, observed, sp: Setpoints) -> None:
        super()._enable(observed, sp)
        sp.position[:] = self._motor_start  # the motor where the gear holds the arm at q_start
        sp.torque_offset[:] = self._tau_rest

    def _shaping_in_order(self) -> np.ndarray:
        """Per knot k >= 1, the part of :meth:`SetpointShaper.shape` that does not depend on the
        shaper's state when knot k follows knot k-1 (``q_prev`` = the previous knot's motor
        reference): ``qdd lead + qd - (g/T) (q_k - q_k-1)``, with the same element-wise operations
        in the same order as ``shape``, so a cycle that uses it gets the same bits."""
        sh, m = self._shaper, self.motor_reference
        w = np.multiply(m.qdd, sh._lead)
        w += m.qd
        w[1:] -= sh._g_over_t * (m.q[1:] - m.q[:-1])
        w[0] = np.nan  # knot 0 has no predecessor: always shaped in full
        return w

    def _shape(self, k: int) -> np.ndarray:
        """The target of knot k: SetpointShaper.shape of its motor reference; when knot k follows
        the knot shaped last, from the precomputed in-order part (5 array operations instead of 9,
        the same arithmetic)."""
        sh, m = self._shaper, self.motor_reference
        if k == self._last_knot + 1 and k > 0:
            tmp, w = self._scratch
            np.multiply(sh._g_over_t, sh._delta, out=tmp)
            np.add(self._in_order[k], tmp, out=w)
            np.divide(w, sh._denominator, out=sh._delta)
            q_d = m.q[k]
            sh._q_prev[:] = q_d
            target = np.add(q_d, sh._delta, out=sh.target)
        else:
            target = sh.shape(m.q[k], m.qd[k], m.qdd[k], self._shape_gap)
        self._last_knot = k
        return target

    def _compute(self, tau: float, sp: Setpoints) -> int:
        ref = self.reference
        k, _ = ref.grid.locate(ref.t_start + tau)
        link = self.link_reference
        m = self.motor_reference
        self._q_d[:] = link[0][k]
        self._qd_d[:] = link[1][k]
        self._qdd_d[:] = link[2][k]
        sp.torque_offset[:] = m.torque[k]
        sp.position[:] = m.q[k] if self._shaper is None else self._shape(k)
        return 0


def make_controller(reference: TcpTrajectory | JointTrajectory, config: ControllerConfig, **kwargs) -> Controller:
    """The built-in controller of ``config.mode``: :class:`ElasticController` for
    ``model_based_elastic``, else :class:`controller.Controller` (same keyword arguments;
    ``gear`` only for the elastic mode)."""
    if config.mode == ELASTIC_MODE:
        return ElasticController(reference, config, **kwargs)
    kwargs.pop("gear", None)
    return Controller(reference, config, **kwargs)
