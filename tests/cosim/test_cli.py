"""The CLI lists its commands and the robot description loads."""
import json
import subprocess
import sys


def test_help_lists_commands():
    out = subprocess.run([sys.executable, "-m", "cosim", "--help"], capture_output=True, text=True, check=True)
    assert "robot-info" in out.stdout


def test_robot_info_reports_reach_and_mass():
    out = subprocess.run([sys.executable, "-m", "cosim", "robot-info"], capture_output=True, text=True, check=True)
    info = json.loads(out.stdout)
    assert len(info["joints"]) == 6
    assert 100.0 < info["moving_mass_kg"] < 250.0
    # zero configuration: arm straight up, flange at 0.55 + 0.625 + 0.925 + 0.110 m
    assert abs(info["flange_at_zero_m"][2] - 2.21) < 1e-12


HEAVY = ("numpy", "scipy", "casadi", "pinocchio", "fmpy", "matplotlib", "dask", "pandas", "pyarrow", "can",
         "toppra", "ruckig", "cosim.cell", "cosim.jobs", "cosim.master", "controller", "planners", "fmus")


def test_help_imports_nothing_heavy():
    """``python -m cosim --help`` and every command's ``--help`` answer from the parser alone:
    no numerical library, no job, no robot cell is imported (what they cost is measured in
    benchmarks/RESULTS.md)."""
    program = ("import contextlib, io, runpy, sys\n"
               "for command in ([], ['run'], ['serve'], ['sweep'], ['bench'], ['identify'], ['calibrate'],\n"
               "                ['build'], ['build-fmus'], ['export-ssp'], ['robot-info']):\n"
               "    sys.argv = ['cosim', *command, '--help']\n"
               "    with contextlib.redirect_stdout(io.StringIO()) as text:\n"
               "        try:\n"
               "            runpy.run_module('cosim', run_name='__main__', alter_sys=True)\n"
               "        except SystemExit as exc:\n"
               "            assert exc.code in (0, None), (command, exc.code)\n"
               "    assert 'usage:' in text.getvalue(), command\n"
               f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))\n")
    done = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]", done.stdout
