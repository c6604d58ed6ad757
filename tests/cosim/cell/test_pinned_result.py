"""The cell refactors change no number: the first 0.5 s of the main job's model_based and
model_based_elastic modes (same seed, scenario settings of scenarios/iso9283.toml: the elastic
plant with the true robot's geometry) give exactly the figures pinned here. A change of these
digits means the simulation changed: say why in the commit.

History: pinned first on the rigid plant after the cell moved to cosim/cell/ with generated
connections (model_based 0.010246121224081707 / 0.003713130149533058 / 0.0016932704552584492;
the full main job was then checked identical to the run before the move); re-pinned when the
plant's dynamics took the true robot's 39 geometric errors (0.010329932221425054 /
0.003713373148548148 / 0.0017588669033020041, now scenarios/iso9283_rigid.toml); re-pinned
when the main job moved to the elastic plant (model_based 1.6025054215459436 / 1.3064348743661816 /
1.604405447673343, elastic 0.02970100643573479 / 0.023368907064561708 / 0.026165395643837082);
re-pinned when "100 us" and "400 us" became exactly 1e-4 and 4e-4 s (they were 9.999999999999999e-05
and 0.00039999999999999996: scenario units multiplied by 1e-6), a change in the 12th digit."""
from __future__ import annotations

import json
from pathlib import Path

from cosim.cli import main
from scenario_files import write_variant

ROOT = Path(__file__).resolve().parents[3]

PINNED = {
    "model_based": {"tcp_error_max_mm": 1.6025054215460774, "tcp_error_rms_mm": 1.3064348743662006,
                    "tcp_error_max_noise_free_mm": 1.604405447673933},
    "model_based_elastic": {"tcp_error_max_mm": 0.029701006435631463, "tcp_error_rms_mm": 0.023368907064531697,
                            "tcp_error_max_noise_free_mm": 0.02616539564343378},
}


def test_model_based_short_run_is_pinned(tmp_path):
    path = write_variant((ROOT / "scenarios" / "iso9283.toml").read_text(), tmp_path / "pin.toml", [
        ('stop_time = "12.6 s"', 'stop_time = "0.5 s"'),
        ('modes = ["standard", "model_based", "model_based_elastic"]', 'modes = ["model_based", "model_based_elastic"]'),
        ("can_log = true", "can_log = false"), ("figures = true", "figures = false")])
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    modes = json.loads((tmp_path / "out" / "summary.json").read_text())["modes"]
    for mode, pinned in PINNED.items():
        for key, value in pinned.items():
            assert modes[mode][key] == value, (mode, key, modes[mode][key], value)
