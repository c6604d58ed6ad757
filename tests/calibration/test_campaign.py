"""Simulated calibration campaign, directly and as the 'calibration' job of `cosim run`."""
import json

import numpy as np
import pinocchio as pin
import pytest

from cosim.cli import main
from calibration.campaign import CampaignConfigError, run_calibration_campaign
from calibration.measurements import read_measurements_csv

SMALL = {
    "candidates": {"values_per_axis": 9},  # 9^6 grid -> a few hundred visible configurations
    "selection": {"restarts": 2, "random_draws": 50},
    "validation": {"poses": 100},
}


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    out = tmp_path_factory.mktemp("campaign")
    return out, run_calibration_campaign(SMALL, out, figures=False)


def test_campaign_summary_and_accuracy(campaign):
    out, summary = campaign
    noise_mm = summary["tracker_noise"]["position_sigma_mm"]
    for key in ("uncalibrated", "calibrated"):
        assert set(summary[key]) == {"e_x", "e_y", "e_z", "e_alpha", "e_beta", "e_gamma"}
        assert all({"max", "peak_to_peak"} <= set(v) for v in summary[key].values())
    uncal_pos = max(summary["uncalibrated"][c]["max"] for c in ("e_x", "e_y", "e_z"))
    assert uncal_pos > 3.0  # several millimetres before calibration
    assert max(summary["uncalibrated"][c]["max"] for c in ("e_alpha", "e_beta", "e_gamma")) > 0.3  # deg
    # the calibrated robot (true pose, no tracker noise) within three times the tracker noise
    assert summary["calibrated_max_position_error_mm"] <= 3.0 * noise_mm
    assert summary["calibrated_within_3_sigma"] is True
    assert summary["identifiable_parameters"] == 30
    assert summary["identifiable_parameters_position_only"] == 25
    # the paper's index (lambda_min of Lambda, whitened units) on this 434-candidate set:
    # measured 2.19x the linear scan, 2.70x the median random selection, 0.93 of the
    # certified upper bound with 2 restarts (the 18.5 of the paper is out of reach here:
    # the bound allows at most 2.35x; docs/explanation/calibration.md)
    assert summary["observation_index"] == "min_eigenvalue"
    assert summary["observation_index_scaling"] == "whitened"
    assert summary["observation_index_ratio_vs_linear_scan"] > 2.0
    assert summary["observation_index_ratio_vs_random"] > 2.4
    assert summary["observation_index_selected_over_upper_bound"] > 0.9
    ratios = summary["observation_index_ratios"]
    assert set(ratios) == {"min_eigenvalue", "d_optimality", "inverse_condition", "noise_amplification"}
    assert ratios["min_eigenvalue"]["ratio_vs_linear_scan"] == summary["observation_index_ratio_vs_linear_scan"]
    for entry in ratios.values():
        assert entry["ratio_vs_linear_scan"] > 1.1 and entry["ratio_vs_random"] > 1.1
    verdict = summary["observation_index_paper_factor"]
    assert all(v >= 18.5 for v in verdict["met"].values()) and all(v < 18.5 for v in verdict["not_met"].values())
    assert len(verdict["met"]) + len(verdict["not_met"]) == 10  # 4 indices + 6 equivalent forms
    assert summary["selection"]["configurations"] == 32
    assert summary["validation_poses"] == 100
    # identified base parameters agree with the hidden truth within their standard deviations
    assert summary["parameter_recovery"]["rms_z_score"] < 2.0
    json.dumps(summary, allow_nan=False)


def test_campaign_files(campaign):
    out, summary = campaign
    for name in summary["files"]:
        assert (out / name).is_file(), name
    meas = read_measurements_csv(out / "measurements.csv")
    assert meas.count == 32 and meas.has_orientation
    model = pin.buildModelFromUrdf(str(out / "calibrated.urdf"))
    assert model.nq == 6
    table = (out / "table2.md").read_text()
    assert "19.026" in table and "e_gamma in deg" in table
    chosen = np.array(summary["selection"]["q_rad"])
    assert np.allclose(chosen, meas.q)


def test_config_errors(tmp_path):
    with pytest.raises(CampaignConfigError, match="unknown key selection.restart;"):
        run_calibration_campaign({"selection": {"restart": 2}}, tmp_path)
    with pytest.raises(CampaignConfigError, match="unknown section 'tracking'"):
        run_calibration_campaign({"tracking": {}}, tmp_path)


def test_cosim_run_job(tmp_path):
    scenario = tmp_path / "cal.toml"
    scenario.write_text(
        '[scenario]\nname = "cal_small"\njob = "calibration"\n'
        '[tracker]\nposition_sigma = "0.1 mm"\nmeasure_orientation = false\n'
        "[candidates]\nvalues_per_axis = 8\n"
        "[selection]\nrestarts = 1\nrandom_draws = 20\n"
        "[validation]\nposes = 100\n"
    )
    assert main(["run", str(scenario), "--out", str(tmp_path / "res"), "--quiet"]) == 0
    summary = json.loads((tmp_path / "res" / "summary.json").read_text())
    assert summary["status"] == "ok" and summary["job"] == "calibration"
    assert summary["identifiable_parameters"] == 25  # position only
    assert summary["calibrated_max_position_error_mm"] < 0.3
    for name in ("table2.png", "configurations.png", "table2.md", "calibrated.urdf"):
        assert (tmp_path / "res" / name).stat().st_size > 0
    bad = tmp_path / "bad.toml"
    bad.write_text('[scenario]\nname = "bad"\njob = "calibration"\n[tracker]\nposition_sigma = "0.1 deg"\n')
    assert main(["run", str(bad), "--out", str(tmp_path / "bad"), "--quiet"]) == 2
