"""The CLI lists its commands and the robot description loads."""
import json
import subprocess
import sys


def test_help_lists_commands():
    out = subprocess.run([sys.executable, "-m", "cosim", "--help"], capture_output=True, text=True, check=True)
    assert "robot-info" in out.stdout


def test_robot_info_reports_reach_and_mass():
    out = subprocess.run([sys.executable, "-m", "cosim", "robot-info"], capture_output=True, text=True, check=True)
    info = json.loads(out.stdout)
    assert len(info["joints"]) == 6
    assert 100.0 < info["moving_mass_kg"] < 250.0
    # zero configuration: arm straight up, flange at 0.55 + 0.625 + 0.925 + 0.110 m
    assert abs(info["flange_at_zero_m"][2] - 2.21) < 1e-12
