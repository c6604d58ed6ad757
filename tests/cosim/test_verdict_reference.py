"""The generated tables of docs/reference/verdicts.md (cosim/verdict_reference.py) describe what the
code does: every exit code constant, every violation kind the verdict and the protection events
produce, the drives' actual start values."""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from cosim.cell import protection, verdict
from cosim.results import exits
from cosim.verdict_reference import MARKERS, drive_protection_markdown, exit_codes_markdown, fill, \
    violation_kinds_markdown
from fmus.servo_drive.params import drive_start_values

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "reference" / "verdicts.md"


def test_every_exit_code_constant_is_documented():
    constants = {value for name, value in vars(exits).items() if name.startswith("EXIT_") and isinstance(value, int)}
    documented = {int(code) for code, *_ in exits.EXIT_CODES if code.isdigit()}
    assert constants == documented
    table = exit_codes_markdown()
    for code in constants:
        assert f"\n| {code} | " in table
    # the verdicts' exit codes are the ones the table names them by
    names = {int(code): name for code, name, *_ in exits.EXIT_CODES if code.isdigit()}
    for status in ("ok", "limit", "fault", "interrupted"):
        assert names[verdict.exit_code(status)] == status
    assert names[verdict.exit_code("failed")] == "failed run"


def test_every_violation_kind_is_documented():
    source = (ROOT / "cosim" / "cell" / "verdict.py").read_text(encoding="utf-8")
    made = {node.args[0].value for node in ast.walk(ast.parse(source))
            if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "violation"
            and node.args and isinstance(node.args[0], ast.Constant)}
    made |= set(protection.KINDS) | {"end_stop"} | set(verdict.PROTECTION_CODES.values())
    made -= verdict.WARNING_KINDS | {"overrun"}  # warnings, not violations
    assert made and made <= set(verdict.VIOLATION_KINDS), made - set(verdict.VIOLATION_KINDS)
    table = violation_kinds_markdown()
    for kind, (judged, _) in verdict.VIOLATION_KINDS.items():
        assert f"| `{kind}` | `{judged}` |" in table
    assert "| `following_error` | `limit` | 0x8611 | rad |" in table
    assert verdict.LIMIT_KINDS == {k for k, (v, _) in verdict.VIOLATION_KINDS.items() if v == "limit"}


def test_drive_protection_table_holds_the_drives_start_values():
    table = drive_protection_markdown()
    axis2 = drive_start_values(2)
    row = next(line for line in table.splitlines() if line.startswith("| `torque_limit` |"))
    assert row.split(" | ")[4] == f"{axis2['torque_limit']:.4g}"
    assert "| `following_error_window` | 0x6065 | rad | 0.05 |" in table
    assert "end_stop_upper" in table


def test_the_page_holds_every_marker_and_fill_replaces_them():
    text = PAGE.read_text(encoding="utf-8")
    filled = fill(text)
    assert not any(marker in filled for marker in MARKERS)
    assert "| 128 + n | killed |" in filled and "0x8612" in filled
    with pytest.raises(ValueError, match="marker"):
        fill(re.sub(r"<!-- generated: exit codes.*-->", "", text))
