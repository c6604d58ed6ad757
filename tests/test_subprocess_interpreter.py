"""Tests and benchmarks start Python subprocesses with `sys.executable`, never with
whatever `python` is first on the PATH (a suite run from a venv that is not activated
would otherwise test another installation)."""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SPAWNERS = {"run", "Popen", "call", "check_call", "check_output", "create_subprocess_exec"}
BARE = {"python", "python3", "python3.11", "python3.12", "python3.13"}


def _bare_python_calls(path: Path) -> list[int]:
    lines = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if not isinstance(node, ast.Call) or not node.args:
            continue
        name = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")
        first = node.args[0]
        if isinstance(first, (ast.List, ast.Tuple)) and first.elts:
            first = first.elts[0]
        if name in SPAWNERS and isinstance(first, ast.Constant) and isinstance(first.value, str) \
                and first.value.split()[0] in BARE:
            lines.append(node.lineno)
    return lines


def test_no_subprocess_starts_a_bare_python():
    offenders = {}
    for folder in ("tests", "benchmarks", "cosim", "examples"):
        for path in (ROOT / folder).rglob("*.py"):
            if found := _bare_python_calls(path):
                offenders[str(path.relative_to(ROOT))] = found
    assert not offenders, f"use sys.executable instead of a bare python: {offenders}"


def test_the_checker_finds_a_bare_python(tmp_path):
    sample = tmp_path / "sample.py"
    sample.write_text('import subprocess\nsubprocess.run(["python", "-m", "cosim"])\n'
                      'subprocess.Popen(("python3", "-c", "pass"))\n', encoding="utf-8")
    assert _bare_python_calls(sample) == [2, 3]
