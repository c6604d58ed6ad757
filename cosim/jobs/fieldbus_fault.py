"""Job ``fieldbus_fault``: a fieldbus fault during the ISO 9283 motion, and the cell's reaction.

The cell of the main job (:mod:`cosim.execution.mode_runs`: true robot, controller, POWERLINK
fieldbus, six servo-drive FMUs, plant FMU, tracker) runs ONE mode of ``[controller] modes``
on the ISO 9283 path while ``[fieldbus.faults]`` injects faults (e.g. a burst of lost
PReq frames to one node). What must happen, and what the job checks and reports:

1. the POWERLINK threshold counters (+8 per error, -1 per good cycle, reaction at 15)
   of the node trip on both sides at the expected cycle (first faulty cycle +
   ceil(threshold / increment) - 1 for a loss burst);
2. the controlled node presents fault code 0x8100 to its drive (abort option
   ``fault``), which runs its CiA 402 fault reaction (ramp at
   ``fault_reaction_deceleration``) and ends in Fault, power stage off, holding brake
   closed (docs/explanation/fmus.md); the managing node reports ``node_fault``, the controller stops
   commanding motion (quick stop to every drive: ramp, then Quick stop active holding
   position, option code 6);
3. the robot comes to rest: every joint speed below ``[rest] speed_tolerance`` over the
   last ``[rest] window`` of the run (which ends 0.5 s after the controller stopped,
   :class:`cosim.cell.link.FieldbusLink`);
4. nothing is lost: the time series (1 ms, with each drive's statusword, error code and
   brake torque) and the controller log up to the end, the CAN log (every frame that was
   on the wire; lost frames are absent) and, in summary.json, the fieldbus summary
   (:meth:`fieldbus.PowerlinkNetwork.summary`: every error, threshold, reaction and EMCY
   with node, cycle and counter values; counters; node/comm faults).

``status`` is ``ok`` when 1-3 hold (the fault was handled), else ``failed`` with the
reason. See docs/explanation/fieldbus_fault.md.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from cosim.cell import wiring
from cosim.execution.mode_runs import prepare, run_mode
from cosim.cell.parts import CELL_FIELDS, check_cell_scenario
from cosim.cell.run import CellRun
from cosim.scenario.cosim_tables import COSIM_FIELDS
from cosim.scenario.loader import SCENARIO_FIELD
from cosim.master import SimulationError
from cosim.scenario.context import RunContext
from cosim.scenario.loader import Scenario
from cosim.scenario.job_type import JobType
from cosim.scenario.schema import Field, Number, Table, Where
from fieldbus import decode_statusword

JOB_NAME = "fieldbus_fault"

REST_TABLE = Table({
    "speed_tolerance": Field(Number(unit="rad/s", gt=0), default=1e-3,
                             doc="every joint speed below this at the end: a number in rad/s > 0"),
    "window": Field(Number(unit="s", gt=0), default=0.05,
                    doc="over the last ... of the run: a number in s > 0"),
}, doc="the [rest] table")

SCHEMA = Table({"scenario": SCENARIO_FIELD, **COSIM_FIELDS, **CELL_FIELDS,
                "rest": Field(REST_TABLE, default={}, doc="when the robot counts as at rest at the end")},
               doc="a fieldbus_fault scenario document")

#: Drive signals recorded besides the cell's own (state, fault code, brake), i = 1..6.
DRIVE_SIGNALS: tuple[str, ...] = tuple(f"{d}.{name}" for name in ("statusword", "error_code", "brake_torque")
                                       for d in wiring.DRIVES)

#: Which threshold counters a loss burst on these frames hits first (side, counter kind,
#: key of fieldbus.ThresholdConfig). A lost PReq also silences the node's PRes.
LOSS_COUNTERS: dict[str, tuple[tuple[str, str, str], ...]] = {
    "preq": (("cn", "loss_of_preq", "cn_loss_of_preq"), ("mn", "loss_of_pres", "mn_loss_of_pres")),
    "both": (("cn", "loss_of_preq", "cn_loss_of_preq"), ("mn", "loss_of_pres", "mn_loss_of_pres")),
    "pres": (("mn", "loss_of_pres", "mn_loss_of_pres"),),
}


def _fill_rest(doc: dict[str, Any]) -> None:
    if not doc.get("rest"):
        doc["rest"] = REST_TABLE.check({}, Where(None) / "rest")


def check(doc: dict[str, Any], where: Where) -> None:
    """The cell's checks (as the iso9283 job), one mode, and at least one fault to inject."""
    check_cell_scenario(doc, where)
    _fill_rest(doc)
    modes = doc["controller"]["modes"]
    if len(modes) != 1:
        raise (where / "controller" / "modes").error("exactly one mode (the run ends with the fault reaction)",
                                                      modes)
    faults = doc["fieldbus"].get("faults") or {}
    if not (faults.get("bursts") or faults.get("silent_nodes")
            or any(faults.get(k, 0.0) > 0.0 for k in ("loss_probability", "late_probability",
                                                        "corrupt_probability"))):
        raise (where / "fieldbus" / "faults").error(
            "a fault to inject: bursts = [...], silent_nodes = [...] or a probability > 0", faults,
            problem="no fault injected")


def expected_trips(fieldbus) -> list[dict[str, Any]]:
    """Per loss burst and counter it hits: the cycle its threshold counter must trip.

    A loss burst from cycle c0 adds ``increment`` per cycle; the counter reaches
    ``threshold`` at the ``ceil(threshold / increment)``-th error, i.e. in cycle
    ``c0 + ceil(threshold / increment) - 1`` (if the burst is that long).
    """
    th = fieldbus.thresholds
    out = []
    for burst in fieldbus.faults.bursts:
        if burst.kind != "loss":
            continue
        for side, kind, key in LOSS_COUNTERS.get(burst.frames, ()):
            threshold = getattr(th, key)
            errors = math.ceil(threshold / th.increment) if threshold > 0 else None
            trips = errors is not None and burst.cycles >= errors
            out.append({"side": side, "node": burst.node, "kind": kind, "first_lost_cycle": burst.start_cycle,
                        "errors_to_trip": errors, "threshold": threshold, "increment": th.increment,
                        "cycle": burst.start_cycle + errors - 1 if trips else None})
    return out


def _drive_states(cell: CellRun) -> list[dict[str, Any]]:
    """State, statusword, error code and brake torque of every drive in the last recorded row."""
    cols, last = cell.recording.columns, _last_row(cell)
    states = []
    for d in wiring.DRIVES:
        sw = int(last[cols.index(f"{d}.statusword")])
        states.append({"drive": d, "state": decode_statusword(sw).value, "statusword": f"0x{sw:04X}",
                       "error_code": f"0x{int(last[cols.index(f'{d}.error_code')]):04X}",
                       "brake_torque_Nm": float(last[cols.index(f"{d}.brake_torque")])})
    return states


def _last_row(cell: CellRun) -> np.ndarray:
    """The recording's last row (read from the end of its file when it streamed)."""
    rec = cell.recording
    if hasattr(rec, "chunks"):
        from cosim.results.timeseries import last_row

        return last_row(rec.path)
    return rec.data[-1]


def _rest(cell: CellRun, window: float, tolerance: float) -> dict[str, Any]:
    rec = cell.recording
    cols = rec.columns
    take = [cols[0]] + [f"plant.qd[{i}]" for i in range(1, 7)]
    if hasattr(rec, "chunks"):  # only the recording's last seconds are read
        from cosim.results.timeseries import tail

        _, data = tail(rec.path, window + 1.0, take)
    else:
        data = rec.data[:, [cols.index(c) for c in take]]
    t = data[:, 0]
    last = t >= t[-1] - window + 1e-12
    qd = np.abs(data[last][:, 1:]).max(axis=0)
    return {"window_s": window, "speed_tolerance_rad_s": tolerance, "max_joint_speed_rad_s": qd.tolist(),
            "at_rest": bool(np.all(qd < tolerance)), "end_time_s": float(t[-1])}


def run(scenario: Scenario, ctx: RunContext) -> dict[str, Any]:
    """Run the scenario's mode with the injected faults; check and report the reaction."""
    doc = scenario.data
    _fill_rest(doc)
    setup = prepare(doc, str(scenario.path))
    mode = doc["controller"]["modes"][0]
    ctx.summary.update(**setup.summary_fields(), mode=mode)
    entry, result, cell, controller = run_mode(ctx, setup, mode, extra_signals=DRIVE_SIGNALS)
    failure = cell.failure
    if failure is not None and not (failure.component == "controller" and controller.stopped):
        ctx.summary.update(modes={mode: entry}, fieldbus=cell.fieldbus)
        raise failure  # an FMU failed: not the reaction under test
    net = cell.fieldbus
    trips = [{k: f[k] for k in ("side", "node", "kind", "cycle", "time_s", "counter", "cumulative", "threshold")}
             for f in net["faults"] if f["event"] == "threshold_reached"]
    expected = expected_trips(setup.fieldbus)
    for e in expected:
        e["tripped_as_expected"] = e["cycle"] is not None and any(
            t["side"] == e["side"] and t["node"] == e["node"] and t["kind"] == e["kind"] and t["cycle"] == e["cycle"]
            for t in trips)
    period = doc["controller"]["period"]
    stop = {"phase": controller.phase.name.lower(), "stop_reason": controller.stop_reason,
            "stopped_at_s": controller.stopped_at_s,
            "stopped_at_cycle": round(controller.stopped_at_s / period) if controller.stopped else None}
    rest = _rest(cell, doc["rest"]["window"], doc["rest"]["speed_tolerance"])
    if controller.stopped:
        entry["status"] = "stopped"  # the expected end of this job, not a failure
    fields: dict[str, Any] = {
        "modes": {mode: entry}, "fieldbus": net, "trips": trips, "expected_trips": expected,
        "controller": stop, "rest": rest, "drives_at_end": _drive_states(cell),
        "files": {"timeseries": ctx.series_name(f"timeseries_{mode}"), "controller": ctx.series_name(f"controller_{mode}"),
                  "tcp": ctx.series_name(f"tcp_{mode}"), "can_log": entry["files"]["can_log"]},
    }
    if doc["results"]["figures"]:
        from cosim.jobs.fieldbus_fault_figure import write_figure

        fields["figures"] = [write_figure(ctx.out_dir / "fieldbus_fault.png", cell, trips, controller).name]
    ctx.summary.update(**fields)
    problems = []
    if not trips:
        problems.append("no threshold counter reached its threshold")
    problems += [f"{e['side']} {e['kind']} counter of node {e['node']} did not trip in cycle {e['cycle']}"
                 for e in expected if e["cycle"] is not None and not e["tripped_as_expected"]]
    if trips and not controller.stopped:
        problems.append("the controller did not stop commanding motion")
    if not rest["at_rest"]:
        problems.append(f"the robot is not at rest: joint speeds {np.round(rest['max_joint_speed_rad_s'], 6)} "
                        f"rad/s over the last {rest['window_s']} s")
    if problems:
        raise SimulationError(JOB_NAME, cell.reached_s, "; ".join(problems))
    # the reaction ran as expected; the run's verdict stays what it is: "fault" (cosim/cell/verdict.py)
    fields["reaction_as_expected"] = True
    return fields


JOB = JobType(JOB_NAME, run, SCHEMA, check,
              "a fieldbus fault during the ISO 9283 motion: threshold trip, CiA 402 fault reaction, robot at rest")
