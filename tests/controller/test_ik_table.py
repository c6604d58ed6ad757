"""The compiled joint reference table (controller/ik_table.cpp) against the Python knot loop
of controller.elastic.joint_reference_on_grid: the same numbers bit for bit on the main job's
ISO 9283 reference (30 520 knots), and on a path that hands knots back to Python."""
from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

import native
from controller import ik_table
from controller.elastic import joint_reference_on_grid
from controller.joint_reference import CartesianToJoint
from planners.iso9283 import ISO_Q_HINT

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def main_job_setup():
    from cosim.api import load_scenario
    from cosim.execution.mode_runs import prepare

    scenario = load_scenario(ROOT / "scenarios" / "iso9283.toml")
    return prepare(copy.deepcopy(scenario.data), str(scenario.path))


def _compiled_or_skip_reason():
    library = ik_table.load()
    if library is None and native.mode() == "require":
        pytest.fail("the compiled IK table did not build under COSIM_NATIVE=require")
    return library


def test_compiled_table_is_the_python_loop_bit_for_bit(main_job_setup):
    from controller import start_configuration

    if _compiled_or_skip_reason() is None:
        pytest.skip("no compiled IK table here (COSIM_NATIVE=off or no C++ compiler/headers): Python path only")
    setup = main_job_setup
    q_start = start_configuration(setup.reference, setup.kinematics, np.array(ISO_Q_HINT))
    python = joint_reference_on_grid(setup.reference, setup.kinematics, q_start, compiled=False)
    ik = CartesianToJoint(setup.kinematics)
    ik.reset(q_start)
    out = np.empty((3, setup.reference.grid.n, 6))
    assert ik_table.solve_table(ik, setup.reference, out)
    for name, a, b in zip(("q", "qd", "qdd"), python, out):
        assert np.array_equal(a, b), f"{name}: max difference {np.max(np.abs(a - b))}"
    # the IK's state afterwards is the last knot's, as after the Python loop
    assert np.array_equal(ik.q, python[0][-1]) and np.array_equal(ik.qdd, python[2][-1])


def test_knots_the_fast_path_refuses_are_solved_by_python(main_job_setup, monkeypatch):
    """A start far from the path's first pose: the first knots need more Newton steps (Python's
    NumericIK); the rest runs compiled again; the table equals the Python loop's."""
    from controller import start_configuration

    if _compiled_or_skip_reason() is None:
        pytest.skip("no compiled IK table here: Python path only")
    setup = main_job_setup
    q_start = start_configuration(setup.reference, setup.kinematics, np.array(ISO_Q_HINT)) + 0.05
    assert ik_table.load() is not None  # built (a run itself only uses it once built)
    handed_back = []
    original = CartesianToJoint.solve

    def counting(self, *args):
        handed_back.append(1)
        return original(self, *args)

    python = joint_reference_on_grid(setup.reference, setup.kinematics, q_start, compiled=False)
    monkeypatch.setattr(CartesianToJoint, "solve", counting)
    compiled = joint_reference_on_grid(setup.reference, setup.kinematics, q_start)
    assert 1 <= len(handed_back) < 100
    for a, b in zip(python, compiled):
        assert np.array_equal(a, b)


def test_a_run_does_not_wait_for_the_compile(tmp_path, monkeypatch, capsys):
    """On a cache without the table, a run's load does not compile (about 40 CPU-s): None, and
    the note says once that the Python loop runs; ``cosim build``'s load would build it."""
    folder = tmp_path / "cache"
    folder.mkdir(mode=0o700)
    monkeypatch.setenv(native.ENV_CACHE, str(folder))
    monkeypatch.setenv(native.ENV_MODE, "auto")
    monkeypatch.setattr(ik_table, "_loaded", [])
    monkeypatch.setattr(native, "_reported", set())
    assert ik_table.load(build=False) is None
    assert "not built yet" in capsys.readouterr().err
    assert not [p for p in folder.iterdir() if p.name.startswith("ik_table")]
