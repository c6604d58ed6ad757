"""Following a simulated-time cell from the command line to the FMUs and back enters each file
of ``cosim/`` once per direction.

The definition the test checks. A profiler (``sys.setprofile``) sees every Python call and
return of ``python -m cosim run`` (``cosim.cli.main``) on a short cut of the main job, the
modes run in this process. At every moment the interpreter's call stack, read from the
entry down, is mapped to the source file of each frame; frames outside ``cosim/`` (fmpy,
numpy, the controller, the fieldbus, the standard library) are dropped and consecutive
frames of the same file merged. What remains is the *file path* of that moment: the chain
of ``cosim/`` files the call went down through to get there, e.g. ``cli.py >
commands/run.py > runs/execute.py > jobs/iso9283.py > execution/... > master/... > cell/link.py``.

*Entered once per direction* means: no file path ever holds the same file twice. Going
down, a call never comes back into a file it has already left downwards (no callback into
a higher floor: ``runner.py > split/cell.py > runner.py`` is what this forbids), so coming
back up, each file is returned to once. Calling the same lower file several times one
after another (the master's step loop calling the bus-cycle task every cycle, a job
calling a helper twice) is one entry per call path and allowed; only a file met again on
the way down of the same path counts.

The test asserts it on every file path of the command, from ``cli.py`` down: loading the
scenario (the loader reads a base scenario through ``scenario/inherit.py``, which reads files
with ``scenario/files.py``, never the loader; the job registry imports the job modules and reads
their ``JOB``, a job module never calls the registry back), the job, the cell's execution, the
master, the FMUs and the way back up. ``returns`` = the number of calls that pushed a file
already on the file path (each one a return to a file already left); ``files`` = the ``cosim/``
files entered. The cell's call paths, those that hold the execution's entry
(``execution/__init__.py``, :func:`cosim.execution.run_cell`), are also counted apart
(``cell_returns``, ``cell_files``) to show the cell was followed all the way down.
"""
from __future__ import annotations

import sys
from pathlib import Path

import cosim

COSIM = Path(cosim.__file__).resolve().parent
ENTRY = "execution/__init__.py"
SCENARIO = """extends = "iso9283"

[scenario]
name = "call_path"

[simulation]
stop_time = "0.02 s"

[controller]
modes = ["standard"]

[results]
can_log = false
"""


class FilePathTracer:
    """The profiler of the module docstring: file paths and the returns into a file already left."""

    def __init__(self, root: Path) -> None:
        self.root = str(root) + "/"
        self.frames: list[bool] = []  # per Python frame on the stack since start: is it a cosim/ frame
        self.path: list[list] = []  # the file path: [file, frames of it merged]
        self.files: set[str] = set()
        self.returns: list[tuple[str, ...]] = []
        self.cell_files: set[str] = set()
        self.cell_returns: list[tuple[str, ...]] = []

    def __call__(self, frame, event, arg) -> None:
        if event == "call":
            name = frame.f_code.co_filename
            ours = name.startswith(self.root)
            self.frames.append(ours)
            if not ours:
                return
            name = name[len(self.root):]
            if self.path and self.path[-1][0] == name:
                self.path[-1][1] += 1
                return
            returned = any(entry[0] == name for entry in self.path)
            self.files.add(name)
            self.path.append([name, 1])
            chain = tuple(entry[0] for entry in self.path)
            in_cell = ENTRY in chain
            if in_cell:
                self.cell_files.add(name)
            if returned:
                self.returns.append(chain)
                if in_cell:
                    self.cell_returns.append(chain)
        elif event == "return":
            if not self.frames:
                return  # a frame entered before the profiler started
            if self.frames.pop() and self.path:
                self.path[-1][1] -= 1
                if not self.path[-1][1]:
                    self.path.pop()


def trace_cli(argv: list[str]) -> tuple[int, FilePathTracer]:
    from cosim.cli import main

    tracer = FilePathTracer(COSIM)
    sys.setprofile(tracer)
    try:
        code = main(argv)
    finally:
        sys.setprofile(None)
    return code, tracer


def test_a_simulated_cell_enters_each_file_once_per_direction(tmp_path, monkeypatch):
    scenario = tmp_path / "call_path.toml"
    scenario.write_text(SCENARIO, encoding="utf-8")
    monkeypatch.setenv("COSIM_MODE_PROCESSES", "0")  # the modes in this process, where the profiler is
    monkeypatch.setenv("MPLBACKEND", "Agg")
    code, tracer = trace_cli(["run", str(scenario), "--out", str(tmp_path / "out"), "--quiet"])
    assert code == 0
    # followed all the way: the CLI, the scenario loading (extends), the job, the execution, the master, the bus-cycle task
    for name in ("cli.py", "runs/scenario.py", "runs/execute.py", "scenario/loader.py", "scenario/inherit.py",
                 "scenario/files.py", "scenario/registry.py", "jobs/iso9283.py", "execution/__init__.py",
                 "master/master.py", "cell/link.py"):
        assert name in tracer.files, sorted(tracer.files)
    for name in ("execution/simulated.py", "execution/cell_master.py", "master/master.py", "master/access.py",
                 "cell/link.py", "tracking/laser_tracker.py"):
        assert name in tracer.cell_files, sorted(tracer.cell_files)
    assert not tracer.cell_returns, _first_return(tracer.cell_returns)
    assert not tracer.returns, _first_return(tracer.returns)


def _first_return(returns: list[tuple[str, ...]]) -> str:
    distinct = sorted({path[-1] for path in returns})
    return (f"{len(returns)} returns into a file already left ({distinct}); "
            f"first: {' > '.join(returns[0])}")
