"""Every fenced code block of the docs runs: one test per page, its blocks in page order.

The conventions (docs/index.md, "Code blocks in these pages"):

* ``bash``   run with ``bash -euo pipefail``; cwd is a fresh folder per page in which ``scenarios/``
  and ``examples/`` link to the repository's, and ``python`` is this test's interpreter (with this
  checkout first on ``PYTHONPATH``); later blocks see the files earlier blocks wrote;
* ``python`` run as a script with the same interpreter, in the same folder;
* ``toml``   parsed with tomllib; a block whose first line is ``# file: NAME.toml`` is written to
  NAME.toml in the folder and loaded (validated) by the scenario loader (a sweep file, one with a
  ``[sweep]`` table, by the sweep loader);
* ``text``   output, listings, formulas: not run.

Any other language, or a block without one, fails the page: nothing escapes the run. A failure
names the page and the line of the block's opening fence.

A command a block cannot run from that folder (the install step of a fresh clone, ``mkdocs serve``,
a USB-CAN adapter we lack) is not a block: say it in the sentence, or write it as ``text`` with a
sentence saying why.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from docs_pages import LANGUAGES, ROOT, Block, blocks, page_id, user_pages

#: Seconds one block may take (a page's blocks together should take well under a minute).
BLOCK_TIMEOUT_S = 300

_FILE = re.compile(r"^#\s*file:\s*(?P<name>[\w.-]+\.toml)\s*$")

PAGES = user_pages()

#: Pages written before these conventions, waiting to be rewritten (issue 28, helpers docs1 and
#: docs2): their blocks are not run yet and their test is reported as xfail. Whoever rewrites a
#: page removes it from here in the same commit; the list must end empty.
PENDING: set[str] = set()


def _environment(folder: Path) -> dict[str, str]:
    bin_dir = folder / ".bin"
    bin_dir.mkdir(exist_ok=True)
    for name in ("python", "python3"):
        link = bin_dir / name
        if not link.exists():
            link.symlink_to(sys.executable)
    env = dict(os.environ)
    env["PATH"] = f"{bin_dir}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    env["MPLBACKEND"] = "Agg"
    env.pop("COLUMNS", None)
    return env


def _page_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "page"
    folder.mkdir(parents=True)
    for name in ("scenarios", "examples"):
        (folder / name).symlink_to(ROOT / name, target_is_directory=True)
    return folder


def _run(block: Block, argv: list[str], folder: Path, env: dict[str, str]) -> None:
    try:
        done = subprocess.run(argv, cwd=folder, env=env, capture_output=True, text=True, timeout=BLOCK_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{block.where}: {block.language} block still running after {BLOCK_TIMEOUT_S} s")
    if done.returncode != 0:
        pytest.fail(f"{block.where}: {block.language} block exited with {done.returncode}\n--- block\n{block.text}"
                    f"--- stdout (end)\n{done.stdout[-3000:]}\n--- stderr (end)\n{done.stderr[-3000:]}")


def _toml(block: Block, folder: Path) -> None:
    try:
        tomllib.loads(block.text)
    except tomllib.TOMLDecodeError as exc:
        pytest.fail(f"{block.where}: toml block is not TOML: {exc}")
    first = block.text.splitlines()[0] if block.text.strip() else ""
    m = _FILE.match(first)
    if not m:
        return
    path = folder / m["name"]
    path.write_text(block.text, encoding="utf-8")
    from cosim.api import load_scenario, load_sweep
    from cosim.scenario.errors import ScenarioError

    sweep = "sweep" in tomllib.loads(block.text)  # a sweep file: validated (with every variant) by the sweep loader
    try:
        (load_sweep if sweep else load_scenario)(path)
    except ScenarioError as exc:
        pytest.fail(f"{block.where}: {m['name']} is not a valid {'sweep' if sweep else 'scenario'}: {exc}")


def run_page(page: Path, tmp_path: Path) -> int:
    """Run every block of ``page``; return how many ran."""
    page_blocks = blocks(page)
    unknown = [f"{b.where}: ```{b.language or '(no language)'}" for b in page_blocks if b.language not in LANGUAGES]
    assert not unknown, ("blocks with a language the docs-code test does not know (one of "
                         f"{', '.join(LANGUAGES)}):\n" + "\n".join(unknown))
    folder = _page_folder(tmp_path)
    env = _environment(folder)
    ran = 0
    for k, block in enumerate(page_blocks):
        if block.language == "bash":
            script = folder / f".block{k}.sh"
            script.write_text(block.text, encoding="utf-8")
            _run(block, ["bash", "-euo", "pipefail", str(script)], folder, env)
        elif block.language == "python":
            script = folder / f".block{k}.py"
            script.write_text(block.text, encoding="utf-8")
            _run(block, [sys.executable, str(script)], folder, env)
        elif block.language == "toml":
            _toml(block, folder)
        else:
            continue
        ran += 1
    return ran


@pytest.mark.parametrize("page", PAGES, ids=[page_id(p) for p in PAGES])
def test_every_code_block_runs(page: Path, tmp_path: Path):
    if page_id(page) in PENDING:
        pytest.xfail("page not yet rewritten to the code-block conventions (PENDING)")
    run_page(page, tmp_path)


def test_pending_pages_exist():
    """A page moved or deleted leaves PENDING with it."""
    assert not [p for p in PENDING if not (ROOT / p).is_file()], "remove moved/deleted pages from PENDING"


def test_the_pages_are_found_and_hold_runnable_blocks():
    assert len(PAGES) >= 15
    assert ROOT / "docs" / "index.md" in PAGES and ROOT / "docs" / "tutorial.md" in PAGES
    runnable = sum(1 for page in PAGES for b in blocks(page) if b.language in ("bash", "python", "toml"))
    assert runnable >= 20


def test_a_failing_or_unknown_block_names_page_and_line(tmp_path):
    """The check itself: a block that fails, and a block without a language, are reported with
    the page and the line of their fence; a later bash block sees what an earlier one wrote."""
    page = tmp_path / "page.md"
    page.write_text("# t\n\n```bash\necho 1 > one.txt\n```\n\n```python\n"
                    "assert open('one.txt').read() == '1\\n'\nimport pathlib; assert pathlib.Path('scenarios').is_dir()\n"
                    "```\n\n```toml\n# file: s.toml\nextends = \"iso9283\"\n[scenario]\nname = \"s\"\n```\n"
                    "\n```bash\npython -c 'import sys; sys.exit(3)'\n```\n", encoding="utf-8")
    with pytest.raises(pytest.fail.Exception, match=r"page\.md:19: bash block exited with 3"):
        run_page(page, tmp_path / "a")
    assert (tmp_path / "a" / "page" / "s.toml").is_file()
    page.write_text("# t\n\n```text\nnot run\n```\n\n```\nls\n```\n", encoding="utf-8")
    with pytest.raises(AssertionError, match=r"page\.md:7: ```\(no language\)"):
        run_page(page, tmp_path / "b")
    page.write_text("```toml\n# file: bad.toml\nextends = \"iso9283\"\n[controller]\nclas = \"x\"\n```\n", encoding="utf-8")
    with pytest.raises(pytest.fail.Exception, match=r"page\.md:1: bad\.toml is not a valid scenario"):
        run_page(page, tmp_path / "c")
