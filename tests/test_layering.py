"""Imports point down only: ground floor (native, robot, fieldbus) imports no package of
ours (fieldbus and robot may use the native build layer, which imports nothing of ours),
the middle floor imports only the ground floor, cosim may import everything."""
import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = {"native", "robot", "fieldbus", "fmus", "controller", "planners", "identification", "cosim"}
ALLOWED = {
    "native": {"native"},
    "robot": {"robot", "native"},
    "fieldbus": {"fieldbus", "native"},
    "fmus": {"fmus", "robot", "fieldbus", "native"},
    "controller": {"controller", "robot", "fieldbus", "native"},
    "planners": {"planners", "robot", "fieldbus", "native"},
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
