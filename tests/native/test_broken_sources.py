"""A deliberately broken copy of each hand-written C source of the project: under
``COSIM_NATIVE=require`` (set by .ci/run) its loader raises with the compiler's message, so
the suite fails instead of silently testing only the Python paths; without the variable the
Python path (or the run without the part) goes on and says so once; with ``off`` nothing is
compiled and nothing is said. The FMUs have no Python path: a broken FMU source is an error
in every mode.

Each case builds into a private empty cache, so the real cache is never touched and the
compiler always sees the broken copy."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

import native

# a missing header stops the compiler at once (an #error would let it parse all of pinocchio's
# templates in ik_table.cpp first, 40 CPU-s)
BROKEN = "#include \"deliberately_broken_by_test_broken_sources.h\"\n"


def _broken_copy(source: Path, folder: Path) -> Path:
    copy = folder / source.name
    copy.write_text(BROKEN + source.read_text())
    return copy


def _rebuilt(monkeypatch, folder, module, attribute, load):
    """``load()`` (an ``lru_cache``d loader) with ``module.attribute`` (a source path) replaced by
    a broken copy in ``folder``; the loader's cache cleared before and after."""
    monkeypatch.setattr(module, attribute, _broken_copy(getattr(module, attribute), folder))
    load.cache_clear()
    try:
        return load()
    finally:
        load.cache_clear()


def _kernel(monkeypatch, folder):
    from cosim.master import kernel

    return _rebuilt(monkeypatch, folder, kernel, "SOURCE", kernel.load_kernel)


def _codec(monkeypatch, folder):
    from fieldbus import codec

    monkeypatch.delenv("FIELDBUS_CODEC", raising=False)
    return _rebuilt(monkeypatch, folder, codec, "SOURCE", codec.load_codec)


def _direct_calls(monkeypatch, folder):
    from native import calls

    return _rebuilt(monkeypatch, folder, calls, "SOURCE", calls.load_calls)


def _fmi3_adapter(monkeypatch, folder):
    from fmus import fmi3

    return _rebuilt(monkeypatch, folder, fmi3, "ADAPTER_SOURCE", fmi3.load_fmi3_adapter)


def _elastic_cycle(monkeypatch, folder):
    from controller import elastic

    return _rebuilt(monkeypatch, folder, elastic, "ELASTIC_CYCLE_SOURCE", elastic.load_elastic_cycle)


def _cycle_outputs_header(monkeypatch, folder):
    """The header both controller cycles include: a broken copy breaks the build that includes
    it (here the elastic cycle's: native.build puts the header next to the source)."""
    from controller import compiled_cycle, elastic

    return _rebuilt(monkeypatch, folder, compiled_cycle, "CYCLE_OUTPUTS_HEADER", elastic.load_elastic_cycle)


def _ik_table(monkeypatch, folder):
    from controller import ik_table

    monkeypatch.setattr(ik_table, "SOURCE", _broken_copy(ik_table.SOURCE, folder))
    monkeypatch.setattr(ik_table, "_loaded", [])
    return ik_table.load(build=True)


def _tracker(monkeypatch, folder):
    from cosim.tracking import laser_tracker

    monkeypatch.setattr(laser_tracker, "KERNEL_SOURCE", _broken_copy(laser_tracker.KERNEL_SOURCE, folder))

    class Master:  # what LaserTracker.setup asks of the co-simulation master
        def __init__(self):
            self.bus = np.zeros(32)

        def reader(self, names):
            return lambda: self.bus[:len(names)]

        def view(self, names, writable=False):
            return self.bus[:len(names)]

    from robot.description import load_model

    tracker = laser_tracker.LaserTracker(load_model())
    tracker.setup(Master())
    return laser_tracker.KERNEL_SOURCE if tracker.compiled else None


def _path_accuracy(monkeypatch, folder):
    from cosim.tracking import metrics

    monkeypatch.setattr(metrics, "KERNEL_SOURCE", _broken_copy(metrics.KERNEL_SOURCE, folder))
    monkeypatch.setattr(metrics, "_KERNEL", [])
    return metrics.candidate_kernel()


def _crash_guard(monkeypatch, folder):
    from cosim.results import crashguard

    monkeypatch.setattr(crashguard, "_SOURCE", _broken_copy(crashguard._SOURCE, folder))
    monkeypatch.setattr(crashguard, "_library", None)
    return crashguard._load()


def _controller_cycle(monkeypatch, folder):
    from controller import Controller, ControllerConfig, TcpTrajectory, compiled_cycle
    from planners.iso9283 import ISO_Q_HINT, iso9283_test_path
    from robot.dynamics import RobotDynamics

    monkeypatch.setattr(compiled_cycle, "FAST_CYCLE_SOURCE", _broken_copy(compiled_cycle.FAST_CYCLE_SOURCE, folder))
    path = iso9283_test_path()
    reference = TcpTrajectory.from_reference(path.reference, path.duration, 400e-6)
    controller = Controller(reference, ControllerConfig(mode="model_based"), dynamics=RobotDynamics(),
                            q_hint=np.array(ISO_Q_HINT))
    return controller.kernel


# (component, what the note names, loader); the loaders return the compiled part or None
COMPONENTS = [
    ("master_kernel", "co-simulation master kernel", _kernel),
    ("fieldbus_codec", "fieldbus codec", _codec),
    ("direct_calls", "direct calls", _direct_calls),
    ("fmi3_adapter", "FMI 3.0 adapter", _fmi3_adapter),
    ("tracker_kernel", "laser tracker kernel", _tracker),
    ("path_accuracy_kernel", "path accuracy kernel", _path_accuracy),
    ("crash_guard", "crash guard", _crash_guard),
    ("controller_cycle", "controller cycle kernel", _controller_cycle),
    ("elastic_cycle", "elastic controller cycle", _elastic_cycle),
    ("cycle_outputs_header", "elastic controller cycle", _cycle_outputs_header),
    ("ik_table", "compiled IK table", _ik_table),
]


@pytest.fixture
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("COSIM_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(native, "_reported", set())
    folder = tmp_path / "src"
    folder.mkdir()
    return folder


def test_every_hand_written_c_source_is_covered():
    root = Path(__file__).resolve().parents[2]
    sources = {p.relative_to(root).as_posix() for package in ("native", "cosim", "fieldbus", "controller", "planners",
                                                              "robot", "calibration", "identification")
               for pattern in ("*.c", "*.cpp", "*.h") for p in (root / package).rglob(pattern)}
    covered = {"cosim/master/kernel.c", "fieldbus/codec.c", "cosim/tracking/tracker_kernel.c",
               "cosim/tracking/polyline_kernel.c", "cosim/results/crashguard.c", "controller/fast_cycle.c", "controller/elastic_cycle.c",
               "controller/ik_table.cpp", "controller/cycle_outputs.h", "native/calls.c"}
    assert sources == covered  # fmus/: fmi3_adapter.c here, the FMU sources below


@pytest.mark.parametrize("name,what,load", COMPONENTS, ids=[c[0] for c in COMPONENTS])
def test_a_broken_source_fails_under_require(name, what, load, private_cache, monkeypatch):
    monkeypatch.setenv("COSIM_NATIVE", "require")
    with pytest.raises(native.NativeBuildError, match="deliberately_broken"):
        load(monkeypatch, private_cache)


@pytest.mark.parametrize("name,what,load", COMPONENTS, ids=[c[0] for c in COMPONENTS])
def test_a_broken_source_falls_back_and_says_so_once(name, what, load, private_cache, monkeypatch, capsys):
    monkeypatch.delenv("COSIM_NATIVE", raising=False)
    assert load(monkeypatch, private_cache) is None
    assert load(monkeypatch, private_cache) is None
    err = capsys.readouterr().err
    assert err.count(f"note: {what}: compiled code unavailable") == 1, err
    assert "compiling failed" in err and "COSIM_NATIVE=require makes this an error" in err
    monkeypatch.setenv("COSIM_NATIVE", "off")
    monkeypatch.setattr(native, "_reported", set())
    assert load(monkeypatch, private_cache) is None
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("mode", ["require", "auto"])
def test_a_broken_fmu_source_is_an_error_in_every_mode(mode, tmp_path, monkeypatch):
    from fmus import build

    monkeypatch.setenv("COSIM_NATIVE", mode)
    recipe = build.RECIPES["servo_drive"]()
    sources = tmp_path / "servo_drive"
    shutil.copytree(recipe.source_dir, sources)
    _broken_copy(recipe.source_dir / "servo_drive.c", sources)
    recipe.source_dir = sources
    monkeypatch.setitem(build.RECIPES, "servo_drive", lambda: recipe)
    monkeypatch.setattr(build, "REPO_ROOT", Path("/"))  # the input hash names files relative to it
    with pytest.raises(build.FmuBuildError, match="deliberately_broken"):
        build.build_fmu("servo_drive", tmp_path / "out")
