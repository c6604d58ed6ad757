"""Calibration from measurements: recovery on unseen robots, CLI, and clear errors."""
import csv
import json
import math

import numpy as np
import pinocchio as pin
import pytest

from cosim.cli import main
from calibration.measurements import Measurements
from calibration.solver import (
    RankDeficientDataError,
    TooFewPosesError,
    calibrate,
)
from calibration.optical_tracker import TrackerNoise
from robot.geometric_errors import ErrorMagnitudes, default_error_model, export_error_urdf, random_geometric_errors
from robot.kinematics import FlangeKinematics, cardan_from_rotation

SIGMA_P = 1e-4  # m, tracker noise of the test data
SIGMA_O = math.radians(0.04)


def _pin_poses(urdf, q):
    model = pin.buildModelFromUrdf(str(urdf))
    data = model.createData()
    fid = model.getFrameId("tool0")
    out = []
    for qi in q:
        pin.framesForwardKinematics(model, data, qi)
        out.append(data.oMf[fid].homogeneous.copy())
    return np.array(out)


def _write_csv(path, q, poses, rng, orientation=True):
    """Measurement file as another tool would write it: csv module, pinocchio FK, noise."""
    header = ["q1", "q2", "q3", "q4", "q5", "q6", "x", "y", "z"] + (["alpha", "beta", "gamma"] if orientation else [])
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for qi, pose in zip(q, poses):
            pos = pose[:3, 3] + rng.normal(0.0, SIGMA_P, 3)
            row = list(qi) + list(pos)
            if orientation:
                small = pin.exp3(rng.normal(0.0, SIGMA_O, 3))
                row += list(cardan_from_rotation(small @ pose[:3, :3]))
            writer.writerow([f"{v:.12g}" for v in row])
    return path


@pytest.fixture(scope="module")
def unseen_robot(tmp_path_factory):
    folder = tmp_path_factory.mktemp("unseen")
    urdf = export_error_urdf(folder / "unseen.urdf", random_geometric_errors(424242))
    return folder, urdf


@pytest.mark.parametrize("orientation", [True, False])
def test_cli_recovers_pose_accuracy_of_an_unseen_robot(unseen_robot, orientation, capsys):
    folder, true_urdf = unseen_robot
    kin = FlangeKinematics()
    rng = np.random.default_rng(7)
    q = rng.uniform(kin.lower, kin.upper, size=(40, 6))
    csv_path = _write_csv(folder / f"meas_{orientation}.csv", q, _pin_poses(true_urdf, q), rng, orientation)
    out = folder / f"out_{orientation}"
    assert main(["calibrate", str(csv_path), "--out", str(out)]) == 0
    assert "calibrated" in capsys.readouterr().err
    params = json.loads((out / "parameters.json").read_text())
    summary = json.loads((out / "summary.json").read_text())
    assert summary["identified_parameters"] == (30 if orientation else 25)
    assert 0.7 < summary["sigma_hat"] < 1.3  # residuals consistent with the tracker noise
    assert all(p["std"] > 0 for p in params["parameters"].values() if p["identified"])
    # fresh poses over the whole joint range: calibrated URDF (loaded by pinocchio) vs the true one
    fresh = np.random.default_rng(8).uniform(kin.lower, kin.upper, size=(300, 6))
    truth = _pin_poses(true_urdf, fresh)
    calibrated = _pin_poses(out / "calibrated.urdf", fresh)
    nominal = _pin_poses(default_error_model().urdf_path, fresh)
    err_cal = np.abs(truth[:, :3, 3] - calibrated[:, :3, 3]).max()
    err_nom = np.abs(truth[:, :3, 3] - nominal[:, :3, 3]).max()
    assert err_nom > 5e-3  # several millimetres uncalibrated
    assert err_cal < 3 * SIGMA_P  # within three times the tracker noise
    if orientation:
        rot_err = [np.linalg.norm(pin.log3(a[:3, :3] @ b[:3, :3].T)) for a, b in zip(truth, calibrated)]
        assert max(rot_err) < 3 * SIGMA_O * math.sqrt(3)


def test_noise_free_data_is_fitted_exactly():
    model = default_error_model()
    kin = FlangeKinematics()
    true = random_geometric_errors(99, ErrorMagnitudes(length_mm=5.0, encoder_offset_deg=1.0, tilt_deg=0.5,
                                                       base_mm=10.0))
    q = np.random.default_rng(1).uniform(kin.lower, kin.upper, size=(30, 6))
    poses = model.flange_transforms(q, true)
    result = calibrate(Measurements(q, poses[:, :3, 3], poses[:, :3, :3]))
    assert result.converged and result.iterations < 15
    assert np.abs(result.residuals).max() < 1e-10
    fresh = np.random.default_rng(2).uniform(kin.lower, kin.upper, size=(50, 6))
    diff = model.flange_transforms(fresh, true) - model.flange_transforms(fresh, result.errors)
    assert np.abs(diff).max() < 1e-9
    assert result.residual_statistics("uncalibrated")["position_norm"]["max"] > 20.0  # mm


def test_damping_engages_for_large_errors():
    """Errors ten times the default magnitudes: the first Gauss-Newton steps overshoot
    in places, Levenberg-Marquardt damping keeps the cost decreasing."""
    model = default_error_model()
    kin = FlangeKinematics()
    big = random_geometric_errors(5, ErrorMagnitudes(length_mm=30.0, encoder_offset_deg=8.0, tilt_deg=8.0,
                                                     base_mm=40.0))
    q = np.random.default_rng(3).uniform(kin.lower, kin.upper, size=(25, 6))
    poses = model.flange_transforms(q, big)
    result = calibrate(Measurements(q, poses[:, :3, 3], poses[:, :3, :3]))
    assert np.all(np.diff(result.cost_history) <= 0.0)
    assert np.abs(result.residuals).max() < 1e-9


def test_too_few_and_rank_deficient_poses(tmp_path, capsys):
    model = default_error_model()
    q = np.zeros((4, 6))
    q[:, 0] = [0.1, 0.2, 0.3, 0.4]
    poses = model.flange_transforms(q)
    with pytest.raises(TooFewPosesError, match="4 poses give 24 equations for 30"):
        calibrate(Measurements(q, poses[:, :3, 3], poses[:, :3, :3]))
    # twenty poses that differ only in joint 1: most parameters are not excited
    q = np.zeros((20, 6))
    q[:, 0] = np.linspace(-1.0, 1.0, 20)
    q[:, 2] = 0.5
    poses = model.flange_transforms(q)
    with pytest.raises(RankDeficientDataError, match="determine only .* of the 30 identifiable parameters"):
        calibrate(Measurements(q, poses[:, :3, 3], poses[:, :3, :3]))
    # the same through the CLI: exit code 2 and the message on stderr
    path = _write_csv(tmp_path / "line.csv", q, poses, np.random.default_rng(0))
    assert main(["calibrate", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "line.csv" in err and "not excited" in err
    with open(tmp_path / "deg.csv", "w") as handle:
        handle.write("q1,q2,q3,q4,q5,q6,x,y,z\n10,20,30,40,50,60,1.0,0.2,0.9\n")
    assert main(["calibrate", str(tmp_path / "deg.csv")]) == 2
    assert "column 'q1'" in capsys.readouterr().err
    assert TrackerNoise().row_sigmas(False).shape == (3,)


def test_calibrated_urdf_drives_the_numeric_ik_of_the_true_robot(unseen_robot):
    """The controller's use: IK on the calibrated description puts the TRUE flange on
    the target within the tracker noise, IK on the nominal one misses by millimetres."""
    from robot.description import load_model
    from robot.inverse_kinematics import NumericIK

    folder, true_urdf = unseen_robot
    kin = FlangeKinematics()
    rng = np.random.default_rng(21)
    q = rng.uniform(kin.lower, kin.upper, size=(40, 6))
    csv_path = _write_csv(folder / "ik.csv", q, _pin_poses(true_urdf, q), rng)
    assert main(["calibrate", str(csv_path), "--out", str(folder / "ik_out")]) == 0
    calibrated_ik = NumericIK(load_model(folder / "ik_out" / "calibrated.urdf"))
    nominal_ik = NumericIK(load_model())
    seeds = rng.uniform(0.5 * kin.lower, 0.5 * kin.upper, size=(10, 6))
    targets = FlangeKinematics().transforms(seeds + 0.05)  # reachable poses in front of the seeds
    miss_cal, miss_nom = [], []
    for target, seed in zip(targets, seeds):
        for solver, misses in ((calibrated_ik, miss_cal), (nominal_ik, miss_nom)):
            q_cmd = solver.solve(target, seed)
            reached = _pin_poses(true_urdf, q_cmd[None])[0]
            misses.append(np.linalg.norm(reached[:3, 3] - target[:3, 3]))
    assert max(miss_nom) > 2e-3
    assert max(miss_cal) < 3 * SIGMA_P
