"""``python -m cosim build``: every native part compiled ahead of the run (the README's first
command), one line per part, failures by ``$COSIM_NATIVE``; and a cold cache still works (a run
builds what it needs at first use)."""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import native
from cosim.commands import build as build_command
from cosim.results.exits import InvalidInput

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def cache(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    folder.mkdir(mode=0o700)
    monkeypatch.setenv(native.ENV_CACHE, str(folder))
    return folder


def _args(*scenarios: Path, no_bytecode: bool = True) -> argparse.Namespace:
    return argparse.Namespace(scenarios=list(scenarios), no_bytecode=no_bytecode)


def test_build_compiles_each_part_into_the_cache_once(cache, monkeypatch, capsys, request):
    monkeypatch.delenv(native.ENV_MODE, raising=False)
    cheap = [part for part in build_command.PARTS
             if part[0] in ("co-simulation master kernel", "laser tracker kernel", "crash guard")]
    assert len(cheap) == 3
    monkeypatch.setattr(build_command, "PARTS", tuple(cheap))
    monkeypatch.setattr(build_command, "MAIN_SCENARIO", Path("no-such-scenario.toml"))  # the fixed parts only
    from cosim.master import kernel
    kernel.load_kernel.cache_clear()  # loaded by an earlier test in this process: from the other cache
    request.addfinalizer(kernel.load_kernel.cache_clear)
    assert build_command.run(_args()) == 0
    first = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0] for line in first] == [what for what, _, _ in cheap]
    assert all(": built (" in line for line in first), first
    built = sorted(p.name.split("-")[0] for p in cache.iterdir() if not p.name.startswith("."))
    assert built == ["cosim_crashguard", "kernel", "tracker_kernel"]
    assert build_command.run(_args()) == 0
    second = capsys.readouterr().out.splitlines()
    assert all(": up to date (" in line for line in second), second


def test_every_native_part_of_the_testbed_is_listed():
    names = [what for what, _, _ in build_command.PARTS]
    for expected in ("master kernel", "fieldbus codec", "tracker kernel", "path accuracy kernel",
                     "elastic controller cycle", "direct calls", "crash guard",
                     "FMI 3.0 adapter", "IK table",
                     "FMUs (FMI 2.0)", "FMUs (FMI 3.0)", "PtP node functions"):
        assert any(expected in name for name in names), expected
    part = build_command.scenario_part(ROOT / "scenarios" / "iso9283.toml")
    assert part is not None and "model_based_elastic" in part[0] and part[2]


def test_a_part_that_cannot_be_built_fails_under_require_and_falls_back_under_auto(monkeypatch, capsys):
    def broken():
        raise native.NativeBuildError("gcc: error: broken.c: 1: expected ';'")

    monkeypatch.setattr(build_command, "PARTS", (("broken part", broken, True),))
    monkeypatch.setattr(build_command, "MAIN_SCENARIO", Path("no-such-scenario.toml"))
    monkeypatch.setenv(native.ENV_MODE, "require")
    assert build_command.run(_args()) == build_command.EXIT_BUILD_FAILED
    out = capsys.readouterr()
    assert "broken part: FAILED: NativeBuildError: gcc: error: broken.c" in out.out
    assert "could not be built" in out.err
    monkeypatch.setenv(native.ENV_MODE, "auto")
    assert build_command.run(_args()) == 0
    assert "broken part: not built, its Python path will run (gcc: error" in capsys.readouterr().out
    # a part without a Python path (the FMUs) fails the command either way
    monkeypatch.setattr(build_command, "PARTS", (("FMUs", broken, False),))
    assert build_command.run(_args()) == build_command.EXIT_BUILD_FAILED


def test_a_bad_scenario_is_invalid_input(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[scenario]\nname = 'x'\njob = 'iso9283'\n[simulation]\nstop_time = 'soon'\n")
    with pytest.raises(InvalidInput, match="bad.toml"):
        build_command.run(_args(bad))


def test_bytecode_is_compiled_into_the_source_tree(tmp_path):
    package = tmp_path / "cosim"
    package.mkdir()
    (package / "mod.py").write_text("X = 1\n")
    assert build_command.compile_bytecode(tmp_path) == 1
    assert list((package / "__pycache__").glob("mod.*.pyc"))


def test_a_cold_cache_still_runs_a_cell_job(cache, tmp_path):
    """An empty native cache: the run builds what it needs at first use (as before ``cosim build``
    existed) and ends ok, with its compiled parts now in the cache."""
    text = (ROOT / "scenarios" / "iso9283.toml").read_text()
    text = text.replace('stop_time = "12.6 s"', 'stop_time = "0.02 s"')
    text = text.replace('modes = ["standard", "model_based", "model_based_elastic"]', 'modes = ["model_based"]')
    assert 'stop_time = "0.02 s"' in text and 'modes = ["model_based"]' in text
    scenario = tmp_path / "short.toml"
    scenario.write_text(text)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
           "MPLBACKEND": "Agg", native.ENV_CACHE: str(cache)}
    env.pop(native.ENV_MODE, None)
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "cosim", "run", str(scenario), "--out", str(out), "--quiet"],
                          env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads((out / "summary.json").read_text())["status"] == "ok"
    built = {p.name.split("-")[0] for p in cache.iterdir() if not p.name.startswith(".")}
    assert {"kernel", "fieldbus_codec", "tracker_kernel", "controller_cycle"} <= built, built
    assert "Python path" not in proc.stderr
