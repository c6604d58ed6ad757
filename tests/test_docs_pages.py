"""The user docs stay light and free of measurement history (issue 28), and the README is the
short landing page the issue asks for.

* every hand-written user page (tests/docs_pages.py: docs/**/*.md, the hand-written part of the
  reference pages whose tables the hook generates) is at most ``MAX_PAGE_BYTES``;
* all of them together stay below ``MAX_TOTAL_BYTES`` (the generated reference, built from the
  code at each site build, is not a file and is not counted);
* no page holds measurement narrative: the patterns of ``NARRATIVE`` (the issue's "before the
  changes", "what moved it", dated fix histories, and the lab-notebook phrases the old pages
  used). Measured figures live in the benchmark results page ``cosim bench`` writes;
* the README starts with the two commands, says what the first run prints and where its
  results are, gives three things to try next and points to the docs site.

Pages still in tests/test_docs_code.py's ``PENDING`` (not yet rewritten) are left out until
they leave that set.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from docs_pages import ROOT, page_id, user_pages
from test_docs_code import PENDING

#: A user page above this is split or trimmed (the issue: "no user page above about 15 KB").
MAX_PAGE_BYTES = 15_000
#: All hand-written user pages together (the issue: "below 150 KB").
MAX_TOTAL_BYTES = 150_000

#: (what it catches, pattern): phrases of measurement narrative, searched case-insensitively in
#: every line of a page (prose and code blocks alike). Chosen on the pages of issue 28 so that
#: each catches history or a lab-notebook figure and none catches a plain instruction.
NARRATIVE: tuple[tuple[str, str], ...] = (
    ("'before the change(s)/fix'", r"\bbefore (?:the|this|these) (?:changes?|fix(?:es)?)\b"),
    ("'what moved it'", r"\bwhat moved it\b"),
    ("'those figures were taken'", r"\b(?:figures|numbers|measurements) were taken\b"),
    ("a dated history '(2026-...'", r"\(\s*20\d\d-\d\d"),
    ("'this session'", r"\bthis session\b"),
    ("'we measured/found/tried/fixed'", r"\bwe (?:measured|found|tried|fixed|changed)\b"),
    ("a machine load figure 'load average 3.7'", r"\bload average (?:of )?(?:about )?\d"),
    ("'the shared 2-core machine'", r"\b(?:shared|this) 2-core (?:machine|vm)\b"),
    ("'used to <verb>' (what the code did before)", r"\bused to (?:be|take|cost|preallocate|hold|write|run|grow)\b"),
    ("'N µs before' (a figure before a change)", r"\b\d+(?:\.\d+)? ?(?:µs|us|ms|MiB|MB|%) before\b|\bbefore \([+\-−]\d"),
    ("'was tried' / 'not kept'", r"\b(?:was|were) tried\b|\bnot kept\b"),
    ("a callgrind count", r"\bcallgrind\b"),
    ("'rerun the benchmark'", r"\brerun the benchmark\b"),
)
_NARRATIVE = [(what, re.compile(pattern, re.IGNORECASE)) for what, pattern in NARRATIVE]


def _pages() -> list[Path]:
    return [p for p in user_pages() if page_id(p) not in PENDING]


def narrative_lines(text: str) -> list[tuple[int, str, str]]:
    """(line number, what, the line) of every line of ``text`` that matches a ``NARRATIVE`` pattern."""
    found = []
    for number, line in enumerate(text.splitlines(), 1):
        for what, pattern in _NARRATIVE:
            if pattern.search(line):
                found.append((number, what, line.strip()))
    return found


def test_no_user_page_above_15_kb():
    pages = _pages()
    assert len(pages) >= 20
    big = [f"{page_id(p)}: {p.stat().st_size} bytes" for p in pages if p.stat().st_size > MAX_PAGE_BYTES]
    assert not big, f"user pages above {MAX_PAGE_BYTES} bytes (split or trim them):\n" + "\n".join(big)


def test_user_docs_together_below_150_kb():
    total = sum(p.stat().st_size for p in _pages())
    assert total < MAX_TOTAL_BYTES, f"hand-written user docs: {total} bytes, expected below {MAX_TOTAL_BYTES}"


def test_no_measurement_narrative_in_user_pages_and_readme():
    hits = [f"{page_id(p)}:{n}: {what}: {line[:120]}"
            for p in _pages() + [ROOT / "README.md"] for n, what, line in narrative_lines(p.read_text(encoding="utf-8"))]
    assert not hits, ("measurement narrative in user pages (measured figures belong in the benchmark "
                      "results page `cosim bench` writes):\n" + "\n".join(hits))


@pytest.mark.parametrize("line", [
    "Those figures were taken before the changes below.",
    "What moved it: the codec.",
    "Fixed the pacer (2026-11-03): late cycles went from 40 to 2.",
    "In this session the median fell to 28 µs.",
    "We measured 47 µs round trip.",
    "on the shared 2-core machine at a load average of about 2",
    "where it used to preallocate 165 MB",
    "133 700 and 272 000 before (+6 %)",
    "was 150 µs before the fix",
    "The nodes' phases in C were tried: not kept.",
    "Instructions per cycle (callgrind, six nodes)",
])
def test_narrative_patterns_catch_history(line):
    assert narrative_lines(line), line


@pytest.mark.parametrize("line", [
    "Run the main job before you change the controller.",
    "The drive applies the set-point before the next SoC.",
    "python -m cosim run scenarios/iso9283.toml --load 2",
    "a load of 8 kg at the flange",
    "Here the scheduler and one worker run on this machine:",
    "Use the results to compare the modes.",
    "the file date is fixed (2026 is the year of the file format)",
    "The controller's output of cycle k acts 800 µs later.",
])
def test_narrative_patterns_leave_instructions_alone(line):
    assert not narrative_lines(line), line


# ----------------------------------------------------------------------------------- README
README = ROOT / "README.md"


def _readme() -> str:
    return README.read_text(encoding="utf-8")


def test_readme_starts_with_the_two_commands():
    text = _readme()
    first = re.search(r"^```(\w*)\n(.*?)^```", text, re.MULTILINE | re.DOTALL)
    assert first, "README: no code block"
    before = text[:first.start()]
    assert before.startswith("# ") and before.count("\n\n") <= 3, \
        "README: the commands come right after the title and one short paragraph"
    assert first.group(1) == "bash"
    commands = [line for line in first.group(2).splitlines() if line.strip()]
    # the first installs everything and runs the main job, the second runs the tests (.ci/run runs it)
    assert commands == ['python -m pip install -e ".[test]" && python -m cosim build && '
                        "python -m cosim run scenarios/iso9283.toml", "python -m pytest -n 2"], commands
    assert "python -m pytest -n 2" in (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert (ROOT / "scenarios" / "iso9283.toml").is_file()


def test_readme_says_what_the_run_prints_and_where_the_results_are():
    text = _readme()
    after = text[text.index("```", text.index("```") + 3) + 3:]
    explanation = after[:after.index("What to try next")]
    assert "prints" in explanation
    assert "`results/iso9283/`" in explanation and "summary.json" in explanation


def test_readme_has_three_things_to_try_next_that_exist():
    text = _readme()
    rest = text[text.index("What to try next"):]
    items = re.findall(r"^- (.+)$", rest.split("\n\n", 2)[1], re.MULTILINE)
    assert len(items) == 3, items
    for item in items:
        assert re.match(r"`python -m cosim \w+", item), item
        for path in re.findall(r"\b((?:examples|scenarios)/[\w./-]+\.toml)\b", item):
            assert (ROOT / path).is_file(), path


def test_readme_points_to_the_docs_site_and_holds_nothing_else():
    text = _readme()
    assert "mkdocs serve" in text and "`docs/`" in text and (ROOT / "mkdocs.yml").is_file()
    assert "|---" not in text, "README: no tables (the command reference is docs/reference/cli.md)"
    assert len(text.encode("utf-8")) < 2_500, "README: what belongs in the docs goes to the docs"
    assert text.count("```") == 2, "README: one code block, the two commands"
