"""The main job's ``export-ssp`` archive, unchanged, runs in two co-simulation engines we did
not write, libcosim (PyPI ``libcosimpy``) and Ecos (PyPI ``ecospy``, which needs the system's
TBB runtime, Debian ``libtbb12``), and their plant joint angles over 1 s equal those of our
master running the same archive to 1e-12 rad. Both packages are test dependencies: without
them these tests fail (they do not skip). The docs' code samples for both engines run here too.
"""
from __future__ import annotations

import re
import zipfile
from pathlib import Path

import numpy as np
import pytest

try:
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
except ImportError as exc:
    pytest.fail(f"libcosimpy is a test dependency (pip install -e '.[test]'): {exc}", pytrace=False)
try:
    from ecospy import EcosSimulation
except (ImportError, OSError) as exc:  # OSError: its library's TBB runtime is missing
    pytest.fail(f"ecospy is a test dependency (pip install -e '.[test]') and needs the system's TBB runtime "
                f"(apt-get install libtbb12, as .ci/run does): {exc}", pytrace=False)

from cosim.cli import main
from cosim.results import read_csv
from cosim.ssp import PARAMETER_SET, load_ssp

REPO = Path(__file__).resolve().parents[3]
SIM_TIME = 1.0  # s
SAMPLE = 1e-3  # s: the joint angles are compared every 1 ms
TOLERANCE = 1e-12  # rad
Q = [f"q[{i}]" for i in range(1, 7)]


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    """The main job's archive, as `python -m cosim export-ssp scenarios/iso9283.toml iso9283.ssp` writes it."""
    out = tmp_path_factory.mktemp("engines") / "iso9283.ssp"
    assert main(["export-ssp", str(REPO / "scenarios" / "iso9283.toml"), str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def ours(archive):
    """Our master on the same archive (scenario ``system = "iso9283.ssp"``, the archive's step):
    plant q every 1 ms from t = 1 ms to 1 s, one row per sample."""
    step = load_ssp(archive).macro_step
    scenario = archive.parent / "ours.toml"
    scenario.write_text(f"""system = "{archive.name}"

[scenario]
name = "iso9283_archive"
job = "fmus"

[simulation]
stop_time = {SIM_TIME!r}
macro_step = {step!r}

[record]
period = {SAMPLE!r}
signals = ["plant.q[*]"]
""")
    out = archive.parent / "ours"
    assert main(["run", str(scenario), "--out", str(out), "--quiet"]) == 0
    columns, rows = read_csv(out / "timeseries.csv")
    assert rows.shape == (round(SIM_TIME / SAMPLE) + 1, 7)
    return rows[1:, [columns.index(f"plant.{q}") for q in Q]]


def test_the_archive_holds_its_step_for_other_engines(archive):
    system = load_ssp(archive)
    assert system.macro_step == 1e-4  # "100 us" in scenarios/iso9283.toml, exactly
    text = zipfile.ZipFile(archive).read("SystemStructure.ssd").decode()
    assert '<osp:FixedStepAlgorithm baseStepSize="0.0001"/>' in text  # libcosim's (and OSP's) fixed step
    # both engines take a connection only between two components (an SSD element each)
    assert text.count("<ssd:Connection ") == text.count(" startElement=") == len(system.connections) == 18


def test_libcosim_runs_the_archive_unchanged_like_our_master(archive, ours):
    log_output_level(CosimLogLevel.ERROR)
    execution = CosimExecution.from_ssp_file(str(archive))  # the step: the archive's FixedStepAlgorithm
    assert execution.num_slaves() == 7
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    plant = execution.slave_index_from_instance_name("plant")
    refs = {v.name.decode(): v.reference for v in execution.slave_variables(plant)}
    steps = round(SAMPLE / load_ssp(archive).macro_step)
    q = []
    for _ in range(len(ours)):
        assert execution.step(steps)
        q.append(observer.last_real_values(plant, [refs[name] for name in Q]))
    assert execution.status().current_time == round(SIM_TIME * 1e9)  # ns
    q = np.array(q)
    assert np.ptp(ours, axis=0).max() > 1e-4  # the arm moves (drives disabled, gravity against the brakes)
    assert np.abs(q - ours).max() <= TOLERANCE, np.abs(q - ours).max()


def _ecos(archive, steps: int, samples: int, parameter_set: str | None) -> np.ndarray:
    q = []
    with EcosSimulation(ssp_path=str(archive), step_size=load_ssp(archive).macro_step) as sim:
        sim.init(parameter_set=parameter_set)
        for _ in range(samples):
            sim.step(steps)
            q.append([sim.get_real(f"plant::{name}") for name in Q])
        assert abs(sim.get_time() - SIM_TIME) < 1e-9
        sim.terminate()
    return np.array(q)


def test_ecos_runs_the_archive_unchanged_like_our_master(archive, ours):
    steps = round(SAMPLE / load_ssp(archive).macro_step)
    q = _ecos(archive, steps, len(ours), PARAMETER_SET)
    assert np.abs(q - ours).max() <= TOLERANCE, np.abs(q - ours).max()
    # the comparison sees the parameter values: without the set, the FMUs' defaults move the arm otherwise
    assert np.abs(_ecos(archive, steps, len(ours), None) - ours).max() > 1e-5


def _doc_samples() -> dict[str, str]:
    """The python code blocks of the how-to page that runs the archive in other engines."""
    text = (REPO / "docs" / "how-to" / "ssp.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    return {("libcosim" if "libcosimpy" in b else "ecos"): b for b in blocks}


@pytest.mark.parametrize("engine", ["libcosim", "ecos"])
def test_the_docs_samples_run(archive, ours, engine, monkeypatch, capsys):
    samples = _doc_samples()
    assert sorted(samples) == ["ecos", "libcosim"]
    monkeypatch.chdir(archive.parent)  # the samples open "iso9283.ssp" in the working folder
    namespace: dict = {"__name__": "__doc_sample__"}
    exec(compile(samples[engine], f"docs/how-to/ssp.md ({engine})", "exec"), namespace)
    assert "q" in capsys.readouterr().out
    assert np.abs(np.array(namespace["q"]) - ours[-1]).max() <= TOLERANCE
