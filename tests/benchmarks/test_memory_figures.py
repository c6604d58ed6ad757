"""The memory benchmark measures the run, not the process that started it, and its target can fail.

``benchmarks/bench_memory.run_measured`` starts a fresh interpreter and takes the peak resident
memory of that process's own address space (``/proc/self/status`` VmHWM as it exits): from a
parent holding 300 MiB a run that allocates 10 MiB is measured at tens of MiB, not at the
parent's size (what the child's ``ru_maxrss`` shows on Linux). A long run that allocates
150 MiB more than the short one fails the 1.10 ratio target; one that does not passes."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _bench_memory():
    spec = importlib.util.spec_from_file_location("bench_memory_under_test", ROOT / "benchmarks" / "bench_memory.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_the_figure_is_the_runs_own_memory_and_the_target_can_fail(tmp_path):
    bench_memory = _bench_memory()
    script = tmp_path / "allocate.py"
    script.write_text("import sys\nblock = bytearray(int(sys.argv[1]) << 20)\nblock[::4096] = b'x' * len(block[::4096])\n",
                      encoding="utf-8")
    parent = bytearray(300 << 20)
    parent[::4096] = b"p" * len(parent[::4096])  # the parent's pages are resident
    status, short, inherited = bench_memory.run_measured([str(script), "10"])
    assert status == 0 and 10 < short < 100, short  # the interpreter and 10 MiB, not the 300 MiB parent
    assert inherited >= short
    status, same, _ = bench_memory.run_measured([str(script), "10"])
    assert status == 0 and bench_memory.within_target(short, same)
    status, grown, _ = bench_memory.run_measured([str(script), "160"])
    assert status == 0 and grown - short > 140
    assert not bench_memory.within_target(short, grown)  # the check reports the failure
    status, code_of_failure, _ = bench_memory.run_measured(["-c", "raise SystemExit(3)"])
    assert status == 3 and code_of_failure > 0  # measured also when the run fails
    del parent
