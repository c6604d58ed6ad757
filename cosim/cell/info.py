"""The :class:`controller.ControllerInfo` of a cell run: what a controller is told of the cell it
runs in (bus cycle, dead time, the arm's limits, the reference and models)."""
from __future__ import annotations

from typing import Any

from controller import ControllerInfo
from controller.contract import DEFAULT_COMPUTE_BUDGET_S
from cosim.cell.wiring import N_JOINTS
from fieldbus import FieldbusConfig
from robot.parameters import load_parameters


def controller_info(controller: Any, fb_config: FieldbusConfig, *, label: str = "",
                    parameters: dict[str, Any] | None = None, source: str = "", reference: Any = None,
                    q_start: Any = None, kinematic_model: Any = None, dynamics: Any = None,
                    compute_budget_s: float | None = None) -> ControllerInfo:
    """The :class:`controller.ControllerInfo` of a cell run: the bus cycle and dead time of
    ``fb_config``, the arm's limits (robot/rx130l.urdf via robot/rx130l_params.toml), and the
    reference, start pose, models and budget given (else the built-in controller's own,
    where ``controller`` has them)."""
    p = load_parameters()
    config = getattr(controller, "config", None)
    budget = compute_budget_s if compute_budget_s is not None else getattr(config, "compute_budget_s", DEFAULT_COMPUTE_BUDGET_S)

    def pick(given: Any, name: str) -> Any:
        return given if given is not None else getattr(controller, name, None)

    return ControllerInfo(period_s=fb_config.cycle_time_s, n_joints=N_JOINTS,
                          dead_time_cycles=fb_config.dead_time_cycles,
                          lookahead_cycles=fb_config.planned_ahead_cycles, compute_budget_s=budget,
                          position_min=p.position_lower.copy(), position_max=p.position_upper.copy(),
                          velocity_max=p.velocity_limit.copy(), torque_max=p.effort_limit.copy(),
                          rated_torque=p.rated_torque.copy(), q_start=pick(q_start, "q_start"),
                          reference=pick(reference, "reference"),
                          kinematic_model=pick(kinematic_model, "kinematic_model"),
                          dynamics=pick(dynamics, "dynamics"), parameters=dict(parameters or {}), label=label,
                          source=source)
