"""Imports point down only, and no import goes round in a circle.

Between our packages: the ground floor (native, robot, fieldbus) imports no package of ours
(fieldbus and robot may use the native build layer, which imports nothing of ours), the middle
floor (fmus, controller, planners, calibration, identification) imports only the ground floor,
cosim may import everything.

Inside cosim/, its subpackages stand on floors (``COSIM_FLOORS``), bottom first; a module imports
its own subpackage and the floors below, never a floor above nor a neighbour on its own floor:

=====  ======================================================  ======================================
0      ``master``, ``results``, ``tracking``                   the FMU master; result files, exit
                                                               codes and interrupts; the laser
                                                               tracker and its metrics
1      ``ssp``                                                 SSP archives of FMUs and connections
2      ``scenario``                                            scenario files, schema, validation,
                                                               the job registry
3      ``cell``                                                what the robot cell is (parts, wiring,
                                                               checks, evaluation, its SSP export)
4      ``execution``                                           how a cell runs (simulated, paced,
                                                               split, served)
5      ``jobs``, ``coupling_study``                            the jobs of ``cosim run``; the
                                                               coupling study
6      ``runs``                                                one run of a scenario: load it, run it
                                                               into a folder, read what it wrote
7      ``sweep``                                               many runs of a scenario
8      ``api``                                                 the public module for scripts
9      ``commands``                                            one module per CLI command
10     ``cli``                                                 the command line (``cosim.cli.main``)
11     ``__main__``, ``cli_reference``, ``verdict_reference``  ``python -m cosim``; the generated
                                                               reference pages
12     ``cosim`` (the package's ``__init__``)                  re-exports ``cosim.api`` on first use
=====  ======================================================  ======================================

The job registry (scenario floor) imports the job modules it lists by name and reads their
``JOB``; that is how a lower floor finds the jobs without importing them. Imports inside
functions count; only those under ``if TYPE_CHECKING:`` (annotations) do not. ``from pkg import
name`` counts as an import of the module ``pkg.name`` when that is a module, of ``pkg`` otherwise.
"""
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


def _import_nodes(path: Path):
    """The absolute import statements anywhere in ``path`` (also inside functions), except
    under ``if TYPE_CHECKING:``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If)
            and getattr(node.test, "id", getattr(node.test, "attr", "")) == "TYPE_CHECKING"
            for n in ast.walk(node)}
    return [node for node in ast.walk(tree) if id(node) not in skip and (
        isinstance(node, ast.Import) or (isinstance(node, ast.ImportFrom) and node.level == 0 and node.module))]


def _all_imports(path: Path) -> set[str]:
    """Every absolute module imported anywhere in ``path`` (``from pkg import name`` as ``pkg``)."""
    names: set[str] = set()
    for node in _import_nodes(path):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        else:
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


def _modules(packages) -> dict[str, Path]:
    """Module name -> file of every module of ``packages``."""
    found = {}
    for package in packages:
        for path in (ROOT / package).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


ALL_MODULES = _modules(sorted(OURS))


def _imported_modules(path: Path) -> set[str]:
    """Like :func:`_all_imports`, with ``from pkg import name`` as the module ``pkg.name`` when
    ``pkg.name`` is one of ours (a submodule imported by name), else as ``pkg``."""
    names: set[str] = set()
    for node in _import_nodes(path):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        else:
            submodules = {f"{node.module}.{alias.name}" for alias in node.names} & ALL_MODULES.keys()
            names.update(submodules)
            if len(submodules) < len(node.names):
                names.add(node.module)
    return names


def _module_graph(packages: tuple[str, ...]) -> dict[str, set[str]]:
    return {module: {m for m in _imported_modules(path) if m.split(".")[0] in OURS}
            for module, path in _modules(packages).items()}


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One circle of each strongly connected part of ``graph`` that has one (a self-import
    included): the shortest way from its first node back to itself, e.g. ``[a, b, a]``."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    parts: list[list[str]] = []

    def connect(node: str) -> None:  # Tarjan's algorithm
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt not in graph:
                continue
            if nxt not in index:
                connect(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            part = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                part.append(member)
                if member == node:
                    break
            if len(part) > 1 or node in graph.get(node, ()):
                parts.append(sorted(part))

    for node in sorted(graph):
        if node not in index:
            connect(node)
    circles = []
    for part in parts:
        start, members = part[0], set(part)
        previous, frontier = {start: None}, [start]
        while previous[start] is None:  # breadth first, until an edge leads back to start
            following = []
            for node in frontier:
                for nxt in sorted(graph[node] & members):
                    if nxt == start and previous[start] is None:
                        previous[start] = node
                    elif nxt not in previous:
                        previous[nxt] = node
                        following.append(nxt)
            if previous[start] is not None or not following:
                break
            frontier = following
        circle, node = [start], previous[start]
        while node != start:
            circle.append(node)
            node = previous[node]
        circles.append([start] + circle[:0:-1] + [start] if len(circle) > 1 else [start, start])
    return circles


def _show(circles: list[list[str]]) -> str:
    return "\n".join(" -> ".join(c) for c in circles)


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


@pytest.mark.parametrize("package", sorted(OURS))
def test_no_circle_of_imports_in_a_package(package):
    """No module of ``package`` imports, directly or through others of the package, itself."""
    circles = _circles(_module_graph((package,)))
    assert not circles, f"import circles in {package}/:\n{_show(circles)}"


COSIM_FLOORS: tuple[tuple[str, ...], ...] = (
    ("master", "results", "tracking"), ("ssp",), ("scenario",), ("cell",), ("execution",),
    ("jobs", "coupling_study"), ("runs",), ("sweep",), ("api",), ("commands",), ("cli",),
    ("__main__", "cli_reference", "verdict_reference"), ("cosim",))
"""cosim's subpackages (and top-level modules) by floor, bottom first (the module docstring)."""


def _subpackage(module: str) -> str:
    """``cosim.cell.parts`` -> ``cell``; ``cosim.api`` -> ``api``; the package itself -> ``cosim``."""
    return module.split(".")[1] if "." in module else module


def _subpackage_graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for module, imported in _module_graph(("cosim",)).items():
        own = _subpackage(module)
        graph.setdefault(own, set()).update(_subpackage(m) for m in imported
                                             if m.split(".")[0] == "cosim" and _subpackage(m) != own)
    return graph


def test_no_circle_between_cosim_subpackages():
    """With each subpackage of cosim/ taken as one node, no import goes round in a circle."""
    circles = _circles(_subpackage_graph())
    assert not circles, f"import circles between cosim's subpackages:\n{_show(circles)}"


def test_cosim_subpackages_import_only_their_floor_and_below():
    floor = {name: level for level, names in enumerate(COSIM_FLOORS) for name in names}
    graph = _subpackage_graph()
    assert set(graph) <= set(floor), f"subpackages of cosim/ without a floor in COSIM_FLOORS: {sorted(set(graph) - set(floor))}"
    offenders = {}
    for module, imported in _module_graph(("cosim",)).items():
        own = _subpackage(module)
        bad = sorted(m for m in imported if m.split(".")[0] == "cosim" and _subpackage(m) != own
                     and floor[_subpackage(m)] >= floor[own])
        if bad:
            offenders[module] = bad
    assert not offenders, f"imports up or sideways between cosim's floors (COSIM_FLOORS): {offenders}"


def test_the_circle_finder_finds_circles():
    """The checks above would see a circle: a self-import, a pair, a longer ring beside a tree."""
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"e"}, "f": {"g"}, "g": {"f"}}
    assert _circles(graph) == [["a", "b", "c", "a"], ["e", "e"], ["f", "g", "f"]]
    assert _circles({"a": {"b"}, "b": set()}) == []

