"""Optical tracker for calibration: measurement noise and visibility (paper section 3.4).

The paper measures the flange with a stereo infrared tracker (Boulder Innovation
Group 3D-Creator: a probe with 4 infrared LEDs on the end effector, three CCD
cameras). This module models

* the measurement: flange position and orientation of the TRUE robot plus Gaussian
  noise (:class:`TrackerNoise`, :func:`measure_flange`);
* visibility: which flange poses the tracker sees (:class:`TrackerSetup`,
  :func:`visible_mask`): inside the cameras' field-of-view cone and depth range, the
  probe's LEDs facing the cameras within an angle, the flange above the floor and
  outside a keep-out cylinder around the robot base.

Frames: everything in ``base_link`` (m, rad). The tracker is registered to the base
frame beforehand, so it reports base-frame poses. Robot self-occlusion of the probe
is not modelled (the facing-angle limit removes most such poses).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


class TrackerConfigError(ValueError):
    """A tracker setting is out of range or malformed."""


DEFAULT_POSITION_SIGMA_M = 1.0e-4
"""Tracker position noise, standard deviation per base-frame axis: 0.1 mm. Source:
volumetric accuracy of multi-camera infrared trackers of the 3D-Creator/FlashPoint
class (0.1 - 0.2 mm RMS); it also matches the paper's calibrated residuals (Table 2:
largest residuals 0.27 - 0.41 mm over the validation poses, i.e. about 3 sigma)."""

DEFAULT_ORIENTATION_SIGMA_RAD = math.radians(0.04)
"""Tracker orientation noise, standard deviation of each component of the rotation
vector: 0.04 deg. Derived: 0.1 mm LED position noise over a ~150 mm LED baseline
gives 1e-4 / 0.15 = 6.7e-4 rad = 0.038 deg; Table 2's calibrated orientation
residuals (0.11 - 0.19 deg max) are about 3 sigma of this."""


@dataclass(frozen=True)
class TrackerNoise:
    """Gaussian tracker noise: per-axis position sigma (m) and per-component sigma of
    the orientation error rotation vector (rad, base-frame axes)."""

    position_sigma_m: float = DEFAULT_POSITION_SIGMA_M
    orientation_sigma_rad: float = DEFAULT_ORIENTATION_SIGMA_RAD

    def __post_init__(self) -> None:
        for name in ("position_sigma_m", "orientation_sigma_rad"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0.0):
                raise TrackerConfigError(f"tracker noise {name!r}: expected a number >= 0, got {value!r}")
        if self.position_sigma_m > 0.01:
            raise TrackerConfigError(
                f"tracker noise 'position_sigma_m' = {self.position_sigma_m!r}: expected metres "
                "(<= 0.01 m); was a value in millimetres given?"
            )
        if self.orientation_sigma_rad > 0.1:
            raise TrackerConfigError(
                f"tracker noise 'orientation_sigma_rad' = {self.orientation_sigma_rad!r}: expected "
                "radians (<= 0.1 rad); was a value in degrees given?"
            )

    def row_sigmas(self, orientation: bool) -> np.ndarray:
        """Noise sigma of each measured pose row (3 or 6,): m then rad."""
        rows = [self.position_sigma_m] * 3
        if orientation:
            rows += [self.orientation_sigma_rad] * 3
        return np.array(rows)


def measure_flange(
    true_transforms: np.ndarray, noise: TrackerNoise, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Noisy tracker readings of flange transforms (n, 4, 4) of the true robot.

    Returns positions (n, 3) in m and rotation matrices (n, 3, 3):
    ``p_meas = p + N(0, sigma_p^2 I)``, ``R_meas = Exp(N(0, sigma_o^2 I)) R``.
    """
    t = np.asarray(true_transforms, dtype=float)
    n = t.shape[0]
    positions = t[:, :3, 3] + rng.normal(0.0, noise.position_sigma_m, size=(n, 3))
    rotvec = rng.normal(0.0, noise.orientation_sigma_rad, size=(n, 3))
    rotations = Rotation.from_rotvec(rotvec).as_matrix() @ t[:, :3, :3]
    return positions, rotations


def _unit(v: tuple[float, float, float], name: str) -> np.ndarray:
    arr = np.asarray(v, dtype=float)
    norm = float(np.linalg.norm(arr))
    if arr.shape != (3,) or not np.all(np.isfinite(arr)) or norm == 0.0:
        raise TrackerConfigError(f"tracker setting {name!r}: expected a non-zero 3-vector, got {v!r}")
    return arr / norm


@dataclass(frozen=True)
class TrackerSetup:
    """Placement and limits of the tracker and the probe (m, deg, base_link frame).

    Defaults (modelling choices; the paper gives no tracker placement): the camera
    bar stands 2.6 m in front of the robot (+x), 1.2 m high, looking at a point 1.0 m
    in front of the base at 0.8 m height; a field-of-view cone of 15 deg half angle
    and a depth range of 1.2 - 3.4 m (class values of 3-camera infrared trackers);
    the probe's LEDs face along a direction 45 deg off the flange z axis (towards
    flange x) and are measured when that direction points within 10 deg of the
    cameras (a flat 4-LED probe is reconstructed reliably only when seen nearly
    face-on); the flange stays 0.15 m above the floor (z = 0) and outside a 0.45 m
    radius cylinder around axis 1 below 0.75 m height. With the 13^6 grid this
    leaves 3,680 visible configurations, close to the paper's "approximately 4000"
    (the facing and field-of-view angles were chosen for that).
    """

    position_m: tuple[float, float, float] = (2.6, 0.0, 1.2)
    target_m: tuple[float, float, float] = (1.0, 0.0, 0.8)
    fov_half_angle_deg: float = 15.0
    range_min_m: float = 1.2
    range_max_m: float = 3.4
    probe_normal_flange: tuple[float, float, float] = (0.7071067811865476, 0.0, 0.7071067811865476)
    probe_max_angle_deg: float = 10.0
    floor_clearance_m: float = 0.15
    base_keepout_radius_m: float = 0.45
    base_keepout_height_m: float = 0.75

    def __post_init__(self) -> None:
        for name in ("position_m", "target_m"):
            arr = np.asarray(getattr(self, name), dtype=float)
            if arr.shape != (3,) or not np.all(np.isfinite(arr)):
                raise TrackerConfigError(f"tracker setting {name!r}: expected a finite 3-vector (m), got {arr!r}")
        for name, lo, hi in (
            ("fov_half_angle_deg", 0.0, 90.0),
            ("probe_max_angle_deg", 0.0, 180.0),
        ):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and lo < value <= hi):
                raise TrackerConfigError(f"tracker setting {name!r} = {value!r}: expected in ({lo}, {hi}] deg")
        if not 0.0 <= self.range_min_m < self.range_max_m:
            raise TrackerConfigError(
                f"tracker settings 'range_min_m' = {self.range_min_m!r}, 'range_max_m' = "
                f"{self.range_max_m!r}: expected 0 <= min < max (m)"
            )
        view = np.subtract(self.target_m, self.position_m)
        if np.linalg.norm(view) == 0.0:
            raise TrackerConfigError("tracker settings 'position_m' and 'target_m' must differ")
        _unit(self.probe_normal_flange, "probe_normal_flange")

    @property
    def view_direction(self) -> np.ndarray:
        """Unit optical axis of the tracker (base frame)."""
        return _unit(tuple(np.subtract(self.target_m, self.position_m)), "target_m")

    @property
    def probe_normal(self) -> np.ndarray:
        """Unit LED facing direction in the flange frame."""
        return _unit(self.probe_normal_flange, "probe_normal_flange")


def visible_mask(setup: TrackerSetup, flange_positions: np.ndarray, probe_normals: np.ndarray) -> np.ndarray:
    """Which flange poses the tracker measures; boolean array of the leading shape.

    ``flange_positions`` (..., 3) m and ``probe_normals`` (..., 3) unit LED facing
    directions, both in base_link.
    """
    p = np.asarray(flange_positions, dtype=float)
    n = np.asarray(probe_normals, dtype=float)
    cam = np.asarray(setup.position_m, dtype=float)
    to_cam = cam - p
    dist = np.linalg.norm(to_cam, axis=-1)
    in_range = (dist >= setup.range_min_m) & (dist <= setup.range_max_m)
    cos_fov = -(to_cam @ setup.view_direction) / np.maximum(dist, 1e-12)
    in_fov = cos_fov >= math.cos(math.radians(setup.fov_half_angle_deg))
    facing = np.einsum("...i,...i->...", n, to_cam) / np.maximum(dist, 1e-12)
    faces = facing >= math.cos(math.radians(setup.probe_max_angle_deg))
    above = p[..., 2] >= setup.floor_clearance_m
    radial = np.hypot(p[..., 0], p[..., 1])
    clear = (radial >= setup.base_keepout_radius_m) | (p[..., 2] >= setup.base_keepout_height_m)
    return in_range & in_fov & faces & above & clear
