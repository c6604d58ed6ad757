"""The docs site: it builds with MkDocs in strict mode (every warning an error), every internal
link and anchor of the built HTML resolves, nothing is fetched from the network when a page is
viewed, and the generated reference documents every scenario key and every command-line argument.

MkDocs, Material and mkdocstrings come with the ``test`` extra (pyproject.toml); without them
these tests fail, they do not skip.
"""
from __future__ import annotations

import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest

from cosim.cli_reference import cli_markdown, undocumented_arguments
from cosim.scenario.reference import job_names, scenario_keys, scenario_keys_markdown, undocumented_keys
from fmus.servo_drive.tuning import elastic_axis_speed_kp

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> tuple[Path, str]:
    """The site built from this checkout: (site folder, mkdocs' console output)."""
    out = tmp_path_factory.mktemp("site")
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(ROOT / "mkdocs.yml"),
         "--site-dir", str(out)],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
        env={**__import__("os").environ, "NO_MKDOCS_2_WARNING": "1", "PYTHONPATH": str(ROOT)})
    log = result.stdout + result.stderr
    assert result.returncode == 0, log
    return out, log


class _Page(HTMLParser):
    """The ids, links and external resources of one HTML page."""

    def __init__(self) -> None:
        super().__init__()
        self.ids: set[str] = set()
        self.links: list[str] = []
        self.external: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        values = dict(attrs)
        if values.get("id"):
            self.ids.add(values["id"])
        if tag == "a" and values.get("name"):
            self.ids.add(values["name"])
        for attr in ("href", "src"):
            url = values.get(attr)
            if not url:
                continue
            scheme = urlsplit(url).scheme
            if scheme in ("http", "https", "mailto", "data"):
                # a page may link out (a tag's href), but loads nothing from the network
                if tag != "a" and scheme in ("http", "https"):
                    self.external.append(f"<{tag} {attr}={url}>")
                continue
            self.links.append(url)


def _pages(site_dir: Path) -> dict[Path, _Page]:
    pages = {}
    for path in sorted(site_dir.rglob("*.html")):
        page = _Page()
        page.feed(path.read_text(encoding="utf-8"))
        pages[path] = page
    return pages


def test_site_builds_without_warnings(site):
    site_dir, log = site
    assert "WARNING" not in log, log
    for page in ("index.html", "tutorial.html", "reference/scenario_keys.html", "reference/cli.html",
                 "reference/api.html", "reference/contracts.html", "reference/fieldbus.html",
                 "reference/benchmarks.html"):
        assert (site_dir / page).is_file(), page


def test_every_internal_link_and_anchor_resolves(site):
    site_dir, _ = site
    pages = _pages(site_dir)
    assert len(pages) >= 25
    broken = []
    checked = 0
    for path, page in pages.items():
        for url in page.links:
            parts = urlsplit(url)
            if not parts.path:
                target = path
            elif parts.path.startswith("/"):  # 404.html: absolute from the site root (served anywhere)
                target = (site_dir / unquote(parts.path).lstrip("/")).resolve()
            else:
                target = (path.parent / unquote(parts.path)).resolve()
            if target.is_dir():
                target = target / "index.html"
            checked += 1
            if not target.is_file() or not target.resolve().is_relative_to(site_dir.resolve()):
                broken.append(f"{path.relative_to(site_dir)}: {url} (no such file)")
            elif parts.fragment and target.suffix == ".html" and unquote(parts.fragment) not in pages[target].ids:
                broken.append(f"{path.relative_to(site_dir)}: {url} (no such anchor)")
    assert checked > 1000
    assert not broken, "\n".join(broken)


def test_pages_load_nothing_from_the_network(site):
    site_dir, _ = site
    external = [f"{path.relative_to(site_dir)}: {item}" for path, page in _pages(site_dir).items()
                for item in page.external]
    assert not external, "\n".join(external)


def test_generated_reference_pages_are_in_the_site(site):
    site_dir, _ = site
    keys = (site_dir / "reference" / "scenario_keys.html").read_text(encoding="utf-8")
    for job in job_names():
        assert f'id="job-{job}"' in keys, job
    assert "stop_time" in keys and "macro_step" in keys
    cli = (site_dir / "reference" / "cli.html").read_text(encoding="utf-8")
    assert 'id="run"' in cli and "--realtime" in cli
    api = (site_dir / "reference" / "api.html").read_text(encoding="utf-8")
    assert 'id="cosim.api.load_scenario"' in api and 'id="cosim.api.run"' in api
    contracts = (site_dir / "reference" / "contracts.html").read_text(encoding="utf-8")
    assert 'id="controller.contract.CellController"' in contracts
    assert 'id="planners.base.Planner"' in contracts
    drive = (site_dir / "how-to" / "own_drive.html").read_text(encoding="utf-8")
    # the drive FMU interface table, generated from fmus.servo_drive.interface.DRIVE_INTERFACE
    assert "<code>q_meas</code>" in drive and "<code>following_error</code>" in drive and "generated:" not in drive
    tutorial = (site_dir / "tutorial.html").read_text(encoding="utf-8")
    # the nine-line scenario is the repository's file itself, not a copy
    assert "my_controller_iso9283" in tutorial and "pd_gravity_controller.py:PDGravity" in tutorial


def test_every_scenario_key_is_documented():
    assert {"fmus", "iso9283", "compare", "calibration", "identification", "planners", "fieldbus_fault"} <= set(job_names())
    total = sum(len(scenario_keys(job)) for job in job_names())
    assert total > 300
    missing = undocumented_keys()
    assert not missing, "keys without a doc= text in their schema: " + ", ".join(f"{j}: {k}" for j, k in missing)


def test_every_sweep_file_key_is_documented():
    """The sweep file's keys are on the scenario-key page (mkdocs_hooks.sweep_keys_markdown), each with a text."""
    from cosim.scenario.reference import table_keys
    from cosim.sweep.loader import SWEEP_SCHEMA
    from mkdocs_hooks import sweep_keys_markdown

    keys = table_keys(SWEEP_SCHEMA)
    assert {"sweep.base", "axes[].seeds", "axes[].distribution.kind", "report.kind"} <= {k.path for k in keys}
    assert not [k.path for k in keys if not k.doc.strip()]
    page = sweep_keys_markdown()
    assert all(f"`{k.path}`" in page for k in keys) and "{#sweep-file}" in page


def test_scenario_key_page_lists_every_key_with_its_unit_and_default():
    page = scenario_keys_markdown()
    for job in job_names():
        for key in scenario_keys(job):
            assert f"`{key.path}`" in page, (job, key.path)
    # a key with a unit and a default, as the schema says
    assert "| `simulation.stop_time` | number | s | required |" in page
    assert '| `simulation.coupling` | string |  | `"jacobi"` |' in page


def test_scenario_key_page_lists_the_cells_defaults():
    """Every value of scenarios/cell.toml and cell_elastic.toml is on the page, with its unit and
    the reason its file gives (the numbers are the files', read when the page is built)."""
    page = scenario_keys_markdown()
    assert "## The robot cell's defaults {#cell-defaults}" in page
    assert '| `true_robot.payload_mass` | `"8 kg"` | kg | the tool on the flange (rated load 10 kg) |' in page
    assert '| `simulation.macro_step` | `"100 us"` | s |' in page
    for i, kp in enumerate(elastic_axis_speed_kp(), start=1):
        assert f"| `fmus[drive{i}].parameters.speed_kp` | `{float(kp)!r}` |" in page
    assert '| `fmus[plant].builtin` | `"rx130l_plant"` |' in page


def test_undocumented_key_is_found():
    """The check itself: a schema key without doc= is reported."""
    from cosim.scenario.reference import _PLACEHOLDER, _walk
    from cosim.scenario.schema import Field, Integer, Table

    keys = list(_walk(Table({"a": Field(Table({"b": Field(Integer()), "c": Field(Integer(), doc="c")}))}), ""))
    assert [(k.path, bool(k.doc)) for k in keys] == [("a", False), ("a.b", False), ("a.c", True)]
    # a doc that only names the table counts as none
    assert _PLACEHOLDER.fullmatch("the [controller.standard] table") and not _PLACEHOLDER.fullmatch("the tracker")


def test_every_command_line_argument_is_documented():
    assert not undocumented_arguments()
    page = cli_markdown()
    for command in ("run", "serve", "sweep", "calibrate", "identify", "view", "bench", "build"):
        assert f"## `{command}`" in page
