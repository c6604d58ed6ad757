"""Every page of the docs that the code, scenarios, examples, benchmarks, tests and the README name
by path (``docs/<...>.md``: in error messages, docstrings, comments) exists, as a file or as a page
the docs site generates (mkdocs_hooks.GENERATED): a page that moves takes its mentions with it."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Where the mentions are looked for (docs/ itself is checked by the site build's link check).
PLACES = ("calibration", "controller", "cosim", "fieldbus", "fmus", "identification", "planners", "robot",
          "scenarios", "examples", "benchmarks", "tests", "README.md", "pyproject.toml", "mkdocs_hooks.py")
SUFFIXES = {".py", ".toml", ".md", ".c", ".h", ".txt", ".cfg", ".yml", ".yaml"}

_MENTION = re.compile(r"\bdocs/[\w./-]+?\.md\b")


def _generated() -> set[str]:
    import mkdocs_hooks

    return {f"docs/{uri}" for uri in mkdocs_hooks.GENERATED}


def _files():
    for place in PLACES:
        path = ROOT / place
        if path.is_file():
            yield path
        elif path.is_dir():
            yield from (p for p in sorted(path.rglob("*")) if p.is_file() and p.suffix in SUFFIXES)


def test_every_docs_page_named_in_the_repository_exists():
    generated = _generated()
    missing = []
    checked = 0
    for path in _files():
        if path == Path(__file__).resolve():
            continue
        for n, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), start=1):
            for page in _MENTION.findall(line):
                checked += 1
                if page not in generated and not (ROOT / page).is_file():
                    missing.append(f"{path.relative_to(ROOT)}:{n}: {page}")
    assert checked > 100  # the code names its pages in many places
    assert not missing, "pages named but not in docs/:\n" + "\n".join(missing)


def test_the_check_finds_a_missing_page():
    assert _MENTION.findall("see docs/robustness.md, \"Verdicts\"") == ["docs/robustness.md"]
    assert not (ROOT / "docs" / "robustness.md").is_file()
