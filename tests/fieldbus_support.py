"""What the fieldbus tests share: the arm's CiA 402 scaling from robot/rx130l_params.toml,
the enabled statusword, the fault configurations the compiled and inline paths are compared
under, and the controller output and CAN-log helpers of the set-point look-ahead and buffer
tests."""
from __future__ import annotations

import tomllib
from pathlib import Path

import can
import numpy as np

from fieldbus import DriveState, JointScaling, statusword_for

TRAIN = tomllib.loads((Path(__file__).resolve().parents[1] / "robot" / "rx130l_params.toml").read_text())["drive_train"]
ENABLED = statusword_for(DriveState.OPERATION_ENABLED)
PREQ_IDS = {0x200 + n for n in range(1, 7)}

#: [fieldbus] tables both the codec test and the inline-cycle test run under
FAULT_CONFIGS = {
    "clean": {},
    "random faults": {"seed": 5, "faults": {"loss_probability": 3e-3, "late_probability": 3e-3,
                                            "corrupt_probability": 3e-3}},
    "bursts": {"faults": {"bursts": [{"node": 2, "start_cycle": 40, "cycles": 20, "frames": "pres", "kind": "loss"},
                                     {"node": 5, "start_cycle": 120, "cycles": 20, "frames": "preq",
                                      "kind": "corrupt"},
                                     {"node": 1, "start_cycle": 200, "cycles": 3, "frames": "soc", "kind": "late"}]}},
    "extrapolate": {"reaction": {"missing_setpoint": "extrapolate"},
                    "faults": {"bursts": [{"node": 3, "start_cycle": 50, "cycles": 1, "frames": "preq", "kind": "loss"},
                                          {"node": 4, "start_cycle": 90, "cycles": 5, "frames": "preq",
                                           "kind": "loss"}]}},
}


def scaling() -> JointScaling:
    """The arm's joint scaling (gear ratios, encoder counts per motor revolution, rated torques)."""
    return JointScaling(TRAIN["gear_ratio"]["value"], TRAIN["encoder_counts_per_motor_rev"]["value"],
                        TRAIN["rated_torque"]["value"])


def output(k):
    """The controller's output computed in cycle k: a smooth, distinct motion per joint
    (CSP set-point, torque and velocity feed-forward)."""
    gains = np.arange(1, 7)
    return (0.2 * np.sin(1e-3 * k * gains), 3.0 * np.cos(2e-3 * k * gains), 0.3 * np.cos(1e-3 * k * gains))


def stack(applied, field):
    """One field of the applied values, cycle by cycle."""
    return np.array([row[field] for row in applied])


def lost_preqs(path):
    """{cycle: nodes whose PReq is in the CAN log} per SoC."""
    seen, cycle = {}, None
    for msg in can.LogReader(str(path)):
        if msg.arbitration_id == 0x080:
            cycle = round(msg.timestamp / 400e-6)
            seen[cycle] = set()
        elif msg.arbitration_id in PREQ_IDS and cycle is not None:
            seen[cycle].add(msg.arbitration_id - 0x200)
    return seen
