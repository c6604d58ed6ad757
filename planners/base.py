"""The planner interface and the plain-data problem, limit and result types.

A planner is a small class with a ``name`` and a ``plan(problem) -> PlanResult``
method. Every planner of this package (own CP/PtP, TOPP-RA, Ruckig) implements it,
so a user can add their own planner and compare it in the same scenario:

>>> class MyPlanner:                 # satisfies the Planner protocol (inheriting is optional)
...     name = "mine"
...     kind = "cp"
...     def plan(self, problem):
...         ...                      # build a Trajectory
...         return PlanResult(status=PlanStatus.FEASIBLE, trajectory=traj, solve_time_s=dt)

Units: SI, joint side (rad, rad/s, rad/s^2, rad/s^3, N m, N m/s).
"""
from __future__ import annotations

import abc
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np

from planners.limits import LIMIT_KINDS, N_JOINTS, JointLimits, PlannerInputError, _as_joint_vector  # noqa: F401
from planners.trajectory import Trajectory

FrictionModel = Literal["full", "coulomb", "none"]


class PlanStatus(str, Enum):
    """Outcome of a planning request.

    OPTIMAL: a solver certified optimality (for IPOPT only "Solve_Succeeded").
    FEASIBLE: a trajectory is returned that the planner believes respects the limits,
        but optimality is not certified (e.g. TOPP-RA's greedy pass, IPOPT "Solved To
        Acceptable Level", Ruckig).
    INFEASIBLE: the request cannot be met (e.g. a boundary state outside the limits,
        TOPP-RA found no controllable path).
    FAILED: the solver stopped without a usable answer (iteration limit, restoration
        failure, exception).
    """

    OPTIMAL = "optimal"
    FEASIBLE = "feasible"
    INFEASIBLE = "infeasible"
    FAILED = "failed"

    @property
    def has_trajectory(self) -> bool:
        return self in (PlanStatus.OPTIMAL, PlanStatus.FEASIBLE)


def _check_cost_and_friction(problem: str, k1: float, k2: float, friction: str) -> None:
    """PlannerInputError naming ``problem`` unless friction is a FrictionModel and the cost weights are usable."""
    if friction not in ("full", "coulomb", "none"):
        raise PlannerInputError(f"{problem}.friction: expected 'full', 'coulomb' or 'none', got {friction!r}")
    if not (k1 >= 0.0 and k2 >= 0.0 and k1 + k2 > 0.0):
        raise PlannerInputError(f"{problem}: k1, k2 must be >= 0 and not both 0, got k1={k1}, k2={k2}")


@dataclass(frozen=True)
class CPProblem:
    """A continuous-path request: move along a fixed joint path q(sigma), sigma in [0, 1].

    path: a ``planners.paths.JointPath`` (joint positions and sigma-derivatives).
    limits: the joint limits to respect.
    dynamics: the ``robot.dynamics.RobotDynamics`` that turns motion into torques
        (``None``: the nominal robot).
    k1, k2: weights of the cost  integral (k1 + k2 tau^T tau) dt  (eq. 36);
        k1 = 1, k2 = 0 is time-optimal.
    friction: which friction terms enter the torque: "full" (Coulomb + viscous),
        "coulomb" (Coulomb only: exactly representable in TOPP-RA) or "none".
    n_intervals: number of sigma intervals of the transcription.
    """

    path: Any
    limits: JointLimits
    dynamics: Any = None
    k1: float = 1.0
    k2: float = 0.0
    friction: FrictionModel = "full"
    n_intervals: int = 200

    def __post_init__(self) -> None:
        _check_cost_and_friction("CPProblem", self.k1, self.k2, self.friction)
        if int(self.n_intervals) < 2:
            raise PlannerInputError(f"CPProblem.n_intervals: expected an integer >= 2, got {self.n_intervals!r}")


@dataclass(frozen=True)
class PtPProblem:
    """A point-to-point request: from (q0, qd0) to (qe, qde), free path and final time.

    Joint vectors of shape (6,) in rad and rad/s; the other fields as in CPProblem.
    """

    q0: np.ndarray
    qe: np.ndarray
    limits: JointLimits
    qd0: np.ndarray = field(default_factory=lambda: np.zeros(N_JOINTS))
    qde: np.ndarray = field(default_factory=lambda: np.zeros(N_JOINTS))
    dynamics: Any = None
    k1: float = 1.0
    k2: float = 0.0
    friction: FrictionModel = "full"
    n_intervals: int = 100

    def __post_init__(self) -> None:
        for name in ("q0", "qe", "qd0", "qde"):
            object.__setattr__(self, name, _as_joint_vector(getattr(self, name), f"PtPProblem.{name}", allow_inf=False))
        _check_cost_and_friction("PtPProblem", self.k1, self.k2, self.friction)


@dataclass
class PlanResult:
    """What a planner returns.

    status: see PlanStatus; ``trajectory`` is None unless status.has_trajectory.
    solve_time_s: wall time of the solver call(s) [s] (problem building excluded;
        see ``build_time_s``).
    message: the solver's own status text (e.g. IPOPT's "Solve_Succeeded").
    info: planner-specific extras (iterations, cost, grid values, ...).
    """

    planner: str
    status: PlanStatus
    trajectory: Trajectory | None
    solve_time_s: float
    build_time_s: float = 0.0
    message: str = ""
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status.has_trajectory and self.trajectory is not None


@runtime_checkable
class Planner(Protocol):
    """The planner contract: ``name``, ``kind`` and ``plan(problem) -> PlanResult``.

    A ``typing.Protocol``: a user's planner satisfies it by having these three members,
    with or without inheriting from ``Planner`` (inheriting gives the defaults below and
    makes a missing ``plan`` an error at instantiation). Contract:

    * ``name`` (str): a short identifier (letters, digits, ``_ - .``) unique in a scenario;
      the scenario's results use it (``trajectory_<name>.csv``, ``planners.<name>``).
    * ``kind`` ("cp" or "ptp"): which problem ``plan`` accepts — a :class:`CPProblem`
      (a fixed joint path q(sigma), find the time law) or a :class:`PtPProblem` (start
      and end state, free path).
    * ``plan(problem)``: returns a :class:`PlanResult`; its ``trajectory`` is a
      :class:`planners.trajectory.Trajectory` (t strictly increasing, sampled at 1 ms or
      finer; q, qd, qdd, tau of shape (n, 6) in rad, rad/s, rad/s^2, N m) when
      ``status`` is OPTIMAL or FEASIBLE, else None. A planner never raises for a request
      that simply cannot be met: it returns status INFEASIBLE or FAILED with a
      ``message``. It raises :class:`PlannerInputError` (a ValueError) for malformed input.
      ``plan`` is called once per scenario entry, before the cell runs (never inside
      the 400 us cycle), so it may take seconds.

    A scenario names a user planner in ``[planners] run`` as ``"file.py:MyPlanner"`` or
    ``"package.module:MyPlanner"``; it is instantiated with the keyword arguments of
    ``[planners.parameters."<that entry>"]`` (docs/how-to/own_controller.md).
    """

    name: str = "planner"
    kind: Literal["cp", "ptp"] = "cp"

    @abc.abstractmethod
    def plan(self, problem: CPProblem | PtPProblem) -> PlanResult:
        """Plan a trajectory for ``problem``."""
