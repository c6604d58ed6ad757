"""examples/hil_external_controller.py is written against python-can and the documented
telegram layout only: it imports the standard library and ``can``, nothing of the project
(python-can finds the ``udpcycle`` interface by its entry point). Its run against ``cosim
serve`` is tested in tests/cosim/hil/test_serve.py."""
import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "hil_external_controller.py"


def test_the_external_controller_imports_only_the_standard_library_and_python_can():
    imported = set()
    for node in ast.walk(ast.parse(EXAMPLE.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            imported.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, "relative import"
            imported.add(node.module.split(".")[0])
    assert "can" in imported
    assert imported - {"can", "__future__"} <= set(sys.stdlib_module_names), imported
    assert "importlib" not in imported and "__import__" not in EXAMPLE.read_text(encoding="utf-8")
