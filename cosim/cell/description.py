"""One typed, frozen description of a robot-cell run, built once from the validated scenario.

:func:`describe_cell` takes what a job decided (the scenario document, the seeded true
robot, the controller's :class:`controller.ControllerInfo`, the run's label and files)
and fills in everything the builder needs: the FMU instances with their start values
(the true robot at rest at the controller's start pose, the drives' axis parameters),
the connections (generated plus the scenario's own, :func:`cosim.cell.wiring.merged_connections`),
the fieldbus configuration, the laser tracker, what is recorded and how often.
:func:`cosim.execution.run_cell` runs a description in any execution mode.
"""
from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

from controller import ControllerInfo
from cosim.cell.protection import PROTECTION_SIGNALS
from cosim.cell.wiring import DRIVES, PLANT, RECORDED_SIGNALS, cell_fmus, drive_variables_of, merged_connections
from cosim.tracking.laser_tracker import TrackerConfig
from fieldbus import FieldbusConfig
from robot.true_robot import TrueRobot


@dataclass(frozen=True)
class CellDescription:
    """Everything one cell run is made of (SI units).

    label: the run's name (file names, progress, summary keys).
    document: the master's document: ``simulation``, ``fmus`` (start values filled in),
        ``connections`` (generated + the scenario's), read-only.
    true_robot: the seeded robot the plant is set to (its kinematics feed the tracker).
    fieldbus: the POWERLINK configuration (cycle time = the controller cycle).
    tracker: the laser tracker's period, noise and seed.
    signals, record_period_s: what the recorder samples and how often (s).
    stop_time_s: end of the run, s.
    controller: what the controller is told at ``setup`` (:class:`controller.ControllerInfo`).
    record_file: the time-series file in the results folder; can_log: the CAN log or None.
    stop_grace_s: how long the run goes on after the controller stopped commanding motion, s.
    """

    label: str
    document: Mapping[str, Any]
    true_robot: TrueRobot
    fieldbus: FieldbusConfig
    tracker: TrackerConfig
    signals: tuple[str, ...]
    record_period_s: float
    stop_time_s: float
    controller: ControllerInfo
    record_file: str = "timeseries.csv"
    can_log: Path | None = None
    stop_grace_s: float = 0.5

    @property
    def period_s(self) -> float:
        """The bus (= controller) cycle, s."""
        return self.fieldbus.cycle_time_s

    def master_document(self) -> dict[str, Any]:
        """A mutable copy of :attr:`document` for ``cosim.scenario.cosim_tables.build_master``."""
        return copy.deepcopy(dict(self.document))


def describe_cell(doc: Mapping[str, Any], true_robot: TrueRobot, controller: ControllerInfo, *, label: str,
                  stop_time: float | None = None, fieldbus: FieldbusConfig | Mapping[str, Any] | None = None,
                  tracker: TrackerConfig | None = None, record_file: str = "timeseries.csv",
                  can_log: Path | None = None, extra_signals: Sequence[str] = (),
                  drive_parameters: Mapping[str, float] | None = None) -> CellDescription:
    """The description of one run of the cell of the validated scenario ``doc``.

    ``controller.q_start`` is where the plant starts at rest; ``drive_parameters`` are set on
    every drive on top of the scenario's (e.g. the job's ``speed_feedforward_gain`` per mode);
    ``extra_signals`` are recorded besides the ``[record]`` signals and
    :data:`cosim.cell.wiring.RECORDED_SIGNALS`. Raises ValueError when the fieldbus cycle
    differs from ``controller.period_s``.
    """
    fb = fieldbus if isinstance(fieldbus, FieldbusConfig) else FieldbusConfig.from_dict(dict(fieldbus or {}))
    if abs(fb.cycle_time_s - controller.period_s) > 1e-12:
        raise ValueError(f"controller period {controller.period_s} s differs from the fieldbus cycle time "
                         f"{fb.cycle_time_s} s")
    tracker = tracker if tracker is not None else TrackerConfig()
    fmus = cell_fmus(doc["fmus"], true_robot, controller.q_start)
    if drive_parameters:
        for fmu in fmus:
            if fmu["name"] in DRIVES:
                fmu["parameters"] = {**fmu["parameters"], **drive_parameters}
    record = doc.get("record") or {"period": tracker.period_s, "signals": []}
    drive_variables = drive_variables_of(fmus)
    signals = list(record["signals"])
    signals += [s for s in extra_signals if s not in signals]
    signals += [s for s in RECORDED_SIGNALS if s not in signals and _available(s, drive_variables)]
    available = {**drive_variables, PLANT: _plant_variables(fmus)}
    signals += [s for s in PROTECTION_SIGNALS if s not in signals and _available(s, available)]
    document = {"simulation": copy.deepcopy(doc["simulation"]), "fmus": fmus,
                "connections": merged_connections(doc.get("connections") or [], drive_variables)}
    return CellDescription(label=label, document=MappingProxyType(document), true_robot=true_robot, fieldbus=fb,
                           tracker=tracker, signals=tuple(signals), record_period_s=record["period"],
                           stop_time_s=float(stop_time if stop_time is not None else doc["simulation"]["stop_time"]),
                           controller=controller, record_file=record_file, can_log=can_log)


def _plant_variables(fmus: Sequence[Mapping[str, Any]]) -> set[str]:
    """The variable names of the cell's plant FMU (its end-stop outputs are recorded where it has them)."""
    from cosim.master import load_model_description
    from fmus.fmu import variables_of

    plant = next((f for f in fmus if f["name"] == PLANT), None)
    return set(variables_of(load_model_description(plant["path"]))) if plant is not None else set()


def _available(signal: str, drive_variables: Mapping[str, set[str]]) -> bool:
    """Whether a signal the cell always records exists (a drive of the minimal interface may lack
    ``current_actual`` or ``following_error``)."""
    instance, _, variable = signal.partition(".")
    return instance not in drive_variables or variable in drive_variables[instance]
