"""Job ``iso9283``: the paper's section 2 experiment, end to end (the testbed's main job).

The EN ISO 9283 test path (``planners.iso9283``: cube, diagonal plane, rectangle,
line, circles at 1 m/s and 5 m/s^2, constant orientation) is driven through the
400 µs controller, the POWERLINK-timed CiA 402 fieldbus, six servo-drive FMUs and
the plant FMU, once per mode in ``[controller] modes``
(:data:`cosim.cell.parts.BUILTIN_MODES`), on the SAME seeded true robot (inertial,
friction and rotor deviations, geometric errors, payload). The modes follow the paper
(section 2.3, Figure 1, eq. 7):

* ``standard``: position set-points only, the drives' P-PI cascade (drive speed
  feed-forward gain 0, no torque offset);
* ``standard_speed_ff`` (optional): the cascade plus the drives' own speed
  feed-forward from target differences, no torque offset;
* ``model_based``: eq. 7, ``Q_M = M(q_d) qdd_d + g(q_d, qd_d) + K_p (q_d - q) + K_d (qd_d - qd)``:
  the velocity reference enters through the drives' speed feed-forward (gain 1), the
  model torque as torque offset, plus the drive set-point shaping.
* ``model_based_elastic``: flatness-based feed-forward for elastic gears (``controller/elastic.py``):
  the motor reference as target, the motor torque as torque offset.

A user's controller (``[controller] class = "file.py:Class"`` or ``fmu = "ctrl.fmu"``,
the controller contract :mod:`controller.contract`) runs on the same robot as one more
entry (``[controller] label``, default the class or FMU name): alone, unless
``[controller] modes`` lists built-in modes, which then run first.

The drive speed feed-forward is the servo-drive FMU parameter ``speed_feedforward_gain``,
set by the job per mode (``[controller.<mode>] drive_speed_feedforward`` overrides the
mode's default). A laser tracker samples the true flange every 1 ms. The cell is built
and run by :mod:`cosim.cell` (``--realtime`` / ``--split`` apply). See docs/explanation/main_job.md.

Results (``results/<name>/`` or ``--out``): ``summary.json``; per mode
``timeseries_<mode>.csv`` (1 ms: plant q, qd, drive torques and currents, drive
following errors, tracker), ``controller_<mode>.csv`` (400 µs: set-points, feed-forward,
compute times), ``tcp_<mode>.csv`` (1 ms: programmed, commanded and measured TCP,
TCP and path errors, joint set-points and lag errors), ``can_<mode>.blf`` (every frame
on the bus); figures ``figure2a_lag_errors.png``, ``figure2b_tcp_error.png``,
``tcp_error_vs_desired_path.png``.
"""
from __future__ import annotations

import math
import os
from typing import Any

from cosim.execution.mode_pool import run_modes
from cosim.execution.mode_runs import prepare, run_user
from cosim.cell.parts import CELL_FIELDS, check_cell_scenario
from cosim.cell.user_controller import make_user_controller, user_controller_label
from cosim.results import figure_process
from cosim.tracking.metrics import TrackingResult
from cosim.scenario.context import RunContext
from cosim.scenario.cosim_tables import COSIM_FIELDS
from cosim.scenario.loader import SCENARIO_FIELD, Scenario
from cosim.scenario.job_type import JobType
from cosim.scenario.schema import Table, Where

JOB_NAME = "iso9283"

SCHEMA = Table({"scenario": SCENARIO_FIELD, **COSIM_FIELDS, **CELL_FIELDS}, doc="an iso9283 scenario document")


def run(scenario: Scenario, ctx: RunContext) -> dict[str, Any]:
    """Run every mode of the scenario on the same true robot; write results; return summary fields."""
    setup = prepare(scenario.data, str(scenario.path))
    path = setup.path
    ctx.summary.update(**setup.summary_fields(), modes={})
    modes: dict[str, Any] = {}
    results: dict[str, TrackingResult] = {}
    failed: list = []
    warm_up = None
    if not setup.doc["results"]["figures"]:
        figure_process.stop()
    elif figure_process.current() is None:  # no figure process warming up matplotlib already:
        from cosim.jobs.iso9283_figures import warm_up  # import it here while the workers run
    for outcome in run_modes(ctx, setup, setup.doc["controller"]["modes"],  # side by side: cosim.execution.mode_pool
                             while_waiting=warm_up, niceness=_niceness(setup.doc["controller"]["modes"])):
        if outcome.entry is not None:
            modes[outcome.mode] = outcome.entry
            results[outcome.mode] = outcome.result
            ctx.note_verdict(outcome.mode, outcome.entry)  # its verdict (the worker's ctx is not this one)
            ctx.summary.update(modes=modes)
        elif outcome.failure is not None:
            from cosim.cell.verdict import failed_verdict

            ctx.note_verdict(outcome.mode, failed_verdict(str(outcome.failure), outcome.failure.time).fields())
        if outcome.failure is not None and (outcome.entry is None or outcome.entry.get("verdict") == "failed"):
            failed.append(outcome)  # a stop after a limit or fault reaction is that run's verdict, not a failure
    if failed:  # every mode that could run has run and is in the summary: fail naming the first that failed
        ctx.label = failed[0].mode
        raise failed[0].failure
    ctrl_t = setup.doc["controller"]
    label = user_controller_label(ctrl_t)
    if label is not None:
        controller = make_user_controller(ctrl_t, Where(scenario.path) / "controller")
        entry, result, cell = run_user(ctx, setup, controller, label)
        modes[label] = entry
        results[label] = result
        ctx.summary.update(modes=modes)
        if cell.failure is not None and entry.get("verdict") == "failed":
            raise cell.failure
    fields: dict[str, Any] = {"modes": modes}
    # runs with tracking figures (a served run's controller is another program: none)
    tracked = {m for m, e in modes.items() if "tcp_error_max_mm" in e}
    if "standard" in tracked and "model_based" in tracked:
        fields["improvement_factor"] = _ratio(modes["standard"]["tcp_error_max_mm"],
                                              modes["model_based"]["tcp_error_max_mm"])
        fields["improvement_factor_rms"] = _ratio(modes["standard"]["tcp_error_rms_mm"],
                                                  modes["model_based"]["tcp_error_rms_mm"])
        fields["improvement_factor_noise_free"] = _ratio(modes["standard"]["tcp_error_max_noise_free_mm"],
                                                         modes["model_based"]["tcp_error_max_noise_free_mm"])
    if "standard_speed_ff" in tracked and "model_based" in tracked:
        fields["improvement_factor_vs_standard_speed_ff"] = _ratio(modes["standard_speed_ff"]["tcp_error_max_mm"],
                                                                   modes["model_based"]["tcp_error_max_mm"])
    if "model_based_elastic" in tracked:
        for base in ("standard", "model_based"):
            if base in tracked:
                fields[f"improvement_factor_elastic_vs_{base}"] = _ratio(
                    modes[base]["tcp_error_max_mm"], modes["model_based_elastic"]["tcp_error_max_mm"])
    if setup.doc["results"]["report"]:
        from cosim.results import report

        if report.wanted(scenario.data):  # every file is written: its time-series part, forked, while figures are drawn
            report.start(ctx.out_dir)
    if setup.doc["results"]["figures"]:
        from cosim.jobs.iso9283_figures import write_figures

        fields["figures"] = [p.name for p in write_figures(ctx.out_dir, results, path)]
    return fields


#: The mode whose worker takes the most CPU: its set-up inverts the elastic model along all
#: 30 520 knots of the path (joint table and flatness-based feed-forward, about 0.2 CPU-s more
#: than another mode's set-up) and its cycle costs more.
LONGEST_MODE = "model_based_elastic"
#: ``nice`` increment of the other modes' workers when it runs (``run_modes(niceness=...)``);
#: ``$COSIM_MODE_NICENESS`` (a whole number >= 0) overrides it, e.g. 0 to compare.
OTHER_MODES_NICENESS = 1
NICENESS_ENV = "COSIM_MODE_NICENESS"


def _niceness(modes: list[str]) -> dict[str, int]:
    """The other modes' workers yield a little CPU to the elastic mode's, so that on two cores
    the three end together rather than the elastic one running alone at the end."""
    if LONGEST_MODE not in modes:
        return {}
    text = os.environ.get(NICENESS_ENV, "").strip()
    try:
        step = int(text) if text else OTHER_MODES_NICENESS
    except ValueError:
        raise ValueError(f"${NICENESS_ENV} = {text!r}: expected a whole number >= 0 (nice steps)") from None
    if step < 0:
        raise ValueError(f"${NICENESS_ENV} = {text!r}: expected a whole number >= 0 (nice steps)")
    return {mode: step for mode in modes if mode != LONGEST_MODE and step}


def _ratio(a: float, b: float) -> float:
    return a / b if (b and math.isfinite(a) and math.isfinite(b)) else float("nan")


JOB = JobType(JOB_NAME, run, SCHEMA, check_cell_scenario,
              "ISO 9283 path through controller, fieldbus, drive and plant FMUs: standard vs model-based")
