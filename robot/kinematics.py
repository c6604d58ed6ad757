"""Forward kinematics of the flange, Cardan angles and the geometric Jacobian.

Frames and units (see docs/explanation/architecture.md): the flange pose is the ``tool0`` frame
in the ``base_link`` frame, positions in m, angles in rad. The paper's orientation is
given by Cardan angles (x-y-z intrinsic), ``R = Rx(alpha) @ Ry(beta) @ Rz(gamma)``; a
*Cardan pose* is the 6-vector ``(x, y, z, alpha, beta, gamma)`` (the paper's z_E).

The geometric Jacobian ``J`` (6x6) maps joint speeds to the flange twist: rows 0-2
are the linear velocity of the flange origin, rows 3-5 the angular velocity, both in
base-frame axes (pinocchio's ``LOCAL_WORLD_ALIGNED`` frame Jacobian).

:class:`FlangeKinematics` works on any pinocchio model of this arm, the nominal one
from :func:`robot.description.load_model` or one with geometric errors folded into
its joint placements (:mod:`robot.geometric_errors`). Single configurations go
through pinocchio; batches of configurations (shape (n, 6)) go through a vectorised
numpy evaluation of the same chain, which agrees with pinocchio to round-off.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from robot.description import FLANGE_FRAME, load_model
from robot.joints import N_JOINTS

ROTATION_TOLERANCE = 1e-6
"""Largest accepted deviation of R @ R.T from the identity (and of det R from 1) for a
rotation matrix given as input. 1e-6 admits rotations printed with 7 significant
digits and rejects anything that is not a rotation."""

_AXIS_OF_JOINT_TYPE = {
    "JointModelRX": (1.0, 0.0, 0.0),
    "JointModelRY": (0.0, 1.0, 0.0),
    "JointModelRZ": (0.0, 0.0, 1.0),
}


class KinematicsInputError(ValueError):
    """A joint vector, pose or rotation matrix given to the kinematics is malformed."""


# ---------------------------------------------------------------------------
# input checks


def as_joint_vector(q: ArrayLike, name: str = "q") -> np.ndarray:
    """Return ``q`` as a float array of shape (6,) (rad), or raise KinematicsInputError."""
    arr = np.asarray(q, dtype=float)
    if arr.shape != (N_JOINTS,):
        raise KinematicsInputError(
            f"argument {name!r}: expected a joint vector of shape ({N_JOINTS},), got shape "
            f"{arr.shape} (value {np.array2string(arr, threshold=12)})"
        )
    if not np.all(np.isfinite(arr)):
        raise KinematicsInputError(f"argument {name!r}: joint vector must be finite, got {arr}")
    return arr


def as_joint_matrix(q: ArrayLike, name: str = "q") -> np.ndarray:
    """Return ``q`` (shape (6,) or (n, 6), rad) as a float array of shape (n, 6)."""
    arr = np.asarray(q, dtype=float)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != N_JOINTS:
        raise KinematicsInputError(
            f"argument {name!r}: expected joint vectors of shape ({N_JOINTS},) or (n, {N_JOINTS}),"
            f" got shape {np.shape(q)}"
        )
    if not np.all(np.isfinite(arr)):
        raise KinematicsInputError(f"argument {name!r}: joint vectors must be finite")
    return arr


def as_vector(v: ArrayLike, length: int, name: str) -> np.ndarray:
    """Return ``v`` as a finite float array of shape (length,), or raise KinematicsInputError."""
    arr = np.asarray(v, dtype=float)
    if arr.shape != (length,):
        raise KinematicsInputError(
            f"argument {name!r}: expected a vector of shape ({length},), got shape {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise KinematicsInputError(f"argument {name!r}: vector must be finite, got {arr}")
    return arr


def as_rotation_matrix(rotation: ArrayLike, name: str = "rotation") -> np.ndarray:
    """Return ``rotation`` as a (3, 3) float array after checking it is a proper rotation.

    Raises KinematicsInputError when the shape is wrong, an entry is not finite,
    ``R @ R.T`` differs from the identity or ``det R`` from 1 by more than
    :data:`ROTATION_TOLERANCE`.
    """
    arr = np.asarray(rotation, dtype=float)
    if arr.shape != (3, 3):
        raise KinematicsInputError(
            f"argument {name!r}: expected a 3x3 rotation matrix, got shape {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise KinematicsInputError(f"argument {name!r}: rotation matrix must be finite, got {arr}")
    orth = float(np.abs(arr @ arr.T - np.eye(3)).max())
    det = float(np.linalg.det(arr))
    if orth > ROTATION_TOLERANCE or abs(det - 1.0) > ROTATION_TOLERANCE:
        raise KinematicsInputError(
            f"argument {name!r}: not a rotation matrix (max |R R^T - I| = {orth:.3g}, "
            f"det R = {det:.6g}; expected orthonormal with det +1 within {ROTATION_TOLERANCE:g})"
        )
    return arr


def as_transform(transform: ArrayLike | pin.SE3, name: str = "pose") -> np.ndarray:
    """Return a checked 4x4 homogeneous transform (m) from a 4x4 array or a pinocchio SE3."""
    if isinstance(transform, pin.SE3):
        arr = np.array(transform.homogeneous)
    else:
        arr = np.asarray(transform, dtype=float)
    if arr.shape != (4, 4):
        raise KinematicsInputError(
            f"argument {name!r}: expected a 4x4 homogeneous transform, got shape {arr.shape}"
        )
    if not np.all(np.isfinite(arr)) or not np.allclose(arr[3], (0.0, 0.0, 0.0, 1.0), atol=0.0):
        raise KinematicsInputError(
            f"argument {name!r}: expected a finite transform with last row (0, 0, 0, 1), got {arr}"
        )
    as_rotation_matrix(arr[:3, :3], name=f"{name} rotation part")
    return arr


# ---------------------------------------------------------------------------
# Cardan angles (x-y-z intrinsic) and poses


def rotation_from_cardan(angles: ArrayLike) -> np.ndarray:
    """Rotation matrix ``Rx(alpha) @ Ry(beta) @ Rz(gamma)`` from Cardan angles (rad).

    ``angles`` has shape (..., 3) holding (alpha, beta, gamma); returns shape (..., 3, 3).
    """
    a = np.asarray(angles, dtype=float)
    if a.shape[-1:] != (3,):
        raise KinematicsInputError(
            f"argument 'angles': expected Cardan angles of shape (..., 3), got shape {a.shape}"
        )
    ca, cb, cg = np.cos(a[..., 0]), np.cos(a[..., 1]), np.cos(a[..., 2])
    sa, sb, sg = np.sin(a[..., 0]), np.sin(a[..., 1]), np.sin(a[..., 2])
    out = np.empty(a.shape[:-1] + (3, 3))
    out[..., 0, 0] = cb * cg
    out[..., 0, 1] = -cb * sg
    out[..., 0, 2] = sb
    out[..., 1, 0] = ca * sg + sa * sb * cg
    out[..., 1, 1] = ca * cg - sa * sb * sg
    out[..., 1, 2] = -sa * cb
    out[..., 2, 0] = sa * sg - ca * sb * cg
    out[..., 2, 1] = sa * cg + ca * sb * sg
    out[..., 2, 2] = ca * cb
    return out


GIMBAL_LOCK_TOLERANCE = 1e-12
"""|cos(beta)| below which Cardan angles are at gimbal lock (beta = +-90 deg); there
gamma is set to 0 and alpha takes the whole rotation about the common axis."""


def cardan_from_rotation(rotation: ArrayLike) -> np.ndarray:
    """Cardan angles (alpha, beta, gamma) in rad with ``R = Rx(alpha) Ry(beta) Rz(gamma)``.

    ``rotation`` has shape (..., 3, 3); returns shape (..., 3) with alpha, gamma in
    (-pi, pi] and beta in [-pi/2, pi/2]. At gimbal lock (|cos beta| <
    :data:`GIMBAL_LOCK_TOLERANCE`) gamma is 0 by convention.
    """
    r = np.asarray(rotation, dtype=float)
    if r.shape[-2:] != (3, 3):
        raise KinematicsInputError(
            f"argument 'rotation': expected rotation matrices of shape (..., 3, 3), got {r.shape}"
        )
    cos_beta = np.hypot(r[..., 0, 0], r[..., 0, 1])
    beta = np.arctan2(r[..., 0, 2], cos_beta)
    alpha = np.arctan2(-r[..., 1, 2], r[..., 2, 2])
    gamma = np.arctan2(-r[..., 0, 1], r[..., 0, 0])
    locked = cos_beta < GIMBAL_LOCK_TOLERANCE
    if np.any(locked):
        # R = Rx(alpha) Ry(+-pi/2) with gamma = 0: R[1,0] = sin(alpha) sin(beta), R[1,1] = cos(alpha)
        sign = np.where(r[..., 0, 2] >= 0.0, 1.0, -1.0)
        alpha = np.where(locked, np.arctan2(sign * r[..., 1, 0], r[..., 1, 1]), alpha)
        gamma = np.where(locked, 0.0, gamma)
    return np.stack([alpha, beta, gamma], axis=-1)


def transform_from_pose(pose: ArrayLike) -> np.ndarray:
    """4x4 homogeneous transform(s) from Cardan pose(s) (x, y, z [m], alpha, beta, gamma [rad]).

    ``pose`` has shape (..., 6); returns shape (..., 4, 4).
    """
    p = np.asarray(pose, dtype=float)
    if p.shape[-1:] != (6,):
        raise KinematicsInputError(
            f"argument 'pose': expected Cardan poses of shape (..., 6), got shape {p.shape}"
        )
    out = np.zeros(p.shape[:-1] + (4, 4))
    out[..., :3, :3] = rotation_from_cardan(p[..., 3:])
    out[..., :3, 3] = p[..., :3]
    out[..., 3, 3] = 1.0
    return out


def pose_from_transform(transform: ArrayLike) -> np.ndarray:
    """Cardan pose(s) (x, y, z [m], alpha, beta, gamma [rad]) of 4x4 transform(s) (..., 4, 4)."""
    t = np.asarray(transform, dtype=float)
    if t.shape[-2:] != (4, 4):
        raise KinematicsInputError(
            f"argument 'transform': expected transforms of shape (..., 4, 4), got shape {t.shape}"
        )
    return np.concatenate([t[..., :3, 3], cardan_from_rotation(t[..., :3, :3])], axis=-1)


def pose_error(target: ArrayLike, actual: ArrayLike) -> np.ndarray:
    """Pose error of ``actual`` relative to ``target`` (both 4x4 transforms, shape (..., 4, 4)).

    Returns shape (..., 6): rows 0-2 ``p_target - p_actual`` (m, base frame), rows 3-5
    the rotation vector of ``R_target @ R_actual.T`` (rad, base-frame axes), i.e. the
    small rotation that carries the actual onto the target orientation. This is the
    error whose derivative is the geometric (or identification) Jacobian.
    """
    t = np.asarray(target, dtype=float)
    a = np.asarray(actual, dtype=float)
    d_rot = t[..., :3, :3] @ np.swapaxes(a[..., :3, :3], -1, -2)
    flat = d_rot.reshape(-1, 3, 3)
    rotvec = Rotation.from_matrix(flat).as_rotvec().reshape(d_rot.shape[:-2] + (3,))
    return np.concatenate([t[..., :3, 3] - a[..., :3, 3], rotvec], axis=-1)


def axis_rotations(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) about the unit ``axis`` (3,) by ``angles`` (n,) in rad."""
    k = np.array(
        [[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]]
    )
    k2 = k @ k
    s = np.sin(angles)[:, None, None]
    c = np.cos(angles)[:, None, None]
    return np.eye(3) + s * k + (1.0 - c) * k2


# ---------------------------------------------------------------------------
# forward kinematics and Jacobian


@dataclass(frozen=True)
class ChainFrames:
    """World (base_link) quantities of the joint chain for n configurations.

    parent_rotations: (n, 6, 3, 3) rotation of the parent link frame of joint i, before
    the joint placement; joint_origins: (n, 6, 3) joint origins in m; joint_axes:
    (n, 6, 3) unit joint axes; flange_rotation (n, 3, 3) and flange_position (n, 3) m.
    Index i = 0 is joint_1.
    """

    parent_rotations: np.ndarray
    joint_origins: np.ndarray
    joint_axes: np.ndarray
    flange_rotation: np.ndarray
    flange_position: np.ndarray


class FlangeKinematics:
    """Flange (tool0 in base_link) forward kinematics and geometric Jacobian of one model.

    ``model`` is any pinocchio model of this arm (default: the nominal URDF model); it
    must be a serial chain of 6 revolute joints with a ``tool0`` frame on joint 6. The
    object keeps its own pinocchio Data, so it is cheap to call but not thread-safe.
    """

    def __init__(self, model: pin.Model | None = None) -> None:
        self.model: pin.Model = load_model() if model is None else model
        self.data: pin.Data = self.model.createData()
        _check_serial_revolute_chain(self.model)
        self.frame_id: int = self.model.getFrameId(FLANGE_FRAME)
        self.lower: np.ndarray = np.array(self.model.lowerPositionLimit, dtype=float)
        self.upper: np.ndarray = np.array(self.model.upperPositionLimit, dtype=float)
        self._placement_rotations = np.array(
            [self.model.jointPlacements[i].rotation for i in range(1, N_JOINTS + 1)]
        )
        self._placement_translations = np.array(
            [self.model.jointPlacements[i].translation for i in range(1, N_JOINTS + 1)]
        )
        self._axes = np.array([_joint_axis(self.model.joints[i]) for i in range(1, N_JOINTS + 1)])
        flange = self.model.frames[self.frame_id].placement
        self._flange_rotation = np.array(flange.rotation)
        self._flange_translation = np.array(flange.translation)

    # single configuration (pinocchio) ------------------------------------------
    def placement(self, q: ArrayLike) -> pin.SE3:
        """Flange placement (pinocchio SE3, m) at joint angles ``q`` (6,) in rad."""
        qv = as_joint_vector(q)
        pin.forwardKinematics(self.model, self.data, qv)
        return pin.SE3(pin.updateFramePlacement(self.model, self.data, self.frame_id))

    def transform(self, q: ArrayLike) -> np.ndarray:
        """Flange 4x4 homogeneous transform in base_link (m) at ``q`` (6,) rad."""
        return self.placement(q).homogeneous

    def position(self, q: ArrayLike) -> np.ndarray:
        """Flange origin (3,) in m, base_link frame."""
        return self.placement(q).translation.copy()

    def rotation(self, q: ArrayLike) -> np.ndarray:
        """Flange rotation matrix (3, 3), base_link frame."""
        return self.placement(q).rotation.copy()

    def pose(self, q: ArrayLike) -> np.ndarray:
        """Cardan pose (x, y, z [m], alpha, beta, gamma [rad]) of the flange, shape (6,)."""
        return pose_from_transform(self.transform(q))

    def jacobian(self, q: ArrayLike) -> np.ndarray:
        """Geometric Jacobian (6, 6): flange linear velocity (m/s) then angular velocity
        (rad/s) per joint speed (rad/s), base-frame axes, at the flange origin."""
        qv = as_joint_vector(q)
        return pin.computeFrameJacobian(
            self.model, self.data, qv, self.frame_id, pin.LOCAL_WORLD_ALIGNED
        ).copy()

    # batches (numpy) -----------------------------------------------------------
    def chain_frames(self, q: ArrayLike) -> ChainFrames:
        """World frames of the chain for configurations ``q`` of shape (6,) or (n, 6) rad."""
        qs = as_joint_matrix(q)
        n = qs.shape[0]
        rot = np.broadcast_to(np.eye(3), (n, 3, 3))
        pos = np.zeros((n, 3))
        parents = np.empty((n, N_JOINTS, 3, 3))
        origins = np.empty((n, N_JOINTS, 3))
        axes = np.empty((n, N_JOINTS, 3))
        for i in range(N_JOINTS):
            parents[:, i] = rot
            pos = pos + rot @ self._placement_translations[i]
            rot = rot @ self._placement_rotations[i]
            origins[:, i] = pos
            axes[:, i] = rot @ self._axes[i]
            rot = rot @ axis_rotations(self._axes[i], qs[:, i])
        flange_pos = pos + rot @ self._flange_translation
        flange_rot = rot @ self._flange_rotation
        return ChainFrames(parents, origins, axes, flange_rot, flange_pos)

    def positions(self, q: ArrayLike) -> np.ndarray:
        """Flange origins (n, 3) m for configurations ``q`` of shape (6,) or (n, 6) rad: the
        operations of :meth:`chain_frames` that lead to the flange position, so the same numbers
        bit for bit, without the per-joint frames and the flange rotation (2.6x less time)."""
        qs = as_joint_matrix(q)
        n = qs.shape[0]
        rot = np.broadcast_to(np.eye(3), (n, 3, 3))
        pos = np.zeros((n, 3))
        for i in range(N_JOINTS):
            pos = pos + rot @ self._placement_translations[i]
            rot = rot @ self._placement_rotations[i]
            rot = rot @ axis_rotations(self._axes[i], qs[:, i])
        return pos + rot @ self._flange_translation

    def transforms(self, q: ArrayLike) -> np.ndarray:
        """Flange transforms (n, 4, 4) for configurations of shape (6,) or (n, 6) rad."""
        frames = self.chain_frames(q)
        n = frames.flange_position.shape[0]
        out = np.zeros((n, 4, 4))
        out[:, :3, :3] = frames.flange_rotation
        out[:, :3, 3] = frames.flange_position
        out[:, 3, 3] = 1.0
        return out

    def jacobians(self, q: ArrayLike) -> np.ndarray:
        """Geometric Jacobians (n, 6, 6) (same convention as :meth:`jacobian`)."""
        frames = self.chain_frames(q)
        lever = frames.flange_position[:, None, :] - frames.joint_origins
        out = np.empty((lever.shape[0], 6, N_JOINTS))
        out[:, :3, :] = np.swapaxes(np.cross(frames.joint_axes, lever), 1, 2)
        out[:, 3:, :] = np.swapaxes(frames.joint_axes, 1, 2)
        return out

    def within_limits(self, q: ArrayLike, tolerance: float = 0.0) -> bool:
        """True when every joint of ``q`` (6,) lies inside the model's position limits."""
        qv = as_joint_vector(q)
        return bool(np.all(qv >= self.lower - tolerance) and np.all(qv <= self.upper + tolerance))


def _joint_axis(joint: pin.JointModel) -> np.ndarray:
    name = joint.shortname()
    if name in _AXIS_OF_JOINT_TYPE:
        return np.array(_AXIS_OF_JOINT_TYPE[name])
    if name == "JointModelRevoluteUnaligned":
        axis = np.array(joint.extract().axis, dtype=float)
        return axis / np.linalg.norm(axis)
    raise KinematicsInputError(
        f"model joint {joint.id}: expected a revolute joint, got joint type {name!r}"
    )


def _check_serial_revolute_chain(model: pin.Model) -> None:
    if model.nq != N_JOINTS or model.njoints != N_JOINTS + 1:
        raise KinematicsInputError(
            f"argument 'model': expected 6 revolute joints, got nq={model.nq}, "
            f"njoints={model.njoints - 1}"
        )
    for i in range(1, N_JOINTS + 1):
        if model.parents[i] != i - 1:
            raise KinematicsInputError(
                f"argument 'model': expected a serial chain, joint {i} has parent {model.parents[i]}"
            )
        _joint_axis(model.joints[i])
    if not model.existFrame(FLANGE_FRAME):
        raise KinematicsInputError(f"argument 'model': no frame {FLANGE_FRAME!r}")
    if model.frames[model.getFrameId(FLANGE_FRAME)].parentJoint != N_JOINTS:
        raise KinematicsInputError(
            f"argument 'model': frame {FLANGE_FRAME!r} must be attached to joint {N_JOINTS}"
        )
