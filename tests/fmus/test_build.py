"""The FMUs build from source, validate with fmpy, run alone, rebuild only on change,
carry sources that rebuild them, and export only the FMI functions."""
import ctypes
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy.validation import validate_fmu

from fmus.build import CFLAGS, build_fmu, compile_binary, ensure_fmus
from fmus.rx130l_plant.spec import plant_spec
from fmus.servo_drive.spec import servo_drive_spec


@pytest.fixture(scope="module")
def paths():
    return ensure_fmus()


@pytest.mark.parametrize("name", ["rx130l_plant", "servo_drive"])
def test_validate_fmu_reports_no_problem(paths, name):
    assert validate_fmu(str(paths[name])) == []


@pytest.mark.parametrize("name", ["rx130l_plant", "servo_drive"])
def test_fmu_contents(paths, name):
    with zipfile.ZipFile(paths[name]) as zf:
        names = set(zf.namelist())
    assert "modelDescription.xml" in names
    assert f"binaries/{fmpy.platform}/{name}.so" in names
    for header in ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h", "model_variables.h"):
        assert f"sources/{header}" in names
    spec = plant_spec() if name == "rx130l_plant" else servo_drive_spec()
    for source in spec.source_files:
        assert f"sources/{source}" in names


def test_simulate_plant_alone(paths):
    result = fmpy.simulate_fmu(str(paths["rx130l_plant"]), stop_time=0.2, step_size=1e-3,
                               output=["q[2]", "qd[2]", "qdd[2]"])
    assert len(result) == 201
    assert np.all(np.isfinite(result["q[2]"]))
    # zero torque from the stretched-up pose: link CoM offsets make axis 2 start to fall
    assert abs(result["q[2]"][-1]) > 1e-6


def test_simulate_drive_alone(paths):
    result = fmpy.simulate_fmu(str(paths["servo_drive"]), stop_time=0.01, step_size=50e-6,
                               start_values={"controlword": 0x06}, output=["statusword", "tau_out"])
    # after the first position sample the shutdown command moved it to Ready to switch on
    assert result["statusword"][-1] & 0x6F == 0x21
    assert np.all(result["tau_out"] == 0.0)


def test_rebuild_only_when_inputs_change(paths, tmp_path):
    out = tmp_path / "fmus"
    first, rebuilt = build_fmu("servo_drive", out)
    assert rebuilt
    mtime = first.stat().st_mtime_ns
    again, rebuilt_again = build_fmu("servo_drive", out)
    assert not rebuilt_again and again.stat().st_mtime_ns == mtime
    (out / "servo_drive.stamp").write_text("stale\n")
    _, rebuilt_stale = build_fmu("servo_drive", out)
    assert rebuilt_stale


def test_sources_rebuild_the_binary(paths, tmp_path):
    """Only the FMU's own sources/ are needed to compile a working binary."""
    with zipfile.ZipFile(paths["rx130l_plant"]) as zf:
        zf.extractall(tmp_path / "fmu")
    sources = tmp_path / "fmu" / "sources"
    binary = tmp_path / "fmu" / "binaries" / fmpy.platform / "rx130l_plant.so"
    binary.unlink()
    compile_binary(sources, plant_spec().source_files, binary)
    result = fmpy.simulate_fmu(str(tmp_path / "fmu"), stop_time=0.01, step_size=1e-3, output=["q[3]"])
    reference = fmpy.simulate_fmu(str(paths["rx130l_plant"]), stop_time=0.01, step_size=1e-3, output=["q[3]"])
    assert np.array_equal(result["q[3]"], reference["q[3]"])


@pytest.mark.parametrize("name, hidden", [("rx130l_plant", "rx130l_plant_fd"), ("servo_drive", "model_do_step")])
def test_only_fmi_symbols_are_exported(paths, tmp_path, name, hidden):
    with zipfile.ZipFile(paths[name]) as zf:
        zf.extractall(tmp_path)
    library = ctypes.CDLL(str(tmp_path / "binaries" / fmpy.platform / f"{name}.so"))
    assert hasattr(library, "fmi2DoStep")
    assert not hasattr(library, hidden)  # generated / internal symbols are hidden
    assert "-fvisibility=hidden" in CFLAGS


def test_cli_build_fmus(tmp_path):
    result = subprocess.run([sys.executable, "-m", "cosim", "build-fmus", "--out", str(tmp_path)],
                            capture_output=True, text=True, check=False, cwd=Path(__file__).resolve().parents[2])
    assert result.returncode == 0, result.stderr
    assert "rx130l_plant" in result.stdout and "valid" in result.stdout
    assert (tmp_path / "servo_drive.fmu").is_file() and (tmp_path / "rx130l_plant.fmu").is_file()
    shutil.rmtree(tmp_path)
