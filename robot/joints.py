"""The number of joints of the arm, defined once for every package (this module imports
nothing, so light modules can use it without loading the robot model).

Source: ``robot/rx130l.urdf`` has six revolute joints (``robot.description`` checks the
loaded model against this number)."""

N_JOINTS = 6
"""Joints of the RX130L-class arm (six revolute joints, joint 1 at the base)."""
