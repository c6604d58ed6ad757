"""Bad input gets one clear line naming file/option/key and the documented exit code, never a traceback.

Exit codes (cosim/results/exits.py, docs/reference/verdicts.md): 2 bad input or unusable output
folder, 3 failed run. Most cases run ``cosim.cli.main`` in this process (a traceback would
fail the test as an exception); a few run ``python -m cosim`` to check stderr as a user sees it.
"""
from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cosim.cli import main
from cosim.results.outdir import open_results_folder
from scenario_files import write_variant

ROOT = Path(__file__).resolve().parents[2]
PLANT_DROP = (ROOT / "scenarios" / "plant_drop.toml").read_text(encoding="utf-8")
ISO = (ROOT / "tests" / "long_forms" / "iso9283.toml").read_text(encoding="utf-8")
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}


def cli(capsys, *argv: str) -> tuple[int, str]:
    """``main(argv)`` in this process: (exit code, stderr); argparse errors count as exit code 2."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse refuses an option value
        code = exc.code
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


def one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.startswith("error:") or ": error:" in line]
    assert len(lines) == 1, err
    return lines[0]


def plant(tmp_path: Path, *edits: tuple[str, str], name: str = "s.toml") -> Path:
    return write_variant(PLANT_DROP, tmp_path / name, list(edits))


def refused_before_running(tmp_path: Path, capsys, path: Path, fragments, prefix: str | None = None) -> None:
    """``cosim run path`` exits 2 with one error line naming ``path`` (``prefix``: followed by
    this key) and every fragment, and makes no results folder (nothing ran)."""
    code, err = cli(capsys, "run", path, "--out", tmp_path / "out", "--quiet")
    assert code == 2
    line = one_error_line(err)
    assert (f"{path}: {prefix}" if prefix is not None else str(path)) in line, line
    for fragment in fragments:
        assert fragment in line, (fragment, line)
    assert not (tmp_path / "out").exists()  # nothing ran, no folder made


def iso(tmp_path: Path, *edits: tuple[str, str]) -> Path:
    return write_variant(ISO, tmp_path / "iso.toml", list(edits))


# ------------------------------------------------------------------------------------------ scenario files
@pytest.mark.parametrize("edits, fragments", [
    ((("stop_time = 0.5", "stop_time = " + "9" * 401),), ["simulation.stop_time", "401 digits", "finite"]),
    ((('macro_step = "200 us"', "macro_step = 5e-324"),), ["simulation.macro_step", "overflows", "5e-324"]),
    ((("stop_time = 0.5", "stop_time = 1e300"),), ["simulation.stop_time", "max_base_steps", "1e+300"]),
    ((('"q0[5]" = 0.6', '"q0[5]" = 0.6\nintegration_step = 0'),),
     ["fmus[0].parameters.integration_step", ">= 1e-07 and <= 0.01", "modelDescription", "got 0"]),
    ((('"q0[5]" = 0.6', '"q0[5]" = 0.6\nintegration_step = -1e-4'),), ["integration_step", ">= 1e-07"]),
    ((('"q0[5]" = 0.6', '"q0[5]" = 0.6\nintegration_step = 1e6'),), ["integration_step", "<= 0.01", "1000000.0"]),
])
def test_scenario_values_refused_before_running(tmp_path, capsys, edits, fragments):
    refused_before_running(tmp_path, capsys, plant(tmp_path, *edits), fragments)


def test_max_base_steps_can_be_raised(tmp_path, capsys):
    path = plant(tmp_path, ("stop_time = 0.5", "stop_time = 0.01"),
                 ('macro_step = "200 us"', 'macro_step = "200 us"\nmax_base_steps = 10'))
    code, err = cli(capsys, "run", path, "--out", tmp_path / "a", "--quiet")
    assert code == 2 and "max_base_steps = 10" in one_error_line(err)
    path = plant(tmp_path, ("stop_time = 0.5", "stop_time = 0.01"),
                 ('macro_step = "200 us"', 'macro_step = "200 us"\nmax_base_steps = 50'))
    assert cli(capsys, "run", path, "--out", tmp_path / "b", "--quiet")[0] == 0


def test_non_utf8_scenario_and_scenario_as_string(tmp_path, capsys):
    path = tmp_path / "latin1.toml"
    path.write_bytes(PLANT_DROP.replace("alone", "\xe9 alone").encode("latin-1"))
    code, err = cli(capsys, "run", path, "--out", tmp_path / "o", "--quiet")
    assert code == 2 and "latin1.toml" in one_error_line(err) and "not UTF-8" in err
    path = tmp_path / "str.toml"
    path.write_text('scenario = "iso9283"\n')
    code, err = cli(capsys, "run", path, "--out", tmp_path / "o", "--quiet")
    assert code == 2 and "scenario: not a table" in one_error_line(err)


def test_python_m_cosim_prints_one_line_and_no_traceback(tmp_path):
    path = plant(tmp_path, ("stop_time = 0.5", "stop_time = " + "1" * 401))
    done = subprocess.run([sys.executable, "-m", "cosim", "run", str(path), "--quiet"], capture_output=True,
                          text=True, env=ENV, cwd=tmp_path, timeout=120)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.strip().count("\n") == 0 and done.stderr.startswith("error: ")
    debug = subprocess.run([sys.executable, "-m", "cosim", "run", str(path), "--quiet", "--debug"],
                           capture_output=True, text=True, env=ENV, cwd=tmp_path, timeout=120)
    assert debug.returncode == 2 and "Traceback" in debug.stderr  # --debug shows where it came from


# ------------------------------------------------------------------------------------------ robot cell
@pytest.mark.parametrize("edits, key, fragments", [
    ((("cycle_time_us = 400", "cycle_time_us = 400\nnodes = 7"),), "fieldbus.nodes", ["expected 6", "got 7"]),
    ((("cycle_time_us = 400", "cycle_time_us = 400\n[fieldbus.bus]\ninterface = \"nosuchbus\""),),
     "fieldbus.bus.interface", ["unknown interface", "simbus", "udp_multicast"]),
    ((("cycle_time_us = 400", "cycle_time_us = 400\n[fieldbus.bus]\noptions = { bitrate = 500000 }"),),
     "fieldbus.bus.options.bitrate", ["would ignore"]),
    ((("cycle_time_us = 400", "cycle_time_us = 400\nstart_time_s = 0.1"),), "fieldbus.start_time_s",
     ["expected 0"]),
    ((('stop_time = "12.6 s"', 'stop_time = "1 s"'),
      ("cycle_time_us = 400", "cycle_time_us = 400\n[fieldbus.faults]\n"
                              "bursts = [{ node = 3, start_cycle = 5000, cycles = 4, frames = \"preq\" }]")),
     "fieldbus.faults.bursts[0]", ["after the end of the run", "start_cycle < 2500"]),
    ((("payload_com = [0.0, 0.0, 0.08]", "payload_com = [0.0, 0.0, 1e6]"),), "true_robot.payload_com[2]",
     ["<= 1"]),
    ((('stop_time = "12.6 s"', "stop_time = 1e300"),), "simulation.stop_time", ["max_base_steps"]),
    ((('signals = ["drive*.current_demand"]', 'signals = ["drive*.current_demand"]\nfile = "mine.csv"'),),
     "record.file", ["does not use", "timeseries_<mode>"]),
])
def test_robot_cell_scenarios_refused_at_validation(tmp_path, capsys, edits, key, fragments):
    refused_before_running(tmp_path, capsys, iso(tmp_path, *edits), fragments, prefix=key)


# ------------------------------------------------------------------------------------------ --out
def test_out_folder_that_is_a_file_or_below_one(tmp_path, capsys):
    path = plant(tmp_path, ("stop_time = 0.5", "stop_time = 0.01"))
    (tmp_path / "afile").write_text("x")
    code, err = cli(capsys, "run", path, "--out", tmp_path / "afile", "--quiet")
    assert code == 2 and "is a file" in one_error_line(err) and "afile" in err
    code, err = cli(capsys, "run", path, "--out", tmp_path / "afile" / "sub", "--quiet")
    assert code == 2 and "not a folder" in one_error_line(err)


def _mount_tmpfs(where: Path, options: str) -> bool:
    where.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        return False
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)], capture_output=True)
    return done.returncode == 0


def _umount(where: Path) -> None:
    subprocess.run(["umount", str(where)], capture_output=True)


def test_out_folder_read_only_or_without_permission(tmp_path, capsys):
    path = plant(tmp_path, ("stop_time = 0.5", "stop_time = 0.01"))
    target = tmp_path / "ro"
    if _mount_tmpfs(target, "size=64k,ro"):  # root: a real read-only file system
        try:
            code, err = cli(capsys, "run", path, "--out", target / "x", "--quiet")
            assert code == 2 and "read-only" in one_error_line(err)
        finally:
            _umount(target)
    else:  # an ordinary user: a folder without write permission
        target.chmod(0o555)
        try:
            code, err = cli(capsys, "run", path, "--out", target / "x", "--quiet")
            assert code == 2 and ("permission" in one_error_line(err) or "read-only" in err)
        finally:
            target.chmod(0o755)
    # /proc takes no new folders, for root either
    code, err = cli(capsys, "run", path, "--out", "/proc/cosim-robustness-test", "--quiet")
    assert code == 2 and "cannot create the folder" in one_error_line(err)


def test_second_run_into_a_locked_folder_is_refused(tmp_path, capsys):
    path = plant(tmp_path, ("stop_time = 0.5", "stop_time = 0.01"))
    out = tmp_path / "out"
    with open_results_folder(out):  # another run holds the folder
        code, err = cli(capsys, "run", path, "--out", out, "--quiet")
        assert code == 2 and "another run is writing into this folder" in one_error_line(err)
    assert cli(capsys, "run", path, "--out", out, "--quiet")[0] == 0  # released: runs


def _fsize_limit():
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # write() returns EFBIG instead of killing the process
    resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))


def test_output_that_cannot_be_written_fails_the_run_cleanly(tmp_path):
    """The time series outgrows the file-size limit mid-run: failed, the reason, no summary.json.tmp."""
    path = plant(tmp_path, ("stop_time = 0.5", "stop_time = 2.0"))
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "cosim", "run", str(path), "--out", str(out), "--quiet"],
                          capture_output=True, text=True, env=ENV, timeout=120, preexec_fn=_fsize_limit)
    assert done.returncode == 3, done.stderr
    assert "Traceback" not in done.stderr and "error: plant_drop: run failed" in done.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and ("File too large" in summary["reason"] or "size" in summary["reason"])
    assert not (out / "summary.json.tmp").exists()


def test_full_disk_fails_the_run_with_the_reason(tmp_path):
    """A real full file system where one can be mounted (root); the file-size test above covers the rest."""
    target = tmp_path / "small"
    if not _mount_tmpfs(target, "size=24k"):
        pytest.skip("no small file system can be mounted here (not root); the file-size test covers the path")
    try:
        path = plant(tmp_path, ("stop_time = 0.5", "stop_time = 2.0"))
        out = target / "out"
        # --ignore-budget: the budget check would refuse this run up front (its estimate exceeds
        # the free space); this test is about a disk that fills while the run goes
        done = subprocess.run([sys.executable, "-m", "cosim", "run", str(path), "--out", str(out), "--quiet",
                               "--ignore-budget"], capture_output=True, text=True, env=ENV, timeout=120)
        assert done.returncode == 3, done.stderr
        assert "Traceback" not in done.stderr and "disk full" in done.stderr
        summary = json.loads((out / "summary.json").read_text())
        assert summary["status"] == "failed" and summary["reason"].startswith("disk full")
        assert not (out / "summary.json.tmp").exists()
    finally:
        _umount(target)


# ------------------------------------------------------------------------------------------ calibrate
def _calibration_data(tmp_path: Path):
    from calibration.measurements import Measurements, write_measurements_csv
    from robot.geometric_errors import default_error_model, random_geometric_errors
    from robot.kinematics import FlangeKinematics

    model, kin = default_error_model(), FlangeKinematics()
    rng = np.random.default_rng(5)
    q = rng.uniform(kin.lower * 0.8, kin.upper * 0.8, size=(40, 6))
    pos = model.flange_transforms(q, random_geometric_errors(11))[:, :3, 3] + rng.normal(0, 1e-4, (40, 3))
    files = {
        "good": Measurements(q, pos),
        "swap_yz": Measurements(q, pos[:, [0, 2, 1]]),
        "swap_q12": Measurements(q[:, [1, 0, 2, 3, 4, 5]], pos),
        "far": Measurements(q, pos * (4.5 / np.linalg.norm(pos, axis=1)[:, None])),
    }
    return {k: write_measurements_csv(tmp_path / f"{k}.csv", m) for k, m in files.items()}


@pytest.fixture(scope="module")
def calibration_files(tmp_path_factory):
    return _calibration_data(tmp_path_factory.mktemp("cal"))


@pytest.mark.parametrize("name, cause", [("swap_yz", "position columns y and z swapped"),
                                         ("swap_q12", "joint columns q1 and q2 swapped"),
                                         ("far", "out-of-reach poses")])
def test_calibrate_refuses_nonsense_and_writes_no_urdf(tmp_path, capsys, calibration_files, name, cause):
    out = tmp_path / "out"
    code, err = cli(capsys, "calibrate", calibration_files[name], "--out", out)
    assert code == 3
    line = one_error_line(err)
    assert f"{name}.csv" in line and "no URDF written" in line and cause in line, line
    assert not (out / "calibrated.urdf").exists() and not (out / "parameters.json").exists()


def test_calibrate_good_data_and_bad_options(tmp_path, capsys, calibration_files):
    assert cli(capsys, "calibrate", calibration_files["good"], "--out", tmp_path / "ok")[0] == 0
    assert (tmp_path / "ok" / "calibrated.urdf").is_file()
    code, err = cli(capsys, "calibrate", calibration_files["good"], "--position-sigma-mm", "0")
    assert code == 2 and "--position-sigma-mm" in err and "expected a finite number > 0" in err
    bad = tmp_path / "latin1.csv"
    bad.write_bytes(calibration_files["good"].read_bytes().replace(b"q1", b"q\xe91", 1))
    code, err = cli(capsys, "calibrate", bad, "--out", tmp_path / "x")
    assert code == 2 and "latin1.csv" in one_error_line(err)


# ------------------------------------------------------------------------------------------ identify
def _record(path: Path, transform=None) -> Path:
    """A slow sum-of-sines record of the nominal arm (torques by RNEA), optionally transformed."""
    from identification.data import motion_record, write_motion_csv
    from robot.dynamics import RobotDynamics

    t = np.arange(0.0, 2.0, 4e-3)
    centre = np.array([0.0, 0.4, 1.2, 0.0, 0.6, 0.0])
    q = centre + 0.3 * np.sin(np.outer(t, [1.1, 1.7, 2.3, 2.9, 3.1, 3.7]))
    arm = RobotDynamics()
    tau = np.array([arm.gravity(x) for x in q])
    if transform is not None:
        q, tau = transform(q, tau)
    return write_motion_csv(path, motion_record(t, q, tau), include_derivatives=False)


@pytest.mark.parametrize("transform, fragments", [
    (lambda q, tau: (np.degrees(q), tau), ["'q", "degrees"]),
    (lambda q, tau: (q, tau / 1000.0), ["'tau", "kN m"]),
    (lambda q, tau: (tau, q), ["swapped"]),
])
def test_identify_checks_units_and_swapped_columns(tmp_path, capsys, transform, fragments):
    path = _record(tmp_path / "rec.csv", transform)
    code, err = cli(capsys, "identify", path, "--out", tmp_path / "out")
    assert code == 2
    line = one_error_line(err)
    assert "rec.csv" in line
    for fragment in fragments:
        assert fragment in line, (fragment, line)
    assert not (tmp_path / "out" / "parameters.json").exists()


@pytest.mark.parametrize("option, value", [("--cutoff-hz", "0"), ("--cutoff-hz", "-3"), ("--max-condition", "nan"),
                                           ("--cutoff-hz", "inf")])
def test_identify_option_values(tmp_path, capsys, option, value):
    code, err = cli(capsys, "identify", tmp_path / "none.csv", option, value)
    assert code == 2 and option in err and "expected a finite number" in err


def test_identify_cutoff_above_nyquist(tmp_path, capsys):
    path = _record(tmp_path / "rec.csv")
    code, err = cli(capsys, "identify", path, "--cutoff-hz", "500", "--out", tmp_path / "o")
    assert code == 2 and "Nyquist" in one_error_line(err)


def test_identify_non_utf8(tmp_path, capsys):
    path = tmp_path / "bad.csv"
    path.write_bytes(b"t,q\xe91\n")
    code, err = cli(capsys, "identify", path)
    assert code == 2 and "bad.csv" in one_error_line(err)


def test_every_csv_reader_accepts_a_byte_order_mark(tmp_path, capsys, calibration_files):
    """A UTF-8 CSV with a byte-order mark (Excel's "CSV UTF-8") reads as without it everywhere a CSV is
    read (robot.textfiles): identify, calibrate, trajectory files, a run's CSV time series."""
    from calibration.measurements import read_measurements_csv
    from cosim.results import read_series
    from identification.data import read_motion_csv
    from planners.trajectory_file import load_trajectory_file

    def with_bom(path: Path) -> Path:
        marked = path.with_name("bom_" + path.name)
        marked.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
        return marked

    record = _record(tmp_path / "rec.csv")
    plain, marked = read_motion_csv(record), read_motion_csv(with_bom(record))
    assert np.array_equal(plain.q, marked.q) and np.array_equal(plain.tau, marked.tau)
    outcomes = []  # this record (gravity torques only) is refused by the plausibility check: the same for both
    for path in (record, with_bom(record)):
        code, err = cli(capsys, "identify", path, "--out", tmp_path / f"id_{path.stem}")
        outcomes.append((code, one_error_line(err).replace(path.name, "<file>")))
    assert outcomes[0] == outcomes[1] and outcomes[0][0] != 2, outcomes
    good = calibration_files["good"]
    assert np.array_equal(read_measurements_csv(with_bom(good)).q, read_measurements_csv(good).q)
    assert cli(capsys, "calibrate", with_bom(good), "--out", tmp_path / "cal")[0] == 0
    trajectory = ROOT / "examples" / "trajectories" / "pick_place_joint.csv"
    copied = tmp_path / "traj.csv"
    copied.write_bytes(trajectory.read_bytes())
    assert np.array_equal(load_trajectory_file(with_bom(copied)).q, load_trajectory_file(copied).q)
    series = tmp_path / "series.csv"
    series.write_text("time,plant.q[1]\n0.0,1.5\n0.001,1.25\n", encoding="utf-8")
    names, data = read_series(with_bom(series))
    assert names == ["time", "plant.q[1]"] and data.tolist() == [[0.0, 1.5], [0.001, 1.25]]


# ------------------------------------------------------------------------------------------ sweep
SWEEP = """[sweep]
name = "s"
base = "base.toml"
{extra}
[[axes]]
key = "simulation.stop_time"
values = [0.01, 0.02]
"""


def test_sweep_limits_and_files(tmp_path, capsys):
    plant(tmp_path, name="base.toml")
    big = tmp_path / "big.toml"
    big.write_text(SWEEP.format(extra="") + '[[axes]]\nkey = "fmus[0].parameters.\\"q0[1]\\""\nseeds = 6000\n')
    code, err = cli(capsys, "sweep", big, "--quiet")
    assert code == 2 and "sweep.max_variants" in one_error_line(err) and "12000 variants" in err
    small = tmp_path / "small.toml"
    small.write_text(SWEEP.format(extra="max_variants = 1"))
    code, err = cli(capsys, "sweep", small, "--quiet")
    assert code == 2 and "at most 1 variants" in one_error_line(err)
    latin = tmp_path / "latin.toml"
    latin.write_bytes(SWEEP.format(extra='description = "\xe9"').encode("latin-1"))
    code, err = cli(capsys, "sweep", latin, "--quiet")
    assert code == 2 and "latin.toml" in one_error_line(err) and "not UTF-8" in err


def test_sweep_scheduler_that_does_not_answer(tmp_path, capsys):
    from cosim.sweep.execute import SCHEDULER_CONNECT_TIMEOUT_S

    plant(tmp_path, name="base.toml")
    path = tmp_path / "sw.toml"
    path.write_text(SWEEP.format(extra=""))
    import time

    t0 = time.perf_counter()
    code, err = cli(capsys, "sweep", path, "--scheduler", "tcp://127.0.0.1:9", "--out", tmp_path / "o", "--quiet")
    assert code == 2 and "--scheduler 'tcp://127.0.0.1:9'" in one_error_line(err) and "no Dask scheduler" in err
    assert time.perf_counter() - t0 < SCHEDULER_CONNECT_TIMEOUT_S + 45  # imports of dask on a loaded machine
    definition = json.loads((tmp_path / "o" / "sweep.json").read_text())  # not left "running"
    assert definition["status"] == "failed" and "no Dask scheduler" in definition["reason"]


def test_sweep_scheduler_that_accepts_and_never_answers(tmp_path, capsys):
    """An address that accepts the TCP connection and then stays silent (a hung scheduler, another
    service): a clear error within 10 s, not a wait for ever (dask's Client waits for its handshake)."""
    import socket
    import threading
    import time

    import dask.distributed  # noqa: F401 - imported before the clock starts: the wait is what is timed

    plant(tmp_path, name="base.toml")
    path = tmp_path / "sw.toml"
    path.write_text(SWEEP.format(extra=""))
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    accepted: list[socket.socket] = []

    def accept() -> None:
        while True:
            try:
                accepted.append(server.accept()[0])
            except OSError:  # closed at the end of the test
                return

    threading.Thread(target=accept, daemon=True).start()
    address = f"tcp://127.0.0.1:{server.getsockname()[1]}"
    try:
        t0 = time.perf_counter()
        code, err = cli(capsys, "sweep", path, "--scheduler", address, "--out", tmp_path / "o", "--quiet")
        elapsed = time.perf_counter() - t0
    finally:
        server.close()
        for conn in accepted:
            conn.close()
    assert accepted, "the test server never saw the connection"
    line = one_error_line(err)
    assert code == 2 and f"--scheduler '{address}'" in line and "no Dask scheduler answered within 5 s" in line
    assert "accepts the connection and never answers" in line
    assert elapsed < 10.0, elapsed
    definition = json.loads((tmp_path / "o" / "sweep.json").read_text())
    assert definition["status"] == "failed" and "no Dask scheduler" in definition["reason"]


def test_identify_refuses_physically_impossible_parameters():
    from types import SimpleNamespace

    from identification.plausibility import check_fit

    record = SimpleNamespace(tau=np.ones((10, 6)) + np.arange(10)[:, None])
    estimate = SimpleNamespace(names=("Izz1R", "Ia3", "fv2"), values=np.array([1.0, -0.5, 0.1]),
                               std=np.array([0.1, 0.01, 0.01]), residual_rms=np.zeros(6))
    reason = check_fit(SimpleNamespace(estimate=estimate), record, "rec.csv")
    assert reason is not None and "Ia3" in reason and "physically impossible" in reason
    estimate.values[1] = -0.02  # within 3 standard deviations of zero: noise, accepted
    assert check_fit(SimpleNamespace(estimate=estimate), record, "rec.csv") is None
    estimate.residual_rms = np.full(6, 100.0)  # explains nothing
    assert "unexplained" in check_fit(SimpleNamespace(estimate=estimate), record, "rec.csv")


# ------------------------------------------------------------------------------------------ second pass
# Neighbours of the bad-input cases above (docs/reference/verdicts.md), found by a fresh pass on the CLI: each is
# refused before anything runs, exit 2, one line naming the file and key (or option).
@pytest.mark.parametrize("old, new, fragments", [
    ("stop_time = 0.5", "stop_time = nan", ["simulation.stop_time"]),
    ("stop_time = 0.5", "stop_time = inf", ["simulation.stop_time"]),
    ("stop_time = 0.5", "stop_time = -1", ["simulation.stop_time"]),
    ("stop_time = 0.5", "stop_time = 0", ["simulation.stop_time"]),
    ("stop_time = 0.5", 'stop_time = "1 parsec"', ["simulation.stop_time"]),
    ("stop_time = 0.5", "stop_time = true", ["simulation.stop_time"]),
    ("stop_time = 0.5", "stop_time = [1]", ["simulation.stop_time"]),
    ("stop_time = 0.5", "stop_time = " + "10" * 30, ["simulation.stop_time", "max_base_steps"]),
    ('macro_step = "200 us"', "macro_step = 0", ["simulation.macro_step"]),
    ('macro_step = "200 us"', "macro_step = 1.0", ["simulation.stop_time", "multiple of macro_step"]),  # > stop
    ('macro_step = "200 us"', 'macro_step = "1 furlong"', ["simulation.macro_step"]),
    ('"q0[5]" = 0.6', '"q0[5]" = 0.6\nintegration_step = nan', ["integration_step"]),
    ('"q0[5]" = 0.6', '"q0[5]" = 0.6\nintegration_step = "x"', ["integration_step"]),
    ('"q0[5]" = 0.6', '"q0[5]" = 0.6\nnosuchparam = 1', ["nosuchparam"]),
    ("stop_time = 0.5", "stop_time = 0.5\nstop_tme = 1", ["stop_tme"]),
    ('builtin = "rx130l_plant"', 'builtin = "nosuch"', ["fmus[0].builtin", "nosuch"]),
    ('builtin = "rx130l_plant"', 'path = "missing.fmu"', ["fmus[0].path", "missing.fmu"]),
    ('job = "fmus"', 'job = "nosuch"', ["nosuch"]),
])
def test_more_scenario_values_refused(tmp_path, capsys, old, new, fragments):
    refused_before_running(tmp_path, capsys, plant(tmp_path, (old, new)), fragments)


def _fmu_like(tmp_path: Path, kind: str) -> Path:
    """Broken FMU archives: not a zip, no modelDescription, malformed or non-UTF-8 XML, no binary here."""
    import zipfile

    path = tmp_path / f"{kind}.fmu"
    if kind == "notzip":
        path.write_text("hello")
        return path
    with zipfile.ZipFile(path, "w") as archive:
        if kind == "nomd":
            archive.writestr("x.txt", "x")
        elif kind == "badxml":
            archive.writestr("modelDescription.xml", "<fmiModelDescription fmiVersion='2.0'")
        elif kind == "latin1xml":
            archive.writestr("modelDescription.xml", "<?xml version='1.0' encoding='UTF-8'?><fmiModelDescription "
                             "fmiVersion='2.0' modelName='\xe9'>".encode("latin-1"))
        elif kind == "nobinary":  # the project's plant without its binaries/ folder (C sources only)
            from cosim.scenario.cosim_tables import resolve_builtin

            with zipfile.ZipFile(resolve_builtin("rx130l_plant")) as source:
                for item in source.infolist():
                    if not item.filename.startswith("binaries/"):
                        archive.writestr(item, source.read(item))
    return path


@pytest.mark.parametrize("kind, fragments", [
    ("notzip", []), ("nomd", []), ("badxml", []), ("latin1xml", []),
    ("nobinary", ["binaries for no platform and C sources", "binaries/linux64/"]),
])
def test_broken_fmu_files_refused_at_validation(tmp_path, capsys, kind, fragments):
    fmu = _fmu_like(tmp_path, kind)
    path = plant(tmp_path, ('builtin = "rx130l_plant"', f'path = "{fmu.name}"'))
    code, err = cli(capsys, "run", path, "--out", tmp_path / "out", "--quiet")
    assert code == 2
    line = one_error_line(err)
    assert "fmus[0].path" in line and fmu.name in line, line
    for fragment in fragments:
        assert fragment in line, (fragment, line)


@pytest.mark.parametrize("edit, key", [
    (("cycle_time_us = 400", "cycle_time_us = 0"), "fieldbus.cycle_time_us"),
    (("cycle_time_us = 400", "cycle_time_us = -400"), "fieldbus.cycle_time_us"),
    (("cycle_time_us = 400", "cycle_time_us = nan"), "fieldbus.cycle_time_us"),
    (("payload_com = [0.0, 0.0, 0.08]", "payload_com = [0.0, 0.0, 80.0]"), "true_robot.payload_com"),  # mm
    (("payload_com = [0.0, 0.0, 0.08]", "payload_com = [0.0, 0.08]"), "true_robot.payload_com"),
    (('stop_time = "12.6 s"', 'stop_time = "-1 s"'), "simulation.stop_time"),
    (('modes = ["standard", "model_based", "model_based_elastic"]', 'modes = ["nosuch"]'), "controller.modes"),
    (("cycle_time_us = 400", 'cycle_time_us = 400\n[fieldbus.faults]\n'
                             'bursts = [{ node = 9, start_cycle = 5, cycles = 4, frames = "preq" }]'),
     "fieldbus.faults.bursts[0]"),
])
def test_more_robot_cell_values_refused(tmp_path, capsys, edit, key):
    path = iso(tmp_path, edit)
    code, err = cli(capsys, "run", path, "--out", tmp_path / "out", "--quiet")
    assert code == 2 and key in one_error_line(err), err


def test_options_and_environment_named_in_errors(tmp_path, capsys, monkeypatch):
    path = plant(tmp_path, ("stop_time = 0.5", "stop_time = 0.01"))
    monkeypatch.setenv("COSIM_MAX_OUTPUT", "abc")
    code, err = cli(capsys, "run", path, "--out", tmp_path / "o1", "--quiet")
    assert code == 2 and "$COSIM_MAX_OUTPUT" in one_error_line(err)
    monkeypatch.delenv("COSIM_MAX_OUTPUT")
    code, err = cli(capsys, "run", path, "--out", tmp_path / "o2", "--quiet", "--max-output", "-5 GB")
    assert code == 2 and "--max-output" in one_error_line(err)
    code, err = cli(capsys, "run", path, "--out", tmp_path / "o3", "--quiet", "--realtime")
    assert code == 2 and "runs no robot cell" in one_error_line(err)
    code, err = cli(capsys, "export-ssp", path, "/proc/cosim-test.ssp")
    assert code == 2 and "OUT '/proc/cosim-test.ssp'" in one_error_line(err)


@pytest.mark.parametrize("option, value, fragment", [("--cpu", "999", "--cpu"), ("--cpu", "abc", "--cpu"),
                                                     ("--accept-from", "no.such.host.invalid", "--accept-from")])
def test_serve_options_refused_before_serving(tmp_path, capsys, option, value, fragment):
    from cosim.execution.split.protocol import free_udp_port

    code, err = cli(capsys, "serve", ROOT / "scenarios" / "hil.toml", option, value, "--out", tmp_path / "o",
                    "--quiet", "--channel", f"127.0.0.1:{free_udp_port()}")
    assert code == 2 and fragment in one_error_line(err), err
    assert not (tmp_path / "o").exists()
