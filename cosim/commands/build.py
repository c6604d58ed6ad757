"""``python -m cosim build [SCENARIO ...]``: compile every native part now, as part of installing.

The README's first command is ``pip install -e ".[test]" && python -m cosim build && python -m
cosim run scenarios/iso9283.toml``. Every compiled part of the testbed is also built at its
first use (:mod:`native`: cached per user by a key over source, compiler, flags and Python),
so a cold cache still works; but a build at first use lands inside the first run and is
counted in its wall time (on a fresh clone the main job then ran at 1.6x real time instead of
3.5x). Building here, once, after the install and before any run is what Ruckig does at
install time, without tying the build to pip: an editable install, a wheel and a plain
checkout all build the same way, into the same per-user cache, with the same errors.

What it builds (:data:`PARTS`, then per scenario):

* the fixed C parts: the master's stepping kernel, the fieldbus codec (CPython extension),
  the direct calls of the loop's compiled functions (CPython extension, :mod:`native.calls`),
  the laser tracker's kernel, the path accuracy's candidate search, the crash guard, the FMI
  3.0 adapter, and the elastic mode's compiled IK table (C++ on pinocchio's headers, :mod:`controller.ik_table`);
* the plant and servo-drive FMUs, FMI 2.0 (what the jobs run) and FMI 3.0;
* the PtP planner's node functions (CasADi-generated C);
* for each SCENARIO (default: the main job, ``scenarios/iso9283.toml``, in the working
  directory or the installed copy of the scenarios) of a robot-cell job: the generated code its built-in controller modes load, made
  exactly as a run makes it (:func:`cosim.execution.mode_runs.prepare` and ``mode_cell`` per mode:
  the compiled controller cycle, the elastic link-torque function), so the run finds them
  under the same cache keys;
* the Python bytecode of the project's packages (``compileall``), which pip writes for a
  regular install but not for an editable one: otherwise the first run compiles about 900
  modules.

Failures follow ``$COSIM_NATIVE`` (:mod:`native`): with ``require`` (``.ci/run``) a part that
cannot be built ends the command with exit code 3; with ``auto`` the line says that the part's
Python path will run instead (same results, slower) and the command goes on (exit 0), except
for the FMUs, which have no Python path (exit 3). A bad scenario file is exit 2.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

NAME = "build"
HELP = ("Compile every native part (FMUs, master kernel, fieldbus codec, tracker kernel, PtP nodes, the "
        "controller code a scenario's modes load) and the Python bytecode now, so that no run pays for "
        "building; the install step of the README's first command.")

#: Exit code when a part could not be built (and must be: FMUs, or $COSIM_NATIVE=require).
EXIT_BUILD_FAILED = 3
#: The main job: built for when no SCENARIO is named and this file exists (relative to the
#: working directory, as ``python -m cosim run scenarios/iso9283.toml`` reads it).
MAIN_SCENARIO = Path("scenarios") / "iso9283.toml"
#: Jobs whose built-in controller modes are made by :mod:`cosim.execution.mode_runs`.
CELL_MODE_JOBS = ("iso9283", "fieldbus_fault", "compare")
#: The project's packages whose bytecode is compiled.
PACKAGES = ("native", "robot", "fieldbus", "fmus", "controller", "planners", "calibration", "identification",
            "cosim")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """SCENARIO ... and ``--no-bytecode``."""
    parser.add_argument("scenarios", type=Path, nargs="*", metavar="SCENARIO",
                        help=f"scenario files whose generated controller code to build as well (default: "
                             f"{MAIN_SCENARIO} when it exists)")
    parser.add_argument("--no-bytecode", action="store_true", help="do not compile the Python bytecode")


# ------------------------------------------------------------------------------------------ the parts
def _master_kernel() -> Any:
    from cosim.master.kernel import load_kernel

    return load_kernel()


def _fieldbus_codec() -> Any:
    from fieldbus.codec import load_codec

    return load_codec()


def _tracker_kernel() -> Any:
    from cosim.tracking.laser_tracker import KERNEL_SOURCE
    from native import load_library

    return load_library(KERNEL_SOURCE)


def _path_accuracy_kernel() -> Any:
    from cosim.tracking.metrics import KERNEL_SOURCE
    from native import load_library

    return load_library(KERNEL_SOURCE)


def _elastic_cycle() -> Any:
    from controller.elastic import load_elastic_cycle

    return load_elastic_cycle()


def _direct_calls() -> Any:
    from native.calls import load_calls

    return load_calls()


def _crash_guard() -> Any:
    import native
    from cosim.results import crashguard

    if native.mode() == "off":
        return None
    native.load_ctypes(native.build("cosim_crashguard", [crashguard._SOURCE]))  # raises what the guard swallows
    return crashguard._load()


def _fmi3_adapter() -> Any:
    from fmus.fmi3 import load_fmi3_adapter

    return load_fmi3_adapter()


def _ik_table() -> Any:
    from controller.ik_table import load

    return load()


def _fmus(fmi: int) -> Callable[[], Any]:
    def build() -> Any:
        from fmus.build import build_fmus

        return build_fmus(fmi=fmi)

    return build


def _ptp_nodes() -> Any:
    import native
    from planners.ptp_nodes import node_functions
    from robot.symbolic import chain_structure

    if native.mode() == "off":
        return None
    try:
        return node_functions(chain_structure())
    except native.NativeBuildError:
        raise
    except Exception as exc:  # noqa: BLE001 - CasADi's loader errors are RuntimeErrors
        raise native.NativeBuildError(str(exc)) from exc


#: (what, build, has a Python path). ``build`` returns None when the part was not built and its
#: Python path runs ($COSIM_NATIVE=off, or =auto after a failure that :mod:`native` reported).
PARTS: tuple[tuple[str, Callable[[], Any], bool], ...] = (
    ("co-simulation master kernel", _master_kernel, True),
    ("fieldbus codec", _fieldbus_codec, True),
    ("laser tracker kernel", _tracker_kernel, True),
    ("path accuracy kernel", _path_accuracy_kernel, True),
    ("elastic controller cycle", _elastic_cycle, True),
    ("direct calls of the loop's compiled functions", _direct_calls, True),
    ("crash guard", _crash_guard, True),
    ("FMI 3.0 adapter", _fmi3_adapter, True),
    ("compiled IK table (C++, pinocchio)", _ik_table, True),
    ("plant and drive FMUs (FMI 2.0)", _fmus(2), False),
    ("plant and drive FMUs (FMI 3.0)", _fmus(3), False),
    ("PtP node functions", _ptp_nodes, True),
)


def scenario_part(path: Path) -> tuple[str, Callable[[], Any], bool] | None:
    """The part building the generated code of ``path``'s built-in controller modes, or None when
    its job has none. Raises :class:`cosim.api.ScenarioError` for a bad file."""
    import copy

    from cosim.api import load_scenario

    scenario = load_scenario(path)
    job = getattr(scenario.job, "name", scenario.job)
    if job not in CELL_MODE_JOBS or not scenario.data.get("controller", {}).get("modes"):
        return None

    def build() -> Any:
        from cosim.execution.mode_runs import mode_cell, prepare

        setup = prepare(copy.deepcopy(scenario.data), str(scenario.path))
        return [mode_cell(setup, mode)[1] for mode in setup.doc["controller"]["modes"]]

    modes = ", ".join(scenario.data["controller"]["modes"])
    return f"controller code of {path} ({modes})", build, True


def compile_bytecode(root: Path) -> int:
    """Compile the bytecode of :data:`PACKAGES` under ``root``; the number of packages done."""
    import compileall

    done = 0
    for package in PACKAGES:
        folder = root / package
        if folder.is_dir() and os.access(folder, os.W_OK):
            compileall.compile_dir(str(folder), quiet=1, workers=1)
            done += 1
    return done


# ------------------------------------------------------------------------------------------ the command
def _cache_entries() -> set[str]:
    import native

    try:
        return set(os.listdir(native.cache_root()))
    except OSError:
        return set()


def build_part(what: str, make: Callable[[], Any], has_python_path: bool) -> bool:
    """Build one part and print one line; False when it failed and must not (see the module docstring)."""
    import native

    before = _cache_entries()
    started = time.perf_counter()
    try:
        result = make()
    except Exception as exc:  # noqa: BLE001 - every failure is one line here
        if has_python_path and native.mode() != "require" and isinstance(exc, (native.NativeBuildError, OSError)):
            print(f"{what}: not built, its Python path will run ({exc})", flush=True)
            return True
        print(f"{what}: FAILED: {type(exc).__name__}: {exc}", flush=True)
        return False
    seconds = time.perf_counter() - started
    if result is None:
        state = "off ($COSIM_NATIVE=off)" if native.mode() == "off" else "not built, its Python path will run"
    elif isinstance(result, dict) and all(isinstance(v, tuple) for v in result.values()):  # build_fmus
        state = ", ".join(f"{p.name} {'built' if rebuilt else 'up to date'}" for p, rebuilt in result.values())
    else:
        state = "built" if _cache_entries() - before else "up to date"
    print(f"{what}: {state} ({seconds:.1f} s)", flush=True)
    return True


def run(args: argparse.Namespace) -> int:
    """Build :data:`PARTS`, each scenario's controller code and the bytecode; see the module docstring."""
    from cosim.results.exits import InvalidInput

    from cosim.scenario.loader import resolve_path

    scenarios = list(args.scenarios) or ([MAIN_SCENARIO] if resolve_path(MAIN_SCENARIO).is_file() else [])
    parts = list(PARTS)
    for path in scenarios:
        from cosim.api import ScenarioError

        try:
            part = scenario_part(path)
        except ScenarioError as exc:
            raise InvalidInput(str(exc)) from None
        if part is not None:
            parts.append(part)
    ok = all([build_part(*part) for part in parts])
    if not args.no_bytecode:
        root = Path(__file__).resolve().parents[2]
        started = time.perf_counter()
        count = compile_bytecode(root)
        print(f"Python bytecode: {count} packages under {root} ({time.perf_counter() - started:.1f} s)", flush=True)
    if not ok:
        print("cosim build: some parts could not be built (see above)", file=sys.stderr)
        return EXIT_BUILD_FAILED
    return 0
