"""FMI 3.0 builds of the plant and the drive: same C model source as the FMI 2.0 builds
(fmus/common/fmi3_wrapper.c instead of fmi2_wrapper.c, modelDescription from fmus/fmi3_spec.py),
valid for fmpy, and the ISO 9283 main job's first 2 s give the same numbers with either build."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from cosim.cli import main
from cosim.results import read_csv
from fmus.build import ensure_fmus
from fmus.fmu import variables_of

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def builds():
    return ensure_fmus(fmi=2), ensure_fmus(fmi=3)


@pytest.mark.parametrize("name", ("rx130l_plant", "servo_drive"))
def test_fmi3_builds_are_valid_and_expose_the_fmi2_variables(builds, name):
    fmi2, fmi3 = builds
    assert fmi3[name].parent.name == "fmi3"
    assert validate_fmu(str(fmi3[name])) == []
    md2, md3 = read_model_description(str(fmi2[name])), read_model_description(str(fmi3[name]))
    assert md3.fmiVersion == "3.0" and md3.coSimulation is not None and md3.modelExchange is None
    v2, v3 = variables_of(md2), variables_of(md3)
    assert list(v2) == list(v3)  # q[1]..q[6] are elements of the Float64[6] array q
    for n, v in v2.items():
        assert (v3[n].type, v3[n].causality) == ({"Real": "Float64", "Integer": "Int32"}[v.type], v.causality), n
        if v.causality == "parameter":
            assert float(v3[n].start) == float(v.start), n
    if name == "rx130l_plant":
        q = next(v for v in md3.modelVariables if v.name == "q")
        assert [d.start for d in q.dimensions] == [6] and q.type == "Float64"


def _scenario(tmp_path: Path, fmus: dict[str, Path], label: str) -> Path:
    text = (REPO / "tests" / "long_forms" / "iso9283.toml").read_text()
    for old, new in (('stop_time = "12.6 s"', 'stop_time = "2 s"'),
                     ('modes = ["standard", "model_based", "model_based_elastic"]', 'modes = ["model_based"]'),
                     ('builtin = "rx130l_plant"', f'path = "{fmus["rx130l_plant"].as_posix()}"'),
                     ('builtin = "servo_drive"', f'path = "{fmus["servo_drive"].as_posix()}"')):
        assert old in text, old
        text = text.replace(old, new)
    path = tmp_path / f"iso9283_{label}.toml"
    path.write_text(text)
    return path


def test_main_job_first_2_s_equal_with_fmi2_and_fmi3_builds(builds, tmp_path):
    outs = {}
    for label, fmus in zip(("fmi2", "fmi3"), builds):
        outs[label] = tmp_path / label
        assert main(["run", str(_scenario(tmp_path, fmus, label)), "--out", str(outs[label]), "--quiet"]) == 0
    for name in ("timeseries_model_based.csv", "tcp_model_based.csv", "controller_model_based.csv"):
        c2, a = read_csv(outs["fmi2"] / name)
        c3, b = read_csv(outs["fmi3"] / name)
        assert c2 == c3 and a.shape == b.shape, name
        simulated = [j for j, c in enumerate(c2) if c != "compute_us"]  # compute_us: the controller's wall time
        a, b = a[:, simulated], b[:, simulated]
        assert a[-1, 0] == pytest.approx(2.0, abs=1e-3)
        both = np.isfinite(a) & np.isfinite(b)
        assert np.array_equal(np.isfinite(a), np.isfinite(b)), name
        assert np.max(np.abs(a[both] - b[both])) <= 1e-12, name  # in fact identical
    columns, rows = read_csv(outs["fmi3"] / "timeseries_model_based.csv")
    assert np.ptp(rows[:, columns.index("plant.q[1]")]) > 0.01  # the arm moved: not a trivial comparison
