"""Candidate grid and tracker visibility: composed FK against direct FK, brute-force filter."""
import itertools
import math

import numpy as np
import pytest

from calibration.candidates import CandidateSetError, joint_grid, visible_candidates
from calibration.optical_tracker import (
    TrackerConfigError,
    TrackerNoise,
    TrackerSetup,
    measure_flange,
    visible_mask,
)
from robot.kinematics import FlangeKinematics


def test_composed_grid_equals_brute_force_visibility():
    kin = FlangeKinematics()
    setup = TrackerSetup(probe_max_angle_deg=25.0, fov_half_angle_deg=25.0)
    cands = visible_candidates(setup, kin, values_per_axis=6)
    # brute force: every grid configuration through the batched FK directly
    grid = joint_grid(kin.lower, kin.upper, 6)
    q = np.array(list(itertools.product(*grid)))
    frames = kin.chain_frames(q)
    mask = visible_mask(setup, frames.flange_position, frames.flange_rotation @ setup.probe_normal)
    mask &= frames.joint_origins[:, 2, 2] >= setup.floor_clearance_m
    mask &= frames.joint_origins[:, 4, 2] >= setup.floor_clearance_m
    assert cands.n_grid == 6**6
    assert np.array_equal(cands.grid_index, np.flatnonzero(mask))
    assert np.allclose(cands.q, q[mask], atol=0)
    assert np.abs(cands.flange_positions - frames.flange_position[mask]).max() < 1e-12
    assert len(cands) > 50


def test_thinning_and_errors():
    setup = TrackerSetup(probe_max_angle_deg=25.0, fov_half_angle_deg=25.0)
    full = visible_candidates(setup, values_per_axis=6)
    thin = visible_candidates(setup, values_per_axis=6, max_candidates=40)
    assert len(thin) == 40 and thin.n_visible == len(full)
    assert np.all(np.isin(thin.grid_index, full.grid_index))
    nowhere = TrackerSetup(position_m=(0.0, 0.0, 30.0), target_m=(0.0, 0.0, 40.0))
    with pytest.raises(CandidateSetError, match="no grid configuration is visible"):
        visible_candidates(nowhere, values_per_axis=4)


def test_visibility_rules():
    setup = TrackerSetup()
    cam = np.array(setup.position_m)
    target = np.array(setup.target_m)
    facing = (cam - target) / np.linalg.norm(cam - target)
    assert visible_mask(setup, target[None], facing[None])[0]
    assert not visible_mask(setup, target[None], -facing[None])[0]  # LEDs face away
    side = target + np.array([0.0, 1.5, 0.0])  # outside the 15 deg cone
    assert not visible_mask(setup, side[None], facing[None])[0]
    low = np.array([1.0, 0.0, 0.05])  # below the floor clearance
    assert not visible_mask(setup, low[None], ((cam - low) / np.linalg.norm(cam - low))[None])[0]
    with pytest.raises(TrackerConfigError, match="fov_half_angle_deg"):
        TrackerSetup(fov_half_angle_deg=0.0)
    with pytest.raises(TrackerConfigError, match="range_min_m"):
        TrackerSetup(range_min_m=4.0, range_max_m=3.0)


def test_tracker_noise_statistics_and_units():
    rng = np.random.default_rng(0)
    noise = TrackerNoise(1e-4, math.radians(0.04))
    transforms = np.repeat(np.eye(4)[None], 20000, axis=0)
    pos, rot = measure_flange(transforms, noise, rng)
    assert np.std(pos, axis=0) == pytest.approx([1e-4] * 3, rel=0.03)
    angles = np.arccos(np.clip((np.trace(rot, axis1=1, axis2=2) - 1) / 2, -1, 1))
    # |rotation vector| of an isotropic 3D normal: RMS = sqrt(3) sigma
    assert np.sqrt(np.mean(angles**2)) == pytest.approx(math.sqrt(3) * math.radians(0.04), rel=0.03)
    with pytest.raises(TrackerConfigError, match="millimetres"):
        TrackerNoise(position_sigma_m=0.1)
    with pytest.raises(TrackerConfigError, match="degrees"):
        TrackerNoise(orientation_sigma_rad=0.5)
