"""Joint-space rigid-body dynamics of the arm with rotor inertia, friction and payload.

Equation of motion (joint side, SI units)::

    tau = M(q) qdd + C(q, qd) qd + g(q) + tau_f(qd),   M(q) = M_rb(q) + diag(Ia)
    tau_f(qd) = fv * qd + fc * tanh(qd / v_s)

``Ia`` is the reflected rotor inertia, ``fv``/``fc`` the viscous/Coulomb friction and
``v_s`` the Coulomb smoothing velocity of ``rx130l_params.toml``. The rigid-body part
is pinocchio's (independent, well-kept reference); the payload is a rigid body fixed
to the flange frame ``tool0`` and folded into the inertia of link 6.

THE DYNAMIC PARAMETER VECTOR (P = 78) is a contract shared by the plant FMU, the
identification and the controller::

    p[10*(i-1) : 10*i]  link i = 1..6, pinocchio order
                        [m, m*cx, m*cy, m*cz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]
                        (kg, kg m, kg m^2; centre of mass and inertia about the
                        joint-i frame origin, axes of the joint-i frame, as
                        ``pin.Inertia.toDynamicParameters()``)
    p[60:66]            rotor inertia Ia, kg m^2 (joint side)
    p[66:72]            viscous friction fv, N m s / rad
    p[72:78]            Coulomb friction fc, N m

The payload is a separate vector ``[mass kg, cx, cy, cz m]`` (point mass, centre of
mass in ``tool0``). The regressor ``Y`` satisfies ``tau = Y(q, qd, qdd) @ p`` where ``p``
has the payload folded in (``parameter_vector(include_payload=True)``).
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike

from robot.description import FLANGE_FRAME, load_model
from robot.parameters import RobotParameters, load_parameters
from robot.joints import N_JOINTS

N_LINK_PARAMETERS = 10
N_PARAMETERS = 78
INERTIAL_SLICE = slice(0, 60)
ROTOR_INERTIA_SLICE = slice(60, 66)
VISCOUS_SLICE = slice(66, 72)
COULOMB_SLICE = slice(72, 78)
LINK6_SLICE = slice(50, 60)
LINK_PARAMETER_NAMES: tuple[str, ...] = ("m", "mx", "my", "mz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
PARAMETER_NAMES: tuple[str, ...] = (
    tuple(f"{name}{i}" for i in range(1, 7) for name in LINK_PARAMETER_NAMES)
    + tuple(f"Ia{i}" for i in range(1, 7))
    + tuple(f"fv{i}" for i in range(1, 7))
    + tuple(f"fc{i}" for i in range(1, 7))
)
PARAMETER_UNITS: tuple[str, ...] = (
    ("kg", "kg m", "kg m", "kg m") + ("kg m^2",) * 6
) * 6 + ("kg m^2",) * 6 + ("N m s/rad",) * 6 + ("N m",) * 6


class DynamicParameterError(ValueError):
    """A dynamic parameter vector, payload or joint-state argument is malformed."""


def link_parameters(parameter_vector: ArrayLike, link: int) -> np.ndarray:
    """The 10 inertial parameters of ``link`` (1..6) of a 78-vector (a copy)."""
    p = _as_parameter_vector(parameter_vector)
    if link not in range(1, 7):
        raise DynamicParameterError(f"link = {link!r}, expected an integer 1..6")
    return p[10 * (link - 1): 10 * link].copy()


def nominal_parameter_vector(model: pin.Model | None = None,
                             parameters: RobotParameters | None = None) -> np.ndarray:
    """The 78-vector of the URDF inertias and the parameter file's rotor and friction values."""
    parameters = parameters or load_parameters()
    model = model or load_model(parameters.urdf_path)
    _check_model(model)
    inertial = np.concatenate([model.inertias[j].toDynamicParameters() for j in range(1, 7)])
    return np.concatenate((inertial, parameters.rotor_inertia, parameters.viscous, parameters.coulomb))


def flange_placement(model: pin.Model | None = None) -> pin.SE3:
    """Placement of ``tool0`` in the joint-6 frame (rotation, translation in m)."""
    model = model or load_model()
    frame = model.frames[model.getFrameId(FLANGE_FRAME)]
    if frame.parentJoint != N_JOINTS:
        raise DynamicParameterError(f"frame {FLANGE_FRAME!r} hangs on joint {frame.parentJoint}, expected 6")
    return pin.SE3(frame.placement)


def payload_link_parameters(payload: ArrayLike, model: pin.Model | None = None,
                            inertia_about_com: ArrayLike | None = None) -> np.ndarray:
    """The 10 inertial parameters, in the joint-6 frame, of a payload fixed to ``tool0``.

    ``payload`` is ``[mass kg, cx, cy, cz m]`` with the centre of mass in ``tool0``;
    ``inertia_about_com`` (kg m^2, 3x3, axes of ``tool0``) defaults to zero (point mass,
    the model of the CasADi functions and the plant FMU).
    """
    mass, com = _as_payload(payload)
    inertia = np.zeros((3, 3)) if inertia_about_com is None else np.asarray(inertia_about_com, dtype=float)
    if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)) or not np.allclose(inertia, inertia.T):
        raise DynamicParameterError(
            f"inertia_about_com = {inertia_about_com!r}, expected a finite symmetric 3x3 matrix in kg m^2"
        )
    body = pin.Inertia(mass, com, inertia)
    return flange_placement(model).act(body).toDynamicParameters()


def fold_payload(parameter_vector: ArrayLike, payload: ArrayLike, model: pin.Model | None = None,
                 inertia_about_com: ArrayLike | None = None) -> np.ndarray:
    """A copy of the 78-vector with the payload added to the link-6 parameters."""
    p = _as_parameter_vector(parameter_vector).copy()
    p[LINK6_SLICE] += payload_link_parameters(payload, model, inertia_about_com)
    return p


def pseudo_inertia(link_parameters_10: ArrayLike) -> np.ndarray:
    """The 4x4 pseudo-inertia matrix ``[[Sigma, h], [h^T, m]]`` of 10 link parameters.

    ``Sigma = tr(I)/2 * 1 - I`` is the second moment of the mass distribution about the
    frame origin. A rigid body is physically consistent (positive mass, positive-definite
    inertia about the centre of mass, triangle inequalities) iff this matrix is
    positive definite (Wensing, Kim, Slotine 2017).
    """
    m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = np.asarray(link_parameters_10, dtype=float)
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    sigma = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    h = np.array([hx, hy, hz])
    return np.block([[sigma, h[:, None]], [h[None, :], np.array([[m]])]])


def is_physically_consistent(link_parameters_10: ArrayLike, tolerance: float = 0.0) -> bool:
    """True if the pseudo-inertia of 10 link parameters has all eigenvalues > ``tolerance``."""
    return bool(np.linalg.eigvalsh(pseudo_inertia(link_parameters_10)).min() > tolerance)


class RobotDynamics:
    """Numeric dynamics of one arm: a 78-parameter vector plus a payload on ``tool0``.

    ``RobotDynamics()`` is the nominal arm (URDF + parameter file, nominal payload);
    ``RobotDynamics(p, payload)`` builds the arm of any parameter vector, e.g. an
    identified one or the true robot's. Joint vectors: shape (6,), rad, rad/s, rad/s^2,
    N m. ``model`` supplies the kinematic structure only (its inertias are replaced);
    ``parameters`` supplies the Coulomb smoothing velocity and the defaults.
    """

    def __init__(self, parameter_vector: ArrayLike | None = None, payload: ArrayLike | None = None, *,
                 model: pin.Model | None = None, parameters: RobotParameters | None = None) -> None:
        self.parameters: RobotParameters = parameters or load_parameters()
        structure = model if model is not None else load_model(self.parameters.urdf_path)
        _check_model(structure)
        if parameter_vector is None:
            parameter_vector = nominal_parameter_vector(structure, self.parameters)
        self._p = _as_parameter_vector(parameter_vector).copy()
        self._p.setflags(write=False)
        mass, com = _as_payload(self.parameters.payload if payload is None else payload)
        self.payload: np.ndarray = np.concatenate(([mass], com))
        self.payload.setflags(write=False)
        self.coulomb_smoothing_velocity: float = self.parameters.coulomb_smoothing_velocity

        folded = fold_payload(self._p, self.payload, structure)
        self.model: pin.Model = pin.Model(structure)
        for j in range(1, 7):
            link = folded[10 * (j - 1): 10 * j]
            if not link[0] > 0.0:
                raise DynamicParameterError(
                    f"parameter_vector: mass of link {j} ({PARAMETER_NAMES[10 * (j - 1)]}) = {float(link[0])!r}, "
                    "expected > 0 (pinocchio needs a positive mass per link)"
                )
            self.model.inertias[j] = pin.Inertia.FromDynamicParameters(link)
        self.model.armature = self._p[ROTOR_INERTIA_SLICE].copy()
        self.data: pin.Data = self.model.createData()
        self._viscous = self._p[VISCOUS_SLICE].copy()
        self._coulomb = self._p[COULOMB_SLICE].copy()

    # -- parameters -------------------------------------------------------------
    def parameter_vector(self, include_payload: bool = False) -> np.ndarray:
        """The 78-vector of this arm (a copy); with the payload folded into link 6 on request."""
        if include_payload:
            return fold_payload(self._p, self.payload, self.model)
        return self._p.copy()

    # -- dynamics terms ---------------------------------------------------------
    def mass_matrix(self, q: ArrayLike) -> np.ndarray:
        """M(q) in kg m^2 (6x6, symmetric), rotor inertia on the diagonal included."""
        mass = pin.crba(self.model, self.data, _joint_vector(q, "q"))
        return np.triu(mass) + np.triu(mass, 1).T

    def gravity(self, q: ArrayLike) -> np.ndarray:
        """Gravity torque g(q) in N m."""
        return pin.computeGeneralizedGravity(self.model, self.data, _joint_vector(q, "q")).copy()

    def friction(self, qd: ArrayLike) -> np.ndarray:
        """Friction torque fv*qd + fc*tanh(qd/v_s) in N m (opposes motion when subtracted from tau)."""
        qd = _joint_vector(qd, "qd")
        return self._viscous * qd + self._coulomb * np.tanh(qd / self.coulomb_smoothing_velocity)

    def nonlinear_effects(self, q: ArrayLike, qd: ArrayLike) -> np.ndarray:
        """C(q, qd) qd + g(q) + friction(qd) in N m."""
        q, qd = _joint_vector(q, "q"), _joint_vector(qd, "qd")
        return pin.nonLinearEffects(self.model, self.data, q, qd) + self.friction(qd)

    def inverse_dynamics(self, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike) -> np.ndarray:
        """Joint torque tau = M qdd + C qd + g + friction in N m."""
        q, qd, qdd = _joint_vector(q, "q"), _joint_vector(qd, "qd"), _joint_vector(qdd, "qdd")
        # pinocchio's RNEA includes the armature (rotor inertia) term Ia * qdd.
        return pin.rnea(self.model, self.data, q, qd, qdd) + self.friction(qd)

    def forward_dynamics(self, q: ArrayLike, qd: ArrayLike, tau: ArrayLike) -> np.ndarray:
        """Joint acceleration qdd in rad/s^2 for the joint torque ``tau`` (N m)."""
        q, qd, tau = _joint_vector(q, "q"), _joint_vector(qd, "qd"), _joint_vector(tau, "tau")
        # pinocchio's ABA includes the armature in the joint-space inertia.
        return pin.aba(self.model, self.data, q, qd, tau - self.friction(qd)).copy()

    # -- linear regressor -------------------------------------------------------
    def regressor(self, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike) -> np.ndarray:
        """Y (6x78) with inverse_dynamics(q, qd, qdd) = Y @ parameter_vector(include_payload=True)."""
        q, qd, qdd = _joint_vector(q, "q"), _joint_vector(qd, "qd"), _joint_vector(qdd, "qdd")
        out = np.zeros((N_JOINTS, N_PARAMETERS))
        self._fill_regressor(out, q, qd, qdd)
        return out

    def regressor_batch(self, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike) -> np.ndarray:
        """Regressors of N samples: arrays (N, 6) in, array (N, 6, 78) out."""
        q, qd, qdd = (_joint_matrix(x, name) for x, name in ((q, "q"), (qd, "qd"), (qdd, "qdd")))
        if not q.shape == qd.shape == qdd.shape:
            raise DynamicParameterError(
                f"q, qd, qdd have shapes {q.shape}, {qd.shape}, {qdd.shape}, expected the same (N, 6)"
            )
        out = np.zeros((q.shape[0], N_JOINTS, N_PARAMETERS))
        for k in range(q.shape[0]):
            self._fill_regressor(out[k], q[k], qd[k], qdd[k])
        return out

    def _fill_regressor(self, out: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> None:
        out[:, INERTIAL_SLICE] = pin.computeJointTorqueRegressor(self.model, self.data, q, qd, qdd)
        diag = np.arange(N_JOINTS)
        out[diag, 60 + diag] = qdd
        out[diag, 66 + diag] = qd
        out[diag, 72 + diag] = np.tanh(qd / self.coulomb_smoothing_velocity)


def _check_model(model: pin.Model) -> None:
    if model.nq != N_JOINTS or model.nv != N_JOINTS or model.njoints != N_JOINTS + 1:
        raise DynamicParameterError(
            f"model has nq={model.nq}, nv={model.nv}, njoints={model.njoints}, expected 6 revolute joints"
        )
    if list(model.idx_qs[1:]) != list(range(N_JOINTS)) or list(model.parents[1:]) != list(range(N_JOINTS)):
        raise DynamicParameterError("model: expected a serial chain with joint i at configuration index i-1")


def _as_parameter_vector(value: ArrayLike) -> np.ndarray:
    p = np.asarray(value, dtype=float)
    if p.shape != (N_PARAMETERS,) or not np.all(np.isfinite(p)):
        raise DynamicParameterError(
            f"parameter_vector has shape {p.shape} (finite: {bool(np.all(np.isfinite(p)))}), "
            f"expected {N_PARAMETERS} finite numbers (layout: robot.dynamics.PARAMETER_NAMES)"
        )
    return p


def _as_payload(value: ArrayLike) -> tuple[float, np.ndarray]:
    payload = np.asarray(value, dtype=float)
    if payload.shape != (4,) or not np.all(np.isfinite(payload)) or payload[0] < 0.0:
        raise DynamicParameterError(
            f"payload = {value!r}, expected [mass >= 0 kg, cx, cy, cz m in tool0] (4 finite numbers)"
        )
    return float(payload[0]), payload[1:].copy()


def _joint_vector(value: ArrayLike, name: str) -> np.ndarray:
    vector = np.asarray(value, dtype=float)
    if vector.shape != (N_JOINTS,):
        raise DynamicParameterError(f"{name} has shape {vector.shape}, expected (6,)")
    return vector


def _joint_matrix(value: ArrayLike, name: str) -> np.ndarray:
    matrix = np.asarray(value, dtype=float)
    if matrix.ndim != 2 or matrix.shape[1] != N_JOINTS:
        raise DynamicParameterError(f"{name} has shape {matrix.shape}, expected (N, 6)")
    return matrix
