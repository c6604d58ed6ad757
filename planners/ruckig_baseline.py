"""Ruckig baselines for point-to-point motion: kinematic limits as given, and torque-feasible.

* :class:`RuckigPlanner` (``name = "ruckig"``): Ruckig's offline, time-optimal,
  jerk-limited, time-synchronised trajectory (``ruckig.Ruckig.calculate``; success is
  ``Result.Working``) under the velocity, acceleration and jerk limits as given, from
  (q0, qd0, qdd = 0) to (qe, qde, qdd = 0). Ruckig knows no dynamics: its trajectory
  may exceed the torque and torque-rate limits (``info["max_constraint_ratio"]`` says by
  how much).
* :class:`FeasibleRuckigPlanner` (``name = "ruckig_feasible"``): Ruckig tuned to the
  torque limits: the acceleration and jerk limits multiplied by one common factor s --
  and the velocity limit too if no s suffices -- the largest s (halving, then geometric
  bisection to the relative ``scale_resolution``) for which the trajectory, sampled every
  ``check_dt`` (1 ms) and evaluated through the inverse dynamics, respects the torque and
  torque-rate limits (the torque rate without the Coulomb term, ``planners.ptp_dynamics``).

"As given": the problem's limits where finite. Ruckig needs finite velocity and
acceleration limits, so where the problem sets none (the paper's eq. 40 limits torque,
torque rate, velocity and position only) the robot's rated values stand in
(``JointLimits.from_robot()``, rx130l_params.toml [limits]; ``fallback_limits`` to
change). Stand-ins are no limits of the problem: the tuned Ruckig may then also scale
them UP (s up to MAX_SCALE_UP), which makes it the strongest Ruckig baseline that keeps
the torque limits; with acceleration or jerk limits in the problem s <= 1.

Both return a ``planners.trajectory.Trajectory`` sampled every ``sample_dt`` s (plus the
final time) whose torque is the inverse dynamics of the sampled (q, qd, qdd) with the
problem's friction model. Ruckig (community edition) has no position limits: a
trajectory that leaves the position range is reported INFEASIBLE.
Units: SI, joint side.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from ruckig import InputParameter, Result, Ruckig
from ruckig import Trajectory as RuckigTrajectory

from planners.base import JointLimits, N_JOINTS, Planner, PlannerInputError, PlanResult, PlanStatus, PtPProblem
from planners.ptp_dynamics import PtPDynamics, boundary_torque_violation, boundary_violation, ptp_dynamics
from planners.trajectory import DEFAULT_CHECK_DT, RATIO_KINDS, Trajectory, uniform_times

MIN_SCALE = 2.0**-6
"""Smallest common limit scale factor tried by FeasibleRuckigPlanner before giving up."""
COARSE_SAMPLES = 500
"""Samples of the quick pre-check of a long candidate trajectory (violations only)."""
MAX_SCALE_UP = 8.0
"""Largest common scale of the stand-in acceleration/jerk limits when the problem sets none."""


@dataclass(frozen=True)
class RuckigMotion:
    """A sampled Ruckig trajectory: times (n,) s and q, qd, qdd (n, 6); Ruckig's result."""

    result: Result
    duration: float
    t: np.ndarray | None = None
    q: np.ndarray | None = None
    qd: np.ndarray | None = None
    qdd: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        return self.result == Result.Working and self.t is not None


def ruckig_motion(problem: PtPProblem, velocity: np.ndarray, acceleration: np.ndarray, jerk: np.ndarray,
                  sample_dt: float = DEFAULT_CHECK_DT, max_samples: int | None = None) -> RuckigMotion:
    """Ruckig's time-optimal trajectory for ``problem``'s boundary states under the given
    kinematic limits (rad/s, rad/s^2, rad/s^3; (6,), jerk may be inf), sampled every
    ``sample_dt`` s from 0 to the duration (the last sample exactly at the end), or at
    ``max_samples`` evenly spaced times if that is fewer."""
    inp = InputParameter(N_JOINTS)
    inp.current_position = problem.q0.tolist()
    inp.current_velocity = problem.qd0.tolist()
    inp.current_acceleration = [0.0] * N_JOINTS
    inp.target_position = problem.qe.tolist()
    inp.target_velocity = problem.qde.tolist()
    inp.target_acceleration = [0.0] * N_JOINTS
    inp.max_velocity = [float(v) for v in velocity]
    inp.max_acceleration = [float(a) for a in acceleration]
    inp.max_jerk = [float(j) for j in jerk]
    trajectory = RuckigTrajectory(N_JOINTS)
    result = Ruckig(N_JOINTS).calculate(inp, trajectory)
    if result != Result.Working:
        return RuckigMotion(result, math.nan)
    duration = float(trajectory.duration)
    times = uniform_times(0.0, duration, sample_dt)
    if max_samples is not None and times.size > max_samples:
        times = np.linspace(0.0, duration, int(max_samples))
    states = np.array([np.concatenate(trajectory.at_time(float(t))[:3]) for t in times])
    q, qd, qdd = (states[:, k * N_JOINTS:(k + 1) * N_JOINTS] for k in range(3))
    return RuckigMotion(result, duration, times, q, qd, qdd)


def kinematic_limits(problem: PtPProblem, fallback: JointLimits | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(velocity, acceleration, jerk, largest allowed scale) for Ruckig.

    The problem's limits where finite; where the problem sets none (inf) the stand-ins
    of ``fallback`` (default: the robot's rated limits, ``JointLimits.from_robot()``,
    rx130l_params.toml [limits]). The largest allowed common scale of acceleration and
    jerk is 1 if the problem sets any acceleration or jerk limit, else MAX_SCALE_UP
    (stand-ins are no limits: a torque-tuned Ruckig may exceed them).
    """
    lim = problem.limits
    stand_in = fallback if fallback is not None else _rated_limits()
    velocity = np.where(np.isfinite(lim.velocity), lim.velocity, stand_in.velocity)
    acceleration = np.where(np.isfinite(lim.acceleration), lim.acceleration, stand_in.acceleration)
    jerk = np.where(np.isfinite(lim.jerk), lim.jerk, stand_in.jerk)
    for kind, values in (("velocity", velocity), ("acceleration", acceleration)):
        if not np.all(np.isfinite(values)):
            raise PlannerInputError(f"Ruckig needs finite {kind} limits: problem and fallback give {values.tolist()}")
    given = lim.active("acceleration") or lim.active("jerk")
    return velocity, acceleration, jerk, 1.0 if given else MAX_SCALE_UP


_RATED: list[JointLimits] = []


def _rated_limits() -> JointLimits:
    if not _RATED:
        _RATED.append(JointLimits.from_robot())
    return _RATED[0]


@dataclass(frozen=True)
class TunedMotion:
    """Result of :func:`torque_tuned_motion`: the motion, its ratios and the scale found."""

    motion: RuckigMotion
    ratios: dict[str, np.ndarray]
    scale: float
    velocity_scaled: bool
    evaluations: int


def torque_tuned_motion(problem: PtPProblem, dyn: PtPDynamics, check_dt: float = DEFAULT_CHECK_DT,
                        scale_resolution: float = 1e-3, fallback: JointLimits | None = None) -> TunedMotion | None:
    """Ruckig with the acceleration and jerk limits times the largest common factor s
    for which the torque and torque-rate ratios at ``check_dt`` are <= 1.

    s ranges over [MIN_SCALE, s_max] (s_max from :func:`kinematic_limits`): s_max is
    tried first, then halved until feasible, then bisected (geometrically) to the
    relative ``scale_resolution``. If even MIN_SCALE fails, the velocity limit is scaled
    by s too (never above the problem's limit). Returns None when nothing works.
    """
    velocity, acceleration, jerk, s_max = kinematic_limits(problem, fallback)
    limits = problem.limits
    count = 0

    def attempt(scale: float, with_velocity: bool) -> tuple[bool, RuckigMotion, dict]:
        nonlocal count
        count += 1
        v = velocity * min(scale, 1.0) if with_velocity else velocity
        # a coarse look first: a violation at any sample (or of a mean rate) is a real one
        motion = ruckig_motion(problem, v, acceleration * scale, jerk * scale, check_dt, COARSE_SAMPLES)
        if not motion.ok:
            return False, motion, {}
        ratios = dyn.ratios(motion.t, motion.q, motion.qd, motion.qdd, limits)
        if _max_ratio(ratios, ("torque", "torque_rate")) > 1.0:
            return False, motion, ratios
        if motion.t.size == COARSE_SAMPLES:
            motion = ruckig_motion(problem, v, acceleration * scale, jerk * scale, check_dt)
        ratios = dyn.ratios(motion.t, motion.q, motion.qd, motion.qdd, limits)
        return _max_ratio(ratios, ("torque", "torque_rate")) <= 1.0, motion, ratios

    for with_velocity in (False, True):
        scale = s_max
        ok, motion, ratios = attempt(scale, with_velocity)
        while not ok and scale > MIN_SCALE:
            scale *= 0.5
            ok, motion, ratios = attempt(scale, with_velocity)
        if not ok:
            continue
        lo, hi = scale, min(s_max, 2.0 * scale)
        best = (motion, ratios)
        while lo < s_max and hi / lo > 1.0 + scale_resolution:
            mid = math.sqrt(lo * hi)
            ok, motion, ratios = attempt(mid, with_velocity)
            if ok:
                lo, best = mid, (motion, ratios)
            else:
                hi = mid
        return TunedMotion(best[0], best[1], lo, with_velocity, count)
    return None


def _trivial(problem: PtPProblem) -> bool:
    return bool(np.all(problem.q0 == problem.qe) and np.all(problem.qd0 == 0) and np.all(problem.qde == 0))


def _check_request(problem: PtPProblem, planner: str) -> PlanResult | None:
    if not isinstance(problem, PtPProblem):
        raise PlannerInputError(f"{planner}.plan: expected a PtPProblem, got {type(problem).__name__}")
    if _trivial(problem):
        raise PlannerInputError(f"{planner}.plan: q0 equals qe and both velocities are zero; nothing to plan")
    reason = boundary_violation(problem) or boundary_torque_violation(
        problem, ptp_dynamics(problem.dynamics, problem.friction))
    if reason:
        return PlanResult(planner, PlanStatus.INFEASIBLE, None, 0.0, message=f"boundary states: {reason}")
    return None


def _trajectory(motion: RuckigMotion, dyn: PtPDynamics, metadata: dict) -> Trajectory:
    tau = dyn.torques(motion.q, motion.qd, motion.qdd)
    return Trajectory(motion.t, motion.q, motion.qd, motion.qdd, tau, metadata=metadata)


def _max_ratio(ratios: dict[str, np.ndarray], kinds=RATIO_KINDS) -> float:
    return float(max(np.max(ratios[k]) for k in kinds))


class RuckigPlanner(Planner):
    """Ruckig with the problem's kinematic limits (velocity, acceleration, jerk) as given.

    ``sample_dt``: output sample time [s] (1 ms); ``fallback_limits``: stand-ins for
    missing kinematic limits (default the robot's rated ones).
    """

    name = "ruckig"
    kind = "ptp"

    def __init__(self, sample_dt: float = DEFAULT_CHECK_DT, fallback_limits: JointLimits | None = None) -> None:
        if not (isinstance(sample_dt, (int, float)) and math.isfinite(sample_dt) and sample_dt > 0.0):
            raise PlannerInputError(f"RuckigPlanner sample_dt: expected a positive time in s, got {sample_dt!r}")
        self.sample_dt = float(sample_dt)
        self.fallback_limits = fallback_limits

    def plan(self, problem: PtPProblem) -> PlanResult:
        refused = _check_request(problem, self.name)
        if refused is not None:
            return refused
        velocity, acceleration, jerk, _ = kinematic_limits(problem, self.fallback_limits)
        start = time.perf_counter()
        motion = ruckig_motion(problem, velocity, acceleration, jerk, self.sample_dt)
        solve_time = time.perf_counter() - start
        if not motion.ok:
            return PlanResult(self.name, PlanStatus.FAILED, None, solve_time, message=str(motion.result))
        dyn = ptp_dynamics(problem.dynamics, problem.friction)
        ratios = dyn.ratios(motion.t, motion.q, motion.qd, motion.qdd, problem.limits)
        if np.max(ratios["position"]) > 1.0:
            return PlanResult(self.name, PlanStatus.INFEASIBLE, None, solve_time,
                              message="Ruckig's trajectory leaves the joint position range",
                              info={"position_ratio": ratios["position"].tolist()})
        metadata = {"planner": self.name, "status": PlanStatus.FEASIBLE.value, "solve_time_s": solve_time,
                    "ruckig_result": str(motion.result), "friction": problem.friction}
        info = {"max_constraint_ratio": _max_ratio(ratios), "ratios": {k: v.tolist() for k, v in ratios.items()},
                "torque_checked": False}
        return PlanResult(self.name, PlanStatus.FEASIBLE, _trajectory(motion, dyn, metadata), solve_time,
                          message=str(motion.result), info=info)


class FeasibleRuckigPlanner(Planner):
    """Ruckig with its kinematic limits scaled until the torque limits hold (module docstring).

    ``sample_dt``: output sample time [s]; ``check_dt``: sample time of the torque check
    [s] (at most ``sample_dt``); ``scale_resolution``: relative resolution of the scale
    factor; ``fallback_limits``: stand-ins for missing kinematic limits. Status FEASIBLE
    on success (``info["scale"]``), INFEASIBLE when no scale works.
    """

    name = "ruckig_feasible"
    kind = "ptp"

    def __init__(self, sample_dt: float = DEFAULT_CHECK_DT, check_dt: float = DEFAULT_CHECK_DT,
                 scale_resolution: float = 1e-3, fallback_limits: JointLimits | None = None) -> None:
        for arg, value in (("sample_dt", sample_dt), ("check_dt", check_dt), ("scale_resolution", scale_resolution)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                raise PlannerInputError(f"FeasibleRuckigPlanner {arg}: expected a positive number, got {value!r}")
        check_dt = min(check_dt, sample_dt)  # the check must see the output samples (or finer ones)
        self.sample_dt = float(sample_dt)
        self.check_dt = float(check_dt)
        self.scale_resolution = float(scale_resolution)
        self.fallback_limits = fallback_limits

    def plan(self, problem: PtPProblem) -> PlanResult:
        refused = _check_request(problem, self.name)
        if refused is not None:
            return refused
        dyn = ptp_dynamics(problem.dynamics, problem.friction)
        start = time.perf_counter()
        tuned = torque_tuned_motion(problem, dyn, self.check_dt, self.scale_resolution, self.fallback_limits)
        solve_time = time.perf_counter() - start
        if tuned is None:
            return PlanResult(self.name, PlanStatus.INFEASIBLE, None, solve_time,
                              message=f"no common limit scale down to {MIN_SCALE:g} (velocity included) "
                                      "keeps the torque and torque-rate limits")
        info = {"evaluations": tuned.evaluations, "scale": tuned.scale, "velocity_scaled": tuned.velocity_scaled}
        if np.max(tuned.ratios["position"]) > 1.0:
            return PlanResult(self.name, PlanStatus.INFEASIBLE, None, solve_time,
                              message="Ruckig's trajectory leaves the joint position range", info=info)
        motion = tuned.motion
        if self.sample_dt != self.check_dt:
            velocity, acceleration, jerk, _ = kinematic_limits(problem, self.fallback_limits)
            v_scale = min(tuned.scale, 1.0) if tuned.velocity_scaled else 1.0
            motion = ruckig_motion(problem, velocity * v_scale, acceleration * tuned.scale, jerk * tuned.scale,
                                   self.sample_dt)
        info.update({"max_constraint_ratio": _max_ratio(tuned.ratios),
                     "ratios": {k: v.tolist() for k, v in tuned.ratios.items()}, "torque_checked": True})
        metadata = {"planner": self.name, "status": PlanStatus.FEASIBLE.value, "solve_time_s": solve_time,
                    "limit_scale": tuned.scale, "velocity_scaled": tuned.velocity_scaled,
                    "friction": problem.friction}
        return PlanResult(self.name, PlanStatus.FEASIBLE, _trajectory(motion, dyn, metadata), solve_time,
                          message=str(motion.result), info=info)
