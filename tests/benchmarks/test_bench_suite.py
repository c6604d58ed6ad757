"""``python -m cosim bench --quick``: the suite runs end to end and bench.json holds every figure."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

from cosim.commands.bench import load_suite

ROOT = Path(__file__).resolve().parents[2]


def test_quick_suite_writes_every_figure(tmp_path):
    done = subprocess.run([sys.executable, "-m", "cosim", "bench", "--quick", "--out", str(tmp_path)], cwd=ROOT,
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads((tmp_path / "bench.json").read_text())
    suite = load_suite()
    assert result["quick"] is True and result["sizes"]["repeats"] == 1
    assert result["errors"] == {} and result["missing"] == []
    for section, keys in suite.REQUIRED.items():
        for key in keys:
            value = result["figures"][section][key]
            assert isinstance(value, (int, float)) and math.isfinite(value) and value >= 0, (section, key, value)
    assert set(result["ratios"]) == set(suite.RATIOS)
    assert all(v > 0 for v in result["ratios"].values())
    f = result["figures"]
    assert result["ratios"]["own_cp_vs_toppra_duration"] == f["planners"]["own_cp_duration_s"] / f["planners"][
        "toppra_duration_s"]
    assert result["ratios"]["in_process_vs_split_realtime_factor"] == f["closed_loop"]["realtime_factor"] / f[
        "closed_loop_split"]["realtime_factor"]
    m = result["machine"]
    assert m["cpu_model"] and m["logical_cpus"] >= 1 and len(m["load_average"]) == 3 and m["numpy"] and m["python"]
    assert f["paced"]["cycles"] == round(result["sizes"]["paced_sim_s"] / 400e-6) + 1
    for label in ("closed-loop real-time factor, split", "own CP solve", "ratios (same run)", "machine:"):
        assert label in done.stdout


def test_missing_figures_and_ratios_are_reported():
    suite = load_suite()
    result = {"figures": {"planners": {"own_cp_solve_s": 2.0, "toppra_solve_s": 0.5, "own_cp_duration_s": float("nan")}},
              "ratios": {}}
    result["ratios"] = suite.ratios(result["figures"])
    assert result["ratios"]["own_cp_vs_toppra_solve_time"] == 4.0
    assert result["ratios"]["own_cp_vs_toppra_duration"] is None
    missing = suite.missing_figures(result)
    assert "planners.own_cp_duration_s" in missing and "closed_loop.realtime_factor" in missing
    assert "ratios.in_process_vs_split_realtime_factor" in missing and "planners.own_cp_solve_s" not in missing


def test_unknown_section_is_refused(tmp_path):
    done = subprocess.run([sys.executable, "-m", "cosim", "bench", "--section", "gpu", "--out", str(tmp_path)],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "--section 'gpu'" in done.stderr and not (tmp_path / "bench.json").exists()
