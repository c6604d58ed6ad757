"""CasADi functions the exciting-trajectory optimisation evaluates at every sample.

* the base regressor ``Theta_1(q, qd, qdd)`` (6 x n_base): the Jacobian of the
  symbolic RNEA of :mod:`robot.symbolic` with respect to the 78 parameters (the
  torques are linear in them, payload zero: the payload is part of link 6's
  parameters), restricted to the independent columns of a
  :class:`~identification.base_parameters.BaseParameters`;
* the reverse-mode product ``d/d(q, qd, qdd) sum(Theta_1 .* W)`` for a weight matrix
  ``W`` (6 x n_base), which turns the gradient of any function of the stacked
  regressor into a gradient in the joint states (one reverse sweep, no full Jacobian);
* the model torque ``tau(q, qd, qdd)`` of a numeric parameter vector and payload and
  its Jacobian (6 x 18), and the flange position ``r_E(q)`` in ``base_link`` (m) and
  its Jacobian (3 x 6), for the constraints of eq. 30.

Each is built once as SX and mapped over the samples of a period (``Function.map``),
so one Python call evaluates a whole period.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from identification.base_parameters import BaseParameters
from robot import spatial_lists as sp
from robot.dynamics import N_JOINTS, N_PARAMETERS
from robot.symbolic import ChainStructure, chain_structure, inverse_dynamics_expression

_OPTIONS = {"cse": True}


def flange_position_expression(structure: ChainStructure, q: ca.SX) -> ca.SX:
    """Position of ``tool0`` in ``base_link`` (m) as a 3x1 SX of the joint angles."""
    rot: list = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    pos: list = [0.0, 0.0, 0.0]
    for i in range(N_JOINTS):
        pos = sp.add(pos, sp.matvec(rot, sp.numeric(structure.translations[i])))
        turn = sp.axis_rotation(structure.axes[i], ca.cos(q[i]), ca.sin(q[i]))
        rot = sp.matmul(sp.matmul(rot, sp.numeric(structure.rotations[i])), turn)
    pos = sp.add(pos, sp.matvec(rot, sp.numeric(structure.flange_translation)))
    return ca.vertcat(*[ca.SX(x) if isinstance(x, (int, float)) else x for x in pos])


@dataclass(frozen=True)
class SampleFunctions:
    """Mapped CasADi functions over ``samples`` joint states (inputs 6 x samples each).

    ``regressor(q, qd, qdd) -> Y`` (6 x samples*n_base, sample blocks side by side);
    ``regressor_vjp(q, qd, qdd, W) -> (gq, gqd, gqdd)`` (6 x samples each) for W (6 x samples*n_base);
    ``torque(q, qd, qdd) -> (tau 6 x samples, dtau 6 x samples*18)``;
    ``flange(q) -> (r 3 x samples, dr 3 x samples*6)``.
    """

    samples: int
    n_base: int
    regressor: ca.Function
    regressor_vjp: ca.Function
    torque: ca.Function
    flange: ca.Function

    def base_regressor(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Stacked base regressor (samples, 6, n_base) of states given as (samples, 6) arrays."""
        y = np.asarray(self.regressor(q.T, qd.T, qdd.T))
        return y.reshape(N_JOINTS, self.samples, self.n_base).transpose(1, 0, 2)

    def regressor_gradient(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                           weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """d sum(Y .* weights) / d(q, qd, qdd): three (samples, 6) arrays; weights (samples, 6, n_base)."""
        w = weights.transpose(1, 0, 2).reshape(N_JOINTS, self.samples * self.n_base)
        gq, gqd, gqdd = self.regressor_vjp(q.T, qd.T, qdd.T, w)
        return np.asarray(gq).T, np.asarray(gqd).T, np.asarray(gqdd).T

    def torques(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Model torques (samples, 6) in N m and their Jacobian (samples, 6, 18) wrt (q, qd, qdd)."""
        tau, jac = self.torque(q.T, qd.T, qdd.T)
        jac = np.asarray(jac).reshape(N_JOINTS, self.samples, 3 * N_JOINTS).transpose(1, 0, 2)
        return np.asarray(tau).T, jac

    def flange_positions(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flange positions (samples, 3) in m and their Jacobian (samples, 3, 6) wrt q."""
        r, jac = self.flange(q.T)
        return np.asarray(r).T, np.asarray(jac).reshape(3, self.samples, N_JOINTS).transpose(1, 0, 2)


def sample_functions(base: BaseParameters, parameter_vector: ArrayLike, payload: ArrayLike, samples: int,
                     structure: ChainStructure | None = None) -> SampleFunctions:
    """Build and map the per-sample functions (see module docstring) over ``samples`` states.

    ``parameter_vector`` (78,) and ``payload`` ``[mass kg, cx, cy, cz m in tool0]`` define the
    model of the torque constraint (the controller's model: nominal by default).
    """
    structure = structure or chain_structure()
    p_num = [float(x) for x in np.asarray(parameter_vector, dtype=float).reshape(N_PARAMETERS)]
    load = [float(x) for x in np.asarray(payload, dtype=float).reshape(4)]
    q, qd, qdd = (ca.SX.sym(name, N_JOINTS) for name in ("q", "qd", "qdd"))
    p = ca.SX.sym("p", N_PARAMETERS)
    tau_p = ca.vertcat(*inverse_dynamics_expression(structure, q, qd, qdd, p, [0.0] * 4))
    y_base = ca.jacobian(tau_p, p)[:, [int(j) for j in base.independent]]
    w = ca.SX.sym("w", N_JOINTS, base.count)
    weighted = ca.sum1(ca.sum2(y_base * w))
    state = ca.vertcat(q, qd, qdd)
    regressor = ca.Function("base_regressor", [q, qd, qdd], [y_base], _OPTIONS)
    vjp = ca.Function("base_regressor_vjp", [q, qd, qdd, w],
                      [ca.gradient(weighted, q), ca.gradient(weighted, qd), ca.gradient(weighted, qdd)], _OPTIONS)
    tau = ca.vertcat(*inverse_dynamics_expression(structure, q, qd, qdd, p_num, load))
    torque = ca.Function("model_torque", [q, qd, qdd], [tau, ca.jacobian(tau, state)], _OPTIONS)
    r = flange_position_expression(structure, q)
    flange = ca.Function("flange_position", [q], [r, ca.jacobian(r, q)], _OPTIONS)
    return SampleFunctions(samples, base.count, regressor.map(samples), vjp.map(samples),
                           torque.map(samples), flange.map(samples))
