"""The 400 µs model-based controller: trajectory interpolation, IK, feed-forward, telegrams.

Middle floor: imports ``robot`` and ``fieldbus`` only. Public API::

    from controller import Controller, ControllerConfig, TcpTrajectory, JointTrajectory
    ref = TcpTrajectory.from_reference(iso_path.reference, iso_path.duration, dt=400e-6)
    ctrl = Controller(ref, ControllerConfig(mode="model_based"), kinematic_model=model, dynamics=dyn)
    output = ctrl.step(inputs)                    # ControllerInput -> ControllerOutput (the contract)
    setpoints = ctrl.run_cycle(cycle, t, observed)  # fieldbus.ObservedActuals -> fieldbus.Setpoints

The controller contract (what any cell controller is given and returns, built-in or a
user's): :mod:`controller.contract`; the cell drives a controller through
:class:`controller.port.ControllerPort`.
"""
from controller.controller import (MODES, Controller, ControllerConfig, ControllerConfigError, ControllerLog, Phase,
                                   start_configuration)
from controller.contract import (MODE_CSP, MODE_CST, MODE_CSV, MODES_OF_OPERATION, CellController, ControllerInfo,
                                 ControllerInput, ControllerOutput, contract_problems)
from controller.cycle_timer import CycleTimer, TimingSummary
from controller.drive_compensation import DriveLoopModel, SetpointShaper, speed_comparison_lead
from controller.feedforward import FeedForward
from controller.joint_reference import CartesianToJoint, SingularConfigurationError
from controller.reference import JointSample, JointTrajectory, ReferenceError, TcpSample, TcpTrajectory, quintic_hermite

__all__ = [
    "MODE_CSP", "MODE_CST", "MODE_CSV", "MODES_OF_OPERATION", "CellController", "ControllerInfo", "ControllerInput",
    "ControllerOutput", "contract_problems",
    "MODES", "CartesianToJoint", "Controller", "ControllerConfig", "ControllerConfigError", "ControllerLog",
    "CycleTimer", "DriveLoopModel", "FeedForward", "JointSample", "JointTrajectory", "Phase", "ReferenceError",
    "SetpointShaper", "SingularConfigurationError", "TcpSample", "TcpTrajectory", "TimingSummary", "quintic_hermite", "speed_comparison_lead", "start_configuration",
]
