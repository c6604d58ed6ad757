"""The pages of the docs site and their fenced code blocks (used by tests/test_docs_code.py and
tests/test_docs_pages.py; no pytest state here).

A *user page* is a Markdown file a reader of the site reads as written by hand: everything under
``docs/`` (of reference/fieldbus.md and reference/object_dictionary.md the hand-written part: the
hook puts their generated tables in at build time). The pages the hook generates from the code
(scenario keys, command line) are not files, and ``benchmarks/RESULTS.md``
(written by ``cosim bench``) is the one measured-results page, not a user page.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

#: Hand-written pages outside docs/ that the site shows.
EXTRA_PAGES: tuple[Path, ...] = ()

#: Fence languages and what the docs-code test does with them (docs/index.md, "Code blocks").
LANGUAGES = ("bash", "python", "toml", "text")

_FENCE = re.compile(r"^(?P<indent>[ \t]*)(?P<fence>`{3,}|~{3,})(?P<info>.*)$")
_SNIPPET = re.compile(r'^\s*-{1,}8<-{1,}\s+"(?P<path>[^"]+)"\s*$')


def user_pages() -> list[Path]:
    """Every hand-written page of the site, sorted (docs/**/*.md and the extra pages)."""
    return sorted(DOCS.rglob("*.md")) + [p for p in EXTRA_PAGES if p.is_file()]


def page_id(path: Path) -> str:
    """The page's path relative to the repository (its full path when outside it)."""
    return path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else str(path)


@dataclass(frozen=True)
class Block:
    """One fenced block: its page, the line of its opening fence (1-based), its language (the first
    word of the info string, "" when none) and its text (indentation of the fence removed, snippets
    ``--8<-- "file"`` replaced by the file they name, as pymdownx.snippets does)."""

    page: Path
    line: int
    language: str
    text: str

    @property
    def where(self) -> str:
        return f"{page_id(self.page)}:{self.line}"


def _expand_snippets(text: str) -> str:
    out = []
    for line in text.splitlines(keepends=True):
        m = _SNIPPET.match(line)
        out.append((ROOT / m["path"]).read_text(encoding="utf-8") if m else line)
    return "".join(out)


def blocks(path: Path) -> list[Block]:
    """The fenced code blocks of one page, in page order."""
    found: list[Block] = []
    lines = path.read_text(encoding="utf-8").splitlines()
    i = 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        indent, fence, info = m["indent"], m["fence"], m["info"].strip()
        language = info.split()[0].lstrip("{.").rstrip("}").lower() if info else ""
        body = []
        j = i + 1
        while j < len(lines):
            close = _FENCE.match(lines[j])
            if close and close["fence"][0] == fence[0] and len(close["fence"]) >= len(fence) \
                    and not close["info"].strip():
                break
            line = lines[j]
            body.append(line[len(indent):] if line.startswith(indent) else line.lstrip())
            j += 1
        text = "\n".join(body) + "\n"
        found.append(Block(path, i + 1, language, _expand_snippets(text)))
        i = j + 1
    return found
