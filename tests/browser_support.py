"""A real headless Chromium driven by Selenium for the tests that open report.html.

Debian's ``chromium`` and ``chromium-driver`` (``.ci/run`` installs them when missing). A test that
needs the browser FAILS when it is missing (:func:`start_browser` raises); it never skips.
"""
from __future__ import annotations

import json
import shutil
import time
from pathlib import Path
from typing import Any

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")
DRIVER_NAMES = ("chromedriver",)
#: Seconds a report may take to become interactive in a test (the benchmark measures it).
READY_TIMEOUT_S = 120.0


def _which(names: tuple[str, ...]) -> str | None:
    return next((p for p in (shutil.which(n) for n in names) if p), None)


def start_browser(width: int = 1500, height: int = 1300) -> Any:
    """A headless Chromium WebDriver with the browser console log captured."""
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    binary, driver = _which(CHROMIUM_NAMES), _which(DRIVER_NAMES)
    if binary is None or driver is None:
        raise RuntimeError("Chromium and chromedriver are needed to open report.html in a real browser: "
                           "apt-get install chromium chromium-driver (.ci/run does it)")
    options = Options()
    options.binary_location = binary
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", f"--window-size={width},{height}",
                "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
                "--host-resolver-rules=MAP * ~NOTFOUND"):  # offline: a page that fetches anything logs an error
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(driver), options=options)


def open_report(driver: Any, path: Path, timeout: float = READY_TIMEOUT_S, scene: bool = True) -> float:
    """Open ``path`` from the file system and wait until the report says it is interactive (summary,
    timeline, plots and readout: ``cosimReport.ready``) and, with ``scene``, its 3D view is built too;
    the seconds from the navigation's start to interactive (the page's own clock)."""
    driver.get(Path(path).resolve().as_uri())
    end = time.monotonic() + timeout
    flag = "r.ready && r.sceneReady" if scene else "r.ready"
    while time.monotonic() < end:
        state = driver.execute_script(f"var r = window.cosimReport; return r ? [{flag}, r.errors] : [false, []];")
        if state[1]:
            raise AssertionError(f"{path}: the report's script failed: {state[1]}")
        if state[0]:
            return driver.execute_script("return window.cosimReport.readyAt / 1000;")
        time.sleep(0.05)
    raise AssertionError(f"{path}: not interactive within {timeout} s")


def console_errors(driver: Any) -> list[dict[str, Any]]:
    """The browser console's errors (level SEVERE) since the last call."""
    return [e for e in driver.get_log("browser") if e.get("level") == "SEVERE"]


def summary_cells(driver: Any) -> list[tuple[str, Any, str]]:
    """Every summary figure the report shows: (dotted key in summary.json, value, text shown)."""
    rows = driver.execute_script(
        "return Array.from(document.querySelectorAll('td.fig')).map(function (td) {"
        " return [td.getAttribute('data-key'), td.getAttribute('data-value'), td.textContent]; });")
    return [(k, json.loads(v), text) for k, v, text in rows]


def report_state(driver: Any) -> dict[str, Any]:
    """What an opened report shows: its notes, run toggles, summary keys, ranking rows, events."""
    return driver.execute_script("""
        var q = function (s) { return Array.from(document.querySelectorAll(s)); };
        return {notes: q('#notes div').map(function (d) { return d.textContent; }),
                runs: q('#toggles label').map(function (l) { return l.getAttribute('data-run'); }),
                keys: q('td.fig').map(function (td) { return td.getAttribute('data-key'); }),
                ranking_rows: q('table.ranking tr').length - 1,
                events: q('#events tr').slice(1).map(function (tr) { return Array.from(tr.cells).map(function (c) { return c.textContent; }); }),
                plots: q('.plot').map(function (d) { return d.id; })};""")
