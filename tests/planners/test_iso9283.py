"""The ISO 9283 test path: geometry, 1 m/s and 5 m/s^2 respected, smooth, stops at
junctions, and its joint trajectory reproduces the Cartesian reference."""
import math

import numpy as np
import pytest

from planners.iso9283 import (
    ISO_ACCELERATION,
    ISO_CUBE_CENTER,
    ISO_CUBE_EDGE,
    ISO_SPEED,
    IsoPathError,
    SegmentTimeLaw,
    cube_is_workable,
    iso9283_test_path,
)
from robot.kinematics import FlangeKinematics


@pytest.fixture(scope="module")
def iso():
    return iso9283_test_path()


def test_poses_lie_in_the_diagonal_plane_ten_percent_in_from_the_corners(iso):
    c = np.asarray(ISO_CUBE_CENTER)
    assert np.allclose(iso.poses["P1"], c)
    normal = iso.info["plane_normal"]
    diagonal = np.linalg.norm(iso.plane_corners[2] - iso.plane_corners[0])
    for k in range(4):
        p = iso.poses[f"P{k + 2}"]
        assert abs((p - c) @ normal) < 1e-12
        assert np.linalg.norm(p - iso.plane_corners[k]) == pytest.approx(0.1 * diagonal)
    assert iso.info["large_circle_radius_m"] == pytest.approx(0.4 * ISO_CUBE_EDGE)
    assert iso.info["small_circle_radius_m"] == pytest.approx(0.04 * ISO_CUBE_EDGE)


def test_the_cube_is_workable_and_close_to_the_largest(iso):
    assert cube_is_workable(ISO_CUBE_CENTER, ISO_CUBE_EDGE)
    assert not cube_is_workable(ISO_CUBE_CENTER, 1.05 * 0.943)  # the searched optimum + 5 %


def test_speed_and_acceleration_respect_1_m_s_and_5_m_s2_and_are_smooth(iso):
    ref = iso.cartesian_trajectory(dt=5e-4)
    assert ref.speed.max() <= ISO_SPEED + 1e-12
    assert ref.speed.max() == pytest.approx(ISO_SPEED)
    accel = np.linalg.norm(ref.acceleration, axis=1)
    assert accel.max() <= ISO_ACCELERATION * (1 + 1e-9)
    assert accel.max() > 0.99 * ISO_ACCELERATION
    # velocity is the derivative of the position, acceleration that of the velocity
    assert np.max(np.abs(np.gradient(ref.position, ref.t, axis=0) - ref.velocity)) < 1e-5
    assert np.max(np.abs(np.gradient(ref.velocity, ref.t, axis=0)[1:-1] - ref.acceleration[1:-1])) < 5e-3
    # acceleration continuous: no jump bigger than the bounded jerk allows in one step
    jerk_bound = max(seg.law.peak_jerk for seg in iso.segments)
    assert np.max(np.linalg.norm(np.diff(ref.acceleration, axis=0), axis=1)) <= 1.5 * jerk_bound * 5e-4
    # constant orientation
    assert np.allclose(ref.rotation, iso.rotation) and np.all(ref.angular_velocity == 0.0)


def test_the_motion_stops_at_every_junction_and_arc_length_is_monotone(iso):
    ends = np.array([seg.t_end for seg in iso.segments])
    ref = iso.reference(ends)
    assert np.max(ref.speed) < 1e-12
    assert np.allclose(ref.position[3], iso.poses["P2"])  # rectangle closed at P2
    assert np.allclose(ref.position[4], iso.poses["P4"])  # line P2 -> P4
    full = iso.cartesian_trajectory(dt=1e-3)
    assert np.all(np.diff(full.arc_length) >= -1e-12)
    assert full.arc_length[-1] == pytest.approx(iso.length)
    assert list(np.unique(full.segment)) == list(range(len(iso.segments)))
    times = np.concatenate([full.t, [-1.0, iso.duration + 1.0], ends])  # progress() is reference() without poses
    segment, arc = iso.progress(times)
    ref = iso.reference(times)
    assert np.array_equal(segment, ref.segment) and np.array_equal(arc, ref.arc_length)


def test_joint_trajectory_reproduces_the_cartesian_reference(iso, tmp_path):
    traj = iso.joint_trajectory(dt=2e-3, n_grid=201)
    ref = iso.reference(traj.t)
    kin = FlangeKinematics()
    assert np.max(np.abs(kin.transforms(traj.q)[:, :3, 3] - ref.position)) < 1e-7
    # joint velocity maps to the Cartesian velocity through the Jacobian
    twist = np.einsum("nij,nj->ni", kin.jacobians(traj.q), traj.qd)
    assert np.max(np.abs(twist[:, :3] - ref.velocity)) < 1e-6
    path = ref.write_csv(tmp_path / "iso.csv")
    assert path.read_text().startswith("t,x,y,z,alpha")


def test_time_law_and_bad_inputs():
    law = SegmentTimeLaw.create(0.1, 1.0, 5.0)  # too short to reach 1 m/s
    assert law.cruise_time == 0.0 and law.cruise_speed == pytest.approx(math.sqrt(0.1 * 5.0 / 2))
    s, v, a = law.evaluate(np.array([0.0, law.duration]))
    assert s[-1] == pytest.approx(0.1) and abs(v).max() < 1e-12
    with pytest.raises(IsoPathError, match="speed"):
        iso9283_test_path(speed=-1.0)
    with pytest.raises(IsoPathError, match="center"):
        iso9283_test_path(center=(1.0, 0.0))
