"""``python -m cosim identify`` on records made here, independently of the identification code.

The records come from a robot the code has never seen (``make_true_robot`` with a seed
used nowhere else, with a payload), torques by ``RobotDynamics.inverse_dynamics``
(pinocchio RNEA + rotor + friction) along sums of sines written in this file, with
encoder quantisation on q and 0.1 %-of-rated quantisation plus noise on tau. The model
must predict the torques of a DIFFERENT trajectory.
"""
from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from cosim.cli import main
from identification.data import read_motion_csv
from identification.errors import IdentificationDataError
from robot.dynamics import RobotDynamics
from robot.parameters import load_parameters
from robot.true_robot import make_true_robot

UNSEEN_SEED = 8675309
PAYLOAD = [6.0, 0.01, -0.02, 0.08]  # kg, m in tool0
DT = 2e-3  # s
CENTRE = np.array([0.0, 0.4, 1.2, 0.0, 0.6, 0.0])
AMPLITUDE = np.array([0.9, 0.5, 0.6, 1.4, 0.8, 1.6])  # rad


def _sines(seed: int, duration: float, joints: tuple[int, ...] = tuple(range(6))):
    """q, qd, qdd of a sum of five sines per joint with random frequencies and phases."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, DT)
    q = np.tile(CENTRE, (t.size, 1))
    qd, qdd = np.zeros_like(q), np.zeros_like(q)
    for j in joints:
        for _ in range(5):
            w = rng.uniform(0.6, 4.0)  # rad/s
            a = AMPLITUDE[j] / 5 * rng.uniform(0.5, 1.0) * 1.2 / w
            phase = rng.uniform(0, 2 * math.pi)
            q[:, j] += a * np.sin(w * t + phase)
            qd[:, j] += a * w * np.cos(w * t + phase)
            qdd[:, j] -= a * w * w * np.sin(w * t + phase)
    return t, q, qd, qdd


def _write_record(path, t, q, qd, qdd, noise_seed: int, derivatives: bool = False,
                  sampling_bias=None) -> np.ndarray:
    arm = make_true_robot(UNSEEN_SEED, payload=PAYLOAD)
    # the plant FMU uses the nominal geometry with the true inertial/friction parameters
    truth = RobotDynamics(arm.dynamic_parameters, arm.payload)
    tau = np.array([truth.inverse_dynamics(a, b, c) for a, b, c in zip(q, qd, qdd)])
    if sampling_bias is not None:  # what a drive that latches torque in step with its speed loop reports
        tau = tau + np.asarray(sampling_bias) * qdd
    params = load_parameters()
    rng = np.random.default_rng(noise_seed)
    lsb_q = 2 * math.pi / (params.encoder_counts_per_motor_rev * params.gear_ratio)
    lsb_tau = 1e-3 * params.rated_torque
    q_meas = np.floor(q / lsb_q) * lsb_q
    tau_meas = np.round((tau + rng.normal(size=tau.shape) * lsb_tau) / lsb_tau) * lsb_tau
    header = ["t"] + [f"q{i}" for i in range(1, 7)] + [f"tau{i}" for i in range(1, 7)]
    columns = [t[:, None], q_meas, tau_meas]
    if derivatives:
        header += [f"qd{i}" for i in range(1, 7)] + [f"qdd{i}" for i in range(1, 7)]
        columns += [qd, qdd]
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for row in np.hstack(columns):
            writer.writerow([f"{v:.10g}" for v in row])
    return tau


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    folder = tmp_path_factory.mktemp("identify")
    data, val = folder / "data.csv", folder / "val.csv"
    _write_record(data, *_sines(11, 12.0), noise_seed=1)
    truth = _write_record(val, *_sines(22, 5.0), noise_seed=2)
    return data, val, truth


def test_identify_from_foreign_csv_predicts_another_trajectory(records, tmp_path):
    data, val, truth = records
    out = tmp_path / "out"
    assert main(["identify", str(data), "--validate", str(val), "--out", str(out)]) == 0
    params = json.loads((out / "parameters.json").read_text())
    assert params["count"] == 52 and params["method"] == "wls"
    first = params["base_parameters"][0]
    assert first["name"] == "Izz1R" and first["definition"] == "Izz1 + Izz2 + Izz3 + Ia1" and first["std"] > 0
    summary = json.loads((out / "summary.json").read_text())
    errors = np.array(summary["relative_rms_error"])
    assert errors.shape == (6,) and np.all(errors < 0.03), errors
    with open(out / "prediction.csv") as handle:
        rows = list(csv.reader(handle))
    assert rows[0] == ["t"] + [f"tau_pred{i}" for i in range(1, 7)]
    predicted = np.array(rows[1:], dtype=float)
    assert predicted.shape == (truth.shape[0], 7)
    # against the noise-free torques of the unseen arm: well below the 0.1 %-of-rated noise floor
    rel_true = np.sqrt(np.mean((predicted[:, 1:] - truth) ** 2, axis=0) / np.mean(truth**2, axis=0))
    assert np.all(rel_true < 0.01), rel_true


def test_identify_with_given_derivatives(tmp_path):
    data = tmp_path / "with_qd.csv"
    _write_record(data, *_sines(33, 8.0), noise_seed=3, derivatives=True)
    out = tmp_path / "out"
    assert main(["identify", str(data), "--out", str(out), "--method", "ols"]) == 0
    params = json.loads((out / "parameters.json").read_text())
    assert params["method"] == "ols" and params["data"]["derivatives"] == "given in the record"
    assert not (out / "summary.json").exists()


def _table(path, header, rows):
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        writer.writerows(rows)


HEADER = ["t"] + [f"q{i}" for i in range(1, 7)] + [f"tau{i}" for i in range(1, 7)]


def _rows(n: int):
    return [[f"{k * DT:.6f}"] + ["0.1"] * 12 for k in range(n)]


def test_not_exciting_data_is_refused_naming_the_parameters(tmp_path, capsys):
    data = tmp_path / "joint1_only.csv"
    _write_record(data, *_sines(44, 4.0, joints=(0,)), noise_seed=4)
    assert main(["identify", str(data), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "rank deficient" in err and "poorly excited base parameters" in err and "fv2" in err
    assert not (tmp_path / "out" / "parameters.json").exists()


def test_too_short_record_is_refused(tmp_path, capsys):
    data = tmp_path / "short.csv"
    t, q, qd, qdd = _sines(55, 0.06)
    _write_record(data, t, q, qd, qdd, noise_seed=5)
    assert main(["identify", str(data), "--out", str(tmp_path / "out")]) == 2
    assert "record too short" in capsys.readouterr().err


@pytest.mark.parametrize("case, match", [
    ("nan", r"column 'q3', line 5: 'nan', expected a finite number in rad"),
    ("missing", r"missing column\(s\) \['tau6'\]"),
    ("unknown", r"unknown column\(s\) \['tau7'\]"),
    ("partial_qd", r"qd columns \['qd1'\] given but"),
    ("text", r"column 'tau2', line 3: 'abc' is not a number"),
    ("backwards", r"non-monotonic"),
    ("irregular", r"expected uniform sampling"),
    ("ragged", r"line 4 has 12 cells, expected 13"),
    ("empty", r"empty file"),
])
def test_malformed_records_raise_clear_errors(tmp_path, case, match):
    path = tmp_path / f"{case}.csv"
    header, rows = list(HEADER), _rows(200)
    if case == "nan":
        rows[3][3] = "nan"
    elif case == "missing":
        header, rows = header[:-1], [r[:-1] for r in rows]
    elif case == "unknown":
        header[-1] = "tau7"
    elif case == "partial_qd":
        header, rows = header + ["qd1"], [r + ["0"] for r in rows]
    elif case == "text":
        rows[1][8] = "abc"
    elif case == "backwards":
        rows[10][0], rows[11][0] = rows[11][0], rows[10][0]
    elif case == "irregular":
        rows = [[f"{k * DT * (1.0 if k < 100 else 1.5):.6f}"] + r[1:] for k, r in enumerate(rows)]
    elif case == "ragged":
        rows[2] = rows[2][:-1]
    if case == "empty":
        path.write_text("")
    else:
        _table(path, header, rows)
    with pytest.raises(IdentificationDataError, match=match) as info:
        read_motion_csv(path)
    assert isinstance(info.value, ValueError) and str(path) in str(info.value)


def test_missing_file_exit_code(tmp_path, capsys):
    assert main(["identify", str(tmp_path / "nope.csv"), "--out", str(tmp_path / "o")]) == 2
    assert "file not found" in capsys.readouterr().err


SAMPLING_BIAS = [-0.2, -0.4, -0.3, -0.05, -0.05, -0.02]  # N m per rad/s^2, ~35 % of Ia3..Ia6


def test_torque_sampling_correction(tmp_path, capsys):
    """A record whose torque carries the drives' sampling term b_i qdd_i: uncorrected, Ia3..Ia6
    come out as Ia_i + b_i; with --torque-sampling-bias b they come back to the truth, and the
    summary says which b was removed. 'drives' measures b on the servo-drive FMU; a bad value is
    refused with exit code 2."""
    data, val = tmp_path / "data.csv", tmp_path / "val.csv"
    _write_record(data, *_sines(11, 12.0), noise_seed=1, sampling_bias=SAMPLING_BIAS)
    _write_record(val, *_sines(22, 5.0), noise_seed=2, sampling_bias=SAMPLING_BIAS)
    arm = make_true_robot(UNSEEN_SEED, payload=PAYLOAD)
    true_ia = np.asarray(arm.dynamic_parameters)[60:66]

    def rotors(out):
        values = {p["name"]: p["value"] for p in json.loads((out / "parameters.json").read_text())["base_parameters"]}
        return np.array([values[f"Ia{j}"] for j in range(3, 7)])

    plain, fixed = tmp_path / "plain", tmp_path / "fixed"
    assert main(["identify", str(data), "--out", str(plain)]) == 0
    bias = ",".join(str(b) for b in SAMPLING_BIAS)
    assert main(["identify", str(data), "--validate", str(val), "--out", str(fixed), f"--torque-sampling-bias={bias}"]) == 0
    uncorrected = rotors(plain) / true_ia[2:] - 1
    corrected = rotors(fixed) / true_ia[2:] - 1
    print("uncorrected / Ia - 1:", uncorrected.round(4), "corrected / Ia - 1:", corrected.round(4))
    # the term is collinear with the rotor columns alone: the correction moves exactly those by -b
    assert np.allclose(rotors(fixed) - rotors(plain), -np.array(SAMPLING_BIAS[2:]), rtol=1e-3)
    assert np.all(np.abs(corrected) < 0.10) and uncorrected[0] < -0.25
    summary = json.loads((fixed / "summary.json").read_text())
    assert summary["torque_sampling_correction"]["bias_Nm_per_rad_s2"] == SAMPLING_BIAS
    assert np.all(np.array(summary["relative_rms_error"]) < 0.03)

    drives = tmp_path / "drives"
    assert main(["identify", str(data), "--validate", str(val), "--out", str(drives),
                 "--torque-sampling-bias", "drives"]) == 0
    measured = json.loads((drives / "summary.json").read_text())["torque_sampling_correction"]
    assert "servo drives" in measured["source"] and all(b < 0 for b in measured["bias_Nm_per_rad_s2"])

    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:
        main(["identify", str(data), "--out", str(tmp_path / "bad"), "--torque-sampling-bias", "1,2,3"])
    assert stop.value.code == 2 and "--torque-sampling-bias" in capsys.readouterr().err
    assert main(["identify", str(data), "--out", str(tmp_path / "bad"), "--torque-sampling-bias", "nope.toml"]) == 2
    assert "nope.toml" in capsys.readouterr().err
