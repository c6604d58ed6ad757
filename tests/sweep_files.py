"""Shared by the sweep tests (tests/cosim/sweep/test_ship.py, test_dask.py): a user's scenario
folder with FMUs and a sweep over it, and a planners-job sweep with a user's planner class in a
file next to the scenario."""
from __future__ import annotations

import re
import shutil
from pathlib import Path

from cosim_fmu_models import build_test_fmu

ROOT = Path(__file__).resolve().parents[1]

BASE = """
connections = []

[scenario]
name = "shipped"
job = "fmus"

[simulation]
stop_time = 0.1
macro_step = 0.01

[[fmus]]
name = "i"
path = "fmus/Integrator.fmu"     # relative to this file: a user's FMU, not in the project
[fmus.parameters]
y0 = 1.0
k = 2.0

[[fmus]]
name = "f"
path = "fmus/Faulty.fmu"
[fmus.parameters]
fail_time = 0.5
mode = 1

[record]
period = 0.01
signals = ["i.y", "f.y"]
"""

SWEEP = """
[sweep]
name = "shipped_sweep"
base = "base.toml"
metrics = ["rows_recorded", "sim_time_s"]
collect = ["timeseries"]

[[axes]]
key = "fmus[0].parameters.y0"
values = [1.0, 3.0]

[[axes]]
key = "fmus[1].parameters.fail_time"     # 0.05 s: that variant fails
values = [0.5, 0.05]
"""


PLANNER_ENTRY = "plans/quintic.py:QuinticPtP"
PLANNER_SWEEP = f"""
[sweep]
name = "planner_sweep"
base = "ptp.toml"
metrics = ["planners.*.duration_s"]

[[axes]]
key = 'planners.parameters."{PLANNER_ENTRY}".speed_factor'
values = [0.5, 0.8]
"""


def client_files(folder: Path) -> Path:
    (folder / "fmus").mkdir(parents=True)
    build_test_fmu("integrator", folder / "fmus")
    build_test_fmu("faulty", folder / "fmus")
    (folder / "base.toml").write_text(BASE, encoding="utf-8")
    (folder / "sweep.toml").write_text(SWEEP, encoding="utf-8")
    return folder / "sweep.toml"


def planner_files(folder: Path) -> Path:
    """The PtP planners job with a user's planner class in a file next to the scenario (relative
    'plans/quintic.py:QuinticPtP', its parameters keyed by that text), no execution."""
    (folder / "plans").mkdir(parents=True, exist_ok=True)
    shutil.copy(ROOT / "examples" / "quintic_planner.py", folder / "plans" / "quintic.py")
    text = (ROOT / "scenarios" / "ptp_line.toml").read_text(encoding="utf-8")
    text = re.sub(r"^run = .*$", f'run = ["ruckig", "{PLANNER_ENTRY}"]', text, count=1, flags=re.M)
    text = re.sub(r"^execute = true$", "execute = false", text, count=1, flags=re.M)
    text = re.sub(r"^execute_only = .*$", "", text, count=1, flags=re.M)
    text = text.replace("figures = true", f'figures = false\n[planners.parameters."{PLANNER_ENTRY}"]\n'
                                          f"speed_factor = 0.8", 1)
    (folder / "ptp.toml").write_text(text, encoding="utf-8")
    (folder / "planner_sweep.toml").write_text(PLANNER_SWEEP, encoding="utf-8")
    return folder / "planner_sweep.toml"
