"""Paths of the robot description files shipped with the package."""
from __future__ import annotations

from pathlib import Path

ROBOT_DIR: Path = Path(__file__).resolve().parent
URDF_PATH: Path = ROBOT_DIR / "rx130l.urdf"
PARAMS_PATH: Path = ROBOT_DIR / "rx130l_params.toml"
FLANGE_FRAME: str = "tool0"
JOINT_NAMES: tuple[str, ...] = tuple(f"joint_{i}" for i in range(1, 7))
