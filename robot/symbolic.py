"""The arm's dynamics as CasADi SX expressions with the dynamic parameters as inputs.

Own recursive algorithms on the kinematic structure read from the pinocchio model
(joint placements, joint axes, parent tree, gravity, the ``tool0`` placement):

- inverse dynamics: recursive Newton-Euler (RNEA),
- forward dynamics: the articulated-body algorithm (ABA),
- mass matrix: the composite-rigid-body algorithm (CRBA).

All are written in pinocchio's convention: spatial vectors in the local joint frame,
``(linear, angular)`` order, link inertias about the joint frame origin, so that the
78-parameter vector of :mod:`robot.dynamics` enters unchanged. Rotor inertia ``Ia``
adds ``Ia * qdd`` and friction ``fv * qd + fc * tanh(qd / v_s)`` adds to the joint
torque; the payload ``[mass, cx, cy, cz]`` (point mass, centre of mass in ``tool0``)
is folded into link 6 symbolically. ``v_s`` and gravity are constants.

Why ABA for forward dynamics: it is O(n) and needs only one scalar division per
joint, while ``M \\ b`` needs a CRBA, an RNEA and a symbolic 6x6 factorisation; on
this arm the ABA expression has fewer operations (see ``benchmarks/bench_dynamics.py``)
and its generated C is a straight line of multiply-adds with six divisions.

The functions have fixed names and input/output order (a contract with the plant FMU):

- ``rx130l_fd(q[6], qd[6], tau[6], p[78], payload[4]) -> qdd[6]``
- ``rx130l_id(q[6], qd[6], qdd[6], p[78], payload[4]) -> tau[6]``
- ``rx130l_mass_matrix(q[6], p[78], payload[4]) -> M[6x6]``
- ``rx130l_bias(q[6], qd[6], p[78], payload[4]) -> C qd + g + friction [6]``
- ``rx130l_gravity(q[6], p[78], payload[4]) -> g[6]``

Units: rad, rad/s, rad/s^2, N m, kg, m (payload centre of mass in ``tool0``).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Sequence

import casadi as ca
import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike

from robot import spatial_lists as sp
from robot.description import FLANGE_FRAME, load_model
from robot.dynamics import (
    COULOMB_SLICE, N_JOINTS, N_PARAMETERS, ROTOR_INERTIA_SLICE, VISCOUS_SLICE, DynamicParameterError,
    nominal_parameter_vector,
)
from robot.parameters import RobotParameters, load_parameters

FORWARD_DYNAMICS_NAME = "rx130l_fd"
INVERSE_DYNAMICS_NAME = "rx130l_id"
MASS_MATRIX_NAME = "rx130l_mass_matrix"
BIAS_NAME = "rx130l_bias"
GRAVITY_NAME = "rx130l_gravity"
_FUNCTION_OPTIONS = {"cse": True}

Expr = Any  # casadi SX or MX (or DM / numpy for constants)


@dataclass(frozen=True)
class ChainStructure:
    """Kinematic structure of the serial arm, numeric constants from the pinocchio model.

    ``rotations[i]``/``translations[i]``: placement of joint i+1 in its parent frame at
    q = 0 (x_parent = R x_child + t, m); ``axes[i]``: unit joint axis in the joint frame;
    ``parents[i]``: index of the parent joint (-1: base); ``gravity``: m/s^2 in the base
    frame; ``flange_rotation``/``flange_translation``: ``tool0`` in the joint-6 frame;
    ``coulomb_smoothing_velocity``: rad/s.
    """

    rotations: tuple[np.ndarray, ...]
    translations: tuple[np.ndarray, ...]
    axes: tuple[np.ndarray, ...]
    parents: tuple[int, ...]
    gravity: np.ndarray
    flange_rotation: np.ndarray
    flange_translation: np.ndarray
    coulomb_smoothing_velocity: float


def chain_structure(model: pin.Model | None = None, parameters: RobotParameters | None = None) -> ChainStructure:
    """Read the structure the symbolic algorithms need from a pinocchio model."""
    parameters = parameters or load_parameters()
    model = model or load_model(parameters.urdf_path)
    if model.nq != N_JOINTS or model.nv != N_JOINTS or model.njoints != N_JOINTS + 1:
        raise DynamicParameterError(f"model has nq={model.nq}, njoints={model.njoints}, expected 6 revolute joints")
    axes = []
    for j in range(1, N_JOINTS + 1):
        axes.append(_joint_axis(model, j))
    flange = model.frames[model.getFrameId(FLANGE_FRAME)]
    if flange.parentJoint != N_JOINTS:
        raise DynamicParameterError(f"frame {FLANGE_FRAME!r} hangs on joint {flange.parentJoint}, expected 6")
    return ChainStructure(
        rotations=tuple(_clean(model.jointPlacements[j].rotation) for j in range(1, 7)),
        translations=tuple(_clean(model.jointPlacements[j].translation) for j in range(1, 7)),
        axes=tuple(axes),
        parents=tuple(int(model.parents[j]) - 1 for j in range(1, 7)),
        gravity=_clean(model.gravity.linear),
        flange_rotation=_clean(flange.placement.rotation),
        flange_translation=_clean(flange.placement.translation),
        coulomb_smoothing_velocity=parameters.coulomb_smoothing_velocity,
    )


def _joint_axis(model: pin.Model, j: int) -> np.ndarray:
    name = model.joints[j].shortname()
    unit = {"JointModelRX": 0, "JointModelRY": 1, "JointModelRZ": 2}
    if name in unit:
        axis = np.zeros(3)
        axis[unit[name]] = 1.0
        return axis
    if name == "JointModelRevoluteUnaligned":
        axis = np.asarray(model.joints[j].extract().axis, dtype=float)
        return axis / np.linalg.norm(axis)
    raise DynamicParameterError(f"joint {model.names[j]!r} is a {name}, expected a revolute joint")


def _clean(array: np.ndarray, tol: float = 1e-15) -> np.ndarray:
    """Copy with round-off entries set to exact 0, +1 or -1 so SX drops them structurally."""
    out = np.array(array, dtype=float, copy=True)
    for target in (0.0, 1.0, -1.0):
        out[np.abs(out - target) < tol] = target
    return out


# ----------------------------------------------------------------------------------
# Link inertias from the parameter vector, payload folded into link 6
# ----------------------------------------------------------------------------------

@dataclass
class _Body:
    mass: Any
    h: list  # first moment m*c, kg m
    inertia: list  # 3x3 about the frame origin, kg m^2

    def momentum(self, lin: Sequence, ang: Sequence) -> tuple[list, list]:
        """Spatial inertia times a motion (lin, ang): (m v + w x h, I w + h x v)."""
        force = sp.add(sp.scale(self.mass, lin), sp.cross(ang, self.h))
        torque = sp.add(sp.matvec(self.inertia, ang), sp.cross(self.h, lin))
        return force, torque

    def matrix(self) -> list:
        """The 6x6 spatial inertia [[m 1, -[h]x], [[h]x, I]] as nested lists."""
        hx = sp.skew(self.h)
        top = [[self.mass if r == c else 0.0 for c in range(3)] + [sp.neg(hx[r][c]) for c in range(3)] for r in range(3)]
        bottom = [[hx[r][c] for c in range(3)] + [self.inertia[r][c] for c in range(3)] for r in range(3)]
        return top + bottom


def _bodies(structure: ChainStructure, p: Expr, payload: Expr) -> list[_Body]:
    bodies = []
    for i in range(N_JOINTS):
        m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = (p[10 * i + k] for k in range(10))
        bodies.append(_Body(m, [hx, hy, hz], [[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]))
    mass = payload[0]
    com_tool = [payload[1], payload[2], payload[3]]
    com = sp.add(sp.matvec(sp.numeric(structure.flange_rotation), com_tool), sp.numeric(structure.flange_translation))
    h = sp.scale(mass, com)  # payload first moment in the joint-6 frame
    squared = sp.dot(com, com)
    last = bodies[-1]
    last.mass = sp.plus(last.mass, mass)
    last.h = sp.add(last.h, h)
    last.inertia = [[sp.plus(last.inertia[r][c],
                           sp.plus(sp.times(mass, squared) if r == c else 0.0, sp.neg(sp.times(h[r], com[c]))))
                     for c in range(3)] for r in range(3)]
    return bodies


def _friction(structure: ChainStructure, p: Expr, qd: Expr) -> list:
    fv, fc = p[VISCOUS_SLICE], p[COULOMB_SLICE]
    v_s = structure.coulomb_smoothing_velocity
    return [fv[i] * qd[i] + fc[i] * ca.tanh(qd[i] / v_s) for i in range(N_JOINTS)]


def _joint_transforms(structure: ChainStructure, q: Expr) -> list[tuple[list, list]]:
    """(R, t) of each joint frame in its parent frame at configuration q."""
    out = []
    for i in range(N_JOINTS):
        rot_q = sp.axis_rotation(structure.axes[i], ca.cos(q[i]), ca.sin(q[i]))
        out.append((sp.matmul(sp.numeric(structure.rotations[i]), rot_q), sp.numeric(structure.translations[i])))
    return out


def _link_velocities(structure: ChainStructure, transforms: list[tuple[list, list]], qd: Expr) -> list[tuple]:
    """Forward pass: (v, w, joint_rate) of each link in its own frame (m/s, rad/s).

    ``joint_rate`` is ``qd_i`` times the joint axis, the part of ``w`` the joint itself adds.
    """
    out: list[tuple] = []
    for i in range(N_JOINTS):
        rot, t = transforms[i]
        parent = structure.parents[i]
        v_p, w_p = out[parent][:2] if parent >= 0 else ([0.0] * 3, [0.0] * 3)
        v, w = sp.motion_to_child(rot, t, v_p, w_p)
        joint_rate = sp.scale(qd[i], sp.numeric(structure.axes[i]))
        out.append((v, sp.add(w, joint_rate), joint_rate))
    return out


# ----------------------------------------------------------------------------------
# Recursive Newton-Euler: inverse dynamics
# ----------------------------------------------------------------------------------

def inverse_dynamics_expression(structure: ChainStructure, q: Expr, qd: Expr, qdd: Expr, p: Expr,
                                payload: Expr, include_gravity: bool = True,
                                include_friction: bool = True, include_rotor: bool = True) -> list:
    """RNEA: the 6 joint torques (N m) as a list of scalar expressions."""
    bodies = _bodies(structure, p, payload)
    transforms = _joint_transforms(structure, q)
    base_acc = sp.scale(-1.0, sp.numeric(structure.gravity)) if include_gravity else [0.0] * 3
    velocities = _link_velocities(structure, transforms, qd)
    acc: list = []
    forces: list = []
    for i in range(N_JOINTS):
        rot, t = transforms[i]
        axis = sp.numeric(structure.axes[i])
        parent = structure.parents[i]
        v, w, joint_rate = velocities[i]
        a_p, aw_p = acc[parent] if parent >= 0 else (base_acc, [0.0] * 3)
        a, aw = sp.motion_to_child(rot, t, a_p, aw_p)
        a = sp.add(a, sp.cross(v, joint_rate))
        aw = sp.add(sp.add(aw, sp.scale(qdd[i], axis)), sp.cross(w, joint_rate))
        acc.append((a, aw))
        body = bodies[i]
        f, n = body.momentum(a, aw)
        pl, pa = body.momentum(v, w)
        forces.append([sp.add(f, sp.cross(w, pl)), sp.add(sp.add(n, sp.cross(w, pa)), sp.cross(v, pl))])
    tau: list = [None] * N_JOINTS
    friction = _friction(structure, p, qd) if include_friction else [0.0] * N_JOINTS
    rotor = p[ROTOR_INERTIA_SLICE]
    for i in reversed(range(N_JOINTS)):
        f, n = forces[i]
        tau[i] = sp.plus(sp.dot(sp.numeric(structure.axes[i]), n), friction[i])
        if include_rotor:
            tau[i] = sp.plus(tau[i], rotor[i] * qdd[i])
        parent = structure.parents[i]
        if parent >= 0:
            rot, t = transforms[i]
            f_par, n_par = sp.force_to_parent(rot, t, f, n)
            forces[parent] = [sp.add(forces[parent][0], f_par), sp.add(forces[parent][1], n_par)]
    return tau


# ----------------------------------------------------------------------------------
# Articulated-body algorithm: forward dynamics
# ----------------------------------------------------------------------------------

def forward_dynamics_expression(structure: ChainStructure, q: Expr, qd: Expr, tau: Expr, p: Expr,
                                payload: Expr, include_friction: bool = True, include_rotor: bool = True) -> list:
    """ABA: the 6 joint accelerations (rad/s^2) as a list of scalar expressions.

    ``include_friction`` / ``include_rotor`` False: the friction and rotor-inertia entries of
    ``p`` are left out structurally (the link side of an elastic joint)."""
    bodies = _bodies(structure, p, payload)
    transforms = _joint_transforms(structure, q)
    friction = _friction(structure, p, qd) if include_friction else [0.0] * N_JOINTS
    rotor = p[ROTOR_INERTIA_SLICE] if include_rotor else [0.0] * N_JOINTS
    bias_acc: list = []
    art_inertia: list = []
    art_bias: list = []
    for i, (v, w, joint_rate) in enumerate(_link_velocities(structure, transforms, qd)):
        bias_acc.append(sp.cross(v, joint_rate) + sp.cross(w, joint_rate))
        body = bodies[i]
        pl, pa = body.momentum(v, w)
        art_inertia.append(body.matrix())
        art_bias.append(sp.cross(w, pl) + sp.add(sp.cross(w, pa), sp.cross(v, pl)))

    u_col: list = [None] * N_JOINTS
    d_inv: list = [None] * N_JOINTS
    u_torque: list = [None] * N_JOINTS
    for i in reversed(range(N_JOINTS)):
        s = sp.spatial_axis(structure.axes[i])
        inertia = art_inertia[i]
        u_col[i] = sp.mat6_vec(inertia, s)
        d_inv[i] = 1.0 / sp.plus(sp.dot(s, u_col[i]), rotor[i])
        u_torque[i] = tau[i] - friction[i] - sp.dot(s, art_bias[i])
        parent = structure.parents[i]
        if parent < 0:
            continue
        scaled_col = sp.scale(d_inv[i], u_col[i])
        reduced: list = [[0.0] * 6 for _ in range(6)]
        for r in range(6):
            for c in range(r, 6):
                reduced[r][c] = reduced[c][r] = sp.plus(inertia[r][c], sp.neg(sp.times(scaled_col[r], u_col[i][c])))
        bias = sp.add(sp.add(art_bias[i], sp.mat6_vec(reduced, bias_acc[i])), sp.scale(u_torque[i], scaled_col))
        rot, t = transforms[i]
        moved = sp.congruence(rot, t, reduced)
        art_inertia[parent] = [[sp.plus(art_inertia[parent][r][c], moved[r][c]) for c in range(6)] for r in range(6)]
        art_bias[parent] = sp.add(art_bias[parent], sp.force_to_parent6(rot, t, bias))

    base_acc = sp.scale(-1.0, sp.numeric(structure.gravity)) + [0.0] * 3
    acc: list = [None] * N_JOINTS
    qdd: list = [None] * N_JOINTS
    for i in range(N_JOINTS):
        rot, t = transforms[i]
        parent = structure.parents[i]
        a_par = acc[parent] if parent >= 0 else base_acc
        lin, ang = sp.motion_to_child(rot, t, a_par[:3], a_par[3:])
        a = sp.add(lin + ang, bias_acc[i])
        qdd[i] = sp.times(sp.plus(u_torque[i], sp.neg(sp.dot(u_col[i], a))), d_inv[i])
        acc[i] = sp.add(a, sp.scale(qdd[i], sp.spatial_axis(structure.axes[i])))
    return qdd


# ----------------------------------------------------------------------------------
# Composite-rigid-body algorithm: mass matrix
# ----------------------------------------------------------------------------------

def mass_matrix_expression(structure: ChainStructure, q: Expr, p: Expr, payload: Expr) -> list:
    """CRBA: M(q) (kg m^2, rotor inertia on the diagonal) as a 6x6 nested list."""
    bodies = _bodies(structure, p, payload)
    transforms = _joint_transforms(structure, q)
    composite = [body.matrix() for body in bodies]
    rotor = p[ROTOR_INERTIA_SLICE]
    mass: list = [[0.0] * N_JOINTS for _ in range(N_JOINTS)]
    for i in reversed(range(N_JOINTS)):
        force = sp.mat6_vec(composite[i], sp.spatial_axis(structure.axes[i]))
        mass[i][i] = sp.plus(sp.dot(sp.spatial_axis(structure.axes[i]), force), rotor[i])
        j = i
        while structure.parents[j] >= 0:
            force = sp.force_to_parent6(*transforms[j], force)
            j = structure.parents[j]
            mass[i][j] = mass[j][i] = sp.dot(sp.spatial_axis(structure.axes[j]), force)
        parent = structure.parents[i]
        if parent >= 0:
            moved = sp.congruence(*transforms[i], composite[i])
            composite[parent] = [[sp.plus(composite[parent][r][c], moved[r][c]) for c in range(6)] for r in range(6)]
    return mass


# ----------------------------------------------------------------------------------
# casadi.Function objects with fixed names and I/O
# ----------------------------------------------------------------------------------

def _symbols(*names_sizes: tuple[str, int]) -> list:
    return [ca.SX.sym(name, size) for name, size in names_sizes]


def _column(items: list) -> ca.SX:
    return ca.vertcat(*[ca.SX(x) if isinstance(x, (float, int)) else x for x in items])


def _matrix(rows: list) -> ca.SX:
    return ca.vertcat(*[ca.horzcat(*[ca.SX(x) if isinstance(x, (float, int)) else x for x in row]) for row in rows])


def _structure_or_default(model: pin.Model | None, parameters: RobotParameters | None) -> ChainStructure:
    if model is None and parameters is None:
        return _default_structure()
    return chain_structure(model, parameters)


@lru_cache(maxsize=1)
def _default_structure() -> ChainStructure:
    return chain_structure()


def forward_dynamics_function(model: pin.Model | None = None,
                              parameters: RobotParameters | None = None) -> ca.Function:
    """``rx130l_fd(q, qd, tau, p, payload) -> qdd`` (SX, ABA), see the module docstring."""
    if model is None and parameters is None:
        return _default_forward_dynamics()
    return _build_forward_dynamics(chain_structure(model, parameters))


def inverse_dynamics_function(model: pin.Model | None = None,
                              parameters: RobotParameters | None = None) -> ca.Function:
    """``rx130l_id(q, qd, qdd, p, payload) -> tau`` (SX, RNEA), see the module docstring."""
    if model is None and parameters is None:
        return _default_inverse_dynamics()
    return _build_inverse_dynamics(chain_structure(model, parameters))


def mass_matrix_function(model: pin.Model | None = None,
                         parameters: RobotParameters | None = None) -> ca.Function:
    """``rx130l_mass_matrix(q, p, payload) -> M`` (SX, CRBA, rotor inertia included)."""
    structure = _structure_or_default(model, parameters)
    q, p, payload = _symbols(("q", N_JOINTS), ("p", N_PARAMETERS), ("payload", 4))
    mass = _matrix(mass_matrix_expression(structure, q, p, payload))
    return ca.Function(MASS_MATRIX_NAME, [q, p, payload], [mass], ["q", "p", "payload"], ["M"],
                       _FUNCTION_OPTIONS)


def bias_function(model: pin.Model | None = None, parameters: RobotParameters | None = None) -> ca.Function:
    """``rx130l_bias(q, qd, p, payload) -> C(q, qd) qd + g(q) + friction(qd)`` (N m)."""
    structure = _structure_or_default(model, parameters)
    q, qd, p, payload = _symbols(("q", N_JOINTS), ("qd", N_JOINTS), ("p", N_PARAMETERS), ("payload", 4))
    zeros = [0.0] * N_JOINTS
    bias = _column(inverse_dynamics_expression(structure, q, qd, zeros, p, payload))
    return ca.Function(BIAS_NAME, [q, qd, p, payload], [bias], ["q", "qd", "p", "payload"], ["bias"],
                       _FUNCTION_OPTIONS)


def gravity_function(model: pin.Model | None = None, parameters: RobotParameters | None = None) -> ca.Function:
    """``rx130l_gravity(q, p, payload) -> g(q)`` (N m)."""
    structure = _structure_or_default(model, parameters)
    q, p, payload = _symbols(("q", N_JOINTS), ("p", N_PARAMETERS), ("payload", 4))
    zeros = [0.0] * N_JOINTS
    gravity = _column(inverse_dynamics_expression(structure, q, zeros, zeros, p, payload, include_friction=False))
    return ca.Function(GRAVITY_NAME, [q, p, payload], [gravity], ["q", "p", "payload"], ["g"], _FUNCTION_OPTIONS)


@lru_cache(maxsize=1)
def _default_forward_dynamics() -> ca.Function:
    return _build_forward_dynamics(_default_structure())


@lru_cache(maxsize=1)
def _default_inverse_dynamics() -> ca.Function:
    return _build_inverse_dynamics(_default_structure())


def _build_forward_dynamics(structure: ChainStructure) -> ca.Function:
    q, qd, tau, p, payload = _symbols(("q", N_JOINTS), ("qd", N_JOINTS), ("tau", N_JOINTS),
                                      ("p", N_PARAMETERS), ("payload", 4))
    qdd = _column(forward_dynamics_expression(structure, q, qd, tau, p, payload))
    return ca.Function(FORWARD_DYNAMICS_NAME, [q, qd, tau, p, payload], [qdd],
                       ["q", "qd", "tau", "p", "payload"], ["qdd"], _FUNCTION_OPTIONS)


def _build_inverse_dynamics(structure: ChainStructure) -> ca.Function:
    q, qd, qdd, p, payload = _symbols(("q", N_JOINTS), ("qd", N_JOINTS), ("qdd", N_JOINTS),
                                      ("p", N_PARAMETERS), ("payload", 4))
    tau = _column(inverse_dynamics_expression(structure, q, qd, qdd, p, payload))
    return ca.Function(INVERSE_DYNAMICS_NAME, [q, qd, qdd, p, payload], [tau],
                       ["q", "qd", "qdd", "p", "payload"], ["tau"], _FUNCTION_OPTIONS)


# ----------------------------------------------------------------------------------
# Geometry as an input: the true robot's kinematic errors in the plant's dynamics
# ----------------------------------------------------------------------------------

N_GEOMETRIC_ERRORS = 39
"""Length of the error vector of :mod:`robot.geometric_errors` (m and rad)."""
N_PLACEMENTS = 12 * (N_JOINTS + 1)
"""Length of the placement vector: per joint 1..6 then the flange (``tool0`` in link 6), the
rotation row by row (9) and the translation (3, m): ``x_parent = R x_child + t``."""


def placements_expression(structure: ChainStructure, errors: Expr) -> list:
    """The joint and flange placements (:data:`N_PLACEMENTS` scalars) with the 39 geometric
    errors ``errors`` folded in exactly as :meth:`robot.geometric_errors.GeometricErrorModel.
    joint_placements` folds them: joint i is ``(R_nom Rot(u, tilt_u) [Rot(v, tilt_v)] Rot(axis,
    offset_i), t_nom + dt_i)`` (``dt`` = ``base`` for joint 1, ``len_i`` otherwise), the flange
    ``(R_f Rot(x, flange_rx) Rot(y, flange_ry), t_f + flange)``. The tilt axes of each joint are
    read from the error model's parameter names (``tilt<i>_<axis>``)."""
    from robot.geometric_errors import ERROR_PARAMETER_NAMES

    index = {name: k for k, name in enumerate(ERROR_PARAMETER_NAMES)}
    unit = np.eye(3)

    def turn(rot: list, axis: np.ndarray, angle: Expr) -> list:
        return sp.matmul(rot, sp.axis_rotation(axis, ca.cos(angle), ca.sin(angle)))

    out: list = []
    for i in range(N_JOINTS):
        rot = sp.numeric(structure.rotations[i])
        tilts = [(name, k) for name, k in index.items() if name.startswith(f"tilt{i + 1}_")]
        for name, k in tilts:  # in parameter order: first u, then v
            rot = turn(rot, unit["xyz".index(name[-1])], errors[k])
        rot = turn(rot, structure.axes[i], errors[index[f"offset{i + 1}"]])
        prefix = "base" if i == 0 else f"len{i + 1}"
        shift = [errors[index[f"{prefix}_{c}"]] for c in "xyz"]
        out += [x for row in rot for x in row] + sp.add(sp.numeric(structure.translations[i]), shift)
    rot = turn(turn(sp.numeric(structure.flange_rotation), unit[0], errors[index["flange_rx"]]),
               unit[1], errors[index["flange_ry"]])
    shift = [errors[index[f"flange_{c}"]] for c in "xyz"]
    out += [x for row in rot for x in row] + sp.add(sp.numeric(structure.flange_translation), shift)
    return out


def structure_with_placements(structure: ChainStructure, placements: Expr) -> ChainStructure:
    """``structure`` with its joint and flange placements taken from ``placements``
    (:data:`N_PLACEMENTS` scalars, e.g. an SX input): the axes, parents, gravity and
    smoothing velocity stay. The algorithms above accept it like a numeric structure."""
    def rotation(k: int) -> list:
        return [[placements[k + 3 * r + c] for c in range(3)] for r in range(3)]

    def translation(k: int) -> list:
        return [placements[k + 9 + c] for c in range(3)]

    return dataclasses.replace(
        structure, rotations=tuple(rotation(12 * i) for i in range(N_JOINTS)),
        translations=tuple(translation(12 * i) for i in range(N_JOINTS)),
        flange_rotation=rotation(12 * N_JOINTS), flange_translation=translation(12 * N_JOINTS))


def placements_function(model: pin.Model | None = None, parameters: RobotParameters | None = None,
                        name: str = "rx130l_placements") -> ca.Function:
    """``name(errors[39]) -> placements[84]``: :func:`placements_expression` on the nominal
    structure (numeric, e.g. ``placements_function()(errors)``, or generated to C)."""
    structure = _structure_or_default(model, parameters)
    errors = ca.SX.sym("errors", N_GEOMETRIC_ERRORS)
    return ca.Function(name, [errors], [_column(placements_expression(structure, errors))], ["errors"],
                       ["placements"], _FUNCTION_OPTIONS)


def forward_dynamics_placements_function(name: str = "rx130l_fd_placements", *, link_only: bool = False,
                                         model: pin.Model | None = None,
                                         parameters: RobotParameters | None = None) -> ca.Function:
    """``name(q, qd, tau, p, payload, placements) -> qdd``: the ABA of :func:`forward_dynamics_function`
    with the joint and flange placements as the input ``placements`` (:data:`N_PLACEMENTS`, e.g.
    :func:`placements_function` of a true robot's geometric errors) instead of constants.
    ``link_only``: without rotor inertia and friction (the link side of an elastic joint).

    Cost: the constant placements of the nominal arm are signed permutations that cost nothing;
    general ones turn them into full 3x3 products (``benchmarks/bench_dynamics.py`` prints both)."""
    placements = ca.SX.sym("placements", N_PLACEMENTS)
    structure = structure_with_placements(_structure_or_default(model, parameters), placements)
    q, qd, tau, p, payload = _symbols(("q", N_JOINTS), ("qd", N_JOINTS), ("tau", N_JOINTS),
                                      ("p", N_PARAMETERS), ("payload", 4))
    qdd = _column(forward_dynamics_expression(structure, q, qd, tau, p, payload, include_friction=not link_only,
                                              include_rotor=not link_only))
    return ca.Function(name, [q, qd, tau, p, payload, placements], [qdd],
                       ["q", "qd", "tau", "p", "payload", "placements"], ["qdd"], _FUNCTION_OPTIONS)


# ----------------------------------------------------------------------------------
# Numeric-parameter inverse dynamics for the planners
# ----------------------------------------------------------------------------------

def numeric_inverse_dynamics_function(parameter_vector: ArrayLike | None = None,
                                      payload: ArrayLike | None = None, *,
                                      model: pin.Model | None = None,
                                      parameters: RobotParameters | None = None,
                                      name: str = "rx130l_id_numeric") -> ca.Function:
    """``name(q, qd, qdd) -> tau`` with the parameters baked in as constants (SX).

    Defaults: the nominal parameter vector and the parameter file's payload. Call the
    function on SX or MX symbols to get an expression for an optimal control problem.
    """
    structure = _structure_or_default(model, parameters)
    parameters = parameters or load_parameters()
    p = _numeric_parameters(parameter_vector, model, parameters)
    load = _numeric_payload(parameters.payload if payload is None else payload)
    q, qd, qdd = _symbols(("q", N_JOINTS), ("qd", N_JOINTS), ("qdd", N_JOINTS))
    tau = _column(inverse_dynamics_expression(structure, q, qd, qdd, p, load))
    return ca.Function(name, [q, qd, qdd], [tau], ["q", "qd", "qdd"], ["tau"], _FUNCTION_OPTIONS)


def inverse_dynamics_symbolic(q: Expr, qd: Expr, qdd: Expr, parameter_vector: ArrayLike | None = None,
                              payload: ArrayLike | None = None) -> Expr:
    """tau(q, qd, qdd) for SX or MX symbols (6x1 each) with numeric (default nominal) parameters."""
    return numeric_inverse_dynamics_function(parameter_vector, payload)(q, qd, qdd)


def _numeric_parameters(parameter_vector: ArrayLike | None, model: pin.Model | None,
                        parameters: RobotParameters) -> list:
    p = nominal_parameter_vector(model, parameters) if parameter_vector is None else np.asarray(
        parameter_vector, dtype=float)
    if p.shape != (N_PARAMETERS,) or not np.all(np.isfinite(p)):
        raise DynamicParameterError(f"parameter_vector has shape {p.shape}, expected {N_PARAMETERS} finite numbers")
    return [float(x) for x in p]


def _numeric_payload(payload: ArrayLike) -> list:
    load = np.asarray(payload, dtype=float)
    if load.shape != (4,) or not np.all(np.isfinite(load)) or load[0] < 0:
        raise DynamicParameterError(f"payload = {payload!r}, expected [mass >= 0 kg, cx, cy, cz m in tool0]")
    return [float(x) for x in load]
