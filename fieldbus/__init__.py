"""POWERLINK-timed CiA 402 telegrams over python-can.

Ground floor: imports no other package of this project.

Public API (see README section in docs or each module's docstring)::

    from fieldbus import FieldbusConfig, JointScaling, PowerlinkNetwork, Setpoints, DriveActuals
    scaling = JointScaling(gear_ratio, encoder_counts_per_motor_rev, rated_torque)
    with PowerlinkNetwork({"cycle_time_us": 400}, scaling, log_path="fieldbus.blf") as net:
        result = net.run_cycle(k, setpoints, actuals)   # result.applied, result.observed
"""
from fieldbus.cia402 import Command, DriveState, EnableSequencer, command_name, decode_statusword, motion_enabled, statusword_for
from fieldbus.cia402_drive_model import Cia402DriveModel
from fieldbus.config import FieldbusConfig, defaults_table
from fieldbus.endpoints import DriveEndpoint, ManagingNodeEndpoint
from fieldbus.errors import FieldbusConfigError, FrameDecodeError, ScalingError
from fieldbus.events import EventLog, FieldbusEvent
from fieldbus.network import PowerlinkNetwork
from fieldbus.process_data import AppliedSetpoints, CycleResult, DriveActuals, ObservedActuals, Setpoints
from fieldbus.scaling import JointScaling
from fieldbus.telegrams import decode

__all__ = [
    "AppliedSetpoints", "Cia402DriveModel", "Command", "CycleResult", "DriveActuals", "DriveEndpoint",
    "DriveState", "ManagingNodeEndpoint",
    "EnableSequencer", "EventLog", "FieldbusConfig", "FieldbusConfigError", "FieldbusEvent",
    "FrameDecodeError", "JointScaling", "ObservedActuals", "PowerlinkNetwork", "ScalingError",
    "Setpoints", "command_name", "decode", "decode_statusword", "defaults_table", "motion_enabled",
    "statusword_for",
]
