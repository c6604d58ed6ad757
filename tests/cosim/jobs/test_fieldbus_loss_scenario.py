"""scenarios/fieldbus_loss.toml, shortened: a burst of lost PReq frames to node 3
during the ISO 9283 motion trips the POWERLINK threshold counters of node 3 at the
expected cycle; drive 3 runs its CiA 402 fault reaction and ends in Fault with its
holding brake taking the gravity load; the controller stops commanding motion; the robot
comes to rest; summary.json, the time series and the CAN log keep the whole story."""
from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

from fieldbus.canlog import open_log, read_frames
import numpy as np
import pytest

from cosim.results import read_csv
from cosim.scenario import ScenarioError, load_scenario
from scenario_files import run_scenario, write_variant

ROOT = Path(__file__).resolve().parents[3]
SCENARIO = (ROOT / "scenarios" / "fieldbus_loss.toml").read_text(encoding="utf-8")
PERIOD = 400e-6
NODE, FIRST_LOST, LOST_CYCLES = 3, 650, 4      # t = 0.26 s: 0.2 s into the path (accelerating)
TRIP = FIRST_LOST + math.ceil(15 / 8) - 1       # the 2nd error brings the counter to 16 >= 15


def variant(tmp_path: Path, replacements: list[tuple[str, str]]) -> Path:
    return write_variant(SCENARIO, tmp_path / "loss.toml", replacements)


@pytest.fixture(scope="module")
def loss_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("loss")
    path = variant(tmp, [('stop_time = "3 s"', 'stop_time = "1 s"'),
                         ('settle_time = "0.2 s"', 'settle_time = "0.05 s"'),
                         ("start_cycle = 2500", f"start_cycle = {FIRST_LOST}"),
                         ("figures = true", "figures = false")])
    out = tmp / "out"
    code, summary = run_scenario(path, out)
    return code, out, summary


def test_the_scenario_is_valid_and_injects_a_burst():
    scenario = load_scenario(ROOT / "scenarios" / "fieldbus_loss.toml")
    assert scenario.job.name == "fieldbus_fault"
    assert scenario.data["fieldbus"]["faults"]["bursts"][0]["node"] == NODE


def test_threshold_trips_on_the_right_node_at_the_expected_cycle(loss_run):
    code, _, summary = loss_run
    # the demonstrated fault reaction is the run's honest verdict: status "fault", exit code 5
    assert code == 5 and summary["status"] == "fault", summary.get("reason")
    assert summary["reaction_as_expected"] is True
    first = summary["first_violation"]
    assert first["kind"] == "fault_reaction" and first["joint"] == NODE
    assert first["time_s"] == pytest.approx(TRIP * PERIOD)
    assert summary["verdicts"]["model_based"]["verdict"] == "fault"
    trips = summary["trips"]
    assert {(t["side"], t["node"], t["kind"], t["cycle"]) for t in trips} == {
        ("cn", NODE, "loss_of_preq", TRIP), ("mn", NODE, "loss_of_pres", TRIP)}
    for t in trips:
        assert (t["counter"], t["cumulative"], t["threshold"]) == (16, 2, 15)
        assert t["time_s"] == pytest.approx(TRIP * PERIOD)
    assert all(e["tripped_as_expected"] and e["cycle"] == TRIP for e in summary["expected_trips"])


def test_summary_lists_every_fault_with_node_cycle_and_counter_values(loss_run):
    _, _, summary = loss_run
    fb = summary["fieldbus"]
    errors = [f for f in fb["faults"] if f["event"] == "error" and f["side"] == "cn"]
    assert [(f["node"], f["cycle"], f["counter"], f["cumulative"]) for f in errors] == [
        (NODE, FIRST_LOST + i, 8 * (i + 1), i + 1) for i in range(LOST_CYCLES)]
    assert len([f for f in fb["faults"] if f["event"] == "injected"]) == LOST_CYCLES
    reactions = {(f["side"], f["cycle"]) for f in fb["faults"] if f["event"] == "fault_reaction"}
    assert reactions == {("cn", TRIP), ("mn", TRIP)}
    assert any(f["event"] == "emcy_sent" and f["node"] == NODE and "0x8100" in f["detail"] for f in fb["faults"])
    assert fb["node_fault"] == [i + 1 == NODE for i in range(6)] == fb["comm_fault"]
    counters = {(c["side"], c["node"], c["kind"]): c for c in fb["counters"]}
    assert counters[("cn", NODE, "loss_of_preq")]["cumulative"] == LOST_CYCLES
    # after the burst the counter decreases by 1 per good cycle (32 -> 0 in 32 cycles)
    assert fb["event_tally"]["cn.loss_of_preq.decrement"] == 32
    assert counters[("cn", NODE, "loss_of_preq")]["counter"] == 0


def test_controller_stops_and_drives_react(loss_run):
    _, out, summary = loss_run
    ctrl = summary["controller"]
    assert ctrl["phase"] == "stopped" and ctrl["stopped_at_cycle"] == TRIP
    assert ctrl["stop_reason"] == f"fieldbus node fault (threshold counter reached) on node(s) [{NODE}]"
    states = {d["drive"]: d for d in summary["drives_at_end"]}
    assert states[f"drive{NODE}"]["state"] == "Fault" and states[f"drive{NODE}"]["error_code"] == "0x8100"
    assert all(d["state"] == "Quick stop active" for name, d in states.items() if name != f"drive{NODE}")
    header, log = read_csv(out / "controller_model_based.csv")
    stopped = log[:, header.index("phase")] == 4  # Phase.STOPPED from the trip cycle on
    assert log[stopped, 0].min() == pytest.approx(TRIP * PERIOD)
    assert np.all(log[stopped, header.index("tau_ff1")] == 0.0)  # no torque offset any more


def test_robot_comes_to_rest_held_by_drives_and_brake(loss_run):
    from cosim.cell.parts import make_true_robot

    _, out, summary = loss_run
    assert summary["rest"]["at_rest"] is True
    header, data = read_csv(out / "timeseries_model_based.csv")
    t = data[:, 0]
    end = t >= t[-1] - 0.05
    qd = data[np.ix_(end, [header.index(f"plant.qd[{i}]") for i in range(1, 7)])]
    assert np.abs(qd).max() < 1e-3  # rad/s, every joint over the last 50 ms (measured < 2e-4)
    at_trip = np.searchsorted(t, TRIP * PERIOD)
    speeds = np.abs(data[at_trip, [header.index(f"plant.qd[{i}]") for i in range(1, 7)]])
    assert speeds.max() > 0.5  # rad/s: the arm was moving when the fault hit (measured 0.72 on axis 1)
    # drive 3 is in Fault (power off): its closed brake carries axis 3's gravity torque
    q_end = data[-1, [header.index(f"plant.q[{i}]") for i in range(1, 7)]]
    doc = load_scenario(ROOT / "scenarios" / "fieldbus_loss.toml").data
    gravity = make_true_robot(doc["true_robot"]).dynamics().gravity(q_end)
    brake = data[-1, header.index(f"drive{NODE}.brake_torque")]
    assert abs(gravity[NODE - 1]) > 50.0  # N m: without the brake the axis would fall
    assert brake == pytest.approx(gravity[NODE - 1], rel=0.02)
    assert data[-1, header.index(f"drive{NODE}.tau_out")] == pytest.approx(brake)


def test_nothing_is_lost_time_series_and_can_log(loss_run):
    _, out, summary = loss_run
    end = summary["rest"]["end_time_s"]
    assert end == pytest.approx(TRIP * PERIOD + 0.5, abs=2e-3)  # the run ends 0.5 s after the stop
    header, data = read_csv(out / "timeseries_model_based.csv")
    assert data[-1, 0] == pytest.approx(end) and data.shape[0] == round(end / 1e-3) + 1
    assert np.all(np.isfinite(data))
    cycles: dict[int, list[int]] = defaultdict(list)
    n = 0
    with open_log(out / summary["files"]["can_log"]) as reader:
        for msg in reader:
            cycles[int(msg.timestamp / PERIOD + 0.01)].append(msg.arbitration_id)  # SoC jitter 0.1 us
            n += 1
    assert n == summary["fieldbus"]["frames_recorded"] > 0
    assert len(cycles) == summary["fieldbus"]["cycles_run"]
    node_frames = {0x200 + NODE, 0x180 + NODE, 0x280 + NODE}
    for k in range(FIRST_LOST, FIRST_LOST + LOST_CYCLES):
        assert not node_frames & set(cycles[k]), k  # lost PReq, hence no PRes
        assert 0x080 in cycles[k] and 0x201 in cycles[k]
    for k in (FIRST_LOST - 1, FIRST_LOST + LOST_CYCLES):
        assert node_frames <= set(cycles[k])
    emcy = [k for k, ids in cycles.items() if 0x080 + NODE in ids]
    assert emcy == [TRIP]


def test_the_report_marks_the_emcy_of_the_tripped_node(loss_run):
    """report.html lists the EMCY the CAN log holds (read through the project's CAN-log reader,
    whatever the log's format), with the node and the error code, at the frame's time."""
    _code, out, _summary = loss_run
    log = read_frames(out / "can_model_based.parquet")
    emcy = [i for i in range(len(log)) if 0x081 <= int(log.frames["id"][i]) <= 0x0FF]
    assert emcy, "the trip sends an EMCY"
    html = (out / "report.html").read_text(encoding="utf-8")
    assert "EMCY node 3 error code 0x8100" in html
    assert f"{float(log.timestamps[emcy[0]])!r}" in html


def test_a_scenario_without_faults_is_rejected(tmp_path):
    path = variant(tmp_path, [('bursts = [ { node = 3, start_cycle = 2500, cycles = 4, frames = "preq", '
                               'kind = "loss" } ]', "bursts = []")])
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert "fieldbus.faults" in str(info.value) and "no fault injected" in str(info.value)


def test_two_modes_are_rejected(tmp_path):
    path = variant(tmp_path, [('modes = ["model_based"]', 'modes = ["standard", "model_based"]')])
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert "controller.modes" in str(info.value) and "exactly one mode" in str(info.value)


def test_the_report_marks_lost_frames_counters_and_the_trip_in_chromium(loss_run, browser):
    """report.html of the loss run in headless Chromium: every injected lost frame, every step of the
    error counters (with its value against the threshold), the thresholds reached, the fault
    reaction, the EMCY and the stop are events at their times, each a marker on the events plot."""
    from browser_support import console_errors, open_report, report_state

    _code, out, summary = loss_run
    open_report(browser, out / "report.html")
    assert console_errors(browser) == []
    rows = report_state(browser)["events"]  # time [s], run, kind, axis, value, limit, unit, reaction, detail
    names = {"injected": "lost frame", "error": "bus counter", "threshold_reached": "bus threshold"}
    expected = [e for e in summary["fieldbus"]["faults"] if e["event"] in names]
    assert len(expected) > 4 and {e["event"] for e in expected} == set(names)
    for e in expected:
        hit = [r for r in rows if r[2] == names[e["event"]] and r[0] == f"{e['time_s']:.4f}" and r[3] == str(e["node"])
               and f"{e['side']} {e['kind']} in cycle {e['cycle']}" in r[8]]
        assert hit, e
        if e["event"] != "injected":
            assert hit[0][4] == str(e["counter"]) and hit[0][5] == str(e["threshold"]) and hit[0][6] == "counts"
    kinds = [r[2] for r in rows]
    assert kinds.count("lost frame") == sum(e["event"] == "injected" for e in expected)
    assert {"fault_reaction", "emcy", "stopped"} <= set(kinds)
    marks = browser.execute_script("return Array.from(document.getElementById('plot-events').data[0].x);")
    assert len(marks) == len(rows) and sorted(marks) == pytest.approx(sorted(float(r[0]) for r in rows), abs=5e-5)
