"""The paper's straight line (eq. 39) for this arm: the CP and PtP benchmark motion.

Constant flange orientation with the tool z axis along base x (Cardan angles
(0, pi/2, 0)); the flange moves 1.2 m sideways, parallel to base y, at x = 1.2 m and
z = 1.1 m. Halfway (y = 0) the forearm points almost exactly along the tool axis, so
the arm passes 3.2 deg (q5 = -0.057 rad) from the wrist singularity q5 = 0: joints 4
and 6 must turn fast there and the time-optimal CP speed drops (paper Figure 7). The
time-optimal duration under the RX130L limits is about 1.03 s (TOPP-RA and own CP;
the paper reports 1.04 s for its line).

End configurations (IK branch: shoulder in front, elbow up, q5 < 0), for the PtP
planners between the same end points (paper sec. 5.5)::

    q_start = paper_line_configurations()[0]   # ~ (-0.503, 0.536, 1.021, -1.596, -0.503, 1.599) rad
    q_end   = paper_line_configurations()[1]   # ~ ( 0.503, 0.536, 1.021,  1.596, -0.503, -1.599) rad
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from planners.base import CPProblem, JointLimits
from planners.paths import DEFAULT_GRID_POINTS, JointPath, LinePath, joint_path

PAPER_LINE_START: tuple[float, float, float] = (1.2, -0.6, 1.1)
"""Flange start position [m] in base_link."""
PAPER_LINE_END: tuple[float, float, float] = (1.2, 0.6, 1.1)
"""Flange end position [m] in base_link."""
PAPER_LINE_ORIENTATION: tuple[float, float, float] = (0.0, math.pi / 2, 0.0)
"""Constant flange orientation, Cardan x-y-z [rad]: tool z axis along base x."""
PAPER_LINE_Q_HINT: tuple[float, ...] = (-0.4, 0.5, 1.3, 0.0, -0.3, 0.0)
"""Joint angles [rad] that pick the IK branch of the start (q5 < 0, elbow up)."""


def paper_line_path() -> LinePath:
    """The Cartesian straight line (eq. 39) with constant orientation."""
    return LinePath(PAPER_LINE_START, PAPER_LINE_END, PAPER_LINE_ORIENTATION)


@lru_cache(maxsize=4)
def paper_line_joint_path(n_grid: int = DEFAULT_GRID_POINTS) -> JointPath:
    """The line mapped to joints by IK (cached; JointPath is immutable)."""
    return joint_path(paper_line_path(), PAPER_LINE_Q_HINT, n_grid=n_grid)


def paper_line_configurations() -> tuple[np.ndarray, np.ndarray]:
    """(q_start, q_end) [rad] of the line, shape (6,) each: the PtP boundary states."""
    jp = paper_line_joint_path()
    return jp.start, jp.end


def paper_cp_problem(limits: JointLimits | None = None, dynamics=None, k1: float = 1.0, k2: float = 0.0,
                     friction: str = "full", n_intervals: int = 200, kinematic_only_limits: bool = False) -> CPProblem:
    """The CP problem along the paper line with the robot's limits.

    ``kinematic_only_limits=True`` switches the jerk and torque-rate limits off (the
    problem TOPP-RA can represent, eq. 38 as in the paper).
    """
    lim = limits or JointLimits.from_robot()
    if kinematic_only_limits:
        lim = lim.replace(jerk=math.inf, torque_rate=math.inf)
    return CPProblem(paper_line_joint_path(), lim, dynamics, k1=k1, k2=k2, friction=friction,
                     n_intervals=n_intervals)
