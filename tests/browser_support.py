"""Real browsers for the tests that open report.html: a headless Chromium driven by Selenium, and
Firefox driven over its own remote protocol (Marionette) by Mozilla's ``marionette_driver``.

Debian's ``chromium``, ``chromium-driver``, ``firefox-esr`` and ``xvfb`` (``.ci/run`` installs them
when missing); ``marionette_driver`` comes with the test extras (pyproject.toml). Firefox needs no
geckodriver this way: Marionette is built into Firefox and ``marionette_driver`` talks to it
directly on a loopback port. Firefox runs as a real window on a private Xvfb display rather than
``--headless``: its headless mode has no WebGL on a machine without a GPU (the report's 3D view
needs it), while under Xvfb it renders WebGL with Mesa's software rasteriser (llvmpipe). A test
that needs a browser FAILS when it is missing (:func:`start_browser`, :func:`start_firefox`
raise); it never skips.
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


FIREFOX_NAMES = ("firefox-esr", "firefox")
#: Script errors of the browser's own code (not the page's), as its log names their source.
INTERNAL_SOURCES = ("JavaScript error: resource://", "JavaScript error: chrome://")
#: Console errors of the browser's own services, by their prefix: Nimbus' remote-settings loader
#: reports that it cannot fetch experiments (offline; Firefox Labs keeps it on whatever the prefs say).
INTERNAL_CONSOLE = ("console.error: RSLoader:",)


class Firefox:
    """A headless Firefox (Marionette session) with its console captured: the page's ``console.*``
    calls go to Firefox's standard output (pref ``devtools.console.stdout.content``), which
    ``gecko_log`` keeps in a file; uncaught script errors are read from Firefox's console service."""

    def __init__(self, width: int = 1500, height: int = 1300) -> None:
        import socket
        import tempfile

        try:
            from marionette_driver.marionette import Marionette
        except ImportError as exc:
            raise RuntimeError("the Python package marionette_driver is needed to drive Firefox: "
                               "pip install -e '.[test]'") from exc
        binary = _which(FIREFOX_NAMES)
        if binary is None:
            raise RuntimeError("Firefox is needed to open report.html in a second real browser: "
                               "apt-get install firefox-esr (.ci/run does it)")
        xvfb = shutil.which("Xvfb")
        if xvfb is None:
            raise RuntimeError("Xvfb is needed to give Firefox a display with WebGL: apt-get install xvfb "
                               "(.ci/run does it)")
        self._xvfb = _start_xvfb(xvfb, width, height)
        with socket.socket() as sock:  # a free loopback port for this session's Marionette server
            sock.bind(("127.0.0.1", 0))
            port = sock.getsockname()[1]
        self._folder = tempfile.TemporaryDirectory(prefix="cosim-firefox-")
        self.log_path = Path(self._folder.name) / "gecko.log"
        prefs = {"devtools.console.stdout.content": True, "devtools.console.stdout.chrome": False,
                 # offline: nothing is looked up or fetched by the browser itself
                 "network.dns.disabled": True, "app.update.enabled": False, "browser.safebrowsing.malware.enabled": False,
                 "browser.safebrowsing.phishing.enabled": False, "datareporting.policy.dataSubmissionEnabled": False,
                 # the browser's own services that log errors offline (remote experiments, backups)
                 "messaging-system.rsexperimentloader.enabled": False, "app.normandy.enabled": False,
                 "browser.backup.enabled": False, "browser.backup.scheduled.enabled": False}
        import os

        display = os.environ.get("DISPLAY")
        os.environ["DISPLAY"] = self._xvfb[1]  # Firefox's environment is this process's, copied at its start
        try:
            self.m = Marionette(bin=binary, headless=False, host="127.0.0.1", port=port, startup_timeout=120,
                                gecko_log=str(self.log_path), prefs=prefs)
            self.m.start_session()
        except BaseException:
            self._xvfb[0].kill()
            self._xvfb[0].wait()
            raise
        finally:
            if display is None:
                os.environ.pop("DISPLAY", None)
            else:
                os.environ["DISPLAY"] = display
        self.m.set_window_rect(width=width, height=height)
        self._log_seen = 0
        self._errors_seen = 0

    def execute_script(self, script: str, *args: Any) -> Any:
        return self.m.execute_script(script, script_args=list(args), sandbox=None)

    def get(self, uri: str) -> None:
        self.m.navigate(uri)

    def save_screenshot(self, path: str) -> None:
        Path(path).write_bytes(self.m.screenshot(format="binary", full=False))

    def console_errors(self) -> list[str]:
        """The page's console errors and uncaught script errors since the last call."""
        text = self.log_path.read_text(encoding="utf-8", errors="replace") if self.log_path.exists() else ""
        lines = text.splitlines()
        new, self._log_seen = lines[self._log_seen:], len(lines)
        errors = [line for line in new if (line.startswith("console.error:") and not line.startswith(INTERNAL_CONSOLE))
                  or (line.startswith("JavaScript error:") and not line.startswith(INTERNAL_SOURCES))]
        with self.m.using_context("chrome"):
            script_errors = self.m.execute_script("""
                return Services.console.getMessageArray().filter(function (m) {
                    return m instanceof Ci.nsIScriptError && !(m.flags & Ci.nsIScriptError.warningFlag)
                        && /^file:/.test(m.sourceName || ''); }).map(function (m) {
                    return m.sourceName + ':' + m.lineNumber + ': ' + m.errorMessage; });""")
        fresh, self._errors_seen = script_errors[self._errors_seen:], len(script_errors)
        return errors + fresh

    def quit(self) -> None:
        try:
            self.m.delete_session()
        finally:
            self.m.cleanup()
            self._folder.cleanup()
            self._xvfb[0].terminate()
            self._xvfb[0].wait(timeout=10)


def _start_xvfb(binary: str, width: int, height: int) -> tuple[Any, str]:
    """An Xvfb server on a free display (it writes the number it took to ``-displayfd``): (process, ":N")."""
    import os
    import subprocess

    read, write = os.pipe()
    try:
        process = subprocess.Popen([binary, "-displayfd", str(write), "-screen", "0", f"{width}x{height}x24",
                                    "-nolisten", "tcp"], pass_fds=(write,), stdout=subprocess.DEVNULL,
                                   stderr=subprocess.DEVNULL)
        os.close(write)
        write = -1
        number = b""
        while not number.endswith(b"\n"):
            chunk = os.read(read, 16)
            if not chunk:
                process.kill()
                raise RuntimeError(f"Xvfb did not start (exit {process.wait()})")
            number += chunk
    finally:
        os.close(read)
        if write >= 0:
            os.close(write)
    return process, f":{int(number)}"


def start_firefox(width: int = 1500, height: int = 1300) -> Firefox:
    """A headless Firefox (:class:`Firefox`); raises when Firefox or marionette_driver is missing."""
    return Firefox(width, height)
