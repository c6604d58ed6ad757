"""Imports point down only: ground floor (native, robot, fieldbus) imports no package of
ours (fieldbus and robot may use the native build layer, which imports nothing of ours),
the middle floor imports only the ground floor, cosim may import everything."""
import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = {"native", "robot", "fieldbus", "fmus", "controller", "planners", "calibration", "identification", "cosim"}
ALLOWED = {
    "native": {"native"},
    "robot": {"robot", "native"},
    "fieldbus": {"fieldbus", "native"},
    "fmus": {"fmus", "robot", "fieldbus", "native"},
    "controller": {"controller", "robot", "fieldbus", "native"},
    "planners": {"planners", "robot", "fieldbus", "native"},
    "calibration": {"calibration", "robot", "fieldbus", "native"},
    "identification": {"identification", "robot", "fieldbus", "native"},
    "cosim": OURS,
}


def _imported_packages(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names & OURS


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_imports_point_down(package):
    offenders = {}
    for path in (ROOT / package).rglob("*.py"):
        bad = _imported_packages(path) - ALLOWED[package]
        if bad:
            offenders[str(path.relative_to(ROOT))] = sorted(bad)
    assert not offenders, f"imports pointing up or sideways: {offenders}"


# Inside cosim/: the master, the results and the scenario layer know nothing of the jobs, the
# robot cell, the laser tracker and tracking metrics, the execution of a cell (cosim/execution/:
# simulated, paced, split, served) or the commands built on them.
COSIM_LOWER = ("master", "results", "scenario")
COSIM_UPPER = {"jobs", "cell", "tracking", "execution", "commands", "sweep", "api", "cli"}


def _all_imports(path: Path) -> set[str]:
    """Every absolute module imported anywhere in ``path`` (also inside functions), except
    under ``if TYPE_CHECKING:``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If)
            and getattr(node.test, "id", getattr(node.test, "attr", "")) == "TYPE_CHECKING"
            for n in ast.walk(node)}
    names: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
    return names


@pytest.mark.parametrize("layer", COSIM_LOWER)
def test_cosim_lower_layers_import_no_job_or_execution_code(layer):
    offenders = {}
    for path in (ROOT / "cosim" / layer).rglob("*.py"):
        bad = sorted(m for m in _all_imports(path) if m.startswith("cosim.") and m.split(".")[1] in COSIM_UPPER)
        if bad:
            offenders[str(path.relative_to(ROOT))] = bad
    assert not offenders, f"cosim/{layer} imports job/execution code: {offenders}"


def _module_graph(packages: tuple[str, ...]) -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for package in packages:
        for path in (ROOT / package).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            module = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            graph[module] = {m for m in _all_imports(path) if m.split(".")[0] in OURS}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    found, state, stack = [], {}, []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt not in graph:
                continue
            if state.get(nxt) == 1:
                found.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node)
    return found


@pytest.mark.parametrize("pairs", [("cosim.scenario", "cosim.execution"), ("planners.base", "planners.trajectory"),
                                   ("fieldbus.config", "fieldbus.timing")])
def test_former_import_cycles_stay_removed(pairs):
    graph = _module_graph(("cosim", "planners", "fieldbus"))
    cycles = [c for c in _cycles(graph) if any(m.startswith(pairs[0]) for m in c)
              and any(m.startswith(pairs[1]) for m in c)]
    assert not cycles, f"import cycle through {pairs}: {cycles[:3]}"


def test_n_joints_is_defined_once():
    defined = [str(p.relative_to(ROOT)) for package in OURS for p in (ROOT / package).rglob("*.py")
               if any(isinstance(n, ast.Assign) and any(getattr(t, "id", "") == "N_JOINTS" for t in n.targets)
                      for n in ast.parse(p.read_text(encoding="utf-8")).body)]
    assert defined == ["robot/joints.py"], defined


def _module_level_imports(path: Path) -> set[str]:
    return {node.module for node in ast.parse(path.read_text(encoding="utf-8")).body
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module}


def test_fieldbus_config_imports_the_timing_model_at_module_level():
    """The configuration checks its cycle budget with the timing model, which names the
    configuration's types for annotations only: a plain downward import, not one hidden in a
    function (which is how a cycle would come back unnoticed)."""
    assert "fieldbus.timing" in _module_level_imports(ROOT / "fieldbus" / "config.py")
    assert "fieldbus.config" not in _all_imports(ROOT / "fieldbus" / "timing.py")


def test_the_cell_imports_nothing_of_its_execution():
    """cosim/cell/ says what a cell IS (description, parts, wiring, checks, evaluation, the data
    a run yields); how it runs is cosim/execution/, which imports the cell, never the reverse
    (imports inside functions count)."""
    offenders = {str(p.relative_to(ROOT)): sorted(m for m in _all_imports(p) if m.startswith("cosim.execution"))
                 for p in (ROOT / "cosim" / "cell").rglob("*.py")}
    offenders = {k: v for k, v in offenders.items() if v}
    assert not offenders, f"cosim/cell imports cosim/execution: {offenders}"


EXECUTION_MODES = ("cosim.execution.simulated", "cosim.execution.paced", "cosim.execution.split",
                   "cosim.execution.served")
EXECUTION_SHARED = ("cosim.execution.cell_master", "cosim.execution.cell_side", "cosim.execution.timing",
                    "cosim.execution.config", "cosim.execution.serve_settings", "cosim.execution.cell_execution")


def _within(module: str, packages) -> str | None:
    return next((p for p in packages if module == p or module.startswith(p + ".")), None)


def test_one_execution_modes_share_floors_and_never_import_each_other():
    """cosim/execution/: the entry (cosim.execution.run_cell) picks one mode module; a mode imports
    the shared floors (the cell on one master, the served cell side, timing, options) and the
    cell's data, never another mode; the shared floors import neither a mode nor the entry; no
    circle of imports goes through cosim/execution/ (imports inside functions count)."""
    graph = _module_graph(("cosim",))
    offenders = {}
    for module, imported in graph.items():
        own = _within(module, EXECUTION_MODES)
        if own:
            bad = [m for m in imported if _within(m, EXECUTION_MODES) not in (None, own)]
        elif _within(module, EXECUTION_SHARED):
            bad = [m for m in imported if m == "cosim.execution" or _within(m, EXECUTION_MODES)]
        else:
            continue
        if bad:
            offenders[module] = sorted(bad)
    assert not offenders, f"execution floors calling up or sideways: {offenders}"
    cycles = [c for c in _cycles(graph) if any(m.startswith("cosim.execution") for m in c)]
    assert not cycles, f"import circles through cosim/execution: {cycles[:3]}"
