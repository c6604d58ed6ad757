"""Candidate measurement configurations for calibration (paper section 3.4).

The joint space is cut into ``values_per_axis`` (13) equally spaced values per axis
between the joint limits, ``13^6 = 4,826,809`` configurations, and only those the
tracker sees (:func:`calibration.optical_tracker.visible_mask`) are kept.

Vectorised forward kinematics by composition: for a serial chain the flange
transform factors as ``T(q) = T(q1, q2, q3, 0, 0, 0) T(0)^-1 T(0, 0, 0, q4, q5, q6)``
(the first factor ends at joint 4's placement, which depends on q1..q3 only). So the
robot's own batched FK (:class:`robot.kinematics.FlangeKinematics`) runs on the
13^3 = 2,197 arm and 2,197 wrist sub-configurations, and the 4.8 million flange
positions and probe directions follow from one 3x4 product each (chunked numpy;
about 2 s). Arm sub-configurations whose elbow or wrist centre is below the floor
clearance are dropped before the products. The result is in grid order (q1 slowest,
q6 fastest), which is the order the paper's "linear scan" walks.

If more configurations are visible than ``max_candidates``, every ``N/max``-th one
(in grid order, evenly spaced, deterministic) is kept; the count before this
thinning is reported.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from calibration.optical_tracker import TrackerSetup, visible_mask
from robot.kinematics import FlangeKinematics

VALUES_PER_AXIS = 13
"""Grid values per joint (paper: 13 per degree of freedom, 13^6 = 4.8e6)."""

_CHUNK = 256
"""Arm sub-configurations per composition chunk (256 x 2197 poses, ~40 MB)."""


class CandidateSetError(ValueError):
    """A candidate-grid argument is malformed, or no configuration is visible."""


@dataclass(frozen=True)
class CandidateSet:
    """Visible candidate configurations.

    ``q`` (N, 6) rad in grid order; ``grid_index`` (N,) flat index into the full grid;
    ``flange_positions`` (N, 3) m and ``probe_normals`` (N, 3) from the nominal model;
    ``n_grid`` grid size; ``n_visible`` visible count before thinning;
    ``values_per_axis``; ``grid`` the per-axis values (6 arrays, rad).
    """

    q: np.ndarray
    grid_index: np.ndarray
    flange_positions: np.ndarray
    probe_normals: np.ndarray
    n_grid: int
    n_visible: int
    values_per_axis: int
    grid: tuple[np.ndarray, ...]

    def __len__(self) -> int:
        return int(self.q.shape[0])


def joint_grid(lower: np.ndarray, upper: np.ndarray, values_per_axis: int = VALUES_PER_AXIS) -> tuple[np.ndarray, ...]:
    """Per-axis grid values (6 arrays of ``values_per_axis``, rad), limits included."""
    if not isinstance(values_per_axis, (int, np.integer)) or values_per_axis < 2:
        raise CandidateSetError(f"argument 'values_per_axis' = {values_per_axis!r}: expected an int >= 2")
    return tuple(np.linspace(lo, hi, int(values_per_axis)) for lo, hi in zip(lower, upper))


def _sub_configurations(grid: tuple[np.ndarray, ...], axes: tuple[int, int, int]) -> np.ndarray:
    combos = np.array(list(itertools.product(*(grid[a] for a in axes))))
    q = np.zeros((combos.shape[0], 6))
    q[:, list(axes)] = combos
    return q


def visible_candidates(
    setup: TrackerSetup,
    kinematics: FlangeKinematics | None = None,
    *,
    values_per_axis: int = VALUES_PER_AXIS,
    max_candidates: int | None = None,
) -> CandidateSet:
    """Grid configurations the tracker sees (see the module docstring).

    ``kinematics``: the model used for planning (default: nominal URDF).
    """
    kin = kinematics or FlangeKinematics()
    grid = joint_grid(kin.lower, kin.upper, values_per_axis)
    g = len(grid[0])
    arm_q = _sub_configurations(grid, (0, 1, 2))
    wrist_q = _sub_configurations(grid, (3, 4, 5))
    arm_frames = kin.chain_frames(arm_q)
    arm_t = kin.transforms(arm_q)
    wrist_t = kin.transforms(wrist_q)
    inv_zero = np.linalg.inv(kin.transforms(np.zeros(6))[0])
    # elbow (joint 3 origin) and wrist centre (joint 5 origin) above the floor
    elbow_z = arm_frames.joint_origins[:, 2, 2]
    wrist_z = arm_frames.joint_origins[:, 4, 2]
    arm_ok = np.flatnonzero((elbow_z >= setup.floor_clearance_m) & (wrist_z >= setup.floor_clearance_m))
    m = arm_t[arm_ok] @ inv_zero
    wrist_pos = wrist_t[:, :3, 3]
    wrist_normal = wrist_t[:, :3, :3] @ setup.probe_normal
    hits_arm, hits_wrist = [], []
    for start in range(0, len(arm_ok), _CHUNK):
        mc = m[start:start + _CHUNK]
        pos = np.einsum("aij,bj->abi", mc[:, :3, :3], wrist_pos) + mc[:, None, :3, 3]
        nrm = np.einsum("aij,bj->abi", mc[:, :3, :3], wrist_normal)
        a, b = np.nonzero(visible_mask(setup, pos, nrm))
        hits_arm.append(arm_ok[start + a])
        hits_wrist.append(b)
    arm_idx = np.concatenate(hits_arm)
    wrist_idx = np.concatenate(hits_wrist)
    flat = arm_idx * g**3 + wrist_idx
    order = np.argsort(flat, kind="stable")
    arm_idx, wrist_idx, flat = arm_idx[order], wrist_idx[order], flat[order]
    n_visible = int(flat.size)
    if n_visible == 0:
        raise CandidateSetError(
            "no grid configuration is visible to the tracker; check the tracker setup "
            f"(position {setup.position_m} m, target {setup.target_m} m, ranges)"
        )
    if max_candidates is not None:
        if max_candidates < 1:
            raise CandidateSetError(f"argument 'max_candidates' = {max_candidates!r}: expected >= 1")
        if n_visible > max_candidates:
            keep = np.unique(np.round(np.linspace(0, n_visible - 1, max_candidates)).astype(int))
            arm_idx, wrist_idx, flat = arm_idx[keep], wrist_idx[keep], flat[keep]
    q = arm_q[arm_idx] + wrist_q[wrist_idx]
    mm = arm_t[arm_idx] @ inv_zero
    pos = np.einsum("aij,aj->ai", mm[:, :3, :3], wrist_pos[wrist_idx]) + mm[:, :3, 3]
    nrm = np.einsum("aij,aj->ai", mm[:, :3, :3], wrist_normal[wrist_idx])
    return CandidateSet(q, flat, pos, nrm, g**6, n_visible, g, grid)
