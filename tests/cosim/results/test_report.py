"""report.html and ``cosim view``: the main job's report opened in a real headless Chromium (no
console errors, the summary figures shown are summary.json's, the timeline at the maximum TCP
error reads back the recorded value, a mode toggled off, linked zoom down to every sample, a
screenshot), several folders overlaid, and bad input (missing, empty, non-results folder, a
corrupt Parquet file, a run still going)."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from browser_support import console_errors, open_report, summary_cells
from cosim.cli import main
from cosim.results import read_series
from cosim.results.panels import PANEL, PANELS
from scenario_files import run_scenario, write_variant

ROOT = Path(__file__).resolve().parents[3]
MAIN_JOB = (ROOT / "scenarios" / "iso9283.toml").read_text(encoding="utf-8")
MODES = ("standard", "model_based", "model_based_elastic")


@pytest.fixture(scope="module")
def main_run(tmp_path_factory):
    """The main job (scenarios/iso9283.toml, its three modes) cut at 1.2 s: 1 s of the path."""
    tmp = tmp_path_factory.mktemp("report")
    path = write_variant(MAIN_JOB, tmp / "iso.toml", [('stop_time = "12.6 s"', 'stop_time = "1.2 s"')])
    out = tmp / "out"
    code, summary = run_scenario(path, out)
    assert code == 0 and summary["status"] == "ok", summary.get("reason")
    return out, summary


def _dig(summary: dict, key: str):
    for part in key.split("."):
        summary = summary[part]
    return summary


def _set_time(driver, t: float) -> None:
    """Move the timeline as a user does (the slider's value and its input event); wait for the readout."""
    driver.execute_script("var s = document.getElementById('timeline'); s.value = arguments[0];"
                          "s.dispatchEvent(new Event('input')); return window.cosimReport.readoutDone;", repr(t))


def test_every_run_writes_its_report(main_run):
    out, summary = main_run
    assert (out / "report.html").stat().st_size > 1_000_000  # Plotly's bundle is inlined
    assert not (out / "report.html.part").exists()
    text = (out / "report.html").read_text(encoding="utf-8")
    assert "@@cosim-report" not in text and "<script src=" not in text  # filled in; nothing loaded from elsewhere
    # (the browser tests resolve no host name at all: anything the page tried to fetch would fail)


def test_main_job_report_in_chromium(main_run, browser, tmp_path):
    out, summary = main_run
    open_report(browser, out / "report.html")
    assert console_errors(browser) == []
    # every figure shown is summary.json's, shown to 6 significant digits
    cells = summary_cells(browser)
    keys = {k for k, _, _ in cells}
    for mode in MODES:
        assert f"modes.{mode}.tcp_error_max_mm" in keys and f"modes.{mode}.joint_lag_max_rad" in keys
    assert "improvement_factor" in keys
    # the PNG figures the run drew are embedded (and decode as images)
    images = browser.execute_script("return Array.from(document.querySelectorAll('details.figures img'))"
                                    ".map(function (i) { return [i.alt, i.naturalWidth > 0]; });")
    assert images == [[name, True] for name in sorted(summary["figures"])]
    for key, value, text in cells:
        assert value == _dig(summary, key), key
        if isinstance(value, float):
            assert float(text) == pytest.approx(value, rel=5e-6), (key, text)
    # the timeline at the largest TCP error of each mode reads back the recorded sample
    for mode in MODES:
        names, data = read_series(out / f"tcp_{mode}.parquet")
        t, err = data[:, names.index("t")], data[:, names.index("tcp_error_mm")]
        k = int(np.nanargmax(err))
        _set_time(browser, float(t[k]))
        shown = browser.execute_script(
            "var td = document.querySelector('td.readout[data-run=\"' + arguments[0] + '\"][data-panel=\"tcp_error\"]');"
            "return [td.getAttribute('data-value'), td.getAttribute('data-time'), td.textContent];", mode)
        assert float(shown[0]) == err[k] and float(shown[1]) == t[k], (mode, shown, err[k])
        assert float(shown[2]) == pytest.approx(err[k], rel=5e-6)
    browser.execute_script("document.getElementById('player').scrollIntoView();")
    browser.save_screenshot(str(tmp_path / "report_at_max_error.png"))
    # a mode toggled off disappears from every plot and the 3D scene
    browser.find_element("css selector", "#toggles input[data-run='standard']").click()
    hidden = browser.execute_script(
        "var out = [];"
        "document.querySelectorAll('.plot').forEach(function (d) { (d.data || []).forEach(function (tr) {"
        "  out.push([d.id, tr.name || '', tr.visible]); }); });"
        "(document.getElementById('scene').data || []).forEach(function (tr) { out.push(['scene', tr.name || '', tr.visible]); });"
        "return out;")
    standard = [v for _, name, v in hidden if name.startswith("standard ") or name == "standard"]
    others = [v for plot, name, v in hidden if name.startswith("model_based") and plot == "plot-tcp_error"]
    assert standard and all(v is False for v in standard)
    assert others and all(v is not False for v in others)
    browser.find_element("css selector", "#toggles input[data-run='standard']").click()
    # zooming one plot zooms all of them, down to every recorded sample
    names, data = read_series(out / "tcp_model_based.parquet")
    t = data[:, names.index("t")]
    a, b = float(t[300]), float(t[500])
    browser.execute_script("return window.cosimReport.setRange(arguments[0], arguments[1]);", a, b)
    ranges = browser.execute_script(
        "return Array.from(document.querySelectorAll('.plot')).filter(function (d) { return d.layout; })"
        ".map(function (d) { return d.layout.xaxis.range; });")
    assert len(ranges) >= 5 and all(r[0] == pytest.approx(a) and r[1] == pytest.approx(b) for r in ranges)
    xs = browser.execute_script(
        "var d = document.getElementById('plot-tcp_error');"
        "var tr = d.data.find(function (tr) { return tr.name === 'model_based'; }); return Array.from(tr.x);")
    inside = t[(t >= a) & (t <= b)]
    assert set(inside.tolist()) <= set(xs) and len(xs) <= inside.size + 2
    browser.save_screenshot(str(tmp_path / "report_zoomed.png"))
    assert console_errors(browser) == []


def check_arm_solids(browser, out: Path, mode: str, shot: Path) -> None:
    """The 3D scene's arm of ``mode`` is one mesh3d of the URDF's links as cylinders; at a time t on
    the timeline each link's cylinder runs from its frame's origin to the next joint's origin as
    the robot's forward kinematics (robot.kinematics, pinocchio's model) puts them at the recorded
    q at t (within 1e-6 m), with the radius the report states; a screenshot."""
    from robot.kinematics import FlangeKinematics

    names, data = read_series(out / f"timeseries_{mode}.parquet")
    t = data[:, names.index("time") if "time" in names else names.index("t")]
    q = np.column_stack([data[:, names.index(f"plant.q[{j}]")] for j in range(1, 7)])
    k = int(np.argmax(np.abs(q).sum(axis=1)))  # a pose far from the zero one
    browser.execute_script("return window.cosimReport.setTime(arguments[0]);", float(t[k]))
    mesh = browser.execute_script(
        "var R = window.cosimReport, name = arguments[0] + ' arm'; return R.sceneDone.then(function () {"
        "  var tr = document.getElementById('scene').data.find(function (d) { return d.name === name; });"
        "  return [tr.type, Array.from(tr.x), Array.from(tr.y), Array.from(tr.z), tr.i.length, R.data.urdf.solids, R.time]; });", mode)
    kind, x, y, z, faces, solids, shown_t = mesh
    assert kind == "mesh3d" and shown_t == t[k]
    links = solids["links"]
    per = solids["per_link"]
    assert [s["link"] for s in links] == ["base_link", *(f"link_{j}" for j in range(1, 7))]
    assert len(x) == len(links) * per == len(links) * (2 * solids["sides"] + 2) and faces == len(links) * 4 * solids["sides"]
    vertices = np.column_stack([x, y, z]).reshape(len(links), per, 3)
    frames = FlangeKinematics().chain_frames(q[k])
    points = np.vstack([np.zeros(3), frames.joint_origins[0], frames.flange_position[0]])  # base, joints 1-6, tool0
    np.testing.assert_allclose(vertices[:, 0], points[:-1], rtol=0, atol=1e-6)
    np.testing.assert_allclose(vertices[:, 1], points[1:], rtol=0, atol=1e-6)
    for solid, v in zip(links, vertices):  # each ring at the link's radius around its axis
        axis = (v[1] - v[0]) / np.linalg.norm(v[1] - v[0])
        for centre, ring in ((v[0], v[2:2 + solids["sides"]]), (v[1], v[2 + solids["sides"]:])):
            off = ring - centre
            assert np.abs(off @ axis).max() < 1e-9
            np.testing.assert_allclose(np.linalg.norm(off, axis=1), solid["radius_m"], rtol=0, atol=1e-9)
    browser.execute_script("document.getElementById('scene').scrollIntoView();")
    browser.save_screenshot(str(shot))
    assert shot.read_bytes()[:4] == b"\x89PNG"


def test_arm_solids_are_the_forward_kinematics_of_the_recorded_joints(main_run, browser, tmp_path):
    out, _ = main_run
    open_report(browser, out / "report.html")
    for mode in MODES:
        check_arm_solids(browser, out, mode, tmp_path / f"arm_solids_{mode}.png")
    assert console_errors(browser) == []


def test_link_radius_from_the_urdf_geometry(tmp_path):
    """A link's cylinder radius is its URDF collision (else visual) cylinder's or box's, else the
    report's table's (rx130l.urdf has no geometry: every link from LINK_RADIUS_M)."""
    from cosim.results import report

    text = (report.ROBOT_DIR / report.URDF_FILE).read_text(encoding="utf-8")
    text = text.replace('<link name="link_2">', '<link name="link_2"><collision><geometry><cylinder radius="0.111" '
                        'length="0.6"/></geometry></collision>', 1)
    text = text.replace('<link name="link_3">', '<link name="link_3"><visual><geometry><box size="0.2 0.3 0.5"/>'
                        '</geometry></visual>', 1)
    (tmp_path / "arm.urdf").write_text(text, encoding="utf-8")
    solids = {s["link"]: s for s in report._urdf_chain(tmp_path / "arm.urdf")["solids"]["links"]}
    assert (solids["link_2"]["radius_m"], solids["link_2"]["radius_from"]) == (0.111, "URDF collision cylinder")
    assert (solids["link_3"]["radius_m"], solids["link_3"]["radius_from"]) == (0.15, "URDF visual box")
    assert solids["link_4"]["radius_m"] == report.LINK_RADIUS_M["link_4"]
    nominal = report._urdf_chain()["solids"]["links"]
    assert [s["radius_m"] for s in nominal] == [report.LINK_RADIUS_M[s["link"]] for s in nominal]


@pytest.fixture(scope="module")
def firefox():
    """One Firefox (Marionette, on a private Xvfb display) for this module; FAILS when Firefox, Xvfb or
    marionette_driver is missing (tests/browser_support.py)."""
    from browser_support import start_firefox

    driver = start_firefox()
    try:
        yield driver
    finally:
        driver.quit()


def test_main_job_report_in_firefox(main_run, firefox, tmp_path):
    """The same report from the file system in Firefox: no console errors, the summary figures are
    summary.json's, the timeline at the largest TCP error reads back the recorded sample, the 3D
    view is drawn (WebGL), a mode toggles off everywhere, a screenshot."""
    out, summary = main_run
    firefox.console_errors()  # what the browser logged before the report was opened
    open_report(firefox, out / "report.html")
    assert firefox.console_errors() == []
    cells = summary_cells(firefox)
    assert {f"modes.{m}.tcp_error_max_mm" for m in MODES} <= {k for k, _, _ in cells}
    for key, value, text in cells:
        assert value == _dig(summary, key), key
        if isinstance(value, float):
            assert float(text) == pytest.approx(value, rel=5e-6), (key, text)
    for mode in MODES:
        names, data = read_series(out / f"tcp_{mode}.parquet")
        t, err = data[:, names.index("t")], data[:, names.index("tcp_error_mm")]
        k = int(np.nanargmax(err))
        _set_time(firefox, float(t[k]))
        shown = firefox.execute_script(
            "var td = document.querySelector('td.readout[data-run=\"' + arguments[0] + '\"][data-panel=\"tcp_error\"]');"
            "return [td.getAttribute('data-value'), td.getAttribute('data-time')];", mode)
        assert float(shown[0]) == err[k] and float(shown[1]) == t[k], (mode, shown, err[k])
    scene = firefox.execute_script(
        "var s = document.getElementById('scene'); var c = s.querySelector('canvas');"
        "var gl = c && (c.getContext('webgl') || c.getContext('experimental-webgl'));"
        "return [s.data.length, !!gl, c ? c.width : 0];")
    assert scene[0] > 0 and scene[1] and scene[2] > 100, scene  # the arm and paths drawn with WebGL
    firefox.execute_script("document.getElementById('player').scrollIntoView();")
    firefox.save_screenshot(str(tmp_path / "report_in_firefox.png"))
    assert (tmp_path / "report_in_firefox.png").read_bytes()[:4] == b"\x89PNG"
    firefox.execute_script("document.querySelector(\"#toggles input[data-run='standard']\").click();")
    visible = firefox.execute_script(
        "return document.getElementById('plot-tcp_error').data.map(function (tr) { return [tr.name, tr.visible]; });")
    assert [v for n, v in visible if n == "standard"] == [False]
    assert all(v is not False for n, v in visible if n != "standard")
    assert firefox.console_errors() == []


def test_panels_are_the_figures_description():
    """The PNG figures' labels and the report's panels come from cosim.results.panels."""
    from cosim.jobs import iso9283_figures as figures

    _, ax = figures._tcp_error_axes()
    assert ax.get_ylabel() == PANEL["tcp_error"].ylabel and ax.get_title() == PANEL["tcp_error"].png_title
    assert ax.get_yscale() == ("log" if PANEL["tcp_error"].log else "linear")
    fig, axes = figures._lag_axes()
    assert axes[0].get_ylabel() == f"axis 1 {PANEL['lag'].ylabel}"
    assert figures.envelope is __import__("cosim.results.panels", fromlist=["envelope"]).envelope
    from cosim.results import report

    assert report.PANELS is PANELS


def test_several_folders_overlaid(main_run, browser, tmp_path):
    out, _ = main_run
    a, b = tmp_path / "run_a", tmp_path / "run_b"
    for folder in (a, b):
        shutil.copytree(out, folder)
    target = tmp_path / "both.html"
    assert main(["view", str(a), str(b), "-o", str(target)]) == 0
    open_report(browser, target)
    assert console_errors(browser) == []
    labels = browser.execute_script(
        "return Array.from(document.querySelectorAll('#toggles label')).map(function (l) { return l.getAttribute('data-run'); });")
    assert labels == [f"{f}/{m}" for f in ("run_a", "run_b") for m in MODES]
    traces = browser.execute_script("return document.getElementById('plot-tcp_error').data.length;")
    assert traces == 6


@pytest.mark.parametrize("case", ["missing", "empty", "not_results"])
def test_view_bad_folder_is_one_line_exit_2(tmp_path, capsys, case):
    folder = tmp_path / "x"
    if case != "missing":
        folder.mkdir()
    if case == "not_results":
        (folder / "notes.txt").write_text("hello", encoding="utf-8")
    assert main(["view", str(folder)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and str(folder) in err[0]
    assert {"missing": "no such folder", "empty": "empty folder", "not_results": "not a results folder"}[case] in err[0]
    assert not (folder / "report.html").exists()


def test_partial_reports_say_what_is_missing(main_run, browser, tmp_path):
    """A corrupt Parquet file is left out and named; a run still going is shown and says so."""
    out, summary = main_run
    broken = tmp_path / "broken"
    shutil.copytree(out, broken)
    tcp = broken / "tcp_standard.parquet"
    tcp.write_bytes(tcp.read_bytes()[: tcp.stat().st_size // 2])
    running = {**summary, "status": "running"}
    (broken / "summary.json").write_text(json.dumps(running), encoding="utf-8")
    (broken / "report.html").unlink()
    assert main(["view", str(broken)]) == 0
    open_report(browser, broken / "report.html")
    assert console_errors(browser) == []
    notes = browser.execute_script(
        "return Array.from(document.querySelectorAll('#notes div')).map(function (d) { return d.textContent; });")
    assert any("tcp_standard.parquet not readable" in n for n in notes), notes
    assert any("still going" in n for n in notes), notes
    names = browser.execute_script("return document.getElementById('plot-tcp_error').data.map(function (t) { return t.name; });")
    assert names == ["model_based", "model_based_elastic"]  # the standard mode's TCP error is missing, the rest shown
    lag = browser.execute_script("return document.getElementById('plot-following_error').data.map(function (t) { return t.name; });")
    assert any(n.startswith("standard") for n in lag)  # its drive signals are there


def test_paced_split_run_plots_compute_time_and_lateness_against_the_tolerance(browser, tmp_path):
    """A paced split run (--realtime --split): its report plots the controller's compute time and every
    cycle's lateness (lateness_<mode>.parquet) with the overrun tolerance as a line, and the timeline
    at the latest cycle reads back the file's value."""
    import subprocess
    import sys

    from realtime_support import write_scenario

    scenario = write_scenario(tmp_path, "200 ms", extra='[realtime]\nscheduling = "normal"\ncpu = "none"\n')
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "cosim", "run", str(scenario), "--realtime", "--split", "--quiet",
                           "--out", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    # a loaded machine may make the drives trip on late cycles (verdict fault, exit 5): the report is the same
    assert done.returncode in (0, 4, 5), done.stderr
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    names, data = read_series(out / "lateness_model_based.parquet")
    t, late = data[:, names.index("t")], data[:, names.index("lateness_us")]
    assert t.size == summary["realtime"]["cycles"] > 100
    open_report(browser, out / "report.html")
    assert console_errors(browser) == []
    lines = browser.execute_script(
        "var d = document.getElementById('plot-lateness');"
        "return [d.data.map(function (tr) { return tr.name; }), d.layout.shapes.map(function (s) { return s.y0; }),"
        " document.getElementById('plot-compute').data.length];")
    assert lines[0] == ["model_based"] and lines[2] == 1
    cells = summary_cells(browser)  # the timing report: summary.json's realtime section, every figure as written
    timing = [(k, v) for k, v, _ in cells if k.startswith("realtime.")]
    assert {"realtime.cycles", "realtime.tolerance_us"} <= {k for k, _ in timing}, [k for k, _, _ in cells]
    for key, value in timing:
        assert value == _dig(summary, key), key
    assert lines[1] == [summary["realtime"]["tolerance_us"]]  # the deadline the lateness is judged against
    k = int(np.argmax(late))
    _set_time(browser, float(t[k]))
    shown = browser.execute_script(
        "var td = document.querySelector('td.readout[data-run=\"model_based\"][data-panel=\"lateness\"]');"
        "return [td.getAttribute('data-value'), td.getAttribute('data-time')];")
    assert float(shown[1]) == t[k] and float(shown[0]) == pytest.approx(late[k], rel=1e-6)  # float32 embedded
    browser.execute_script("document.getElementById('plot-lateness').scrollIntoView();")
    browser.save_screenshot(str(tmp_path / "report_lateness.png"))


def _unpack(packed: dict) -> np.ndarray:
    """An array the report embeds (base64 little-endian, zlib-deflated when ``z``), as the page decodes it."""
    import base64
    import zlib

    raw = base64.b64decode(packed["b64"])
    raw = zlib.decompress(raw) if packed["z"] else raw
    width = np.dtype("<" + packed["dtype"]).itemsize
    if packed.get("shuffle"):  # byte k of every value, then byte k + 1
        raw = np.frombuffer(raw, dtype=np.uint8).reshape(width, -1).T.tobytes()
    values = np.frombuffer(raw, dtype="<" + packed["dtype"])
    if "uniform" in packed:  # a time column: t0 + k dt plus the residual
        t0, dt = packed["uniform"]
        values = t0 + np.arange(values.size, dtype=np.float64) * dt + values
    return values


def test_decimation_keeps_every_peak_and_the_full_values_are_embedded(tmp_path, monkeypatch):
    """The overview each plot opens with (2000 columns of min and max) holds the run's largest TCP
    error and every curve's extremes, sample for sample; every sample is embedded beside it (the
    readout and a zoom read them) while the budget lasts, and a curve beyond the budget is named."""
    from cosim.results import report, write_columns

    rng = np.random.default_rng(7)
    n = 200_001  # 200 s at 1 ms: 100 samples per overview column
    t = np.arange(n) * 1e-3
    err = 0.05 + 0.01 * rng.random(n)
    peak = int(rng.integers(n // 3, n - 1))
    err[peak] = 3.25  # one sample: the run's maximum
    tcp = {"t": t, "tcp_error_mm": err, **{f"lag{j}": 1e-4 * rng.standard_normal(n) for j in range(1, 7)}}
    write_columns(tmp_path / "tcp_mine.parquet", tcp, {"t": "s", "tcp_error_mm": "mm"})
    ts = {"time": t, **{f"drive{j}.current_actual": rng.standard_normal(n) for j in range(1, 7)}}
    write_columns(tmp_path / "timeseries_mine.parquet", ts, {"time": "s"})
    (tmp_path / "summary.json").write_text(json.dumps({"status": "ok", "modes": {"mine": {"status": "ok"}}}))
    monkeypatch.setattr(report, "FULL_VALUES_BUDGET", 8 * n)  # the six lags and two currents whole, four not
    data = report.collect([tmp_path])
    run = data["runs"][0]
    curve = run["series"]["tcp_error"][0]
    ox, oy = _unpack(curve["ox"]), _unpack(curve["oy"])
    assert 2 <= oy.size <= 2 * report.OVERVIEW_COLUMNS + 2 and oy.max() == err.max() == 3.25
    assert ox[np.argmax(oy)] == t[peak]  # at its time, too
    assert np.array_equal(_unpack(curve["full"]), err)  # every sample a click (or a zoom) away
    assert np.array_equal(_unpack(run["times"]["tcp"]["full"]), t)
    whole, decimated = [], []
    for key, source in (("lag", tcp), ("current", ts)):
        for c in run["series"][key]:
            y = source[c["column"]] * (1e3 if key == "lag" else 1.0)
            oy = _unpack(c["oy"])
            assert oy.max() == np.float32(y.max()) and oy.min() == np.float32(y.min()), c["column"]
            if c["full"] is not None:
                assert np.array_equal(_unpack(c["full"]), y.astype(np.float32))
                whole.append(c["column"])
            else:
                decimated.append(c["label"])
    assert len(whole) == 8 and len(decimated) == 4
    note = next(n for n in data["notes"] if "embedded decimated only" in n)
    assert all(f"mine: {label}" in note for label in decimated)


@pytest.fixture(scope="module")
def limit_run(tmp_path_factory):
    """A controller commanding 1e6 N m (tests/cosim/cell/runaway_torque.py) for 1 s of the main job: the
    drives clamp the torque, joint 3 reaches its software position limit (fault 0x8612, an EMCY) and
    its end stop; the run ends with verdict ``limit``."""
    tmp = tmp_path_factory.mktemp("limit")
    shutil.copy(ROOT / "tests" / "cosim" / "cell" / "runaway_torque.py", tmp / "runaway_torque.py")
    path = write_variant(MAIN_JOB, tmp / "runaway.toml", [
        ('stop_time = "12.6 s"', 'stop_time = "1.0 s"'),
        ('modes = ["standard", "model_based", "model_based_elastic"]',
         'modes = []\nclass = "runaway_torque.py:RunawayTorque"'), ("figures = true", "figures = false")])
    out = tmp / "out"
    code, summary = run_scenario(path, out)
    assert code == 4 and summary["status"] == "limit", summary.get("reason")
    return out, summary


def test_limit_run_report_shows_what_stopped_it_where_and_when(limit_run, browser, tmp_path):
    """The report of a run that ended ``limit``, in Chromium: the run is badged ``limit``, the note says
    which limit came first and where the motion stopped, every violation is listed at its time with
    its value and limit, the drive's EMCY (from the CAN log) and the stop are among the events, all
    are marked on the events timeline and in the 3D view, and the timeline at the stop reads back
    the TCP error recorded there."""
    from browser_support import report_state
    from fieldbus.canlog import read_frames

    out, summary = limit_run
    entry = summary["modes"]["RunawayTorque"]
    stop = entry["stopped_at_s"]
    open_report(browser, out / "report.html")
    assert console_errors(browser) == []
    state = report_state(browser)
    assert state["runs"] == ["RunawayTorque"]
    badge = browser.execute_script("return document.querySelector('#toggles label').textContent;")
    assert badge.strip().endswith("limit")
    first = entry["first_violation"]
    assert any("ended 'limit'" in n and f"first violation: {first['kind']} axis {first['joint']} at t = "
               f"{first['time_s']} s" in n for n in state["notes"]), state["notes"]
    assert f"RunawayTorque: limit, the motion stopped at t = {stop:.6g} s: {entry['stop_reason']}" in state["notes"]
    rows = [tuple(r) for r in state["events"]]
    for v in entry["violations"]:  # time [s], run, kind, axis, value, limit, unit, reaction, detail
        assert any(r[0] == f"{v['time_s']:.4f}" and r[2] == v["kind"] and r[3] == str(v["joint"])
                   and r[6] == v["unit"] and r[8] == v["detail"] for r in rows), v
    kinds = {r[2] for r in rows}
    assert {"torque_limit", "position_limit", "end_stop", "emcy", "stopped"} <= kinds
    log = read_frames(out / "can_RunawayTorque.parquet")
    emcy = np.flatnonzero((log.frames["id"] > 0x80) & (log.frames["id"] <= 0xFF))
    assert emcy.size >= 1
    t_emcy = float(log.timestamps[emcy[0]])
    assert any(r[2] == "emcy" and r[0] == f"{t_emcy:.4f}" and r[3] == "3" and "0x8612" in r[8] for r in rows), rows
    assert any(r[2] == "stopped" and r[0] == f"{stop:.4f}" and entry["stop_reason"] in r[8] for r in rows)
    assert len(rows) == len(entry["violations"]) + emcy.size + 1
    marks = browser.execute_script(
        "var e = document.getElementById('plot-events').data[0];"
        "var s = document.getElementById('scene').data.find(function (t) { return t.name === 'RunawayTorque events'; });"
        "return [Array.from(e.x), s ? s.x.length : 0];")
    assert sorted(marks[0]) == pytest.approx(sorted([v["time_s"] for v in entry["violations"]] + [t_emcy, stop]))
    assert marks[1] == len(rows)  # every event a cross on the 3D path
    names, data = read_series(out / "tcp_RunawayTorque.parquet")
    t, err = data[:, names.index("t")], data[:, names.index("tcp_error_mm")]
    _set_time(browser, stop)
    shown = browser.execute_script(
        "var td = document.querySelector('td.readout[data-run=\"RunawayTorque\"][data-panel=\"tcp_error\"]');"
        "return [td.getAttribute('data-value'), td.getAttribute('data-time')];")
    k = int(np.argmin(np.abs(t - float(shown[1]))))
    assert abs(t[k] - stop) <= 1e-3 and float(shown[0]) == err[k]
    browser.execute_script("document.getElementById('player').scrollIntoView();")
    browser.save_screenshot(str(tmp_path / "report_limit_run.png"))
    assert console_errors(browser) == []


CRASHING = """

class Crashing(RunawayTorque):
    \"\"\"PD + gravity on every joint (no runaway torque) until t = 0.15 s, then a bug: an exception.\"\"\"

    def __init__(self) -> None:
        super().__init__(joint=3, torque=0.0)

    def step(self, inputs):
        if inputs.time_s >= 0.15:
            raise IndexError("axis 7 of 6: a bug in the user's controller")
        out = super().step(inputs)
        return out
"""


def test_failed_run_and_report_off(tmp_path, browser, monkeypatch):
    """A run whose controller raises ends ``failed`` and still gets its report (the note says where
    and why it stopped; the stop is an event at its time); ``[results] report = false`` and
    ``COSIM_REPORT=0`` write none (``cosim view`` writes it later)."""
    text = (ROOT / "tests" / "cosim" / "cell" / "runaway_torque.py").read_text(encoding="utf-8")
    text = text.replace("tau[self.joint - 1] = self.torque", "pass")  # no runaway: a plain PD + gravity
    (tmp_path / "crashing.py").write_text(text + CRASHING, encoding="utf-8")
    path = write_variant(MAIN_JOB, tmp_path / "crash.toml", [
        ('stop_time = "12.6 s"', 'stop_time = "0.4 s"'),
        ('modes = ["standard", "model_based", "model_based_elastic"]', 'modes = []\nclass = "crashing.py:Crashing"'),
        ("figures = true", "figures = false")])
    code, summary = run_scenario(path, tmp_path / "out")
    assert code != 0 and summary["status"] == "failed", summary
    where = summary["stopped_at_s"]
    assert 0.15 <= where < 0.16 and "axis 7 of 6" in summary["reason"]
    open_report(browser, tmp_path / "out" / "report.html")
    assert console_errors(browser) == []
    from browser_support import report_state

    state = report_state(browser)
    assert any(n.startswith(f"the run ended 'failed' at t = {where:.6g} s") and "axis 7 of 6" in n
               for n in state["notes"]), state["notes"]
    assert any(r[2] == "stopped" and r[0] == f"{where:.4f}" and "axis 7 of 6" in r[8] for r in state["events"])
    names, data = read_series(tmp_path / "out" / "tcp_Crashing.parquet")
    assert data[:, names.index("t")].max() <= where + 1e-3  # what the run recorded before it stopped is drawn
    assert browser.execute_script("return document.getElementById('plot-tcp_error').data.length;") == 1
    # no report when the scenario or the environment says so
    off = write_variant(path.read_text(encoding="utf-8"), tmp_path / "off.toml",
                        [("[results]", "[results]\nreport = false")])
    run_scenario(off, tmp_path / "off")
    assert (tmp_path / "off" / "summary.json").exists() and not (tmp_path / "off" / "report.html").exists()
    monkeypatch.setenv("COSIM_REPORT", "0")
    run_scenario(path, tmp_path / "env")
    assert (tmp_path / "env" / "summary.json").exists() and not (tmp_path / "env" / "report.html").exists()
    assert not list((tmp_path / "env").glob("report.html*"))
    assert main(["view", str(tmp_path / "off")]) == 0 and (tmp_path / "off" / "report.html").exists()
