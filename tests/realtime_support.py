"""Shared set-up of the realtime/split tests: a short ISO 9283 cell (motion starts after a
10 ms settle), built exactly as the iso9283 job builds it, and a short scenario file."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PERIOD = 400e-6
N_JOINTS = 6
BUS_TARGETS = [f"bus.target_position[{i}]" for i in range(1, 7)]


def short_scenario_text(stop_time: str, dead_time: int = 1, name: str = "rt_short",
                        extra: str = "") -> str:
    """scenarios/iso9283.toml cut down: one mode, settle 10 ms, 400 us recording of the
    drives' applied targets, no figures; ``extra`` TOML appended."""
    text = (ROOT / "scenarios" / "iso9283.toml").read_text()
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
    """(doc, controller, true_robot, ctx, fieldbus config, tracker config) as the iso9283 job builds them."""
    from controller import Controller, ControllerConfig, TcpTrajectory
    from cosim.jobs import iso9283, robot_cell
    from cosim.jobs.laser_tracker import TrackerConfig
    from cosim.scenario import RunContext, load_scenario
    from fieldbus import FieldbusConfig
    from planners.iso9283 import ISO_Q_HINT, iso9283_test_path

    scenario = load_scenario(scenario_path)
    doc = scenario.data
    iso9283.fill_table_defaults(doc)
    ctrl_t = doc["controller"]
    stop_time = doc["simulation"]["stop_time"]
    true_robot = iso9283.make_true_robot(doc["true_robot"])
    path = iso9283_test_path(speed=doc["path"]["speed"], acceleration=doc["path"]["acceleration"])
    reference = TcpTrajectory.from_reference(path.reference, path.duration, PERIOD)
    kin, dyn, _, _ = iso9283.controller_models(ctrl_t, true_robot)
    fb = FieldbusConfig.from_dict(doc["fieldbus"])
    config = ControllerConfig(mode="model_based", period_s=PERIOD, lead_cycles=1 + fb.dead_time_cycles,
                              compute_budget_s=ctrl_t["compute_budget"], settle_time_s=ctrl_t["settle_time"])
    controller = Controller(reference, config, kinematic_model=kin, dynamics=dyn, q_hint=np.array(ISO_Q_HINT),
                            drive_model=robot_cell.drive_loop_model(doc["fmus"], PERIOD),
                            capacity=int(stop_time / PERIOD) + 16)
    tracker = TrackerConfig(doc["tracker"]["period"], doc["tracker"]["noise_sigma"], doc["tracker"]["seed"])
    ctx = RunContext(scenario, out_dir, quiet=True)
    return doc, controller, true_robot, ctx, fb, tracker


def column_block(recording, names: list[str]) -> np.ndarray:
    cols = recording.columns
    return recording.data[:, [cols.index(n) for n in names]]
