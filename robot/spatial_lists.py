"""Spatial algebra on plain lists of scalars, for building lean CasADi SX expressions.

Vectors are lists of 3 (or 6) scalars and matrices nested lists, each entry a CasADi
SX/MX scalar or a Python float. Python floats 0 and 1 are dropped structurally
(``x * 0``, ``x * 1``, ``x + 0`` are never formed), so the constant structure of the
arm (unit joint axes, identity placements, zero offsets) costs no operations.

Conventions are pinocchio's: spatial motion ``(linear, angular)`` and force
``(force, torque)`` in the local frame; a placement ``(R, t)`` maps child to parent
coordinates ``x_parent = R x_child + t``.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np


def add(a: Sequence, b: Sequence) -> list:
    """Element-wise sum of two vectors."""
    return [plus(x, y) for x, y in zip(a, b)]


def plus(x: Any, y: Any) -> Any:
    """x + y, skipping a Python zero."""
    if is_zero(x):
        return y
    if is_zero(y):
        return x
    return x + y


def times(x: Any, y: Any) -> Any:
    """x * y, skipping Python zeros and ones."""
    if is_zero(x) or is_zero(y):
        return 0.0
    if is_one(x):
        return y
    if is_one(y):
        return x
    return x * y


def is_zero(x: Any) -> bool:
    """True for a Python number equal to 0."""
    return isinstance(x, (float, int)) and x == 0


def is_one(x: Any) -> bool:
    """True for a Python number equal to 1."""
    return isinstance(x, (float, int)) and x == 1


def dot(a: Sequence, b: Sequence) -> Any:
    """Scalar product."""
    total: Any = 0.0
    for x, y in zip(a, b):
        total = plus(total, times(x, y))
    return total


def cross(a: Sequence, b: Sequence) -> list:
    """Cross product of two 3-vectors."""
    return [
        plus(times(a[1], b[2]), neg(times(a[2], b[1]))),
        plus(times(a[2], b[0]), neg(times(a[0], b[2]))),
        plus(times(a[0], b[1]), neg(times(a[1], b[0]))),
    ]


def neg(x: Any) -> Any:
    """-x, keeping a Python zero."""
    return 0.0 if is_zero(x) else -x


def scale(s: Any, a: Sequence) -> list:
    """Scalar times vector."""
    return [times(s, x) for x in a]


def matvec(m: Sequence[Sequence], a: Sequence) -> list:
    """Matrix (3x3) times vector."""
    return [dot(row, a) for row in m]


def matTvec(m: Sequence[Sequence], a: Sequence) -> list:
    """Transposed matrix (3x3) times vector."""
    return [dot([m[r][c] for r in range(3)], a) for c in range(3)]


def matmul(a: Sequence[Sequence], b: Sequence[Sequence]) -> list:
    """Product of two 3x3 matrices."""
    return [[dot(a[r], [b[k][c] for k in range(3)]) for c in range(3)] for r in range(3)]


def numeric(matrix: np.ndarray | list) -> list:
    """A numpy vector or matrix as (nested) lists of Python floats; a (nested) list, e.g. of
    symbolic entries (a placement that is an input of the function), is returned as it is."""
    if isinstance(matrix, list):
        return matrix
    return [[float(x) for x in row] for row in matrix] if matrix.ndim == 2 else [float(x) for x in matrix]


def axis_rotation(axis: np.ndarray, c: Any, s: Any) -> list:
    """Rotation matrix about a unit ``axis`` (numeric) by an angle with cosine c, sine s."""
    k = int(np.argmax(np.abs(axis)))
    if abs(abs(axis[k]) - 1.0) < 1e-15:  # a (signed) unit axis: exact, no (1 - c) terms
        sign = float(np.sign(axis[k]))
        i, j = (k + 1) % 3, (k + 2) % 3
        rot: list = [[0.0] * 3 for _ in range(3)]
        rot[k][k] = 1.0
        rot[i][i], rot[j][j] = c, c
        rot[j][i], rot[i][j] = times(sign, s), neg(times(sign, s))
        return rot
    a = [float(x) for x in axis]
    one_minus_c = 1.0 - c
    axis_cross = [[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]]
    return [[plus(plus(c if r == col else 0.0, times(s, axis_cross[r][col])), times(one_minus_c, a[r] * a[col]))
             for col in range(3)] for r in range(3)]


def skew(a: Sequence) -> list:
    """The 3x3 cross-product matrix [a]x."""
    return [[0.0, neg(a[2]), a[1]], [a[2], 0.0, neg(a[0])], [neg(a[1]), a[0], 0.0]]


def motion_to_child(rot: list, t: list, lin: Sequence, ang: Sequence) -> tuple[list, list]:
    """Motion (lin, ang) of the parent frame expressed in the child frame."""
    return matTvec(rot, add(lin, cross(ang, t))), matTvec(rot, ang)


def force_to_parent(rot: list, t: list, force: Sequence, torque: Sequence) -> tuple[list, list]:
    """Force (force, torque) on the child frame expressed in the parent frame."""
    f_parent = matvec(rot, force)
    return f_parent, add(matvec(rot, torque), cross(t, f_parent))


def rotate_block(rot: list, block: list, symmetric: bool) -> list:
    """R B R^T of a 3x3 block (only the upper triangle is computed when symmetric)."""
    left = matmul(rot, block)
    out: list = [[0.0] * 3 for _ in range(3)]
    for r in range(3):
        for c in range(r if symmetric else 0, 3):
            out[r][c] = dot(left[r], rot[c])
            if symmetric:
                out[c][r] = out[r][c]
    return out


def congruence(rot: list, t: list, inertia: list) -> list:
    """X* I X*^T: a symmetric 6x6 inertia moved from the child to the parent frame.

    X* = [[1, 0], [T, 1]] [[R, 0], [0, R]] with T = [t]x: rotate the three 3x3 blocks,
    then shift by t, so the symbolic rotation and the constant offset never multiply.
    """
    a = rotate_block(rot, [row[:3] for row in inertia[:3]], True)
    b = rotate_block(rot, [row[3:] for row in inertia[:3]], False)
    c = rotate_block(rot, [row[3:] for row in inertia[3:]], True)
    shift = skew(t)
    ta = matmul(shift, a)  # T A
    top_right = [[plus(b[r][k], ta[k][r]) for k in range(3)] for r in range(3)]  # B + A T^T = B + (T A)^T
    tb = matmul(shift, top_right)  # T (B + A T^T)
    bottom_right: list = [[0.0] * 3 for _ in range(3)]
    for r in range(3):
        for k in range(r, 3):
            # T A T^T + T B + B^T T^T + C = T (B + A T^T) + (T B)^T + C
            tb_only = dot(shift[k], [b[j][r] for j in range(3)])  # (T B)[k][r]
            bottom_right[r][k] = bottom_right[k][r] = plus(plus(tb[r][k], tb_only), c[r][k])
    out = [a[r] + top_right[r] for r in range(3)]
    out += [[top_right[k][r] for k in range(3)] + bottom_right[r] for r in range(3)]
    return out


def force_to_parent6(rot: list, t: list, force: list) -> list:
    """A spatial force (6 entries) on the child frame expressed in the parent frame."""
    f, n = force_to_parent(rot, t, force[:3], force[3:])
    return f + n


def mat6_vec(m: list, v: Sequence) -> list:
    """Matrix (rows of any length) times vector."""
    return [dot(row, v) for row in m]


def spatial_axis(axis: np.ndarray) -> list:
    """Motion subspace (linear, angular) of a revolute joint about ``axis``."""
    return [0.0, 0.0, 0.0] + [float(x) for x in axis]
