"""Shared by the job tests: scenario files written from a TOML text with a few exact edits,
and run in this process the way ``python -m cosim run`` runs them."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from cosim.cli import main


def write_variant(text: str, path: Path, replacements: list[tuple[str, str]]) -> Path:
    """Write ``text`` to ``path`` with each ``(old, new)`` applied once, in order; return ``path``.

    Each ``old`` must occur in the text as edited so far (an assertion names it otherwise), so a
    test cannot silently run the unedited scenario after the scenario file changed.
    """
    for old, new in replacements:
        assert old in text, old
        text = text.replace(old, new, 1)
    path.write_text(text, encoding="utf-8")
    return path


def run_scenario(path: Path, out: Path) -> tuple[int, dict[str, Any]]:
    """``cosim run path --out out --quiet`` in this process: (exit code, the run's summary.json)."""
    code = main(["run", str(path), "--out", str(out), "--quiet"])
    return code, json.loads((out / "summary.json").read_text())
