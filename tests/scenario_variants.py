"""Shared by the job tests: a scenario file written from a TOML text with a few exact edits."""
from __future__ import annotations

from pathlib import Path


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
