"""FMUs that crash, hang or end the simulation themselves.

A C test FMU (tests/c_test_fmus.py, built here with the system compiler) segfaults, aborts,
calls _exit or hangs in fmi2DoStep from 0.5 s on. Run out of process ([[fmus]]
out_of_process = true), that becomes a clean ``failed`` naming the component, the time and
the signal, with the other FMU's data up to that time on disk. An FMU that returns
fmi2Discard with fmi2Terminated ends the run normally at its fmi2LastSuccessfulTime, in
process and out of process, with both engines.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from c_test_fmus import build_misbehave_fmu
from cosim.cli import main
from cosim.results import read_series

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}

SCENARIO = """
connections = ["clock.y -> bad.u"]

[scenario]
name = "misbehave"
job = "fmus"

[simulation]
stop_time = {stop}
macro_step = 0.001
engine = "{engine}"

[[fmus]]
name = "clock"
path = "Misbehave.fmu"

[[fmus]]
name = "bad"
path = "Misbehave.fmu"
{bad_options}
[fmus.parameters]
mode = {mode}
fail_time = 0.5

[record]
period = 0.01
signals = ["clock.y", "bad.y", "bad.echo"]
"""


@pytest.fixture(scope="module")
def fmu_dir(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("misbehave")
    build_misbehave_fmu(folder)
    return folder


def scenario(fmu_dir: Path, tmp_path: Path, mode: int, bad_options: str = "out_of_process = true",
             stop: float = 1.0, engine: str = "auto") -> Path:
    (tmp_path / "Misbehave.fmu").write_bytes((fmu_dir / "Misbehave.fmu").read_bytes())
    path = tmp_path / "s.toml"
    path.write_text(SCENARIO.format(mode=mode, bad_options=bad_options, stop=stop, engine=engine))
    return path


def read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    """The run's time series of ``path``'s stem (Parquet, the default format; while the run
    goes, its stream ``.parquet.partial``)."""
    return read_series(path)


def test_the_test_fmu_is_valid(fmu_dir):
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(fmu_dir / "Misbehave.fmu")) == []


@pytest.mark.parametrize("mode, options, words", [
    (2, "out_of_process = true", ["SIGSEGV", "signal 11"]),
    (3, "out_of_process = true", ["SIGABRT"]),
    (4, "out_of_process = true", ["exited with code 3"]),
    (5, 'out_of_process = true\nstep_timeout = "1 s"', ["step timeout of 1 s", "hangs"]),
])
def test_crash_or_hang_out_of_process_fails_cleanly(fmu_dir, tmp_path, capsys, mode, options, words):
    path = scenario(fmu_dir, tmp_path, mode, options)
    out = tmp_path / "out"
    if mode == 2:  # as a user runs it: one process, stderr without a traceback
        done = subprocess.run([sys.executable, "-m", "cosim", "run", str(path), "--out", str(out), "--quiet"],
                              env=ENV, capture_output=True, text=True, timeout=120)
        code, err = done.returncode, done.stderr
    else:
        code, err = main(["run", str(path), "--out", str(out), "--quiet"]), capsys.readouterr().err
    assert code == 3, err
    assert "Traceback" not in err and "error: misbehave: run failed" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and summary["failed_component"] == "bad"
    assert summary["stopped_at_s"] == pytest.approx(0.499)
    for word in words:
        assert word in summary["reason"], summary["reason"]
    header, data = read_csv(out / "timeseries.parquet")
    assert header == ["time", "clock.y", "bad.y", "bad.echo"]
    assert data.shape[0] == 50 and data[-1, 0] == pytest.approx(0.49)  # every sample before the crash
    assert np.allclose(data[:, 1], data[:, 0]) and np.allclose(data[:, 2], data[:, 0])


def test_interrupt_while_an_isolated_fmu_hangs_is_an_interrupt(fmu_dir, tmp_path):
    path = scenario(fmu_dir, tmp_path, 5)  # hangs at 0.5 s; default step timeout 60 s
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "cosim", "run", str(path), "--out", str(out), "--quiet"],
                            env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:  # initialized (the summary names the engine), then 0.5 s hangs
        try:
            if "engine" in json.loads((out / "summary.json").read_text()):
                break
        except (OSError, ValueError):
            pass
        time.sleep(0.1)
    time.sleep(2.0)  # the 500 steps before the hang take well under a second
    os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C: the FMU's process ignores it, the run handles it
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["signal"] == "SIGINT"
    assert summary["stopped_at_s"] == pytest.approx(0.499)
    _, data = read_csv(out / "timeseries.csv")  # the rows buffered while it hung are flushed
    assert data.shape[0] == 50 and data[-1, 0] == pytest.approx(0.49)


@pytest.mark.parametrize("options, engine", [("", "auto"), ("", "python"), ("out_of_process = true", "auto")])
def test_fmu_that_ends_the_simulation_ends_the_run_normally(fmu_dir, tmp_path, capsys, options, engine):
    path = scenario(fmu_dir, tmp_path, 1, options, engine=engine)
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 0, capsys.readouterr().err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "ok"
    assert summary["ended_by"]["instance"] == "bad" and summary["ended_by"]["status"] == "fmi2Discard"
    assert summary["ended_by"]["last_successful_time"] == pytest.approx(0.5)
    _, data = read_csv(out / "timeseries.parquet")
    assert data[-1, 0] == pytest.approx(0.5) and data[-1, 2] == pytest.approx(0.5)  # its last values, at 0.5 s
    assert data[-2, 0] == pytest.approx(0.49)


def test_out_of_process_gives_the_same_numbers(fmu_dir, tmp_path, capsys):
    text = (ROOT / "scenarios" / "plant_drop.toml").read_text()
    runs = {}
    for isolation in ("none", "all"):
        path = tmp_path / f"{isolation}.toml"
        path.write_text(text.replace("stop_time = 0.5", f'stop_time = 0.05\nisolation = "{isolation}"'))
        assert main(["run", str(path), "--out", str(tmp_path / isolation), "--quiet"]) == 0, capsys.readouterr().err
        runs[isolation] = read_csv(tmp_path / isolation / "timeseries.parquet")
    assert runs["none"][0] == runs["all"][0]
    assert np.array_equal(runs["none"][1], runs["all"][1])  # bit for bit


def test_step_timeout_needs_out_of_process(fmu_dir, tmp_path, capsys):
    path = scenario(fmu_dir, tmp_path, 0, 'step_timeout = "1 s"')
    code = main(["run", str(path), "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "fmus[1].step_timeout" in err and "out_of_process = true" in err


@pytest.mark.parametrize("mode, name", [(2, "SIGSEGV"), (3, "SIGABRT")])
def test_in_process_crash_still_leaves_a_final_status(fmu_dir, tmp_path, mode, name):
    """Without isolation a segfault or abort() ends the process; the crash guard (cosim/results/crashguard.c)
    still replaces the running summary with a failed one naming the signal and the last simulated
    time reached (to the heartbeat: here every 1 ms), and the user's FMU in the process makes the
    recorders write through, so the rows up to that time are on disk - as out of process."""
    path = scenario(fmu_dir, tmp_path, mode, "")
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "cosim", "run", str(path), "--out", str(out), "--quiet"],
                          env=ENV, capture_output=True, text=True, timeout=120)
    assert done.returncode == -getattr(signal, name)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and summary["signal"] == name
    assert f"died from {name}" in summary["reason"] and "out of process" in summary["reason"]
    assert summary["stopped_at_s"] == pytest.approx(0.499) and summary["sim_time_s"] == pytest.approx(0.499)
    assert "at t = 0.499 s" in summary["reason"]
    header, data = read_csv(out / "timeseries.parquet")  # the stream the run left (.partial)
    assert header == ["time", "clock.y", "bad.y", "bad.echo"]
    assert data.shape[0] == 50 and data[-1, 0] == pytest.approx(0.49)  # every sample before the crash
    assert not (out / "summary.json.tmp").exists()


def test_second_instance_of_a_once_per_process_fmu_runs_out_of_process(fmu_dir, tmp_path, capsys):
    """canBeInstantiatedOnlyOncePerProcess="true": a second instance in the master's process would share the
    first one's global state; it runs in its own process automatically, and out_of_process = false is refused."""
    import zipfile

    with zipfile.ZipFile(fmu_dir / "Misbehave.fmu") as source, zipfile.ZipFile(tmp_path / "Misbehave.fmu", "w") as out:
        for item in source.infolist():
            data = source.read(item)
            if item.filename == "modelDescription.xml":
                data = data.replace(b'canHandleVariableCommunicationStepSize="true"',
                                    b'canHandleVariableCommunicationStepSize="true" '
                                    b'canBeInstantiatedOnlyOncePerProcess="true"')
            out.writestr(item, data)
    path = tmp_path / "s.toml"
    path.write_text(SCENARIO.format(mode=0, bad_options="", stop=0.2, engine="auto"))
    assert main(["run", str(path), "--out", str(tmp_path / "o"), "--quiet"]) == 0, capsys.readouterr().err
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["status"] == "ok" and summary["out_of_process"] == ["bad"]  # "clock" stays in process
    _, data = read_csv(tmp_path / "o" / "timeseries.parquet")
    assert np.allclose(data[:, 2], data[:, 0])  # bad.y follows the clock as in process
    path.write_text(SCENARIO.format(mode=0, bad_options="out_of_process = false", stop=0.2, engine="auto"))
    code = main(["run", str(path), "--out", str(tmp_path / "o2"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "fmus[1].out_of_process" in err and "canBeInstantiatedOnlyOncePerProcess" in err
