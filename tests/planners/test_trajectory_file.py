"""User trajectory files (planners/trajectory_file.py): format, derivation, IK, limit checks, errors."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planners.base import JointLimits
from planners.trajectory_file import (TrajectoryFileError, TrajectoryLimitError, file_kind,
                                      load_trajectory_file)
from robot.dynamics import RobotDynamics
from robot.kinematics import FlangeKinematics, pose_from_transform

Q0 = np.array([0.0, 0.4, 1.8, 0.0, 0.9, math.pi])
DQ = np.array([0.5, 0.2, -0.3, 0.4, -0.3, 0.6])


def _quintic(t: np.ndarray, duration: float):
    """A rest-to-rest quintic from Q0 to Q0 + DQ: q, qd, qdd (n, 6)."""
    s = t / duration
    h = 10 * s**3 - 15 * s**4 + 6 * s**5
    hd = (30 * s**2 - 60 * s**3 + 30 * s**4) / duration
    hdd = (60 * s - 180 * s**2 + 120 * s**3) / duration**2
    return Q0 + np.outer(h, DQ), np.outer(hd, DQ), np.outer(hdd, DQ)


def _write(path: Path, header: list[str], rows: np.ndarray | list, comment: str = "") -> Path:
    with open(path, "w", encoding="utf-8") as f:
        if comment:
            f.write(comment + "\n")
        f.write(", ".join(header) + "\n")
        for row in rows:
            f.write(",".join(v if isinstance(v, str) else repr(float(v)) for v in row) + "\n")
    return path


def _joint_file(tmp_path: Path, duration: float = 2.0, dt: float = 0.01, name: str = "joint.csv") -> Path:
    t = np.linspace(0.0, duration, int(round(duration / dt)) + 1)
    q, _, _ = _quintic(t, duration)
    return _write(tmp_path / name, ["t"] + [f"q{j}" for j in range(1, 7)], np.column_stack([t, q]), "# a test file")


def test_joint_file_quintic_spline_reproduces_a_rest_to_rest_quintic(tmp_path):
    traj = load_trajectory_file(_joint_file(tmp_path))
    q, qd, qdd = _quintic(traj.t, 2.0)
    # the interpolating quintic spline with rest ends reproduces a quintic polynomial exactly
    assert np.abs(traj.q - q).max() < 1e-12
    assert np.abs(traj.qd - qd).max() < 1e-10
    assert np.abs(traj.qdd - qdd).max() < 1e-8
    assert np.allclose(np.diff(traj.t), 1e-3)
    assert traj.metadata["kind"] == "joint" and "quintic" in traj.metadata["derivation"]
    # torques: the nominal arm's inverse dynamics of the resampled motion
    dyn = RobotDynamics()
    for k in (0, 700, 2000):
        assert np.allclose(traj.tau[k], dyn.inverse_dynamics(traj.q[k], traj.qd[k], traj.qdd[k]), atol=1e-9)
    # flange position columns from FK
    fk = FlangeKinematics().transforms(traj.q[[0, -1]])[:, :3, 3]
    assert np.allclose([traj.cartesian["x"][[0, -1]], traj.cartesian["y"][[0, -1]]], fk[:, :2].T)
    assert 0.0 < traj.metadata["limit_ratios"]["velocity"] < 1.0


def test_units_in_brackets_and_any_sample_rate(tmp_path):
    t = np.sort(np.concatenate([[0.0, 2.0], np.random.default_rng(3).uniform(0.01, 1.99, 150)]))
    q, qd, _ = _quintic(t, 2.0)
    path = _write(tmp_path / "deg.csv", ["t [ms]"] + [f"q{j} [deg]" for j in range(1, 7)],
                  np.column_stack([t * 1e3, np.degrees(q)]))
    traj = load_trajectory_file(path)
    ref_q, ref_qd, _ = _quintic(traj.t, 2.0)
    assert np.abs(traj.q - ref_q).max() < 1e-9
    assert np.abs(traj.qd - ref_qd).max() < 1e-6


def test_velocities_given_hermite_and_consistent_accelerations(tmp_path):
    t = np.linspace(0.0, 2.0, 41)
    q, qd, qdd = _quintic(t, 2.0)
    header = ["t"] + [f"q{j}" for j in range(1, 7)] + [f"qd{j}" for j in range(1, 7)]
    traj = load_trajectory_file(_write(tmp_path / "qqd.csv", header, np.column_stack([t, q, qd])))
    ref_q, ref_qd, ref_qdd = _quintic(traj.t, 2.0)
    assert np.abs(traj.q - ref_q).max() < 1e-6
    assert np.abs(traj.qd - ref_qd).max() < 1e-4
    assert np.abs(traj.qdd - ref_qdd).max() < 0.02 * np.abs(ref_qdd).max()
    # with qdd and tau given too, they are used as given (tau linear between samples)
    tau = np.tile(np.arange(1.0, 7.0), (t.size, 1))
    header += [f"qdd{j}" for j in range(1, 7)] + [f"tau{j} [N m]" for j in range(1, 7)]
    traj = load_trajectory_file(_write(tmp_path / "all.csv", header, np.column_stack([t, q, qd, qdd, tau])))
    idx = np.searchsorted(traj.t, t)
    assert np.allclose(traj.qdd[idx], qdd, rtol=0, atol=1e-12) and np.allclose(traj.tau, np.arange(1.0, 7.0))
    assert traj.metadata["derivation"].startswith("q, qd, qdd as given")


def test_smoothing_spline_states_its_deviation_and_tames_noise(tmp_path):
    t = np.linspace(0.0, 2.0, 401)
    q, _, qdd = _quintic(t, 2.0)
    sigma = 2e-5
    noisy = q + sigma * np.random.default_rng(0).standard_normal(q.shape)
    path = _write(tmp_path / "noisy.csv", ["t"] + [f"q{j}" for j in range(1, 7)], np.column_stack([t, noisy]))
    smooth = load_trajectory_file(path, smoothing=sigma, check=False)
    raw = load_trajectory_file(path, check=False)
    assert smooth.metadata["smoothing_rms_deviation_rad"] <= sigma * (1 + 1e-6)
    _, _, ref_qdd = _quintic(smooth.t, 2.0)
    err_smooth = np.abs(smooth.qdd - ref_qdd).max()
    err_raw = np.abs(raw.qdd - ref_qdd).max()
    assert err_smooth < 0.2 * err_raw, (err_smooth, err_raw)
    assert "smoothing spline" in smooth.metadata["derivation"]


def test_cartesian_file_quaternion_and_cardan_through_ik(tmp_path):
    t = np.linspace(0.0, 2.0, 101)
    q, _, _ = _quintic(t, 2.0)
    tf = FlangeKinematics().transforms(q)
    xyzw = Rotation.from_matrix(tf[:, :3, :3]).as_quat()          # scalar last (scipy)
    quat = np.column_stack([xyzw[:, 3], xyzw[:, :3]])
    path = _write(tmp_path / "cart.csv", ["t", "x", "y", "z", "qw", "qx", "qy", "qz"],
                  np.column_stack([t, tf[:, :3, 3], quat]))
    assert file_kind(path) == "cartesian"
    traj = load_trajectory_file(path, q_seed=Q0)
    ref_q, _, _ = _quintic(traj.t, 2.0)
    idx = np.searchsorted(traj.t, t)
    assert np.abs(traj.q[idx] - q).max() < 1e-8          # IK at the samples
    assert np.abs(traj.q - ref_q).max() < 1e-6           # quintic spline between them
    pose = pose_from_transform(tf)
    path2 = _write(tmp_path / "cardan.csv", ["t", "x [mm]", "y [mm]", "z [mm]", "alpha [deg]", "beta [deg]",
                                             "gamma [deg]"],
                   np.column_stack([t, pose[:, :3] * 1e3, np.degrees(pose[:, 3:])]))
    traj2 = load_trajectory_file(path2, q_seed=Q0)
    assert np.abs(traj2.q - traj.q).max() < 1e-8
    assert traj2.metadata["kind"] == "cartesian"


def test_cartesian_errors(tmp_path):
    rows = [[0.0, 5.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0], [1.0, 5.0, 0.1, 1.0, 1.0, 0.0, 0.0, 0.0]]
    path = _write(tmp_path / "far.csv", ["t", "x", "y", "z", "qw", "qx", "qy", "qz"], rows)
    with pytest.raises(TrajectoryFileError, match=r"line 2.*not reachable"):
        load_trajectory_file(path)
    path = _write(tmp_path / "noori.csv", ["t", "x", "y", "z"], [r[:4] for r in rows])
    with pytest.raises(TrajectoryFileError, match="missing orientation"):
        load_trajectory_file(path)
    rows[1][4] = 2.0
    path = _write(tmp_path / "quat.csv", ["t", "x", "y", "z", "qw", "qx", "qy", "qz"], rows)
    with pytest.raises(TrajectoryFileError, match=r"line 3, column 'qw': quaternion .* norm 2"):
        load_trajectory_file(path)


def test_limit_violation_names_file_column_line_time_value_limit(tmp_path):
    # too fast: the derived acceleration exceeds the limit between two samples
    path = _joint_file(tmp_path, duration=0.3, name="fast.csv")
    with pytest.raises(TrajectoryLimitError) as info:
        load_trajectory_file(path)
    err = info.value
    assert err.file == str(path) and err.kind == "acceleration" and err.derived
    assert err.column.startswith("qdd") and err.line >= 2 and abs(err.value) > err.limit
    lim = JointLimits.from_robot()
    assert err.limit == float(lim.acceleration[int(err.column[3:]) - 1])
    assert "fast.csv" in str(err) and "exceeds the acceleration limit" in str(err) and f"t = {err.time:.6g} s" in str(err)
    # a position sample beyond the URDF range: exactly at a file line
    t = np.linspace(0.0, 2.0, 21)
    q, _, _ = _quintic(t, 2.0)
    q[:, 2] += lim.position_upper[2] + 0.01 - q[0, 2]        # starts 0.01 rad beyond the upper limit of joint 3
    path = _write(tmp_path / "pos.csv", ["t"] + [f"q{j}" for j in range(1, 7)], np.column_stack([t, q]))
    with pytest.raises(TrajectoryLimitError, match=r"line 2, column 'q3'.*t = 0 s \(line 2\): q3 = .* exceeds the "
                                                   r"position range") as info:
        load_trajectory_file(path)
    assert not info.value.derived and info.value.limit == (lim.position_lower[2], lim.position_upper[2])
    # limits are a parameter: a slower robot rejects the nominal file
    with pytest.raises(TrajectoryLimitError, match="velocity limit"):
        load_trajectory_file(_joint_file(tmp_path), limits=lim.replace(velocity=0.05))


@pytest.mark.parametrize("header, rows, match", [
    (["t", "q1", "q2", "q3", "q4", "q5"], [[0, 0, 0, 0, 0, 0], [1, 0, 0, 0, 0, 0]],
     r"column 'q6': missing: q is given for .* but not for \['q6'\]"),
    (["time", "q1"], [[0, 0], [1, 0]], r"column 'time': unknown column"),
    (["q1", "q2", "q3", "q4", "q5", "q6"], [[0] * 6, [1] * 6], r"column 't': missing"),
    (["t", "q1", "q2", "q3", "q4", "q5", "q6"], [[0, 0, 0, 0, 0, 0, 0], [1, 0, "nan", 0, 0, 0, 0]],
     r"line 3, column 'q2': value 'nan': expected a finite number"),
    (["t", "q1", "q2", "q3", "q4", "q5", "q6"], [[0, 0, 0, 0, 0, 0, 0], [1, 0, "abc", 0, 0, 0, 0]],
     r"line 3, column 'q2': value 'abc' is not a number"),
    (["t", "q1", "q2", "q3", "q4", "q5", "q6"], [[0] * 7, [0.5] * 7, [0.5] * 7],
     r"line 4, column 't': t = 0.5 s is not after the previous sample's t = 0.5 s \(line 3\)"),
    (["t", "q1", "q2", "q3", "q4", "q5", "q6"], [[0] * 7, [1, 0, 0]], r"line 3: 3 values, expected 7"),
    (["t", "q1 [grad]", "q2", "q3", "q4", "q5", "q6"], [[0] * 7, [1] * 7], r"column 'q1': unit \[grad\]"),
    (["t", "q1", "q2", "q3", "q4", "q5", "q6"], [[0] * 7], r"expected at least 2 samples"),
    (["t"] + [f"q{j}" for j in range(1, 7)] + [f"qdd{j}" for j in range(1, 7)], [[0] * 13, [1] * 13],
     r"column 'qd1': missing: qdd1..qdd6 given without qd1..qd6"),
])
def test_malformed_files(tmp_path, header, rows, match):
    path = _write(tmp_path / "bad.csv", header, [[str(v) for v in r] for r in rows])
    with pytest.raises(TrajectoryFileError, match=match) as info:
        load_trajectory_file(path)
    assert str(path) in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(TrajectoryFileError, match="no such file"):
        load_trajectory_file(tmp_path / "nope.csv")
