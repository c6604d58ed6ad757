"""The paper's kinematics with 39 geometric error parameters (Springer et al. 2013, eq. 8-9).

Parameter vector ``p_e`` (shape (39,), order of :data:`ERROR_PARAMETER_NAMES`):

=========  ======================================  ==========================================
index      names                                   meaning
=========  ======================================  ==========================================
0 - 14     ``len2_x`` ... ``len6_z``               error (m) of the origin vector of joint_2 ..
                                                   joint_6, in the parent link frame (eq. 8)
15 - 17    ``flange_x/y/z``                        error (m) of the joint_6 -> tool0 vector, in
                                                   the link_6 frame
18 - 23    ``offset1`` ... ``offset6``             encoder offsets (rad): the arm's true joint
                                                   angle is ``q + offset`` for a reading ``q``
24 - 33    ``tilt1_x, tilt1_y, tilt2_x, tilt3_x,`` misalignment (rad) of the joint frames:
           ``tilt3_z, tilt4_x, tilt4_y, tilt5_x,`` small rotations about link axes
           ``tilt6_x, tilt6_y``                    perpendicular to the joint axis, applied at
                                                   the joint origin (see "Tilts" below)
34 - 35    ``flange_rx``, ``flange_ry``            misalignment (rad) of the flange (tool0)
                                                   frame: rotations about its own x and y axes
                                                   at its origin (a tool / probe mounting tilt)
36 - 38    ``base_x/y/z``                          base tolerances (m): position error of the
                                                   arm (the joint_1 origin) in base_link
=========  ======================================  ==========================================

This is the paper's split: 6x3 length errors, 6 encoder offsets, 12 misalignment
angles and 3 tolerances of the inertial (base) frame, 39 in all. The 6 length vectors
are the five link vectors joint_2 ... joint_6 and the flange vector; the error of the
joint_1 origin vector is a pure translation of the whole arm in base_link and is
therefore counted as the 3 base tolerances. The base orientation is covered by
``tilt1_x``, ``tilt1_y`` (tilt of axis 1) and ``offset1`` (rotation about it). The 12
misalignment angles are 10 joint tilts and the flange's 2 (below).

Tilts: each joint gets the two rotations about the link axes perpendicular to its axis
(x/y for the z joints 1, 4, 6; x/z for the y joints 2, 3, 5), except a rotation that
duplicates the parent joint's encoder offset exactly: when the joint origin lies on
the parent joint's axis line and one tilt axis is parallel to it (within
:data:`COLLINEAR_ANGLE_TOLERANCE_RAD` and :data:`COLLINEAR_DISTANCE_TOLERANCE_M`), that
tilt is a rotation about the parent axis, i.e. the same parameter as the parent's
offset. On the RX130L this removes the rotation about z at joint 2 (joint 2's origin is
on axis 1: it would equal ``offset1``) and about z at joint 5 (on axis 4: ``offset4``);
their two slots go to the flange tilts ``flange_rx``, ``flange_ry``, which no other
parameter can produce (``tilt6_x/y`` tilt axis 6 *before* its rotation, the flange
tilts act after it). A URDF for which this rule does not leave exactly 10 joint tilts
is rejected (the 39-parameter split is defined for this arm's structure).

Folding (exact, not linearised): joint i's placement in its parent link frame becomes
``SE3(R_nom @ Rot(u, tilt_u) [@ Rot(v, tilt_v)] @ Rot(axis, offset_i), t_nom + dt)``
where ``u < v`` are its tilt axes (link axes of the joint frame) and ``dt`` is ``len_i``
(``base`` for joint 1). The flange placement (the ``tool0`` fixed joint origin) becomes
``SE3(R_f @ Rot(x, flange_rx) @ Rot(y, flange_ry), t_f + flange)``: the translation is
in the link_6 frame, the tilt rotates the flange frame about its own origin. Because
the offset is a rotation about the joint axis folded into the placement, the error
model's joint angle is the encoder reading ``q``. Rotations commute with nothing, so
their order (first ``u`` then ``v``; first ``x`` then ``y``) is part of the definition.

The identification Jacobian ``d(flange pose)/d(p_e)`` has rows 0-2 the flange position
derivative (m per unit) and rows 3-5 the derivative of the flange orientation as a
small rotation vector in base-frame axes (rad per unit), i.e. the derivative of
:func:`robot.kinematics.pose_error` (``target=perturbed``, ``actual=unperturbed``).
Identifiability (rank-revealing QR over well-spread configurations, checked in
tests/robot/test_geometric_errors.py and tests/calibration/test_identifiability.py):
**30** of the 39 columns are independent for full pose measurements, the paper's 30
(the 4R + 2P + 6 count of a complete model of a 6R arm); **25** for position-only
measurements (the flange tilts and ``offset6`` then have no first-order effect, as they
turn the flange about its own origin, and the wrist tilts ``tilt6_x/y`` merge with
translations). The other columns are linear combinations of those (e.g. ``len2_y`` and
``len3_y`` move the arm along the common direction of the parallel axes 2 and 3;
``offset2``, ``offset3`` merge with ``len3_x``, ``len4_x``, ``tilt4_y``), so a
calibration must reduce the set by QR as the paper does.
The simulated "true" arm is drawn from the same 39-parameter family, so a calibration
against it can be exact.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike

from robot.description import FLANGE_FRAME, JOINT_NAMES, URDF_PATH, load_model
from robot.kinematics import (
    N_JOINTS,
    FlangeKinematics,
    KinematicsInputError,
    axis_rotations,
)

N_ERROR_PARAMETERS = 39
N_JOINT_TILTS = 10
"""Joint misalignment angles of the 39 (the other 2 of the paper's 12 are the flange's)."""
FLANGE_TILT_NAMES = ("flange_rx", "flange_ry")
COLLINEAR_ANGLE_TOLERANCE_RAD = 0.02
"""A tilt axis counts as parallel to the parent joint's axis within 0.02 rad (1.1 deg);
loose enough for a calibrated URDF (tilts ~0.1 deg folded into its origins) to keep
the layout of the nominal one."""
COLLINEAR_DISTANCE_TOLERANCE_M = 0.02
"""A joint origin counts as lying on the parent joint's axis line within 0.02 m (again
loose enough for calibrated URDFs, whose origins move by a few mm)."""
_AXIS_LETTERS = "xyz"


class GeometricErrorInputError(ValueError):
    """An error-parameter vector or error-model argument is malformed."""


# ---------------------------------------------------------------------------
# default magnitudes of the random errors: the ONE place for these numbers


@dataclass(frozen=True)
class ErrorMagnitudes:
    """Standard deviations of the normally distributed random geometric errors.

    Units are the readable ones (mm, deg); :func:`random_geometric_errors` converts
    to m and rad. The defaults are chosen so that an arm with such errors, used
    uncalibrated (p_e = 0 in the controller), shows flange errors like Table 2 of
    the paper (RX130L, uncalibrated: maximum e_x 7.8, e_y 19.0, e_z 12.6 mm and
    1.1 - 1.8 deg in the Cardan angles). Measured over 4000 random configurations
    and seeds 0 - 29 (``benchmarks/bench_ik.py`` prints it, the tests check a band):
    maximum |e_x|, |e_y|, |e_z| median 16, 16, 13 mm (range 8 - 22 mm); maximum
    Cardan-angle errors (|beta| < 45 deg) median 1.1, 0.9, 1.1 deg (range 0.3 - 2.1).
    Source: assembly tolerances of a 200 kg class arm (about +-1 mm per link
    vector, +-2 mm base placement, +-0.1 deg joint-axis and flange misalignment) and encoder
    zero offsets of a resolver-fed drive after a manual zeroing (about 0.2 deg);
    scaled to reproduce the paper's Table 2.
    """

    length_mm: float = 1.0
    """each component of the 5 link vectors and the flange vector (mm)"""
    encoder_offset_deg: float = 0.2
    """each encoder offset (deg)"""
    tilt_deg: float = 0.1
    """each misalignment angle, joint and flange tilts (deg)"""
    base_mm: float = 2.0
    """each base-frame tolerance (mm)"""


DEFAULT_ERROR_MAGNITUDES = ErrorMagnitudes()


# ---------------------------------------------------------------------------
# the error model


@dataclass(frozen=True)
class _JointGeometry:
    rotation: np.ndarray  # nominal placement rotation (3, 3)
    translation: np.ndarray  # nominal placement translation (3,) m
    axis: np.ndarray  # unit joint axis in the joint frame (3,)
    tilt_axes: tuple[int, ...]  # indices of the link axes (0 x, 1 y, 2 z) it is tilted about


class GeometricErrorModel:
    """The arm's kinematics with the 39 error parameters on top of one nominal URDF.

    ``urdf_path`` defaults to the project's ``rx130l.urdf``. The nominal joint axes
    must be link axes (x, y or z) for the tilt parameters to be named after them, and
    exactly two joints must sit on their parent joint's axis (see the module docstring).
    """

    def __init__(self, urdf_path: str | Path | None = None) -> None:
        self.urdf_path: Path = Path(urdf_path or URDF_PATH).resolve()
        self.nominal_model: pin.Model = load_model(self.urdf_path)
        nominal = FlangeKinematics(self.nominal_model)  # checks the chain structure
        self._flange_id = nominal.frame_id
        joints = []
        for i in range(1, N_JOINTS + 1):
            placement = self.nominal_model.jointPlacements[i]
            axis = nominal._axes[i - 1]
            along = np.flatnonzero(np.abs(axis) > 1.0 - 1e-12)
            if along.size != 1:
                raise GeometricErrorInputError(
                    f"URDF {str(self.urdf_path)!r}: joint {JOINT_NAMES[i - 1]!r} axis {axis} is "
                    "not a link axis (x, y or z); tilt parameters need one"
                )
            rotation = np.array(placement.rotation)
            translation = np.array(placement.translation)
            parent_axis = nominal._axes[i - 2] if i > 1 else None
            tilt_axes = tuple(
                k for k in range(3)
                if k != along[0] and not _duplicates_parent_offset(rotation[:, k], translation, parent_axis)
            )
            joints.append(_JointGeometry(rotation, translation, axis, tilt_axes))
        self._joints: tuple[_JointGeometry, ...] = tuple(joints)
        n_tilts = sum(len(j.tilt_axes) for j in joints)
        if n_tilts != N_JOINT_TILTS:
            raise GeometricErrorInputError(
                f"URDF {str(self.urdf_path)!r}: the 39-parameter split needs {N_JOINT_TILTS} joint tilts "
                f"(two joints on their parent joint's axis, like the RX130L's joints 2 and 5), got "
                f"{n_tilts}: {[(JOINT_NAMES[i], [_AXIS_LETTERS[k] for k in j.tilt_axes]) for i, j in enumerate(joints)]}"
            )
        # parameter index of each joint's first tilt
        starts = np.cumsum([0] + [len(j.tilt_axes) for j in joints])[:-1] + _TILT_START
        self._tilt_start: tuple[int, ...] = tuple(int(s) for s in starts)
        flange = self.nominal_model.frames[self._flange_id].placement
        self._flange_rotation = np.array(flange.rotation)
        self._flange_translation = np.array(flange.translation)
        self.parameter_names: tuple[str, ...] = self._make_names()

    # names and slices ----------------------------------------------------------
    def _make_names(self) -> tuple[str, ...]:
        names = [f"len{i}_{c}" for i in range(2, N_JOINTS + 1) for c in _AXIS_LETTERS]
        names += [f"flange_{c}" for c in _AXIS_LETTERS]
        names += [f"offset{i}" for i in range(1, N_JOINTS + 1)]
        for i, joint in enumerate(self._joints, start=1):
            names += [f"tilt{i}_{_AXIS_LETTERS[k]}" for k in joint.tilt_axes]
        names += list(FLANGE_TILT_NAMES)
        names += [f"base_{c}" for c in _AXIS_LETTERS]
        assert len(names) == N_ERROR_PARAMETERS
        return tuple(names)

    def check_errors(self, errors: ArrayLike | None, name: str = "errors") -> np.ndarray:
        """Return ``errors`` as a finite (39,) float array (None means all zero)."""
        if errors is None:
            return np.zeros(N_ERROR_PARAMETERS)
        arr = np.asarray(errors, dtype=float)
        if arr.shape != (N_ERROR_PARAMETERS,):
            raise GeometricErrorInputError(
                f"argument {name!r}: expected {N_ERROR_PARAMETERS} error parameters "
                f"(order of ERROR_PARAMETER_NAMES), got shape {arr.shape}"
            )
        if not np.all(np.isfinite(arr)):
            bad = [self.parameter_names[k] for k in np.flatnonzero(~np.isfinite(arr))]
            raise GeometricErrorInputError(f"argument {name!r}: non-finite values for {bad}")
        return arr

    def _split(self, errors: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(translations (6, 3) m for joints 1..6, flange (3,) m, offsets (6,) rad)."""
        translations = np.empty((N_JOINTS, 3))
        translations[0] = errors[36:39]
        translations[1:] = errors[0:15].reshape(5, 3)
        return translations, errors[15:18], errors[18:24]

    def _joint_tilts(self, i: int, errors: np.ndarray) -> np.ndarray:
        """Tilt angles (rad) of joint i (0-based), in the order of its tilt axes."""
        start = self._tilt_start[i]
        return errors[start : start + len(self._joints[i].tilt_axes)]

    def joint_placements(self, errors: ArrayLike | None) -> tuple[list[pin.SE3], pin.SE3]:
        """Placements (pinocchio SE3, m) of joints 1..6 in their parent frames and of
        the flange in link_6, with ``errors`` (39,) folded in exactly."""
        p = self.check_errors(errors)
        translations, flange, offsets = self._split(p)
        placements = []
        for i, joint in enumerate(self._joints):
            tilt = _tilt_rotation(joint.tilt_axes, self._joint_tilts(i, p))
            rot = joint.rotation @ tilt @ _rot(joint.axis, offsets[i])
            placements.append(pin.SE3(rot, joint.translation + translations[i]))
        flange_tilt = _tilt_rotation((0, 1), p[_FLANGE_TILT])
        return placements, pin.SE3(self._flange_rotation @ flange_tilt, self._flange_translation + flange)

    # models ----------------------------------------------------------------------
    def model(self, errors: ArrayLike | None = None) -> pin.Model:
        """A new pinocchio model of the arm with ``errors`` (39,) folded into the joint
        placements and the flange frame (inertias stay attached to their links)."""
        placements, flange = self.joint_placements(errors)
        model = pin.Model(self.nominal_model)
        for i, placement in enumerate(placements, start=1):
            model.jointPlacements[i] = placement
        # tool0 and the fixed joint that carries it share the flange placement
        flange_frame = model.frames[self._flange_id]
        model.frames[flange_frame.parentFrame].placement = flange
        flange_frame.placement = flange
        return model

    def kinematics(self, errors: ArrayLike | None = None) -> FlangeKinematics:
        """:class:`FlangeKinematics` of the error model (FK, Jacobian, batches)."""
        return FlangeKinematics(self.model(errors))

    # URDF export -----------------------------------------------------------------
    def urdf(self, errors: ArrayLike | None = None, robot_name: str | None = None) -> str:
        """URDF text of the arm with ``errors`` folded into the joint origins.

        Everything but the origins of joint_1 ... joint_6 and of the flange joint is
        copied from the nominal URDF. Numbers are written with ``repr`` (17 significant
        digits, exact round trip); an XML comment lists every error parameter.
        """
        p = self.check_errors(errors)
        placements, flange = self.joint_placements(p)
        parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
        root = ET.parse(self.urdf_path, parser=parser).getroot()
        if robot_name is not None:
            root.set("name", robot_name)
        joints = {j.get("name"): j for j in root.iter("joint")}
        for name, placement in zip(JOINT_NAMES, placements):
            _set_origin(joints[name], placement, self.urdf_path)
        flange_joint = [j for j in root.iter("joint") if _child(j) == FLANGE_FRAME]
        if len(flange_joint) != 1:
            raise GeometricErrorInputError(
                f"URDF {str(self.urdf_path)!r}: expected one joint with child {FLANGE_FRAME!r}"
            )
        _set_origin(flange_joint[0], flange, self.urdf_path)
        lines = [
            "Geometric error parameters folded into the joint origins below",
            "(robot/geometric_errors.py; lengths and base in m, angles in rad):",
        ]
        lines += [f"  {n} = {v!r}" for n, v in zip(self.parameter_names, p.tolist())]
        root.insert(0, ET.Comment("\n  " + "\n  ".join(lines) + "\n"))
        ET.indent(root, space="  ")
        text = self.urdf_path.read_text(encoding="utf-8")
        prolog = text[: text.index("<robot")]  # XML declaration and header comment
        return prolog + ET.tostring(root, encoding="unicode") + "\n"

    def write_urdf(self, path: str | Path, errors: ArrayLike | None = None) -> Path:
        """Write :meth:`urdf` to ``path`` (parent folders created) and return the path."""
        out = Path(path)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(self.urdf(errors), encoding="utf-8")
        return out

    # batched kinematics and identification Jacobian ----------------------------------
    def flange_transforms(self, q: ArrayLike, errors: ArrayLike | None = None) -> np.ndarray:
        """Flange transforms (n, 4, 4) of the error model for q of shape (6,) or (n, 6) rad."""
        return self.kinematics(errors).transforms(q)

    def identification_jacobian(
        self, q: ArrayLike, errors: ArrayLike | None = None
    ) -> np.ndarray:
        """d(flange pose)/d(p_e) at ``errors`` for q of shape (6,) or (n, 6); shape (n, 6, 39).

        Rows 0-2: flange position (m per m or per rad); rows 3-5: flange orientation as
        a small rotation vector in base-frame axes (rad per m or per rad). Exact for
        the folding above (no linearisation around p_e = 0).
        """
        p = self.check_errors(errors)
        try:
            frames = self.kinematics(p).chain_frames(q)
        except KinematicsInputError as exc:
            raise GeometricErrorInputError(str(exc)) from exc
        n = frames.flange_position.shape[0]
        flange = frames.flange_position
        out = np.zeros((n, 6, N_ERROR_PARAMETERS))

        def put_rotation(column: int, omega: np.ndarray, origin: np.ndarray) -> None:
            out[:, :3, column] = np.cross(omega, flange - origin)
            out[:, 3:, column] = omega

        for i, joint in enumerate(self._joints):
            parent = frames.parent_rotations[:, i]
            origin = frames.joint_origins[:, i]
            # translation of the joint origin, in the parent link frame
            first = 36 if i == 0 else 3 * (i - 1)
            out[:, :3, first : first + 3] = parent
            # misalignment: about u, then about v (rotated by the first)
            for column, omega in zip(
                range(self._tilt_start[i], self._tilt_start[i] + len(joint.tilt_axes)),
                _tilt_axes_in_frame(joint.rotation, joint.tilt_axes, self._joint_tilts(i, p)),
            ):
                put_rotation(column, parent @ omega, origin)
            # encoder offset: rotation about the joint axis (a geometric-Jacobian column)
            put_rotation(18 + i, frames.joint_axes[:, i], origin)
        # flange vector, in the link_6 frame: link_6 rotation = flange rotation @ (R_f R_tilt)^T
        flange_tilts = p[_FLANGE_TILT]
        link6 = frames.flange_rotation @ (self._flange_rotation @ _tilt_rotation((0, 1), flange_tilts)).T
        out[:, :3, 15:18] = link6
        # flange tilt: rotation about the flange's own x, then y axis at its origin
        for column, omega in zip(range(_FLANGE_TILT.start, _FLANGE_TILT.stop),
                                 _tilt_axes_in_frame(self._flange_rotation, (0, 1), flange_tilts)):
            out[:, 3:, column] = link6 @ omega
        return out


_TILT_START = 24
_FLANGE_TILT = slice(34, 36)


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    return axis_rotations(np.asarray(axis, dtype=float), np.array([angle]))[0]


def _tilt_rotation(axes: tuple[int, ...], angles: np.ndarray) -> np.ndarray:
    """Product of rotations about the link axes ``axes`` by ``angles`` (rad), in order."""
    out = np.eye(3)
    for k, angle in zip(axes, angles):
        out = out @ _rot(np.eye(3)[k], float(angle))
    return out


def _tilt_axes_in_frame(rotation: np.ndarray, axes: tuple[int, ...], angles: np.ndarray) -> list[np.ndarray]:
    """Rotation axis of each tilt in the parent frame of ``rotation @ tilts``: the k-th
    tilt turns about its link axis rotated by the tilts before it."""
    out, acc = [], np.array(rotation, dtype=float)
    for k, angle in zip(axes, angles):
        out.append(acc @ np.eye(3)[k])
        acc = acc @ _rot(np.eye(3)[k], float(angle))
    return out


def _duplicates_parent_offset(tilt_axis: np.ndarray, origin: np.ndarray, parent_axis: np.ndarray | None) -> bool:
    """True when a tilt about ``tilt_axis`` (parent-frame direction) at the joint origin
    ``origin`` (m, parent frame) is a rotation about the parent joint's axis line
    (``parent_axis`` through the parent frame's origin), i.e. its encoder offset."""
    if parent_axis is None:
        return False
    parallel = abs(float(np.dot(tilt_axis, parent_axis))) >= math.cos(COLLINEAR_ANGLE_TOLERANCE_RAD)
    distance = float(np.linalg.norm(origin - np.dot(origin, parent_axis) * parent_axis))
    return parallel and distance <= COLLINEAR_DISTANCE_TOLERANCE_M


def _child(joint: ET.Element) -> str | None:
    child = joint.find("child")
    return None if child is None else child.get("link")


def _set_origin(joint: ET.Element, placement: pin.SE3, urdf_path: Path) -> None:
    origin = joint.find("origin")
    if origin is None:
        origin = ET.SubElement(joint, "origin")
    rpy = pin.rpy.matrixToRpy(placement.rotation)
    check = pin.rpy.rpyToMatrix(*rpy)
    if not np.allclose(check, placement.rotation, atol=1e-14, rtol=0.0):
        raise GeometricErrorInputError(
            f"URDF {str(urdf_path)!r}: joint {joint.get('name')!r} rotation has no exact rpy form"
        )
    origin.set("xyz", " ".join(repr(float(x)) for x in placement.translation))
    origin.set("rpy", " ".join(repr(float(x)) for x in rpy))


# ---------------------------------------------------------------------------
# module-level conveniences on the project's nominal URDF

_DEFAULT: GeometricErrorModel | None = None


def default_error_model() -> GeometricErrorModel:
    """The :class:`GeometricErrorModel` of the project's nominal ``rx130l.urdf`` (shared)."""
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = GeometricErrorModel()
    return _DEFAULT


ERROR_PARAMETER_NAMES: tuple[str, ...] = default_error_model().parameter_names
"""The 39 parameter names in vector order (see the module docstring)."""


def error_model(errors: ArrayLike | None = None) -> pin.Model:
    """Pinocchio model of the nominal arm with ``errors`` (39,) folded into its placements."""
    return default_error_model().model(errors)


def export_error_urdf(path: str | Path, errors: ArrayLike | None = None) -> Path:
    """Write the URDF of the nominal arm with ``errors`` (39,) folded in; returns the path."""
    return default_error_model().write_urdf(path, errors)


def identification_jacobian(q: ArrayLike, errors: ArrayLike | None = None) -> np.ndarray:
    """Identification Jacobian (n, 6, 39) of the nominal arm at ``errors``; see
    :meth:`GeometricErrorModel.identification_jacobian`."""
    return default_error_model().identification_jacobian(q, errors)


def is_angle_parameter(name: str) -> bool:
    """True for the error parameters in rad (encoder offsets, joint and flange tilts),
    False for those in m (lengths, flange vector, base)."""
    return name.startswith(("offset", "tilt")) or name in FLANGE_TILT_NAMES


def errors_as_dict(errors: ArrayLike) -> dict[str, float]:
    """``{name: value}`` of an error vector (39,) (m and rad)."""
    p = default_error_model().check_errors(errors)
    return dict(zip(ERROR_PARAMETER_NAMES, p.tolist()))


def random_geometric_errors(
    seed: int | np.random.Generator,
    magnitudes: ErrorMagnitudes = DEFAULT_ERROR_MAGNITUDES,
) -> np.ndarray:
    """Seeded random error vector (39,) in m and rad: independent normal errors with the
    standard deviations of ``magnitudes`` (mm and deg, see :class:`ErrorMagnitudes`).

    The same ``seed`` (an int, or a numpy Generator that is advanced) gives the same
    vector on every machine.
    """
    if isinstance(seed, np.random.Generator):
        rng = seed
    elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and seed >= 0:
        rng = np.random.default_rng(int(seed))
    else:
        raise GeometricErrorInputError(
            f"argument 'seed': expected a non-negative int or a numpy Generator, got {seed!r}"
        )
    scale = error_standard_deviations(magnitudes)
    return rng.standard_normal(N_ERROR_PARAMETERS) * scale


def error_standard_deviations(magnitudes: ErrorMagnitudes = DEFAULT_ERROR_MAGNITUDES) -> np.ndarray:
    """Standard deviation (39,) of each error parameter in m and rad, from ``magnitudes``
    (mm and deg): the prior of a calibration (how large each error is expected to be)."""
    for field in ("length_mm", "encoder_offset_deg", "tilt_deg", "base_mm"):
        value = getattr(magnitudes, field)
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0.0):
            raise GeometricErrorInputError(
                f"argument 'magnitudes': {field} must be a finite number >= 0, got {value!r}"
            )
    scale = np.empty(N_ERROR_PARAMETERS)
    scale[0:18] = magnitudes.length_mm * 1e-3
    scale[18:24] = math.radians(magnitudes.encoder_offset_deg)
    scale[24:36] = math.radians(magnitudes.tilt_deg)
    scale[36:39] = magnitudes.base_mm * 1e-3
    return scale
