"""``python -m cosim bench --quick``: the suite runs end to end, bench.json holds every figure, and the
results page (RESULTS.md) holds every figure of bench.json with the machine, its load, date and commit."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

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
    assert_page_holds_every_figure(result, (tmp_path / "RESULTS.md").read_text(encoding="utf-8"))
    assert "A `--quick` run" in (tmp_path / "RESULTS.md").read_text(encoding="utf-8")
    assert str(suite.RESULTS_PAGE) not in done.stderr  # a quick run leaves the project's page alone


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


def _rows(page: str) -> dict[str, list[str]]:
    """The cells of every table row of the page whose second cell is a `key`, by key."""
    out = {}
    for line in page.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
        if len(cells) >= 3 and cells[1].startswith("`") and cells[1].endswith("`"):
            out[cells[1].strip("`")] = cells
    return out


def assert_page_holds_every_figure(result: dict, page: str) -> None:
    """Every figure of bench.json (each leaf of every section, each ratio) is a row of the page with
    its value (4 significant digits) and, where the suite's table gives one, its unit; the machine,
    both load averages, the date and the commit are there, and each section's description."""
    suite = load_suite()
    rows = _rows(page)
    leaves = [(f"{section}.{key}", value) for section, figures in result["figures"].items()
              for key, value in suite._leaves(figures)]
    leaves += [(f"ratios.{key}", value) for key, value in result["ratios"].items()]
    assert len(leaves) > 10
    for key, value in leaves:
        assert key in rows, key
        shown = rows[key][2]
        assert shown == suite.page_value(value), (key, shown, value)
        if isinstance(value, float) and math.isfinite(value):
            assert float(shown) == pytest.approx(value, rel=5e-4, abs=1e-12), (key, shown, value)
    assert len(rows) == len(leaves)  # nothing else
    for section, key, label, unit in suite.ROWS:
        if section in result["figures"] and key in result["figures"][section]:
            assert rows[f"{section}.{key}"][0] == label and rows[f"{section}.{key}"][3] == unit.replace("us", "µs")
    m = result["machine"]
    for text in (m["cpu_model"], f"{m['cpus_usable']} usable of {m['logical_cpus']} logical CPUs",
                 suite.page_value(m["load_average"]), suite.page_value(m["load_average_after"]), result["started_at"],
                 f"`{result['git']['commit']}`"):
        assert text in page, text
    descriptions = suite.section_descriptions()
    for section in result["figures"]:
        assert f"## {section}\n\n{descriptions[section]}" in page, section


def test_results_page_of_a_real_run_holds_every_figure(tmp_path):
    """A real quick run of two cheap sections: DIR/RESULTS.md beside bench.json, regenerated equal by
    --page-from; the commit is this checkout's; the project's page is not touched; a bad bench.json
    is one error line, exit 2."""
    done = subprocess.run([sys.executable, "-m", "cosim", "bench", "--quick", "--section", "bus", "--section",
                           "identification", "--out", str(tmp_path)], cwd=ROOT, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads((tmp_path / "bench.json").read_text())
    page = (tmp_path / "RESULTS.md").read_text(encoding="utf-8")
    assert set(result["figures"]) == {"bus", "identification"}
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    assert result["git"]["commit"] == head and isinstance(result["git"]["dirty"], bool)
    assert_page_holds_every_figure(result, page)
    assert "bus, identification" in page and str(load_suite().RESULTS_PAGE) not in done.stderr
    again = subprocess.run([sys.executable, "-m", "cosim", "bench", "--page-from", str(tmp_path / "bench.json"),
                            "--page", str(tmp_path / "again.md")], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0 and (tmp_path / "again.md").read_text(encoding="utf-8") == page
    (tmp_path / "broken.json").write_text("{", encoding="utf-8")
    bad = subprocess.run([sys.executable, "-m", "cosim", "bench", "--page-from", str(tmp_path / "broken.json")],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and bad.stderr.startswith("error: --page-from ")


def test_the_committed_results_page_is_the_writers_page():
    """benchmarks/RESULTS.md (the docs site's Benchmark results) is a page results_page wrote: its
    marker line, the machine and load rows, and every section of the suite."""
    suite = load_suite()
    page = suite.RESULTS_PAGE.read_text(encoding="utf-8")
    assert "<!-- written by `python -m cosim bench` from its bench.json" in page
    for text in ("| load average before (1, 5, 15 min) |", "| load average after (1, 5, 15 min) |", "| git commit | `",
                 "| CPU |", "| date (UTC) |"):
        assert text in page, text
    for section in suite.SECTIONS:
        assert f"\n## {section}\n" in page, section
