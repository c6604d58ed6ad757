"""Runs of the built-in controller modes along the ISO 9283 test path on the cell, shared by the
jobs that make them (``iso9283``, ``fieldbus_fault``, the comparison of controllers).

:func:`prepare` builds once what every mode of a scenario shares (:class:`CellSetup`: the
seeded true robot, the path and its TCP reference on the controller grid, the controller's
models, tracker, fieldbus); :func:`mode_cell` gives one mode's cell description and
built-in controller; :func:`run_mode` runs and evaluates it
(:func:`cosim.cell.evaluation.evaluate_run`).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from controller import Controller, ControllerConfig, TcpTrajectory
from controller.elastic import make_controller
from cosim.cell import wiring
from cosim.cell.description import CellDescription, describe_cell
from cosim.cell.evaluation import DEFINITIONS, evaluate_run
from cosim.cell.parts import (BUILTIN_MODES, TORQUE_FEEDFORWARD_MODES, can_log_path, controller_models,
                              drive_speed_feedforward, fill_cell_defaults, make_true_robot, mode_fmus, tracker_config)
from cosim.cell.run import CellRun
from cosim.cell.info import controller_info
from cosim.execution import run_cell
from cosim.tracking.laser_tracker import TrackerConfig
from cosim.tracking.metrics import TrackingResult
from cosim.scenario.context import RunContext


@dataclass
class CellSetup:
    """Everything the modes of one scenario share (built once by :func:`prepare`).

    doc: the validated scenario document; true_robot; path (planners.iso9283 test path);
    reference (:class:`TcpTrajectory` on the controller grid); kinematics/dynamics of the
    controller and their labels; tracker; fieldbus (FieldbusConfig); capacity (controller
    log rows); mode_settings (per mode: controller_mode, drive_speed_feedforward,
    torque_feedforward, description).
    """

    doc: dict[str, Any]
    true_robot: Any
    path: Any
    reference: TcpTrajectory
    kinematics: Any
    dynamics: Any
    kinematics_label: str
    dynamics_label: str
    tracker: TrackerConfig
    fieldbus: Any
    capacity: int
    mode_settings: dict[str, dict[str, Any]]
    source: str = ""

    def summary_fields(self) -> dict[str, Any]:
        """summary.json fields describing the set-up (true robot, controller model, path, definitions)."""
        tr, ctrl_t = self.true_robot, self.doc["controller"]
        return {
            "true_robot": {"seed": tr.seed, "payload_mass_kg": float(tr.payload[0]),
                           "payload_com_m": tr.payload[1:].tolist(),
                           "dynamic_deviations": self.doc["true_robot"]["dynamic_deviations"],
                           "geometric_errors": self.doc["true_robot"]["geometric_errors"]},
            "controller_model": {"kinematics": self.kinematics_label, "dynamics": self.dynamics_label,
                                 "payload_known": ctrl_t["payload_known"],
                                 "drive_compensation": ctrl_t["drive_compensation"], "modes": self.mode_settings},
            "path": {"duration_s": self.path.duration, "length_m": self.path.length, "speed_m_s": self.path.speed,
                     "acceleration_m_s2": self.path.acceleration, "segments": self.path.segment_names},
            "definitions": DEFINITIONS,
        }


def prepare(doc: dict[str, Any], source: str) -> CellSetup:
    """Build the shared set-up of a validated cell document (``source``: the file, for messages)."""
    from fieldbus import FieldbusConfig
    from planners.iso9283 import iso9283_test_path

    fill_cell_defaults(doc)
    ctrl_t = doc["controller"]
    period = ctrl_t["period"]
    true_robot = make_true_robot(doc["true_robot"])
    path = iso9283_test_path(speed=doc["path"]["speed"], acceleration=doc["path"]["acceleration"])
    reference = TcpTrajectory.from_reference(path.reference, path.duration, period)
    kin, dyn, kin_label, dyn_label = controller_models(ctrl_t, true_robot)
    tracker = tracker_config(doc["tracker"])
    fb = FieldbusConfig.from_dict(doc["fieldbus"], source=source)
    mode_settings = {mode: {"controller_mode": BUILTIN_MODES[mode].controller_mode,
                            "drive_speed_feedforward": drive_speed_feedforward(ctrl_t, mode),
                            "torque_feedforward": BUILTIN_MODES[mode].controller_mode in TORQUE_FEEDFORWARD_MODES,
                            "description": BUILTIN_MODES[mode].description} for mode in ctrl_t["modes"]}
    return CellSetup(doc, true_robot, path, reference, kin, dyn, kin_label, dyn_label, tracker, fb,
                     int(doc["simulation"]["stop_time"] / period) + 16, mode_settings, source)


def mode_cell(setup: CellSetup, mode: str, ctx: RunContext | None = None,
              extra_signals: Sequence[str] = ()) -> tuple[CellDescription, Controller]:
    """The cell description and the built-in controller of one mode: the drives get the
    mode's ``speed_feedforward_gain`` (:func:`cosim.cell.parts.mode_fmus`); the controller
    runs the mode's controller mode at ``[controller] period`` (s) with the set-up's models,
    set-points ``1 + dead_time_cycles`` cycles ahead of the fieldbus, and the drives' position
    loops (:func:`cosim.cell.wiring.drive_loop_model`) when it feeds torque forward with
    ``drive_compensation``. Files (``timeseries_<mode>.csv``, ``can_<mode>.blf``) go to
    ``ctx``'s results folder; ``extra_signals`` are recorded besides the cell's."""
    from planners.iso9283 import ISO_Q_HINT

    doc, ctrl_t = setup.doc, setup.doc["controller"]
    period = ctrl_t["period"]
    settings = setup.mode_settings[mode]
    mode_doc = {**doc, "fmus": mode_fmus(doc["fmus"], settings["drive_speed_feedforward"])}
    drive_model = (wiring.drive_loop_model(mode_doc["fmus"], period)
                   if ctrl_t["drive_compensation"] and settings["torque_feedforward"] else None)
    config = ControllerConfig(mode=settings["controller_mode"], period_s=period,
                              lead_cycles=setup.fieldbus.lead_cycles,
                              compute_budget_s=ctrl_t["compute_budget"], settle_time_s=ctrl_t["settle_time"])
    controller = make_controller(setup.reference, config, kinematic_model=setup.kinematics, dynamics=setup.dynamics,
                                 q_hint=np.array(ISO_Q_HINT), drive_model=drive_model, capacity=setup.capacity)
    can_log = can_log_path(ctx, doc["results"], mode)
    info = controller_info(controller, setup.fieldbus, label=mode, source=setup.source)
    cell = describe_cell(mode_doc, setup.true_robot, info, label=mode, fieldbus=setup.fieldbus,
                         tracker=setup.tracker, record_file=f"timeseries_{mode}.csv", can_log=can_log,
                         extra_signals=extra_signals)
    return cell, controller


def run_mode(ctx: RunContext, setup: CellSetup, mode: str, extra_signals: Sequence[str] = ()
             ) -> tuple[dict[str, Any], TrackingResult, CellRun, Controller]:
    """Run one mode on the cell and evaluate it: (summary entry, tracking result, cell run, controller).

    The drives get the mode's ``speed_feedforward_gain``; ``extra_signals`` are recorded
    besides the scenario's [record] signals. A failure of the run is in ``cell.failure``
    (not raised); everything recorded up to it is evaluated and written.
    """
    settings = setup.mode_settings[mode]
    cell_description, controller = mode_cell(setup, mode, ctx, extra_signals)
    cell = run_cell(cell_description, controller, ctx)
    rec = cell.recording
    if cell.failure is not None and (rec is None or not rec.columns or cell.rows_recorded == 0):
        raise cell.failure  # failed before the first sample (e.g. an FMU refused its parameters): nothing to evaluate
    entry, result = evaluate_run(ctx, mode, cell, controller, setup.reference, setup.path, setup.true_robot)
    entry = {"drive_speed_feedforward": settings["drive_speed_feedforward"],
             "torque_feedforward": settings["torque_feedforward"], **entry}
    return entry, result, cell, controller


def user_cell(setup: CellSetup, controller: Any, label: str, ctx: RunContext | None = None) -> CellDescription:
    """The cell description of a user's controller (``[controller] class`` / ``fmu``) on the
    set-up's robot and path: the drives run their plain cascade (``speed_feedforward_gain``
    0: the controller feeds forward itself, e.g. through ``velocity_offset``/``torque_offset``),
    the controller is told the TCP reference, the start pose (IK of the path start near the
    ISO hint), the controller's models and ``[controller.parameters]``."""
    from controller import start_configuration
    from planners.iso9283 import ISO_Q_HINT

    doc, ctrl_t = setup.doc, setup.doc["controller"]
    q_start = start_configuration(setup.reference, setup.kinematics, np.array(ISO_Q_HINT))
    info = controller_info(controller, setup.fieldbus, label=label, parameters=ctrl_t.get("parameters"),
                           source=setup.source, reference=setup.reference, q_start=q_start,
                           kinematic_model=setup.kinematics, dynamics=setup.dynamics,
                           compute_budget_s=ctrl_t["compute_budget"])
    can_log = can_log_path(ctx, doc["results"], label)
    user_doc = {**doc, "fmus": mode_fmus(doc["fmus"], False)}
    return describe_cell(user_doc, setup.true_robot, info, label=label, fieldbus=setup.fieldbus,
                         tracker=setup.tracker, record_file=f"timeseries_{label}.csv", can_log=can_log)


def run_user(ctx: RunContext, setup: CellSetup, controller: Any, label: str
             ) -> tuple[dict[str, Any], TrackingResult, CellRun]:
    """Run a user's controller on the cell and evaluate it as the built-in modes (a failure
    of the run is in ``cell.failure``; what was recorded up to it is evaluated and written)."""
    description = user_cell(setup, controller, label, ctx)
    cell = run_cell(description, controller, ctx)
    entry, result = evaluate_run(ctx, label, cell, controller, setup.reference, setup.path, setup.true_robot,
                                 kinematic_model=setup.kinematics, q_start=description.controller.q_start,
                                 port_timing=cell.controller_timing)
    return {"user_controller": True, **entry}, result, cell
