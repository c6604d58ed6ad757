"""Cartesian paths and their joint paths: FK round trip, Jacobian derivatives vs finite
differences, clear errors for unreachable and singular paths."""
import math

import numpy as np
import pytest

from planners.paths import (
    CirclePath,
    CompositePath,
    LinePath,
    PathError,
    PathSingularError,
    PathUnreachableError,
    SplinePath,
    joint_path,
    rectangle_path,
)
from robot.kinematics import FlangeKinematics

TOOL_FORWARD = (0.0, math.pi / 2, 0.0)  # Cardan angles: flange z axis along base x
Q_HINT = (0.0, 0.5, 1.3, 0.0, -0.3, 0.0)


def _finite_difference_check(path, n_grid=801):
    jp = joint_path(path, Q_HINT, n_grid=n_grid)
    kin = FlangeKinematics()
    pts = path.evaluate(jp.sigma)
    assert np.max(np.abs(kin.transforms(jp.q)[:, :3, 3] - pts.position)) < 1e-9
    fd1 = np.gradient(jp.q, jp.sigma, axis=0, edge_order=2)
    fd2 = np.gradient(jp.dq, jp.sigma, axis=0, edge_order=2)
    scale1, scale2 = np.max(np.abs(jp.dq)), np.max(np.abs(jp.ddq))
    assert np.max(np.abs(fd1 - jp.dq)) < 1e-4 * scale1
    assert np.max(np.abs(fd2 - jp.ddq)) < 1e-3 * scale2
    # quintic Hermite evaluation between grid points agrees with a direct solve there
    mid = 0.5 * (jp.sigma[10] + jp.sigma[11])
    fine = joint_path(path, Q_HINT, n_grid=2 * (n_grid - 1) + 1)
    q_mid, dq_mid, _, _ = jp.evaluate([mid])
    assert np.max(np.abs(q_mid[0] - fine.q[21])) < 1e-9
    assert np.max(np.abs(dq_mid[0] - fine.dq[21])) < 1e-6 * scale1
    return jp


def test_line_joint_path_matches_fk_and_finite_differences():
    jp = _finite_difference_check(LinePath([1.2, -0.5, 1.0], [1.2, 0.5, 1.0], TOOL_FORWARD))
    assert jp.min_singular_value > 0.01


def test_circle_joint_path_matches_fk_and_finite_differences():
    circle = CirclePath(center=[1.0, 0.5, 0.8], normal=[1, 0, 0], radius=0.25, orientation=TOOL_FORWARD)
    pts = circle.evaluate(np.linspace(0, 1, 9))
    assert np.allclose(np.linalg.norm(pts.position - circle.center, axis=1), 0.25)
    assert circle.length == pytest.approx(2 * math.pi * 0.25)
    _finite_difference_check(circle)


def test_spline_passes_through_waypoints():
    waypoints = np.array([[1.1, -0.3, 0.9], [1.2, 0.0, 1.0], [1.1, 0.3, 0.9]])
    spline = SplinePath(waypoints, TOOL_FORWARD)
    assert np.allclose(spline.evaluate(spline.knots).position, waypoints)
    _finite_difference_check(spline, n_grid=401)


def test_rectangle_has_three_inner_corners_and_composite_checks_continuity():
    rect = rectangle_path([1.1, -0.2, 0.8], [0, 0.4, 0], [0, 0, 0.4], TOOL_FORWARD)
    assert np.allclose(rect.corners, [0.25, 0.5, 0.75])
    assert rect.length == pytest.approx(1.6)
    assert list(rect.segment_index([0.1, 0.3, 0.6, 0.9])) == [0, 1, 2, 3]
    pts = rect.evaluate([0.0, 0.25, 0.5, 0.75, 1.0])
    assert np.allclose(pts.position[2], [1.1, 0.2, 1.2])
    with pytest.raises(PathError, match="meet"):
        CompositePath([LinePath([1, 0, 1], [1, 0.1, 1], TOOL_FORWARD), LinePath([1, 0.2, 1], [1, 0.3, 1], TOOL_FORWARD)])


def test_out_of_reach_point_raises_a_clear_error():
    with pytest.raises(PathUnreachableError, match="out of reach"):
        joint_path(LinePath([1.2, 0.0, 0.9], [1.2, 1.8, 0.9], TOOL_FORWARD), Q_HINT, n_grid=101)


def test_path_through_the_wrist_singularity_raises_a_clear_error():
    kin = FlangeKinematics()
    q_singular = np.array([0.0, 0.4, 1.2, 0.0, 0.0, 0.0])
    pose = kin.transform(q_singular)
    p = pose[:3, 3]
    line = LinePath(p - [0.0, 0.2, 0.0], p + [0.0, 0.2, 0.0], pose[:3, :3])
    with pytest.raises(PathSingularError, match="singular"):
        joint_path(line, [-0.2, 0.4, 1.2, 0.0, -0.3, 0.0], n_grid=201)


def test_bad_path_definitions_raise_value_errors():
    with pytest.raises(PathError, match="LinePath start"):
        LinePath([1, 2], [1, 2, 3], TOOL_FORWARD)
    with pytest.raises(PathError, match="radius"):
        CirclePath([1, 0, 1], [1, 0, 0], -0.1, TOOL_FORWARD)
    with pytest.raises(PathError, match="sigma"):
        LinePath([1, 0, 1], [1, 1, 1], TOOL_FORWARD).evaluate([1.5])
    with pytest.raises(PathError, match="orthogonal"):
        rectangle_path([1, 0, 1], [0, 1, 0], [0, 1, 1], TOOL_FORWARD)


def test_start_out_of_reach_is_also_the_robot_packages_unreachable_error():
    from robot.inverse_kinematics import UnreachablePoseError

    with pytest.raises(UnreachablePoseError, match="out of reach"):
        joint_path(LinePath([2.5, 0.0, 1.0], [2.5, 0.5, 1.0], TOOL_FORWARD), Q_HINT, n_grid=11)
