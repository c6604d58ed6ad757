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

from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Sequence

import casadi as ca
import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike

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
# 3-vector helpers: every vector is a list of 3 scalars (SX/MX elements or floats), so
# that numeric zeros and ones of the structure vanish from the expression graph.
# ----------------------------------------------------------------------------------

def _add(a: Sequence, b: Sequence) -> list:
    return [_plus(x, y) for x, y in zip(a, b)]


def _plus(x: Any, y: Any) -> Any:
    if _is_zero(x):
        return y
    if _is_zero(y):
        return x
    return x + y


def _times(x: Any, y: Any) -> Any:
    if _is_zero(x) or _is_zero(y):
        return 0.0
    if _is_one(x):
        return y
    if _is_one(y):
        return x
    return x * y


def _is_zero(x: Any) -> bool:
    return isinstance(x, (float, int)) and x == 0


def _is_one(x: Any) -> bool:
    return isinstance(x, (float, int)) and x == 1


def _dot(a: Sequence, b: Sequence) -> Any:
    total: Any = 0.0
    for x, y in zip(a, b):
        total = _plus(total, _times(x, y))
    return total


def _cross(a: Sequence, b: Sequence) -> list:
    return [
        _plus(_times(a[1], b[2]), _neg(_times(a[2], b[1]))),
        _plus(_times(a[2], b[0]), _neg(_times(a[0], b[2]))),
        _plus(_times(a[0], b[1]), _neg(_times(a[1], b[0]))),
    ]


def _neg(x: Any) -> Any:
    return 0.0 if _is_zero(x) else -x


def _scale(s: Any, a: Sequence) -> list:
    return [_times(s, x) for x in a]


def _matvec(m: Sequence[Sequence], a: Sequence) -> list:
    return [_dot(row, a) for row in m]


def _matTvec(m: Sequence[Sequence], a: Sequence) -> list:
    return [_dot([m[r][c] for r in range(3)], a) for c in range(3)]


def _matmul(a: Sequence[Sequence], b: Sequence[Sequence]) -> list:
    return [[_dot(a[r], [b[k][c] for k in range(3)]) for c in range(3)] for r in range(3)]


def _numeric(matrix: np.ndarray) -> list:
    return [[float(x) for x in row] for row in matrix] if matrix.ndim == 2 else [float(x) for x in matrix]


def _axis_rotation(axis: np.ndarray, c: Any, s: Any) -> list:
    """Rotation matrix about a unit ``axis`` (numeric) by an angle with cosine c, sine s."""
    k = int(np.argmax(np.abs(axis)))
    if abs(abs(axis[k]) - 1.0) < 1e-15:  # a (signed) unit axis: exact, no (1 - c) terms
        sign = float(np.sign(axis[k]))
        i, j = (k + 1) % 3, (k + 2) % 3
        rot: list = [[0.0] * 3 for _ in range(3)]
        rot[k][k] = 1.0
        rot[i][i], rot[j][j] = c, c
        rot[j][i], rot[i][j] = _times(sign, s), _neg(_times(sign, s))
        return rot
    a = [float(x) for x in axis]
    one_minus_c = 1.0 - c
    skew = [[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]]
    return [[_plus(_plus(c if r == col else 0.0, _times(s, skew[r][col])), _times(one_minus_c, a[r] * a[col]))
             for col in range(3)] for r in range(3)]


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
        force = _add(_scale(self.mass, lin), _cross(ang, self.h))
        torque = _add(_matvec(self.inertia, ang), _cross(self.h, lin))
        return force, torque

    def matrix(self) -> list:
        """The 6x6 spatial inertia [[m 1, -[h]x], [[h]x, I]] as nested lists."""
        hx = _skew(self.h)
        top = [[self.mass if r == c else 0.0 for c in range(3)] + [_neg(hx[r][c]) for c in range(3)] for r in range(3)]
        bottom = [[hx[r][c] for c in range(3)] + [self.inertia[r][c] for c in range(3)] for r in range(3)]
        return top + bottom


def _skew(a: Sequence) -> list:
    return [[0.0, _neg(a[2]), a[1]], [a[2], 0.0, _neg(a[0])], [_neg(a[1]), a[0], 0.0]]


def _bodies(structure: ChainStructure, p: Expr, payload: Expr) -> list[_Body]:
    bodies = []
    for i in range(N_JOINTS):
        m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = (p[10 * i + k] for k in range(10))
        bodies.append(_Body(m, [hx, hy, hz], [[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]))
    mass = payload[0]
    com_tool = [payload[1], payload[2], payload[3]]
    com = _add(_matvec(_numeric(structure.flange_rotation), com_tool), _numeric(structure.flange_translation))
    h = _scale(mass, com)  # payload first moment in the joint-6 frame
    squared = _dot(com, com)
    last = bodies[-1]
    last.mass = _plus(last.mass, mass)
    last.h = _add(last.h, h)
    last.inertia = [[_plus(last.inertia[r][c],
                           _plus(_times(mass, squared) if r == c else 0.0, _neg(_times(h[r], com[c]))))
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
        rot_q = _axis_rotation(structure.axes[i], ca.cos(q[i]), ca.sin(q[i]))
        out.append((_matmul(_numeric(structure.rotations[i]), rot_q), _numeric(structure.translations[i])))
    return out


def _motion_to_child(rot: list, t: list, lin: Sequence, ang: Sequence) -> tuple[list, list]:
    """Motion (lin, ang) of the parent frame expressed in the child frame."""
    return _matTvec(rot, _add(lin, _cross(ang, t))), _matTvec(rot, ang)


def _force_to_parent(rot: list, t: list, force: Sequence, torque: Sequence) -> tuple[list, list]:
    """Force (force, torque) on the child frame expressed in the parent frame."""
    f_parent = _matvec(rot, force)
    return f_parent, _add(_matvec(rot, torque), _cross(t, f_parent))


# ----------------------------------------------------------------------------------
# Recursive Newton-Euler: inverse dynamics
# ----------------------------------------------------------------------------------

def inverse_dynamics_expression(structure: ChainStructure, q: Expr, qd: Expr, qdd: Expr, p: Expr,
                                payload: Expr, include_gravity: bool = True,
                                include_friction: bool = True, include_rotor: bool = True) -> list:
    """RNEA: the 6 joint torques (N m) as a list of scalar expressions."""
    bodies = _bodies(structure, p, payload)
    transforms = _joint_transforms(structure, q)
    base_acc = _scale(-1.0, _numeric(structure.gravity)) if include_gravity else [0.0] * 3
    vel: list = []
    acc: list = []
    forces: list = []
    for i in range(N_JOINTS):
        rot, t = transforms[i]
        axis = _numeric(structure.axes[i])
        parent = structure.parents[i]
        v_p, w_p = vel[parent] if parent >= 0 else ([0.0] * 3, [0.0] * 3)
        a_p, aw_p = acc[parent] if parent >= 0 else (base_acc, [0.0] * 3)
        v, w = _motion_to_child(rot, t, v_p, w_p)
        joint_rate = _scale(qd[i], axis)
        w = _add(w, joint_rate)
        a, aw = _motion_to_child(rot, t, a_p, aw_p)
        a = _add(a, _cross(v, joint_rate))
        aw = _add(_add(aw, _scale(qdd[i], axis)), _cross(w, joint_rate))
        vel.append((v, w))
        acc.append((a, aw))
        body = bodies[i]
        f, n = body.momentum(a, aw)
        pl, pa = body.momentum(v, w)
        forces.append([_add(f, _cross(w, pl)), _add(_add(n, _cross(w, pa)), _cross(v, pl))])
    tau: list = [None] * N_JOINTS
    friction = _friction(structure, p, qd) if include_friction else [0.0] * N_JOINTS
    rotor = p[ROTOR_INERTIA_SLICE]
    for i in reversed(range(N_JOINTS)):
        f, n = forces[i]
        tau[i] = _plus(_dot(_numeric(structure.axes[i]), n), friction[i])
        if include_rotor:
            tau[i] = _plus(tau[i], rotor[i] * qdd[i])
        parent = structure.parents[i]
        if parent >= 0:
            rot, t = transforms[i]
            f_par, n_par = _force_to_parent(rot, t, f, n)
            forces[parent] = [_add(forces[parent][0], f_par), _add(forces[parent][1], n_par)]
    return tau


# ----------------------------------------------------------------------------------
# 6x6 spatial helpers for ABA and CRBA (nested lists of scalars)
# ----------------------------------------------------------------------------------

def _rotate_block(rot: list, block: list, symmetric: bool) -> list:
    """R B R^T of a 3x3 block (only the upper triangle is computed when symmetric)."""
    left = _matmul(rot, block)
    out: list = [[0.0] * 3 for _ in range(3)]
    for r in range(3):
        for c in range(r if symmetric else 0, 3):
            out[r][c] = _dot(left[r], rot[c])
            if symmetric:
                out[c][r] = out[r][c]
    return out


def _congruence(rot: list, t: list, inertia: list) -> list:
    """X* I X*^T: a symmetric 6x6 inertia moved from the child to the parent frame.

    X* = [[1, 0], [T, 1]] [[R, 0], [0, R]] with T = [t]x: rotate the three 3x3 blocks,
    then shift by t, so the symbolic rotation and the constant offset never multiply.
    """
    a = _rotate_block(rot, [row[:3] for row in inertia[:3]], True)
    b = _rotate_block(rot, [row[3:] for row in inertia[:3]], False)
    c = _rotate_block(rot, [row[3:] for row in inertia[3:]], True)
    skew = _skew(t)
    ta = _matmul(skew, a)  # T A
    top_right = [[_plus(b[r][k], ta[k][r]) for k in range(3)] for r in range(3)]  # B + A T^T = B + (T A)^T
    tb = _matmul(skew, top_right)  # T (B + A T^T)
    bottom_right: list = [[0.0] * 3 for _ in range(3)]
    for r in range(3):
        for k in range(r, 3):
            # T A T^T + T B + B^T T^T + C = T (B + A T^T) + (T B)^T + C
            tb_only = _dot(skew[k], [b[j][r] for j in range(3)])  # (T B)[k][r]
            bottom_right[r][k] = bottom_right[k][r] = _plus(_plus(tb[r][k], tb_only), c[r][k])
    out = [a[r] + top_right[r] for r in range(3)]
    out += [[top_right[k][r] for k in range(3)] + bottom_right[r] for r in range(3)]
    return out


def _force_to_parent6(rot: list, t: list, force: list) -> list:
    f, n = _force_to_parent(rot, t, force[:3], force[3:])
    return f + n


def _mat6_vec(m: list, v: Sequence) -> list:
    return [_dot(row, v) for row in m]


def _spatial_axis(axis: np.ndarray) -> list:
    return [0.0, 0.0, 0.0] + [float(x) for x in axis]


# ----------------------------------------------------------------------------------
# Articulated-body algorithm: forward dynamics
# ----------------------------------------------------------------------------------

def forward_dynamics_expression(structure: ChainStructure, q: Expr, qd: Expr, tau: Expr, p: Expr,
                                payload: Expr) -> list:
    """ABA: the 6 joint accelerations (rad/s^2) as a list of scalar expressions."""
    bodies = _bodies(structure, p, payload)
    transforms = _joint_transforms(structure, q)
    friction = _friction(structure, p, qd)
    rotor = p[ROTOR_INERTIA_SLICE]
    vel: list = []
    bias_acc: list = []
    art_inertia: list = []
    art_bias: list = []
    for i in range(N_JOINTS):
        rot, t = transforms[i]
        axis = _numeric(structure.axes[i])
        parent = structure.parents[i]
        v_p, w_p = vel[parent] if parent >= 0 else ([0.0] * 3, [0.0] * 3)
        v, w = _motion_to_child(rot, t, v_p, w_p)
        joint_rate = _scale(qd[i], axis)
        w = _add(w, joint_rate)
        vel.append((v, w))
        bias_acc.append(_cross(v, joint_rate) + _cross(w, joint_rate))
        body = bodies[i]
        pl, pa = body.momentum(v, w)
        art_inertia.append(body.matrix())
        art_bias.append(_cross(w, pl) + _add(_cross(w, pa), _cross(v, pl)))

    u_col: list = [None] * N_JOINTS
    d_inv: list = [None] * N_JOINTS
    u_torque: list = [None] * N_JOINTS
    for i in reversed(range(N_JOINTS)):
        s = _spatial_axis(structure.axes[i])
        inertia = art_inertia[i]
        u_col[i] = _mat6_vec(inertia, s)
        d_inv[i] = 1.0 / _plus(_dot(s, u_col[i]), rotor[i])
        u_torque[i] = tau[i] - friction[i] - _dot(s, art_bias[i])
        parent = structure.parents[i]
        if parent < 0:
            continue
        scaled_col = _scale(d_inv[i], u_col[i])
        reduced: list = [[0.0] * 6 for _ in range(6)]
        for r in range(6):
            for c in range(r, 6):
                reduced[r][c] = reduced[c][r] = _plus(inertia[r][c], _neg(_times(scaled_col[r], u_col[i][c])))
        bias = _add(_add(art_bias[i], _mat6_vec(reduced, bias_acc[i])), _scale(u_torque[i], scaled_col))
        rot, t = transforms[i]
        moved = _congruence(rot, t, reduced)
        art_inertia[parent] = [[_plus(art_inertia[parent][r][c], moved[r][c]) for c in range(6)] for r in range(6)]
        art_bias[parent] = _add(art_bias[parent], _force_to_parent6(rot, t, bias))

    base_acc = _scale(-1.0, _numeric(structure.gravity)) + [0.0] * 3
    acc: list = [None] * N_JOINTS
    qdd: list = [None] * N_JOINTS
    for i in range(N_JOINTS):
        rot, t = transforms[i]
        parent = structure.parents[i]
        a_par = acc[parent] if parent >= 0 else base_acc
        lin, ang = _motion_to_child(rot, t, a_par[:3], a_par[3:])
        a = _add(lin + ang, bias_acc[i])
        qdd[i] = _times(_plus(u_torque[i], _neg(_dot(u_col[i], a))), d_inv[i])
        acc[i] = _add(a, _scale(qdd[i], _spatial_axis(structure.axes[i])))
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
        force = _mat6_vec(composite[i], _spatial_axis(structure.axes[i]))
        mass[i][i] = _plus(_dot(_spatial_axis(structure.axes[i]), force), rotor[i])
        j = i
        while structure.parents[j] >= 0:
            force = _force_to_parent6(*transforms[j], force)
            j = structure.parents[j]
            mass[i][j] = mass[j][i] = _dot(_spatial_axis(structure.axes[j]), force)
        parent = structure.parents[i]
        if parent >= 0:
            moved = _congruence(*transforms[i], composite[i])
            composite[parent] = [[_plus(composite[parent][r][c], moved[r][c]) for c in range(6)] for r in range(6)]
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
