"""The 400 µs controller of the paper's section 2.3: set-points and eq. 7 feed-forward.

:class:`Controller` is the built-in cell controller: it satisfies the controller
contract (:class:`controller.contract.CellController`: ``setup``, ``step``, ``close``)
and the cell drives it through that contract like any user controller. Every cycle ``k``
(time ``t_k = k T``, ``T`` = ``period_s``) :meth:`Controller.step` gets what the
fieldbus delivered in that cycle (:class:`controller.contract.ControllerInput`:
statusword, position, velocity, torque per drive, latched at ``t_k``) and returns the
:class:`controller.contract.ControllerOutput` for the next cycle in mode 8 (CSP: target
joint angle in rad, torque offset in N m, CiA 402 controlword); :meth:`Controller.run_cycle`
does the same with a ``fieldbus.ObservedActuals`` and returns the ``fieldbus.Setpoints``
(the same arrays). The fieldbus scales them to telegram units, sends
them in cycle ``k + 1`` and the drives apply them ``dead_time_cycles`` later, so a
set-point computed in cycle ``k`` acts from ``t_k + lead_cycles T`` with
``lead_cycles = 1 + dead_time_cycles``. The controller therefore evaluates the
reference at that application time: the joint set-point the drive applies at ``t`` is
``q_d(t)`` and the lag error ``q_d(t) - q(t)`` holds no pure transport delay.

Per cycle, for a Cartesian reference (:class:`controller.reference.TcpTrajectory`):
interpolate the planned flange motion at the application time, numeric IK of the
controller's kinematic model (warm started), consistent ``qd_d``, ``qdd_d``
(:mod:`controller.joint_reference`), then - mode ``model_based`` - the feed-forward
torque of eq. 7 from the controller's dynamic model (:mod:`controller.feedforward`);
mode ``standard`` sends the set-points with a zero torque offset (the drives' own
cascade alone, as an industrial controller without a model). With a ``drive_model``
the model-based mode also shapes the target positions so the drives' speed
feed-forward and speed filter add no lag (:mod:`controller.drive_compensation`). A joint reference
(:class:`controller.reference.JointTrajectory`) skips the IK.

Phases: ``enabling`` (CiA 402 enable sequence per drive with
:class:`fieldbus.EnableSequencer`, target = start configuration), ``settling`` (all
drives in Operation enabled; hold the start for ``settle_time_s`` so the speed-loop
integrators take the static load), ``tracking`` (trajectory time
``tau = (k - k_start) T`` for the set-point computed in cycle ``k``), ``finished``
(``tau`` past the end: hold the last point) and ``stopped``: as soon as a drive shows
Fault, Fault reaction active or Quick stop active, or the managing node reports a
node fault (threshold counter), the controller stops commanding motion - quick stop
(0x0002) to every drive, target = the last observed position, no torque offset - and
keeps the reason. It never restarts motion by itself.

Compiled paths: with ``compiled`` the cycle's numerics run in a generated C kernel
(:mod:`controller.compiled_cycle`), with ``fast_cycle`` the whole cycle around it
(``fast_cycle.c``). They are an implementation detail of this class: a subclass that
replaces one of the cycle's methods (:func:`overridden_hooks`) gets the Python path,
so its code is never bypassed.

Each cycle that computes a reference is timed with ``time.perf_counter_ns`` (and its
thread CPU time with ``time.thread_time_ns``; the controller's own work: interpolation, IK, derivatives, feed-forward, controlwords);
:meth:`Controller.timing` gives p50/p99/max and the deadline misses (compute time
above ``compute_budget_s``). Everything the controller computed is kept per cycle in
:attr:`Controller.log` (outside the timed section).
"""
from __future__ import annotations

import math
import struct
import time
from dataclasses import asdict, dataclass
from enum import IntEnum
from functools import partial

import numpy as np
import pinocchio as pin

import native
from controller.cycle_timer import CycleTimer, TimingSummary
from controller.drive_compensation import DriveLoopModel, SetpointShaper
from controller.feedforward import FeedForward
from controller.contract import DEFAULT_COMPUTE_BUDGET_S, ControllerInfo, ControllerInput, ControllerOutput
from controller.compiled_cycle import FAST_REJECTED, FAST_STOP_CHECK, CompiledCycle, CompiledCycleError
from controller.joint_reference import SINGULARITY_TOLERANCE, CartesianToJoint, SingularConfigurationError
from controller.reference import JointTrajectory, TcpTrajectory
from fieldbus import Command, DriveState, EnableSequencer, ObservedActuals, Setpoints, decode_statusword
from robot.dynamics import RobotDynamics
from robot.inverse_kinematics import LIMIT_TOLERANCE, NumericIK
from robot.joints import N_JOINTS

MODES: tuple[str, ...] = ("standard", "model_based", "model_based_elastic")
STOP_STATES = {DriveState.FAULT: "Fault", DriveState.FAULT_REACTION_ACTIVE: "Fault reaction active",
                DriveState.QUICK_STOP_ACTIVE: "Quick stop active"}
"""Drive states in which a controller stops commanding motion (state -> name for the reason)."""


class ControllerConfigError(ValueError):
    """A controller setting is out of range or inconsistent (message names key, value, expectation)."""


class Phase(IntEnum):
    """What the controller does in a cycle (the integer is logged)."""

    ENABLING = 0
    SETTLING = 1
    TRACKING = 2
    FINISHED = 3
    STOPPED = 4


@dataclass(frozen=True)
class ControllerConfig:
    """Controller settings (SI units).

    mode: ``"standard"`` (set-points only), ``"model_based"`` (plus eq. 7 feed-forward) or
        ``"model_based_elastic"`` (flatness-based feed-forward for elastic gears: use
        :class:`controller.elastic.ElasticController`, or :func:`controller.elastic.make_controller`).
    period_s: cycle time T, s (paper: 400 µs).
    lead_cycles: cycles from computing a set-point to the drive applying it
        (1 + the fieldbus ``dead_time_cycles``).
    compute_budget_s: compute time above which a cycle counts as a deadline miss, s.
    settle_time_s: hold at the start configuration after all drives are enabled, s.
    enable_timeout_s: longest time the enable sequence may take before the controller
        gives up (stops with a reason), s.
    compiled: evaluate the cycle's numerics (Newton step, qd, qdd, feed-forward) with the
        generated C kernel of :mod:`controller.compiled_cycle` (same mathematics; the
        Python path stays the fallback of every cycle the kernel's checks reject).
    fast_cycle: with ``compiled``, run the whole cycle around the kernel (stop check,
        acceptance, set-point shaping, set-points, log row) in one C call
        (``controller/fast_cycle.c``, bit-identical to the Python code around the kernel).
    """

    mode: str = "model_based"
    period_s: float = 400e-6
    lead_cycles: int = 2
    compute_budget_s: float = DEFAULT_COMPUTE_BUDGET_S
    settle_time_s: float = 0.2
    enable_timeout_s: float = 0.5
    compiled: bool = True
    fast_cycle: bool = True

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ControllerConfigError(f"controller mode = {self.mode!r}: expected one of {MODES}")
        for name in ("period_s", "compute_budget_s", "enable_timeout_s"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value)
                                                                                    and value > 0.0):
                raise ControllerConfigError(f"controller {name} = {value!r}: expected a number of seconds > 0")
        if isinstance(self.settle_time_s, bool) or not isinstance(self.settle_time_s, (int, float)) or not (
                math.isfinite(self.settle_time_s) and self.settle_time_s >= 0.0):
            raise ControllerConfigError(f"controller settle_time_s = {self.settle_time_s!r}: expected seconds >= 0")
        if isinstance(self.lead_cycles, bool) or not isinstance(self.lead_cycles, int) or self.lead_cycles < 0:
            raise ControllerConfigError(f"controller lead_cycles = {self.lead_cycles!r}: expected an integer >= 0")

    @property
    def settle_cycles(self) -> int:
        return int(round(self.settle_time_s / self.period_s))

    @property
    def lead_time_s(self) -> float:
        """Time from computing a set-point to its application, s."""
        return self.lead_cycles * self.period_s


_COMPUTING = frozenset((Phase.SETTLING, Phase.TRACKING, Phase.FINISHED))
_perf_counter_ns = time.perf_counter_ns
_thread_time_ns = time.thread_time_ns
_SCALAR_ROW = struct.Struct("@6d")
_JOINT_ROW_BYTES = 6 * N_JOINTS * 8
_SCALAR_ROW_BYTES = _SCALAR_ROW.size


LOG_COLUMNS = (("t", "t_apply", "phase", "tau")
               + tuple(f"{g}{j + 1}" for g in ("q_d", "qd_d", "qdd_d", "tau_ff", "target", "q_obs")
                       for j in range(N_JOINTS))
               + ("compute_us", "ik_iterations"))
"""Column names of the controller log (:meth:`ControllerLog.columns`, the streamed file)."""
LOG_KINDS = tuple("Integer" if name in ("phase", "ik_iterations") else "Real" for name in LOG_COLUMNS)
"""Recorder kinds of :data:`LOG_COLUMNS` (phase and IK iterations are integers)."""
LOG_PREALLOCATE_ROWS = 1 << 22
"""Most rows a log preallocates (28 min at 400 us): address space only (``np.empty``: a page
becomes resident when a row is written into it), so a paced run never reallocates in its
loop and a streaming log (:meth:`ControllerLog.stream_to`) never holds more than its block."""
LOG_STREAM_BLOCK_ROWS = 2048
"""Rows a streaming log holds before it hands them to its sink (0.8 s at 400 us, 0.7 MB)."""


class ControllerLog:
    """Per-cycle record of the controller: in memory (address space reserved for up to
    :data:`LOG_PREALLOCATE_ROWS`, grows by doubling beyond), or streamed (:meth:`stream_to`): a
    block of :data:`LOG_STREAM_BLOCK_ROWS` rows handed to a recorder sink whenever it is
    full, so memory stays bounded for any length of run.

    Columns (one row per call of :meth:`Controller.step`): ``t`` (cycle time, s),
    ``t_apply`` (time the set-point acts, s), ``phase`` (:class:`Phase`), ``tau`` (trajectory
    time of the set-point, s), ``q_d``, ``qd_d``, ``qdd_d`` (6 each: rad, rad/s, rad/s^2),
    ``tau_ff`` (6, N m: the torque offset sent), ``target`` (6, rad: the target position
    sent; differs from q_d with drive set-point shaping), ``q_obs`` (6, rad: position
    actual seen this cycle), ``compute_us`` (NaN when not timed), ``ik_iterations``.
    """

    def __init__(self, capacity: int) -> None:
        self.rows = 0
        self.streamed_rows = 0
        self.sink = None
        n = min(max(int(capacity), 16), LOG_PREALLOCATE_ROWS)
        # rows are only ever read up to self.rows, all written: no fill, so untouched rows cost no memory
        self.scalars = np.empty((n, 6))  # t, t_apply, phase, tau, compute_us, ik_iterations
        self.joints = np.empty((n, 6, N_JOINTS))  # q_d, qd_d, qdd_d, tau_ff, target, q_obs
        self._bind()

    def _bind(self) -> None:
        self._joints_address = int(self.joints.ctypes.data)
        self._capacity = self.scalars.shape[0]
        self._pack_scalars = partial(_SCALAR_ROW.pack_into, memoryview(self.scalars).cast("B"))

    def _grow(self) -> None:
        if self.sink is not None:
            self._spill()
            return
        self.scalars = np.concatenate([self.scalars, np.full_like(self.scalars, np.nan)])
        self.joints = np.concatenate([self.joints, np.full_like(self.joints, np.nan)])
        self._bind()

    @property
    def total_rows(self) -> int:
        """Rows logged so far (streamed ones included)."""
        return self.streamed_rows + self.rows

    def block(self) -> np.ndarray:
        """The rows held in memory as one (rows, len(LOG_COLUMNS)) array (a copy)."""
        n = self.rows
        return np.concatenate([self.scalars[:n, :4], self.joints[:n].reshape(n, 6 * N_JOINTS),
                               self.scalars[:n, 4:6]], axis=1)

    def stream_to(self, sink, block_rows: int = LOG_STREAM_BLOCK_ROWS) -> None:
        """From now on hand the rows to ``sink`` (a recorder sink: ``open(columns, kinds)``,
        ``write(block)``, ``flush()``, ``close()``) in blocks of ``block_rows``; the rows held
        so far go first. The memory held shrinks to one block. :meth:`close_stream` ends it."""
        sink.open(list(LOG_COLUMNS), list(LOG_KINDS))
        if self.rows:
            sink.write(self.block())
        self.streamed_rows += self.rows
        self.rows = 0
        n = max(int(block_rows), 16)
        self.scalars = np.full((n, 6), np.nan)
        self.joints = np.full((n, 6, N_JOINTS), np.nan)
        self._bind()
        self.sink = sink

    def _spill(self) -> None:
        """Hand the rows held to the sink (then let it write to disk if its interval passed)."""
        if self.rows:
            self.sink.write(self.block())
            self.streamed_rows += self.rows
            self.rows = 0
        self.sink.flush()

    def flush(self) -> None:
        """Streaming: the rows held go to the sink now and the sink writes them to disk."""
        if self.sink is not None:
            if self.rows:
                self.sink.write(self.block())
                self.streamed_rows += self.rows
                self.rows = 0
            self.sink.flush()

    def close_stream(self) -> None:
        """Streaming: hand over the rows held and close the sink (again: no-op)."""
        sink = self.sink
        if sink is None:
            return
        try:
            if self.rows:
                sink.write(self.block())
                self.streamed_rows += self.rows
                self.rows = 0
        finally:
            self.sink = None
            sink.close()

    def next_joints_address(self) -> int:
        """Memory address of the next row's joint block (6 x 6 doubles: q_d, qd_d, qdd_d,
        tau_ff, target, q_obs) for a compiled writer; complete the row with :meth:`commit`."""
        if self.rows == self._capacity:
            self._grow()
        return self._joints_address + _JOINT_ROW_BYTES * self.rows

    def commit(self, t: float, t_apply: float, phase: int, tau: float, compute_us: float, iterations: int) -> None:
        """Complete the row whose joint block was written at :meth:`next_joints_address`."""
        k = self.rows
        self._pack_scalars(_SCALAR_ROW.size * k, t, t_apply, phase, tau, compute_us, iterations)
        self.rows = k + 1

    def append(self, t: float, t_apply: float, phase: int, tau: float, q: np.ndarray, qd: np.ndarray,
               qdd: np.ndarray, tau_ff: np.ndarray, target: np.ndarray, q_obs: np.ndarray, compute_us: float,
               iterations: int) -> None:
        """Add one row (values copied)."""
        k = self.rows
        if k == self.scalars.shape[0]:
            self._grow()
            k = self.rows
        row = self.scalars[k]
        row[0] = t
        row[1] = t_apply
        row[2] = phase
        row[3] = tau
        row[4] = compute_us
        row[5] = iterations
        block = self.joints[k]
        block[0] = q
        block[1] = qd
        block[2] = qdd
        block[3] = tau_ff
        block[4] = target
        block[5] = q_obs
        self.rows = k + 1

    def columns(self) -> dict[str, np.ndarray]:
        """Flat columns (copies) named :data:`LOG_COLUMNS` (``t, t_apply, phase, tau,
        q_d1..6, qd_d1..6, qdd_d1..6, tau_ff1..6, target1..6, q_obs1..6, compute_us,
        ik_iterations``) of the rows held in memory: all of them unless the log streams
        (then read the streamed file)."""
        n = self.rows
        s = self.scalars[:n]
        out = {"t": s[:, 0].copy(), "t_apply": s[:, 1].copy(), "phase": s[:, 2].copy(), "tau": s[:, 3].copy()}
        for g, name in enumerate(("q_d", "qd_d", "qdd_d", "tau_ff", "target", "q_obs")):
            for j in range(N_JOINTS):
                out[f"{name}{j + 1}"] = self.joints[:n, g, j].copy()
        out["compute_us"] = s[:, 4].copy()
        out["ik_iterations"] = s[:, 5].copy()
        return out


_HOOKS = ("run_cycle", "_compute", "_set_outputs", "_stop_condition", "_enable", "_stop", "_fast_step")


def overridden_hooks(cls: type) -> list[str]:
    """The cycle methods of :class:`Controller` that ``cls`` (a subclass) replaces: the
    compiled paths, which do those steps in C, are then switched off for it."""
    return [name for name in _HOOKS if getattr(cls, name) is not getattr(Controller, name)]


def start_configuration(reference: TcpTrajectory | JointTrajectory, model: pin.Model,
                        q_hint: np.ndarray | None = None) -> np.ndarray:
    """Joint angles (6,) rad of the reference's first sample: the IK solution of
    ``model`` nearest to ``q_hint`` for a Cartesian reference, else its first q."""
    if isinstance(reference, JointTrajectory):
        return reference.q[0].copy()
    ik = NumericIK(model)
    first = reference.sample(reference.t_start)
    if q_hint is None:
        return ik.solve_all(first.target)[0].copy()
    return ik.solve_nearest(first.target, np.asarray(q_hint, dtype=float)).copy()


class Controller:
    """The cyclic controller (see module docstring).

    Args:
        reference: a :class:`TcpTrajectory` (flange motion, IK each cycle) or a
            :class:`JointTrajectory` (joint motion, no IK).
        config: :class:`ControllerConfig`.
        kinematic_model: pinocchio model for the IK (default: the nominal URDF); pass
            ``robot.description.load_model(calibrated_urdf)`` for a calibrated arm.
        dynamics: the model of the feed-forward (default: the nominal
            :class:`RobotDynamics`); unused in mode ``standard``.
        q_hint: joint angles (6,) rad near the wanted IK branch of the start pose.
        drive_model: the drives' position-loop structure
            (:class:`controller.drive_compensation.DriveLoopModel`); in mode
            ``model_based`` the targets are shaped with it so that the drives' speed
            feed-forward and filter add no lag (:mod:`controller.drive_compensation`);
            None sends q_d unchanged.
        capacity: expected number of cycles (log preallocation).
    """

    def __init__(self, reference: TcpTrajectory | JointTrajectory, config: ControllerConfig | None = None, *,
                 kinematic_model: pin.Model | None = None, dynamics: RobotDynamics | None = None,
                 q_hint: np.ndarray | None = None, drive_model: DriveLoopModel | None = None,
                 capacity: int = 65536) -> None:
        from robot.description import load_model

        self.config = config or ControllerConfig()
        if self.config.mode == "model_based_elastic" and not hasattr(type(self), "_elastic_mode"):
            raise ControllerConfigError("controller mode 'model_based_elastic': build it with "
                                        "controller.elastic.ElasticController (or controller.elastic.make_controller)")
        if not isinstance(reference, (TcpTrajectory, JointTrajectory)):
            raise ControllerConfigError(
                f"reference: expected a controller.reference.TcpTrajectory or JointTrajectory, "
                f"got {type(reference).__name__}")
        self.reference = reference
        self.kinematic_model = kinematic_model if kinematic_model is not None else load_model()
        self.model_based = self.config.mode == "model_based"
        self.dynamics = dynamics if dynamics is not None else (RobotDynamics() if self.model_based else None)
        self.feedforward = FeedForward(self.dynamics) if self.dynamics is not None else None
        self.q_start = start_configuration(reference, self.kinematic_model, q_hint)
        self.q_start.setflags(write=False)
        self._ik = CartesianToJoint(self.kinematic_model) if isinstance(reference, TcpTrajectory) else None
        if self._ik is not None:
            self._ik.reset(self.q_start)
        self.kernel: CompiledCycle | None = None
        self.kernel_note = "not used (joint reference)" if self._ik is None else "disabled (config.compiled)"
        if self._ik is not None and self.config.compiled and native.mode() == "off":
            self.kernel_note = "disabled (COSIM_NATIVE=off)"
        elif self._ik is not None and self.config.compiled:
            try:
                self.kernel = CompiledCycle(self.kinematic_model, self.dynamics)
            except CompiledCycleError as exc:
                native.fallback("controller cycle kernel", exc)  # raises under COSIM_NATIVE=require
                self.kernel_note = f"unavailable, Python path used: {exc}"
            else:
                self.kernel_note = str(self.kernel.library_path)
                self.kernel.reset(self.q_start)
                self._packed_base = reference.packed.ctypes.data
                self._scratch = np.zeros(24)
                self._scratch_address = self._scratch.ctypes.data
                ik = self._ik.ik
                self._tol2, self._accept2 = ik._tol2, ik._accept2
                self._lower = (ik.lower - LIMIT_TOLERANCE).tolist()
                self._upper = (ik.upper + LIMIT_TOLERANCE).tolist()
        self.kernel_cycles = 0
        self.fallback_cycles = 0
        self._h = self.config.period_s  # time since the state the IK seed is predicted from (s)
        # samples between this cycle's target and the last one sent, as the drives see them: > 1
        # after a jump only when the bus interpolates the cycles skipped (set-point look-ahead;
        # controller.drive_compensation, "After a jump"); set by setup(info)
        self._shape_gap = 1
        self._bus_interpolates_jumps = False
        self._shaper = SetpointShaper(drive_model) if (drive_model is not None and self.model_based) else None
        if self._shaper is not None:
            if abs(drive_model.period_s - self.config.period_s) > 1e-12:
                raise ControllerConfigError(f"drive_model.period_s = {drive_model.period_s!r}: expected the "
                                            f"controller period {self.config.period_s!r} s")
            self._shaper.reset(self.q_start)
        self.timer = CycleTimer(self.config.compute_budget_s, capacity)
        self.log = ControllerLog(capacity)
        self.setpoints = Setpoints.zeros(N_JOINTS)
        self.setpoints.position[:] = self.q_start
        self.setpoints.controlword[:] = int(Command.DISABLE_VOLTAGE)
        # the contract's view of the same arrays (CSP; the bus carries position and torque offset)
        sp = self.setpoints
        self.output = ControllerOutput(controlword=sp.controlword, modes_of_operation=sp.modes_of_operation,
                                       target_position=sp.position, target_velocity=sp.target_velocity,
                                       velocity_offset=sp.velocity_offset, target_torque=sp.target_torque,
                                       torque_offset=sp.torque_offset)
        self._sequencers = [EnableSequencer() for _ in range(N_JOINTS)]
        self._zeros = np.zeros(N_JOINTS)
        self._tau_rest = np.zeros(N_JOINTS)
        if self.feedforward is not None:
            self._tau_rest[:] = self.feedforward.torque(self.q_start, self._zeros, self._zeros)
        self.phase = Phase.ENABLING
        self.stop_reason: str | None = None
        self.stopped_at_s: float | None = None
        self.enabled_at_s: float | None = None
        self.motion_start_cycle: int | None = None
        self._settle_until = 0
        self._first_cycle: int | None = None
        self._last_cycle: int | None = None
        self._hold = self.q_start.copy()
        self._q_d = self.q_start.copy()
        self._qd_d = np.zeros(N_JOINTS)
        self._qdd_d = np.zeros(N_JOINTS)
        # the compiled path's whole cycle (controller/fast_cycle.c) in one foreign call
        self._fast = self.kernel if (self.kernel is not None and self.config.fast_cycle) else None
        overridden = overridden_hooks(type(self))
        if overridden and self._fast is not None:
            # the whole-cycle C path would skip a subclass's own code: never bypass it
            self._fast = None
            self.kernel_note += f" (whole-cycle path off: {type(self).__name__} overrides {', '.join(overridden)})"
        self._observed_bound: tuple | None = None
        if self._fast is not None:
            self._fast.bind_fast_cycle(
                h=self.config.period_s, accept2=self._accept2, tol2=self._tol2, singular_tol=SINGULARITY_TOLERANCE,
                lower=np.array(self._lower), upper=np.array(self._upper), model_based=self.model_based,
                shaper=self._shaper, desired=(self._q_d, self._qd_d, self._qdd_d), setpoints=self.setpoints,
                enable_operation=int(Command.ENABLE_OPERATION))
            self._ref_t_start = reference.t_start
            self._ref_duration = reference.duration
        self._lead_time_s = self.config.lead_time_s
        self._period_s = self.config.period_s

    # ------------------------------------------------------------------ properties
    @property
    def mode(self) -> str:
        return self.config.mode

    @property
    def duration(self) -> float:
        """Length of the reference trajectory, s."""
        return self.reference.duration

    @property
    def motion_start_s(self) -> float | None:
        """Time (s) at which the drives apply trajectory time 0 (None before tracking)."""
        if self.motion_start_cycle is None:
            return None
        return (self.motion_start_cycle + self.config.lead_cycles) * self.config.period_s

    @property
    def finished(self) -> bool:
        """True once the last set-point of the trajectory has been computed."""
        return self.phase is Phase.FINISHED

    @property
    def stopped(self) -> bool:
        return self.phase is Phase.STOPPED

    def timing(self) -> TimingSummary:
        """Compute-time statistics of the cycles that computed a reference."""
        return self.timer.summary()

    def summary(self) -> dict:
        """JSON-ready state: mode, phase, times, stop reason, timing, config."""
        return {"mode": self.mode, "phase": self.phase.name.lower(), "reference": self.reference.kind,
                "trajectory_duration_s": self.duration, "enabled_at_s": self.enabled_at_s,
                "motion_start_s": self.motion_start_s, "stop_reason": self.stop_reason,
                "stopped_at_s": self.stopped_at_s, "q_start_rad": self.q_start.tolist(),
                "cycle_timing_us": self.timing().as_dict(), "config": asdict(self.config),
                "compiled_kernel": self.kernel_note, "kernel_cycles": self.kernel_cycles,
                "fallback_cycles": self.fallback_cycles}

    # ------------------------------------------------------------------ the contract
    def setup(self, info: ControllerInfo) -> None:
        """The cell's information (:class:`controller.contract.ControllerInfo`): checked
        against this controller's own configuration (cycle time, lead)."""
        if abs(info.period_s - self.config.period_s) > 1e-12:
            raise ControllerConfigError(f"controller period {self.config.period_s} s differs from the cell's bus "
                                        f"cycle {info.period_s} s")
        if info.lead_cycles != self.config.lead_cycles:
            raise ControllerConfigError(f"controller lead_cycles = {self.config.lead_cycles}: expected the cell's "
                                        f"1 + dead_time_cycles = {info.lead_cycles}")
        # with a set-point look-ahead the managing node interpolates the cycles a jump skips
        self._bus_interpolates_jumps = getattr(info, "lookahead_cycles", 0) > 0

    def step(self, inputs: ControllerInput) -> ControllerOutput:
        """One cycle through the contract (:class:`controller.contract.CellController`):
        :meth:`run_cycle` with the input's cycle, time and actual values; the returned
        :attr:`output` (mode 8, CSP: target position and torque offset) aliases
        :attr:`setpoints`."""
        self.run_cycle(inputs.cycle, inputs.time_s, inputs)
        return self.output

    def close(self) -> None:
        """Nothing to release (the log stays readable)."""

    def warm_up(self) -> None:
        """Run the Python-path cycle's numerics once (reference sample, IK, derivatives,
        feed-forward) at the start of the reference and put everything back: its first call
        in a fresh process pays for lazy set-up and cold caches, which a paced controller
        must not pay inside a cycle. Changes nothing the cycles compute."""
        ik = self._ik
        ref = self.reference
        sample = ref.sample(ref.t_start)
        if ik is not None:
            saved = (ik.q.copy(), ik.qd.copy(), ik.qdd.copy(), ik._have_seed, ik.last_iterations,
                     ik.ik.last_iterations)
            try:
                ik.set_state(self.q_start, 0.0, 0.0)
                q, qd, qdd = ik.solve(sample.target, sample.twist, sample.acceleration, self.config.period_s)
                ik.ik.solve(sample.target, self.q_start)
            finally:
                ik.q[:], ik.qd[:], ik.qdd[:] = saved[0], saved[1], saved[2]
                ik._have_seed, ik.last_iterations, ik.ik.last_iterations = saved[3], saved[4], saved[5]
        else:
            q, qd, qdd = sample.q, sample.qd, sample.qdd
        if self.feedforward is not None:
            self.feedforward.torque(np.array(q), np.array(qd), np.array(qdd))

    # ------------------------------------------------------------------ the cycle
    def run_cycle(self, cycle: int, t: float, observed: ObservedActuals | ControllerInput) -> Setpoints:
        """One controller cycle at time ``t`` (s) of cycle number ``cycle``: read the actual
        values, return the set-points for the next cycle (a reused object)."""
        started = _perf_counter_ns()
        cpu_started = _thread_time_ns()
        last = self._last_cycle
        # the time since the state the next IK seed is predicted from: one period, or more
        # after cycles this controller did not run (a split controller that fell behind)
        if last is not None and cycle - last == 1:  # the usual cycle: the expressions below give these
            self._h = self._period_s
            self._shape_gap = 1
        else:
            self._h = self.config.period_s if (last is None or cycle - last <= 1) \
                else (cycle - last) * self.config.period_s
            self._shape_gap = cycle - last if (self._bus_interpolates_jumps and last is not None and cycle - last > 1) \
                else 1
        if self._fast is not None and self.phase in _COMPUTING:
            done = self._fast_step(cycle, t, observed, started, cpu_started)
            if done:
                return self.setpoints
        if self._first_cycle is None:
            self._first_cycle = cycle
        self._last_cycle = cycle
        cfg = self.config
        sp = self.setpoints
        phase = self.phase
        if phase is not Phase.STOPPED:
            problem = self._stop_condition(observed, phase)
            if problem is not None:
                self._stop(t, problem, observed)
                phase = self.phase
        timed = False
        iterations = 0
        tau = math.nan
        if phase is Phase.ENABLING:
            self._enable(observed, sp)
            if all(observed.fresh.tolist()) and all((int(s) & 0x6F) == 0x27 for s in observed.statusword.tolist()):
                self.phase = Phase.SETTLING
                self.enabled_at_s = t
                self._settle_until = cycle + cfg.settle_cycles
            elif t - (self._first_cycle * cfg.period_s) > cfg.enable_timeout_s:
                states = [decode_statusword(int(s)).value for s in observed.statusword.tolist()]
                self._stop(t, f"the drives did not reach Operation enabled within {cfg.enable_timeout_s} s "
                              f"(states {states})", observed)
        if self.phase in (Phase.SETTLING, Phase.TRACKING, Phase.FINISHED):
            if self.phase is Phase.SETTLING and cycle >= self._settle_until:
                self.phase = Phase.TRACKING
                self.motion_start_cycle = cycle
            tau = 0.0 if self.phase is Phase.SETTLING else (cycle - self.motion_start_cycle) * cfg.period_s
            try:
                iterations = self._compute(tau, sp)
            except SingularConfigurationError as exc:
                self._stop(t, str(exc), observed)
            else:
                timed = True
                if self.phase is Phase.TRACKING and tau >= self.reference.duration:
                    self.phase = Phase.FINISHED
                sp.controlword[:] = int(Command.ENABLE_OPERATION)
        if self.phase is Phase.STOPPED:
            sp.controlword[:] = int(Command.QUICK_STOP)
            sp.position[:] = self._hold
            sp.torque_offset[:] = 0.0
        elapsed = time.perf_counter_ns() - started
        if timed:
            self.timer.record(elapsed, time.thread_time_ns() - cpu_started)
        self.log.append(t, t + cfg.lead_time_s, int(self.phase), tau, self._q_d, self._qd_d, self._qdd_d,
                        sp.torque_offset, sp.position, observed.position, elapsed * 1e-3 if timed else math.nan,
                        iterations)
        return sp

    def _fast_step(self, cycle: int, t: float, observed: ObservedActuals, started: int, cpu_started: int) -> bool:
        """A settling/tracking/finished cycle through the compiled whole cycle
        (``fast_cycle.c``): the same set-points, state, log row and timing as the Python
        path. False when the Python path must take this cycle (a drive not in Operation
        enabled or a node fault, a kernel result failing a check, unusual observed
        arrays); nothing has changed then."""
        bound = self._observed_bound
        if bound is None or observed.position is not bound[0] or observed.statusword is not bound[1] \
                or observed.node_fault is not bound[2]:
            if not self._bind_fast_observed(observed):
                return False
        phase = self.phase
        if phase is Phase.SETTLING:
            tau = 0.0
        else:
            tau = (cycle - self.motion_start_cycle) * self._period_s
        ref = self.reference
        k, offset = ref.grid.locate(self._ref_t_start + tau)
        if offset == 0.0:
            address = self._packed_base + 192 * k
        else:
            ref.packed_sample(self._ref_t_start + tau, self._scratch)
            address = self._scratch_address
        log = self.log
        row = log.rows  # the log row the compiled cycle writes (ControllerLog.next_joints_address)
        if row == log._capacity:
            log._grow()
            row = log.rows
        joints = log._joints_address + _JOINT_ROW_BYTES * row
        h = self._h
        fast = self._fast
        if self._shape_gap != 1 and self._shaper is not None:
            # a jump the bus interpolates: shape over the samples in between (drive_compensation)
            self._set_shaper_gains(fast.plan.out, self._shape_gap)
            fast.h[0] = h
            status = fast.fast_cycle(address, joints)
            fast.h[0] = self._period_s
            self._set_shaper_gains(fast.plan.out, 1)
        elif h != self._period_s:  # a jumped cycle: predict the seed over the cycles not run
            fast.h[0] = h
            status = fast.fast_cycle(address, joints)
            fast.h[0] = self._period_s
        else:
            status = fast.fast_cycle(address, joints)
        if status == FAST_STOP_CHECK or status == FAST_REJECTED:
            return False
        self._fast_step_done(cycle, t, phase, tau, self._ref_duration, started, cpu_started, status)
        return True

    def _set_shaper_gains(self, plan, gap: int) -> None:
        """Write the set-point shaper's gains for a target ``gap`` samples after the previous one
        (:meth:`SetpointShaper.gains`; 1 = its own) into ``plan.g_over_t`` / ``plan.denominator``,
        the arrays a compiled cycle reads."""
        g_over_t, denominator = self._shaper.gains(gap)
        plan.g_over_t[:] = np.broadcast_to(g_over_t, (N_JOINTS,)).tolist()
        plan.denominator[:] = np.broadcast_to(denominator, (N_JOINTS,)).tolist()

    def _bind_fast_observed(self, observed: ObservedActuals) -> bool:
        """Point the compiled cycle (``self._fast``) at ``observed``'s arrays when they are not
        the ones bound; False when they do not have the layout it reads."""
        bound = self._observed_bound
        if bound is None or observed.position is not bound[0] or observed.statusword is not bound[1] \
                or observed.node_fault is not bound[2]:
            try:
                self._fast.bind_observed(observed.statusword, observed.node_fault, observed.position)
            except ValueError:
                return False
            self._observed_bound = (observed.position, observed.statusword, observed.node_fault)
        return True

    def _fast_step_done(self, cycle: int, t: float, phase: Phase, tau: float, duration: float, started: int,
                        cpu_started: int, iterations: int) -> None:
        """After a cycle the compiled path took (the log row written): the phase changes of the
        Python path (settled, reference of ``duration`` s done), the cycle's timing and the log."""
        self._last_cycle = cycle
        self.kernel_cycles += 1
        if phase is Phase.TRACKING:
            if tau >= duration:
                phase = self.phase = Phase.FINISHED
        elif phase is Phase.SETTLING and cycle >= self._settle_until:
            phase = self.phase = Phase.TRACKING
            self.motion_start_cycle = cycle
            if tau >= duration:
                phase = self.phase = Phase.FINISHED
        elapsed = _perf_counter_ns() - started
        self.timer.record(elapsed, _thread_time_ns() - cpu_started)
        # the row's scalars (ControllerLog.commit inlined: phase, an IntEnum, packs as its value)
        log = self.log
        k = log.rows
        log._pack_scalars(_SCALAR_ROW_BYTES * k, t, t + self._lead_time_s, phase, tau, elapsed * 1e-3, iterations)
        log.rows = k + 1

    def _enable(self, observed: ObservedActuals, sp: Setpoints) -> None:
        """Enable sequence: next controlword per drive, hold the start configuration."""
        fresh = observed.fresh.tolist()
        for i, status in enumerate(observed.statusword.tolist()):
            if fresh[i]:
                sp.controlword[i] = self._sequencers[i].next_controlword(int(status))
        sp.position[:] = self.q_start
        sp.torque_offset[:] = self._tau_rest if self.model_based else 0.0

    def _compute(self, tau: float, sp: Setpoints) -> int:
        """Desired joint motion and torque offset at trajectory time ``tau``; returns IK steps."""
        ref = self.reference
        kernel = self.kernel
        if kernel is not None:
            t = ref.t_start + tau
            k, offset = ref.grid.locate(t)
            if offset == 0.0:
                address = self._packed_base + 192 * k
            else:
                ref.packed_sample(t, self._scratch)
                address = self._scratch_address
            h = self._h
            kernel.run(address, h)
            accepted = self._kernel_accepts()
            if not accepted and h != self.config.period_s:
                accepted = self._kernel_newton(address)
            if h != self.config.period_s:
                kernel.h[0] = self.config.period_s  # the whole-cycle path reads h from there
            if accepted:
                e2 = kernel.info.tolist()[0]
                kernel.accept()
                self.kernel_cycles += 1
                state = kernel.state
                q, qd, qdd = state[:6], state[6:12], state[12:]
                self._set_outputs(sp, q, qd, qdd, kernel.tau if self.model_based else None)
                return 0 if e2 <= self._tol2 else 1
            # the Python path decides (more Newton steps, fallback branches, singularity)
            self.fallback_cycles += 1
            self._ik.set_state(kernel.state[:6], kernel.state[6:12], kernel.state[12:])
            sample = ref.sample(t)
            q, qd, qdd = self._ik.solve(sample.target, sample.twist, sample.acceleration, h)
            kernel.set_state(q, qd, qdd)
            torque = self.feedforward.torque(q, qd, qdd) if self.model_based else None
            self._set_outputs(sp, q, qd, qdd, torque)
            return self._ik.last_iterations
        if self._ik is not None:
            sample = ref.sample(ref.t_start + tau)
            q, qd, qdd = self._ik.solve(sample.target, sample.twist, sample.acceleration, self._h)
            iterations = self._ik.last_iterations
        else:
            sample = ref.sample(ref.t_start + tau)
            q, qd, qdd = sample.q, sample.qd, sample.qdd
            iterations = 0
        self._set_outputs(sp, q, qd, qdd, self.feedforward.torque(q, qd, qdd) if self.model_based else None)
        return iterations

    def _kernel_accepts(self) -> bool:
        """The kernel's last result passes the acceptance checks (converged Newton step,
        not singular, inside the joint limits)."""
        kernel = self.kernel
        e2, s2, hadamard = kernel.info.tolist()
        return (e2 <= self._accept2 and s2 <= self._accept2 and hadamard >= SINGULARITY_TOLERANCE
                and all(lo <= x <= hi for lo, x, hi in zip(self._lower, kernel.result[:6].tolist(), self._upper)))

    def _kernel_newton(self, address: int) -> bool:
        """After a jumped cycle whose one Newton step did not converge: further Newton steps
        through the kernel (``h = 0``: the seed is the last result; qd, qdd follow at each
        new q), at most NumericIK's ``newton_iterations``, each a few µs, instead of the
        Python-path IK. True with an accepted result in the kernel; False with the state
        untouched (the Python path decides)."""
        kernel = self.kernel
        saved = kernel.state.copy()
        result = kernel.result
        for _ in range(self._ik.ik.newton_iterations):
            e2, s2, _ = kernel.info.tolist()
            if not (math.isfinite(e2) and math.isfinite(s2)) or s2 > self._ik.ik._max_step2:
                break
            kernel.state[:] = result
            kernel.run(address, 0.0)
            if self._kernel_accepts():
                kernel.state[:] = saved
                return True
        kernel.state[:] = saved
        return False

    def _set_outputs(self, sp: Setpoints, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                     torque: np.ndarray | None) -> None:
        """Keep the desired motion, write target position and torque offset."""
        self._q_d[:] = q
        self._qd_d[:] = qd
        self._qdd_d[:] = qdd
        if self.model_based:
            sp.torque_offset[:] = torque
            sp.position[:] = q if self._shaper is None else self._shaper.shape(q, qd, qdd, self._shape_gap)
        else:
            sp.torque_offset[:] = 0.0
            sp.position[:] = q

    def _stop_condition(self, observed: ObservedActuals, phase: Phase) -> str | None:
        """Why motion must stop now (None: no reason)."""
        faults = observed.node_fault.tolist()
        if phase is not Phase.ENABLING and not any(faults) and all(
                (s & 0x6F) == 0x27 for s in observed.statusword.tolist()):
            return None  # fast path: every drive in Operation enabled
        if any(faults):
            nodes = [i + 1 for i, f in enumerate(faults) if f]
            return f"fieldbus node fault (threshold counter reached) on node(s) {nodes}"
        if phase is Phase.ENABLING:
            return None  # the enable sequence resets faults itself
        fresh = observed.fresh.tolist()
        for i, status in enumerate(observed.statusword.tolist()):
            if not fresh[i]:
                continue  # a missed PRes: values held; the threshold counter decides
            state = decode_statusword(int(status))
            if state in STOP_STATES:
                code = int(observed.error_code[i])
                extra = f", error code 0x{code:04X}" if code else ""
                return f"drive {i + 1} reports {STOP_STATES[state]}{extra}"
        return None

    def _stop(self, t: float, reason: str, observed: ObservedActuals) -> None:
        self.phase = Phase.STOPPED
        self.stop_reason = reason
        self.stopped_at_s = t
        # hold where the drives are (the last set-point where no fresh value arrived)
        self._hold[:] = np.where(observed.fresh, observed.position, self.setpoints.position)
        self._q_d[:] = self._hold
        self._qd_d[:] = 0.0
        self._qdd_d[:] = 0.0
