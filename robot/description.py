"""Paths of the robot description files and the pinocchio model loader."""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import pinocchio as pin

ROBOT_DIR: Path = Path(__file__).resolve().parent
URDF_PATH: Path = ROBOT_DIR / "rx130l.urdf"
PARAMS_PATH: Path = ROBOT_DIR / "rx130l_params.toml"
FLANGE_FRAME: str = "tool0"
JOINT_NAMES: tuple[str, ...] = tuple(f"joint_{i}" for i in range(1, 7))


class RobotDescriptionError(ValueError):
    """A robot description file is missing or malformed."""


def load_model(urdf_path: str | Path | None = None) -> pin.Model:
    """Return a fresh pinocchio model of the arm (fixed base, 6 revolute joints).

    ``urdf_path`` defaults to the nominal ``rx130l.urdf``. The model is copied from a
    cache, so callers may modify it freely.
    """
    return pin.Model(_load_cached(str(Path(urdf_path or URDF_PATH).resolve())))


@lru_cache(maxsize=16)
def _load_cached(path: str) -> pin.Model:
    if not Path(path).is_file():
        raise RobotDescriptionError(f"URDF file {path!r} does not exist")
    try:
        model = pin.buildModelFromUrdf(path)
    except Exception as exc:  # pinocchio raises plain exceptions for parse errors
        raise RobotDescriptionError(f"URDF file {path!r} could not be parsed: {exc}") from exc
    if model.nq != 6 or not model.existFrame(FLANGE_FRAME):
        raise RobotDescriptionError(
            f"URDF file {path!r}: expected 6 revolute joints and a frame {FLANGE_FRAME!r}, "
            f"got nq={model.nq}"
        )
    return model
