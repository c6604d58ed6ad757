"""The controller contract: what a cell controller is given, what it returns, and when.

Every controller of the robot cell - the built-in ``standard`` / ``standard_speed_ff`` /
``model_based`` modes (:class:`controller.Controller`), a user's Python class named in a
scenario (``[controller] class = "my_ctrl.py:MyController"``) and a controller FMU
(:class:`controller.fmu_controller.FmuController`) - satisfies :class:`CellController`
and is driven by the cell through it, the same way. Data crossing it is plain: numpy
arrays of shape ``(n_joints,)`` (joint 1 first) in SI units, the CiA 402 words as
integers, like ``fieldbus.Setpoints`` and ruckig's input/output parameters.

When it is called
-----------------
Lifecycle: ``setup(info)`` once before the first cycle (:class:`ControllerInfo`: cycle
time, dead time, joint limits, the reference to track, the start pose, the nominal models,
the ``[controller.parameters]`` table); then ``step(inputs)`` once per bus cycle; then
``close()`` once when the run ends for whatever reason (end of run, failure, signal).

Cycle ``k`` (``t_k = t0 + k T``, T = ``info.period_s``, 400 µs in the paper): at the
start of cycle (SoC) the drives latch their actual values; the PRes frames carry them to
the managing node; then ``step`` is called with :class:`ControllerInput` - the values
latched at ``t_k`` as the bus delivered them (quantised by the CiA 402 scaling; values of
a node whose PRes was lost are held with ``fresh`` False). What ``step`` returns
(:class:`ControllerOutput`) goes into the PReqs of cycle ``k + 1`` and the drives apply it
from ``t_{k+1+d}`` where ``d = info.dead_time_cycles``; so an output computed in cycle ``k``
acts ``info.lead_cycles = 1 + d`` cycles after ``t_k`` (``1 + d + lookahead`` with a set-point
look-ahead on the bus): evaluate your reference there.

What "late" means
-----------------
In simulated time (``cosim run`` without ``--realtime``) the controller is never late:
its compute time is measured, not waited for. Under ``--realtime`` / ``--split`` the cell
runs on the wall clock: a cycle whose frames cannot all be on the bus by the next SoC is
an *overrun* (``[realtime] overrun_policy``, :mod:`cosim.execution.timing.policy`); the output the
controller computed in the previous cycle then does not go out as computed:
``hold`` / ``skip`` send the previous (or extrapolated) set-points instead - the next
``step`` sees ``previous_output_late`` True; ``lost_frame`` drops the cycle's PReqs as
lost frames (the POWERLINK threshold counters count them) - the next ``step`` sees
``previous_output_lost`` True. A controller whose own compute exceeds its share of the
cycle (``info.compute_budget_s``) makes the next cycle late.

Modes of operation (CiA 402 0x6060, per drive)
----------------------------------------------
``8`` cyclic synchronous position (CSP: ``target_position`` plus ``velocity_offset`` and
``torque_offset`` as feed-forward), ``9`` cyclic synchronous velocity (CSV:
``target_velocity`` plus ``velocity_offset`` and ``torque_offset``), ``10`` cyclic
synchronous torque (CST: ``target_torque`` plus ``torque_offset``). The drive shows the
mode it runs in ``modes_of_operation_display`` (0x6061): a switch takes effect when the
drive accepts it (CiA 402), so read the display before relying on a new mode. A value
outside :data:`MODES_OF_OPERATION` stops the run with an error.

Stopping
--------
A controller may stop commanding motion (a drive fault, a node fault, its own reason):
it sets the attributes ``stop_reason`` (str) and ``stopped_at_s`` (s) - optional
attributes the cell reads - and then commands a quick stop; the cell ends the run
``stop_grace_s`` (0.5 s) later with that reason. A controller that raises or returns
a non-finite number ends the run at once: status failed, the reason and
``stopped_at_s`` in summary.json, the time series up to that cycle on disk.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any, Protocol, runtime_checkable

import numpy as np

from robot.joints import N_JOINTS

DEFAULT_COMPUTE_BUDGET_S = 100e-6
"""The controller's default share of the bus cycle, s: a quarter of the paper's 400 µs cycle
(section 2.3.2), the rest left to the bus and the drives; a choice of this testbed, not a
figure of the paper (``[controller] compute_budget`` sets it per scenario)."""

MODE_CSP = 8
"""Cyclic synchronous position (CiA 402 modes of operation 8)."""
MODE_CSV = 9
"""Cyclic synchronous velocity (CiA 402 modes of operation 9)."""
MODE_CST = 10
"""Cyclic synchronous torque (CiA 402 modes of operation 10)."""
MODES_OF_OPERATION: tuple[int, ...] = (MODE_CSP, MODE_CSV, MODE_CST)
"""The modes of operation a cell controller may command."""


@dataclass(frozen=True)
class ControllerInfo:
    """What the cell tells a controller once, at ``setup`` (SI units, arrays (n_joints,)).

    period_s: the bus cycle T, s. n_joints: number of drives (6).
    dead_time_cycles: cycles between the PReq carrying an output and the drive applying it.
    lookahead_cycles: the bus's set-point look-ahead (``[fieldbus] setpoint_lookahead``, 0 by
        default): each output goes out that many cycles later as the set-point due next,
        and before that in as many PReqs as a look-ahead entry the drives keep for a lost
        PReq. A new controlword or mode of operation goes out at once (the drives' look-ahead
        is replaced), so the enable sequence and a stop are not delayed. With a set-point
        buffer in the drives (``[fieldbus] setpoint_buffer`` = D) it is D: the drives hold up
        to D planned set-points and a lost PReq run of up to D cycles costs nothing.
    lead_cycles: ``1 + dead_time_cycles + lookahead_cycles``: an output computed at ``t_k``
        acts from ``t_k + lead_cycles * period_s``.
    compute_budget_s: the controller's share of the cycle, s (compute above it is a
        deadline miss; under ``--realtime`` it makes the next cycle late).
    position_min/position_max: joint position limits, rad; velocity_max: rad/s;
        torque_max: joint torque limit, N·m (all from the URDF, robot/rx130l_params.toml);
        rated_torque: the drives' rated joint torque, N·m (0.1 % steps of torque actual).
    q_start: the joint angles (rad) the arm starts at rest in.
    reference: the motion to track: a :class:`controller.reference.TcpTrajectory`
        (flange pose, ``sample(t)``) or :class:`controller.reference.JointTrajectory`
        (``sample(t).q/qd/qdd``), trajectory time from ``reference.t_start``;
        None when the job has none.
    kinematic_model: the controller's pinocchio model (nominal URDF or a calibrated one).
    dynamics: the controller's :class:`robot.dynamics.RobotDynamics` (nominal model,
        with the declared payload), or None.
    parameters: the scenario's ``[controller.parameters]`` table (SI numbers as given).
    label: the run's name (e.g. ``"model_based"`` or the user controller's label).
    source: the scenario file, for messages.
    asynchronous: SDO and NMT in the bus's asynchronous slot, optional (None where the bus has
        none): a :class:`fieldbus.asynchronous.AsyncPort` with ``sdo_read(node, index,
        subindex)``, ``sdo_write(node, index, subindex, value)`` and ``nmt(node, command)``,
        each returning a result whose ``answered_cycle``, ``answer`` / ``abort`` are filled in
        one cycle or more later (docs/how-to/sdo_nmt.md). Values in the objects' bus units.
    """

    period_s: float
    n_joints: int = N_JOINTS
    dead_time_cycles: int = 1
    lookahead_cycles: int = 0
    compute_budget_s: float = DEFAULT_COMPUTE_BUDGET_S
    position_min: np.ndarray | None = None
    position_max: np.ndarray | None = None
    velocity_max: np.ndarray | None = None
    torque_max: np.ndarray | None = None
    rated_torque: np.ndarray | None = None
    q_start: np.ndarray | None = None
    reference: Any = None
    kinematic_model: Any = None
    dynamics: Any = None
    parameters: Mapping[str, Any] = field(default_factory=dict)
    label: str = ""
    source: str = ""
    asynchronous: Any = None

    @property
    def lead_cycles(self) -> int:
        return 1 + self.dead_time_cycles + self.lookahead_cycles


@dataclass(slots=True)
class ControllerInput:
    """What a controller is given each cycle (arrays are reused by the cell: copy what you keep).

    cycle: the cycle number k (0 at the first cycle of the run).
    time_s: ``t_k``, s: when the values below were latched (SoC of cycle k).
    statusword: CiA 402 statusword (0x6041) per drive.
    modes_of_operation_display: the mode each drive runs (0x6061: 8, 9 or 10).
    position: position actual (0x6064), rad, joint side.
    velocity: velocity actual (0x606C), rad/s, joint side.
    torque: torque actual (0x6077), N·m, joint side (the drive's own estimate from its current).
    error_code: CiA 402 error code (0x603F) per drive.
    fresh: True where the drive's PRes arrived valid this cycle (else the values are held).
    node_fault: True where the managing node's POWERLINK threshold counter for the drive
        tripped: the controller must stop commanding motion.
    previous_output_late: the output returned in the previous cycle did not go out as
        computed (overrun, policy ``hold``/``skip``: the drives got a substitute).
    previous_output_lost: the output returned in the previous cycle was lost (overrun,
        policy ``lost_frame``: its PReqs counted as lost frames).
    """

    cycle: int
    time_s: float
    statusword: np.ndarray
    modes_of_operation_display: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    torque: np.ndarray
    error_code: np.ndarray
    fresh: np.ndarray
    node_fault: np.ndarray
    previous_output_late: bool = False
    previous_output_lost: bool = False

    @classmethod
    def zeros(cls, n_joints: int = N_JOINTS) -> "ControllerInput":
        f = np.zeros
        return cls(0, 0.0, f(n_joints, np.int64), np.full(n_joints, MODE_CSP, np.int64), f(n_joints), f(n_joints),
                   f(n_joints), f(n_joints, np.int64), np.ones(n_joints, bool), f(n_joints, bool))


OUTPUT_REAL = ("target_position", "target_velocity", "velocity_offset", "target_torque", "torque_offset")
"""The real-valued fields of :class:`ControllerOutput` (rad, rad/s, rad/s, N·m, N·m)."""
OUTPUT_INTEGER = ("controlword", "modes_of_operation")
"""The integer fields of :class:`ControllerOutput`."""


@dataclass(slots=True)
class ControllerOutput:
    """What a controller returns each cycle, per drive (arrays (n_joints,), SI units).

    controlword: CiA 402 controlword (0x6040), e.g. 0x000F enable operation, 0x0002 quick stop.
    modes_of_operation: 0x6060 per drive: 8 (CSP), 9 (CSV) or 10 (CST).
    target_position: 0x607A, rad (used in mode 8).
    target_velocity: 0x60FF, rad/s (used in mode 9).
    velocity_offset: 0x60B1, rad/s (speed feed-forward in modes 8 and 9).
    target_torque: 0x6071, N·m (used in mode 10).
    torque_offset: 0x60B2, N·m (torque feed-forward in modes 8, 9 and 10).

    A controller may return the same object every cycle (the cell reads it before the next
    ``step``); :meth:`zeros` gives one with the right types.
    """

    controlword: np.ndarray
    modes_of_operation: np.ndarray
    target_position: np.ndarray
    target_velocity: np.ndarray
    velocity_offset: np.ndarray
    target_torque: np.ndarray
    torque_offset: np.ndarray

    @classmethod
    def zeros(cls, n_joints: int = N_JOINTS, mode: int = MODE_CSP) -> "ControllerOutput":
        """Controlword 0 (disable voltage), the given mode, every set-point 0."""
        return cls(np.zeros(n_joints, np.int64), np.full(n_joints, mode, np.int64),
                   *(np.zeros(n_joints) for _ in OUTPUT_REAL))

    def copy(self) -> "ControllerOutput":
        return type(self)(*(np.array(getattr(self, f.name), copy=True) for f in fields(self)))


@runtime_checkable
class CellController(Protocol):
    """A controller of the robot cell (see the module docstring for timing and units).

    Optional attributes the cell reads when present: ``stop_reason`` (str or None) and
    ``stopped_at_s`` (s or None) - the controller stopped commanding motion;
    ``motion_start_s`` (s) - when the drives apply trajectory time 0 of
    ``info.reference`` (the evaluation aligns the reference with it); ``summary()`` -
    a JSON-ready dict put in summary.json.
    """

    def setup(self, info: ControllerInfo) -> None:
        """Called once before the first cycle."""

    def step(self, inputs: ControllerInput) -> ControllerOutput:
        """Called once per bus cycle, after the cycle's PRes frames; returns the next output."""

    def close(self) -> None:
        """Called once when the run ends (also after a failure)."""


CONTRACT_METHODS = ("setup", "step", "close")
"""The methods a controller class must have (callables)."""


def contract_problems(cls: type) -> list[str]:
    """What keeps ``cls`` from satisfying :class:`CellController` (empty: nothing)."""
    missing = [name for name in CONTRACT_METHODS if not callable(getattr(cls, name, None))]
    return [f"no method {name}()" for name in missing]
