"""Shared set-up of the realtime/split tests: a short ISO 9283 cell (motion starts after a
10 ms settle), built by the cell builder the iso9283 job uses, and a short scenario file."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from robot.joints import N_JOINTS

ROOT = Path(__file__).resolve().parents[1]
PERIOD = 400e-6
BUS_TARGETS = [f"bus.target_position[{i}]" for i in range(1, 7)]


def short_scenario_text(stop_time: str, dead_time: int = 1, name: str = "rt_short",
                        extra: str = "") -> str:
    """scenarios/iso9283.toml cut down: one mode, settle 10 ms, 400 us recording of the
    drives' applied targets, no figures; ``extra`` TOML appended."""
    text = (ROOT / "tests" / "long_forms" / "iso9283.toml").read_text()
    subs = [
        (r'stop_time = "[^"]*"', f'stop_time = "{stop_time}"'),
        (r'modes = \[[^\]]*\]', 'modes = ["model_based"]'),
        (r'settle_time = "[^"]*"', 'settle_time = "10 ms"'),
        (r'(\[record\][^\[]*?)period = "1 ms"', r'\1period = "400 us"'),
        (r'signals = \["drive\*.current_demand"\]', "signals = [" + ", ".join(f'"{s}"' for s in BUS_TARGETS) + "]"),
        (r'cycle_time_us = 400', f'cycle_time_us = 400\ndead_time_cycles = {dead_time}'),
        (r'figures = true', 'figures = false'),
        (r'name = "iso9283"', f'name = "{name}"'),
    ]
    for pattern, replacement in subs:
        text, count = re.subn(pattern, replacement, text, count=1, flags=re.S)
        assert count == 1, pattern
    return text + "\n" + extra


def write_scenario(tmp_path: Path, stop_time: str, dead_time: int = 1, extra: str = "") -> Path:
    path = tmp_path / "rt_short.toml"
    path.write_text(short_scenario_text(stop_time, dead_time, extra=extra))
    return path


def build_cell(scenario_path: Path, out_dir: Path):
    """(cell description, built-in controller, ctx) of the scenario's model_based mode, built
    by the one cell builder the jobs use (:func:`cosim.execution.mode_runs.mode_cell`)."""
    from cosim.execution.mode_runs import mode_cell, prepare
    from cosim.scenario import RunContext, load_scenario

    scenario = load_scenario(scenario_path)
    setup = prepare(scenario.data, str(scenario.path))
    cell, controller = mode_cell(setup, "model_based")
    return cell, controller, RunContext(scenario, out_dir, quiet=True)


def column_block(recording, names: list[str]) -> np.ndarray:
    cols = recording.columns
    return recording.data[:, [cols.index(n) for n in names]]


def hil_scenario(tmp_path: Path, stop_time: str = "5 s", loss_threshold: int = 80) -> Path:
    """scenarios/hil.toml at a 2 ms bus cycle (drives sampling at it too), stopping at
    ``stop_time``, the drives' loss-of-SoC/PReq counters tripping at ``loss_threshold``
    (0: never), written to ``tmp_path``/hil.toml."""
    text = (ROOT / "tests" / "long_forms" / "hil.toml").read_text()
    text = text.replace('stop_time = "6 s"', f'stop_time = "{stop_time}"')
    text = text.replace('period = "400 us"', 'period = "2 ms"').replace("cycle_time_us = 400", "cycle_time_us = 2000")
    text = text.replace('builtin = "servo_drive"',
                        'builtin = "servo_drive"\n[fmus.parameters]\nposition_sample_time = 0.002  # s, the bus cycle')
    import re

    for key in ("cn_loss_of_soc", "cn_loss_of_preq"):  # the served drives' thresholds (scenarios/hil.toml sets them)
        text, count = re.subn(rf"^{key} = \d+", f"{key} = {loss_threshold}", text, count=1, flags=re.MULTILINE)
        assert count == 1, key
    path = tmp_path / "hil.toml"
    path.write_text(text)
    return path
