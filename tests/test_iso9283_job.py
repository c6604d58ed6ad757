"""The ISO 9283 main job end to end on a short slice (both modes through controller,
fieldbus, six drive FMUs and the plant FMU), and its failure paths: a failing FMU and a
drive fault that makes the controller stop."""
from __future__ import annotations

import json
from pathlib import Path

import can
import numpy as np
import pytest

from cosim.cli import main
from cosim.results import read_csv

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = (ROOT / "scenarios" / "iso9283.toml").read_text(encoding="utf-8")
MODE_KEYS = ("tcp_error_max_mm", "tcp_error_rms_mm", "path_accuracy_AT_mm", "joint_lag_max_rad", "cycle_compute_us",
             "deadline_misses")


def write_scenario(tmp_path: Path, replacements: list[tuple[str, str]]) -> Path:
    text = SCENARIO
    for old, new in replacements:
        assert old in text, old
        text = text.replace(old, new, 1)
    path = tmp_path / "iso.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    """Both modes, 0.1 s settling + 0.7 s of the path (the first rectangle edge)."""
    tmp = tmp_path_factory.mktemp("iso")
    path = write_scenario(tmp, [('stop_time = "12.6 s"', 'stop_time = "0.8 s"'),
                                ('settle_time = "0.2 s"', 'settle_time = "0.1 s"')])
    out = tmp / "out"
    code = main(["run", str(path), "--out", str(out), "--quiet"])
    return code, out, json.loads((out / "summary.json").read_text())


def test_short_run_summary_and_improvement(short_run):
    code, out, summary = short_run
    assert code == 0 and summary["status"] == "ok"
    for key in ("scenario", "status", "sim_time_s", "wall_time_s", "realtime_factor", "modes", "improvement_factor"):
        assert key in summary
    assert summary["sim_time_s"] == pytest.approx(1.6)  # two modes of 0.8 s
    for mode in ("standard", "model_based"):
        entry = summary["modes"][mode]
        for key in MODE_KEYS:
            assert key in entry, (mode, key)
        assert len(entry["joint_lag_max_rad"]) == 6
        assert set(entry["cycle_compute_us"]) >= {"p50", "p99", "max"}
        assert entry["controller_cycles_timed"] > 1500 and entry["path_completed"] is False
        assert entry["motion_start_s"] == pytest.approx(0.1 + 0.0036 + 2 * 400e-6, abs=2e-3)
        assert 0.0 < entry["path_accuracy_AT_mm"] <= entry["tcp_error_max_mm"] + 1e-9
    std, mb = summary["modes"]["standard"], summary["modes"]["model_based"]
    # the standard cascade lags by tens of micrometres at 1 m/s; the feed-forward removes most of it
    assert 0.01 < std["tcp_error_max_noise_free_mm"] < 1.0
    assert summary["improvement_factor_noise_free"] > 5.0
    assert summary["improvement_factor"] > 1.5  # measured: includes the tracker noise (2 um per axis)
    assert summary["improvement_factor"] == pytest.approx(std["tcp_error_max_mm"] / mb["tcp_error_max_mm"])
    assert max(mb["joint_lag_max_rad"]) < max(std["joint_lag_max_rad"])
    # geometric error of the uncalibrated nominal model: millimetres against the programmed path
    assert std["tcp_path_error_max_mm"] > 1.0


def test_short_run_files(short_run):
    _, out, summary = short_run
    for mode in ("standard", "model_based"):
        header, data = read_csv(out / f"timeseries_{mode}.csv")
        assert "plant.q[1]" in header and "drive3.current_actual" in header and "tracker.z" in header
        assert data.shape[0] == 801 and np.all(np.isfinite(data))
        header, data = read_csv(out / f"tcp_{mode}.csv")
        for column in ("x_programmed", "x_commanded", "x_measured", "tcp_error_mm", "lag1", "q_d6"):
            assert column in header
        assert data.shape[0] == 801
        header, data = read_csv(out / f"controller_{mode}.csv")
        assert "tau_ff2" in header and data.shape[0] == 2001  # cycles at 0, 0.4 ms, ..., 0.8 s
        tau_ff = data[:, header.index("tau_ff2")]
        assert (np.abs(tau_ff).max() > 50.0) == (mode == "model_based")  # gravity of axis 2
        frames = list(can.BLFReader(str(out / f"can_{mode}.blf")))
        assert len(frames) >= 2000 * 19  # SYNC + 6 RPDO + 12 TPDO per cycle
        assert {0x080, 0x201, 0x181, 0x286} <= {f.arbitration_id for f in frames}
        assert summary["modes"][mode]["fieldbus"]["frames_recorded"] == len(frames)
    for name in ("figure2a_lag_errors.png", "figure2b_tcp_error.png", "tcp_error_vs_desired_path.png"):
        png = out / name
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
        assert name in summary["figures"]


def test_failing_fmu_stops_cleanly_with_partial_results(tmp_path):
    path = write_scenario(tmp_path, [
        ('stop_time = "12.6 s"', 'stop_time = "0.3 s"'),
        ('modes = ["standard", "model_based"]', 'modes = ["model_based"]'),
        ('name = "drive2"\nbuiltin = "servo_drive"      # gains: fmus/servo_drive/drive_params.toml (axis 2)\n',
         'name = "drive2"\nbuiltin = "servo_drive"\n[fmus.parameters]\nback_emf_constant = 1e300\n'),
    ])
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed"
    assert "fmi2Error" in summary["reason"] or "nan" in summary["reason"] or "inf" in summary["reason"]
    assert summary["failed_component"] in ("plant", "drive2")
    assert 0.0 < summary["stopped_at_s"] < 0.3
    assert summary["modes"]["model_based"]["status"] == "failed"
    header, data = read_csv(out / "timeseries_model_based.csv")
    assert 1 <= data.shape[0] <= summary["stopped_at_s"] / 1e-3 + 2
    assert (out / "controller_model_based.csv").is_file() and (out / "tcp_model_based.csv").is_file()


def test_drive_fault_stops_the_controller_and_fails_the_run(tmp_path):
    path = write_scenario(tmp_path, [
        ('stop_time = "12.6 s"', 'stop_time = "1.0 s"'),
        ('modes = ["standard", "model_based"]', 'modes = ["standard"]'),
        ('settle_time = "0.2 s"', 'settle_time = "0.05 s"'),
        ('can_log = true', 'can_log = false'),
        ('name = "drive4"\nbuiltin = "servo_drive"      # gains: fmus/servo_drive/drive_params.toml (axis 4)\n',
         'name = "drive4"\nbuiltin = "servo_drive"\n[fmus.parameters]\nfollowing_error_window = 1e-6\n'),
    ])
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and summary["failed_component"] == "controller"
    assert "motion stopped" in summary["reason"] and "drive 4" in summary["reason"]
    assert "0x8611" in summary["reason"]  # CiA 402 following error
    entry = summary["modes"]["standard"]
    assert entry["controller_phase"] == "stopped" and entry["stopped_at_s"] < 0.5
    header, data = read_csv(out / "controller_standard.csv")
    cw_quick_stop = data[:, header.index("phase")] == 4  # Phase.STOPPED
    assert cw_quick_stop.any()
