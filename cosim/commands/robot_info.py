"""``python -m cosim robot-info``: print the robot description's key figures."""
from __future__ import annotations

import argparse
import json

NAME = "robot-info"
HELP = "Print the robot description (joints, limits, masses, flange pose at zero) as JSON."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """No options."""


def run(args: argparse.Namespace) -> int:
    """Load the URDF with pinocchio and print a JSON summary."""
    import numpy as np
    import pinocchio as pin

    from robot.description import URDF_PATH

    model = pin.buildModelFromUrdf(str(URDF_PATH))
    data = model.createData()
    q0 = np.zeros(model.nq)
    pin.framesForwardKinematics(model, data, q0)
    flange = data.oMf[model.getFrameId("tool0")].translation
    info = {
        "urdf": str(URDF_PATH),
        "joints": [model.names[i] for i in range(1, model.njoints)],
        "lower_rad": model.lowerPositionLimit.tolist(),
        "upper_rad": model.upperPositionLimit.tolist(),
        "velocity_rad_s": model.velocityLimit.tolist(),
        "effort_Nm": model.effortLimit.tolist(),
        "moving_mass_kg": float(sum(i.mass for i in model.inertias[1:])),
        "flange_at_zero_m": flange.tolist(),
    }
    print(json.dumps(info, indent=2))
    return 0
