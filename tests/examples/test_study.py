"""examples/payload_deadtime_study.py runs as a user would run it (its own process, another
working directory), prints and plots its table, and the table equals the same 8 variants
run through ``python -m cosim sweep`` from a hand-written sweep file, to the last digit."""
from __future__ import annotations

import csv
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "payload_deadtime_study.py"


def _env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")


@pytest.mark.slow   # two sweeps of 8 closed-loop cell runs in subprocesses: 20-80 s depending on the load
def test_study_script_matches_cosim_sweep(tmp_path):
    # 0.3 s per variant (the script's default is 0.5 s) keeps the two runs of 8 variants short
    ran = subprocess.run([sys.executable, str(EXAMPLE), "--out", str(tmp_path / "script"), "--workers", "2",
                          "--stop-time", "0.3 s"],
                         cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=600)
    assert ran.returncode == 0, ran.stderr[-3000:]
    lines = ran.stdout.strip().splitlines()
    assert lines[0].split()[:3] == ["payload", "dead", "time"] and len(lines) == 1 + 8
    assert (tmp_path / "script" / "payload_deadtime_study.png").stat().st_size > 20_000
    with open(tmp_path / "script" / "table.csv", newline="") as f:
        script_rows = list(csv.DictReader(f))
    assert len(script_rows) == 8

    (tmp_path / "study.toml").write_text(textwrap.dedent(f"""
        [sweep]
        name = "payload_deadtime_cli"
        base = "{ROOT / 'scenarios' / 'iso9283_rigid.toml'}"
        metrics = ["modes.*.tcp_error_max_mm", "modes.*.tcp_error_rms_mm", "modes.*.path_accuracy_AT_mm"]

        [overrides]
        "simulation.stop_time" = "0.3 s"
        "results.can_log" = false
        "results.figures" = false

        [[axes]]
        key = "true_robot.payload_mass"
        values = ["0 kg", "10 kg"]

        [[axes]]
        key = "fieldbus.dead_time_cycles"
        values = [1, 3]

        [[axes]]
        key = "controller.modes"
        values = [["standard"], ["model_based"]]
        """), encoding="utf-8")
    cli = subprocess.run([sys.executable, "-m", "cosim", "sweep", "study.toml", "--out", "cli", "--workers", "2",
                          "--quiet"], cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=600)
    assert cli.returncode == 0, cli.stderr[-3000:]
    with open(tmp_path / "cli" / "sweep.csv", newline="") as f:
        cli_rows = {(float(r["true_robot.payload_mass"]), int(r["fieldbus.dead_time_cycles"]),
                     r["controller.modes"]): r for r in csv.DictReader(f)}
    assert len(cli_rows) == 8
    for row in script_rows:
        mode = row["mode"]
        other = cli_rows[(float(row["payload_kg"]), int(row["dead_time_cycles"]), f'["{mode}"]')]
        assert other["status"] == "ok"
        for metric in ("tcp_error_max_mm", "tcp_error_rms_mm", "path_accuracy_AT_mm"):
            # both tables write repr(float): equal text is equal to the last digit
            assert row[metric] == other[f"modes.{mode}.{metric}"], (row, metric)
    # the study shows what it is for: the model-based feed-forward tracks far better than the cascade
    by = {(float(r["payload_kg"]), int(r["dead_time_cycles"]), r["mode"]): float(r["tcp_error_max_mm"])
          for r in script_rows}
    for payload in (0.0, 10.0):
        for dead in (1, 3):
            assert by[(payload, dead, "model_based")] < 0.1 * by[(payload, dead, "standard")]
