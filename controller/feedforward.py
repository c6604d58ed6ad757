"""The feed-forward torque of the paper's eq. 7 from the model the controller is given.

    Q_M,ff = M(q_d) qdd_d + g(q_d, qd_d)

``M`` includes the reflected rotor inertia (pinocchio armature), ``g`` the Coriolis,
centrifugal and gravity torques and the friction ``fv qd + fc tanh(qd / v_s)`` (joint
side, N m) - exactly :meth:`robot.dynamics.RobotDynamics.inverse_dynamics`. The model
is whatever :class:`~robot.dynamics.RobotDynamics` the caller passes: the nominal arm,
an identified parameter vector, or (to bound what feed-forward can do) the true
robot's. This class only prepares the evaluation for the 400 µs cycle: its own
pinocchio Data, friction coefficients as plain floats, a reused output array.
"""
from __future__ import annotations

import ctypes
import hashlib
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike

import native

from robot.dynamics import COULOMB_SLICE, ROTOR_INERTIA_SLICE, VISCOUS_SLICE, RobotDynamics
from robot.parameters import RobotParameters, load_parameters
from robot.symbolic import ChainStructure, chain_structure, inverse_dynamics_expression
from robot.joints import N_JOINTS


class FeedForward:
    """Evaluates eq. 7's feed-forward torque of one :class:`RobotDynamics` model."""

    def __init__(self, dynamics: RobotDynamics) -> None:
        self.dynamics = dynamics
        self.model: pin.Model = dynamics.model
        self.data: pin.Data = self.model.createData()
        p = dynamics.parameter_vector()
        self._viscous = p[VISCOUS_SLICE].tolist()
        self._coulomb = p[COULOMB_SLICE].tolist()
        self._inv_vs = 1.0 / float(dynamics.coulomb_smoothing_velocity)
        self.tau = np.zeros(N_JOINTS)
        self._friction = [0.0] * N_JOINTS

    def torque(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Feed-forward joint torque (6,) in N m (a reused array) for q, qd, qdd (6,)."""
        rigid = pin.rnea(self.model, self.data, q, qd, qdd)  # includes armature * qdd
        friction = self._friction
        fv, fc, inv_vs = self._viscous, self._coulomb, self._inv_vs
        for i, v in enumerate(qd.tolist()):
            friction[i] = fv[i] * v + fc[i] * math.tanh(v * inv_vs)
        np.add(rigid, friction, out=self.tau)
        return self.tau


# ----------------------------------------------------------------------------------
# Elastic joints: flatness-based feed-forward (mode model_based_elastic)
# ----------------------------------------------------------------------------------
#
# The plant's flexible-joint model (fmus/rx130l_plant, docs/explanation/fmus.md), per axis, joint side:
#     link:   tau_g = M(q) qdd + c(q, qd) + g(q) + f_l(qd)          (link side, no rotor)
#     gear:   tau_g = k d + k3 d^3 + c_g dd/dt,   d = q_m - q
#     motor:  tau_m = Ia qdd_m + f_m(qd_m) + tau_g
# The link angle q is a flat output: from q and its derivatives up to the 4th follow
# tau_g, its first two time derivatives, the deflection d and its derivatives, the motor
# reference q_m = q + d (with qd_m, qdd_m) and the motor torque tau_m
# (De Luca, "Feedforward/feedback laws for the control of flexible robots", IEEE ICRA
# 2000; Thuemmel, Otter, Franke, "Nonlinear inverse models for control", Modelica 2005).


@dataclass(frozen=True)
class GearModel:
    """The controller's model of the gears (arrays (6,), joint side, SI): stiffness k
    (N m/rad), stiffening k3 (N m/rad^3), damping c_g (N m s/rad), the fraction of the
    viscous/Coulomb friction on the motor side, Stribeck torque (N m) and velocity
    (rad/s), Coulomb smoothing velocity (rad/s). Backlash is not inverted."""

    stiffness: np.ndarray
    stiffness_cubic: np.ndarray
    damping: np.ndarray
    motor_friction_share: np.ndarray
    stribeck_torque: np.ndarray
    stribeck_velocity: np.ndarray
    coulomb_smoothing_velocity: float

    @classmethod
    def from_parameters(cls, parameters: RobotParameters | None = None) -> "GearModel":
        """The ``[elastic]`` table of the parameter file (default: the nominal one)."""
        p = parameters or load_parameters()
        return cls(np.array(p.stiffness), np.array(p.stiffness_cubic), np.array(p.gear_damping),
                   np.array(p.motor_friction_share), np.array(p.stribeck_torque), np.array(p.stribeck_velocity),
                   float(p.coulomb_smoothing_velocity))


@dataclass(frozen=True)
class ElasticReference:
    """Motor-side reference of an elastic arm (arrays (n, 6) or (6,)): angle q_m, speed
    qd_m, acceleration qdd_m (rad, rad/s, rad/s^2; motor angle / gear ratio), motor torque
    tau_m (N m, joint side: what the drive must deliver), gear torque tau_g (N m) and
    deflection d = q_m - q (rad)."""

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    torque: np.ndarray
    gear_torque: np.ndarray
    deflection: np.ndarray


_LINK_TORQUE_FUNCTIONS: dict[bytes, ca.Function] = {}


def _structure_key(structure: ChainStructure) -> bytes:
    return np.concatenate([np.ravel(a) for a in (*structure.rotations, *structure.translations, *structure.axes,
                                                structure.parents, structure.gravity,
                                                [structure.coulomb_smoothing_velocity])]).tobytes()


def _link_torque_function(structure: ChainStructure) -> ca.Function:
    """The cached :func:`_build_link_torque_function` of a kinematic structure."""
    key = _structure_key(structure)
    if key not in _LINK_TORQUE_FUNCTIONS:
        _LINK_TORQUE_FUNCTIONS[key] = _build_link_torque_function(structure)
    return _LINK_TORQUE_FUNCTIONS[key]


def _build_link_torque_function(structure: ChainStructure) -> ca.Function:
    """CasADi function (q, qd, qdd, qddd, qdddd, p[78], payload[4], fv_l[6], fc_l[6]) ->
    (tau_g, dtau_g/dt, d2tau_g/dt2): the link-side torque along the motion whose Taylor
    coefficients at t are the given derivatives, differentiated exactly (forward AD in t)."""
    q, qd, qdd, q3, q4, fv, fc = (ca.SX.sym(n, N_JOINTS) for n in ("q", "qd", "qdd", "qddd", "qdddd", "fv_l", "fc_l"))
    p = ca.SX.sym("p", 78)
    payload = ca.SX.sym("payload", 4)
    t = ca.SX.sym("t")
    q_t = q + qd * t + qdd * t ** 2 / 2 + q3 * t ** 3 / 6 + q4 * t ** 4 / 24
    qd_t = qd + qdd * t + q3 * t ** 2 / 2 + q4 * t ** 3 / 6
    qdd_t = qdd + q3 * t + q4 * t ** 2 / 2
    rigid = inverse_dynamics_expression(structure, [q_t[i] for i in range(N_JOINTS)],
                                        [qd_t[i] for i in range(N_JOINTS)], [qdd_t[i] for i in range(N_JOINTS)],
                                        [p[i] for i in range(78)], [payload[i] for i in range(4)],
                                        include_friction=False, include_rotor=False)
    vs = structure.coulomb_smoothing_velocity
    tau = ca.vertcat(*rigid) + fv * qd_t + fc * ca.tanh(qd_t / vs)
    tau_d = ca.jacobian(tau, t)
    tau_dd = ca.jacobian(tau_d, t)
    outputs = [ca.substitute(e, t, 0.0) for e in (tau, tau_d, tau_dd)]
    return ca.Function("elastic_link_torque", [q, qd, qdd, q3, q4, p, payload, fv, fc], outputs,
                       ["q", "qd", "qdd", "qddd", "qdddd", "p", "payload", "fv_l", "fc_l"],
                       ["tau_g", "tau_g_d", "tau_g_dd"], {"cse": True})


MAP_BLOCK = 256
"""Knots per CasADi map call in :func:`link_torque_derivatives`."""
_COMPILED_LINK_TORQUE: dict[bytes, tuple[ca.Function, ctypes._CFuncPtr] | None] = {}
LINK_TORQUE_CFLAGS = ("-O2", "-fPIC", "-shared", "-std=c99", "-ffp-contract=off")
"""Flags of the compiled link torque (no contraction into fused multiply-adds: the compiled
code then does the CasADi virtual machine's operations in its order, bit for bit)."""


_GRID_DRIVER = r"""
/* Added by controller/feedforward.py: the generated function on every knot of a grid in one
   call. Inputs and outputs are (n, 6) row-major arrays (knot k at offset 6 k, the layout a
   CasADi map passes to each evaluation); p, payload, fv_l, fc_l are shared by all knots. */
#include <stdlib.h>
CASADI_SYMBOL_EXPORT int elastic_link_torque_grid(long long n, const double* q, const double* qd,
    const double* qdd, const double* q3, const double* q4, const double* p, const double* payload,
    const double* fv, const double* fc, double* tau, double* tau_d, double* tau_dd) {
  casadi_int sz_arg, sz_res, sz_iw, sz_w, k;
  const casadi_real** arg;
  casadi_real** res;
  casadi_int* iw;
  casadi_real* w;
  int status = 0;
  elastic_link_torque_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  arg = (const casadi_real**) calloc((size_t) (sz_arg > 9 ? sz_arg : 9), sizeof(*arg));
  res = (casadi_real**) calloc((size_t) (sz_res > 3 ? sz_res : 3), sizeof(*res));
  iw = (casadi_int*) malloc((size_t) (sz_iw > 0 ? sz_iw : 1) * sizeof(*iw));
  w = (casadi_real*) malloc((size_t) (sz_w > 0 ? sz_w : 1) * sizeof(*w));
  if (!arg || !res || !iw || !w) {
    status = -1;
  } else {
    arg[5] = p; arg[6] = payload; arg[7] = fv; arg[8] = fc;
    for (k = 0; k < n && status == 0; ++k) {
      arg[0] = q + 6 * k; arg[1] = qd + 6 * k; arg[2] = qdd + 6 * k; arg[3] = q3 + 6 * k; arg[4] = q4 + 6 * k;
      res[0] = tau + 6 * k; res[1] = tau_d + 6 * k; res[2] = tau_dd + 6 * k;
      status = elastic_link_torque(arg, res, iw, w, 0);
    }
  }
  free(arg); free(res); free(iw); free(w);
  return status;
}
"""


def _generator_key(structure_key: bytes) -> bytes:
    """The identity of the generated link torque source without generating it (building the
    CasADi expression and its C code costs ~0.11 CPU-s, paid only when the library is not
    cached): the kinematic structure, the CasADi version and the source files the expression
    is built from (this module, robot/symbolic.py, robot/spatial_lists.py, robot/dynamics.py)."""
    import robot.dynamics
    import robot.spatial_lists
    import robot.symbolic

    digest = hashlib.sha256(b"elastic_link_torque generated source v2\0" + structure_key)
    digest.update(ca.__version__.encode() + b"\0")
    for module in (sys.modules[__name__], robot.symbolic, robot.spatial_lists, robot.dynamics):
        digest.update(Path(module.__file__).read_bytes() + b"\0")
    return digest.digest()


def _compiled_link_torque(structure: ChainStructure):
    """(``casadi.external`` function, ctypes grid driver) of the compiled link torque, or None
    (see :func:`_compiled_link_torque_function`)."""
    if native.mode() == "off":
        return None
    key = _structure_key(structure)
    if key in _COMPILED_LINK_TORQUE:
        return _COMPILED_LINK_TORQUE[key]

    def make() -> ca.Function:
        def generate(folder: Path) -> list[Path]:  # only when the library is not cached yet
            generator = ca.CodeGenerator("elastic_link_torque.c", {"with_header": False,
                                                                   "casadi_int": "long long int"})
            generator.add(_link_torque_function(structure))
            generator.generate(str(folder) + "/")
            c_file = folder / "elastic_link_torque.c"
            # the whole grid in one call (link_torque_derivatives)
            c_file.write_text(c_file.read_text() + _GRID_DRIVER)
            return [c_file]

        library = native.build("elastic_link_torque", generate=generate, key=_generator_key(key),
                               cflags=LINK_TORQUE_CFLAGS)
        lib = native.load_ctypes(library)  # owner and mode checks before CasADi loads it
        grid = lib.elastic_link_torque_grid
        grid.restype = ctypes.c_int
        grid.argtypes = [ctypes.c_longlong] + [ctypes.c_void_p] * 12
        try:
            return ca.external("elastic_link_torque", str(library)), grid
        except RuntimeError as exc:
            raise native.NativeBuildError(f"loading {library} with casadi.external failed: {exc}") from None

    compiled = native.optional("elastic link torque", make)
    _COMPILED_LINK_TORQUE[key] = compiled
    return compiled


def _compiled_link_torque_function(structure: ChainStructure) -> ca.Function | None:
    """:func:`_link_torque_function` generated as C, compiled and loaded (``casadi.external``)
    through the native layer (:mod:`native`, cached by the SHA-256 of the generated source),
    or None when compiled code is off or unavailable (``$COSIM_NATIVE``: the CasADi virtual
    machine then evaluates the same expression). Same results bit for bit (the C code runs
    the virtual machine's operations in its order, ``-ffp-contract=off``; exact-equality test
    in tests/controller/test_elastic.py)."""
    compiled = _compiled_link_torque(structure)
    return None if compiled is None else compiled[0]


def _compiled_link_torque_grid(structure: ChainStructure):
    """The same library's ``elastic_link_torque_grid`` (ctypes; see ``_GRID_DRIVER``), or None."""
    compiled = _compiled_link_torque(structure)
    return None if compiled is None else compiled[1]


def link_torque_derivatives(dynamics: RobotDynamics, gear: GearModel, q: ArrayLike, qd: ArrayLike,
                            qdd: ArrayLike, qddd: ArrayLike, qdddd: ArrayLike
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gear torque the links need and its first two time derivatives (each (n, 6), N m,
    N m/s, N m/s^2) along a joint motion given by its derivatives up to the 4th (each
    (n, 6) or (6,)): the rigid links of ``dynamics`` (no rotor inertia) plus the link-side
    share of its friction."""
    structure = chain_structure(dynamics.model)
    p = dynamics.parameter_vector()
    share = gear.motor_friction_share
    fv_l, fc_l = (1.0 - share) * p[VISCOUS_SLICE], (1.0 - share) * p[COULOMB_SLICE]
    args = [np.atleast_2d(np.asarray(a, dtype=float)) for a in (q, qd, qdd, qddd, qdddd)]
    fixed = (p, np.asarray(dynamics.payload, dtype=float), fv_l, fc_l)
    grid = _compiled_link_torque_grid(structure)
    if grid is not None and all(a.ndim == 2 and a.shape[1] == N_JOINTS for a in args) \
            and len({a.shape[0] for a in args}) == 1 and [np.size(c) for c in fixed] == [78, 4, 6, 6]:
        # the compiled function knot by knot in one C call: the numbers of the map below bit
        # for bit (each knot's evaluation is the same call on the same 6-vectors), without
        # CasADi's map and matrix conversions (0.24 -> 0.05 CPU-s on the ISO path's 30 520 knots)
        rows = [np.ascontiguousarray(a) for a in args]
        consts = [np.ascontiguousarray(c, dtype=np.float64) for c in fixed]
        out = np.empty((3, rows[0].shape[0], N_JOINTS))
        status = grid(rows[0].shape[0], *(a.ctypes.data for a in rows), *(c.ctypes.data for c in consts),
                      *(o.ctypes.data for o in out))
        if status != 0:
            raise RuntimeError(f"elastic_link_torque_grid failed (status {status})")
        return out[0], out[1], out[2]
    evaluate = _compiled_link_torque_function(structure) or _link_torque_function(structure)
    columns = [np.ascontiguousarray(a.T) for a in args]
    n = columns[0].shape[1]
    out = np.empty((3, N_JOINTS, n))
    # blocks of MAP_BLOCK knots: building and calling a CasADi map costs more than linear in
    # its width (30 520 knots at once 0.40 s, in blocks of 256 0.17 s); each knot's numbers
    # are the same either way
    width = min(n, MAP_BLOCK)
    block = evaluate.map(width)
    for start in range(0, n, width):
        stop = min(start + width, n)
        mapped = block if stop - start == width else evaluate.map(stop - start)
        for k, value in enumerate(mapped(*(c[:, start:stop] for c in columns), *fixed)):
            out[k, :, start:stop] = np.array(value)
    return out[0].T, out[1].T, out[2].T


def gear_deflection(gear: GearModel, tau_g: np.ndarray, tau_g_d: np.ndarray, tau_g_dd: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Deflection d (rad) and its first two derivatives with k d + k3 d^3 + c_g dd/dt = tau_g:
    the spring part solved by Newton (exact for k3 = 0), the damper to first order in
    c_g / k (the gear's time constant, ~1 ms)."""
    k, k3, c = gear.stiffness, gear.stiffness_cubic, gear.damping
    d0 = tau_g / k
    for _ in range(50):
        step = (k * d0 + k3 * d0 ** 3 - tau_g) / (k + 3 * k3 * d0 ** 2)
        d0 = d0 - step
        if np.all(np.abs(step) <= 1e-15 * (1.0 + np.abs(d0))):
            break
    k_eff = k + 3 * k3 * d0 ** 2
    d0_d = tau_g_d / k_eff
    d0_dd = (tau_g_dd - 6 * k3 * d0 * d0_d ** 2) / k_eff
    return d0 - c * d0_d / k_eff, d0_d - c * d0_dd / k_eff, d0_dd


def motor_friction(dynamics: RobotDynamics, gear: GearModel, v: np.ndarray) -> np.ndarray:
    """Motor-side friction (N m, joint side) at motor speed v (rad/s, joint units): the
    motor share of viscous + Coulomb plus the Stribeck term."""
    p = dynamics.parameter_vector()
    smooth = np.tanh(v / gear.coulomb_smoothing_velocity)
    return (gear.motor_friction_share * (p[VISCOUS_SLICE] * v + p[COULOMB_SLICE] * smooth)
            + gear.stribeck_torque * np.exp(-(v / gear.stribeck_velocity) ** 2) * smooth)


def elastic_feedforward(dynamics: RobotDynamics, gear: GearModel, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike,
                        qddd: ArrayLike, qdddd: ArrayLike) -> ElasticReference:
    """The motor reference and motor torque that make the links of an elastic arm follow
    ``q`` (derivatives up to the 4th, each (n, 6) or (6,)): flatness-based inversion of the
    flexible-joint model with the link dynamics of ``dynamics`` (rotor inertia
    ``Ia = p[60:66]`` on the motor side) and the gears of ``gear``."""
    tau_g, tau_g_d, tau_g_dd = link_torque_derivatives(dynamics, gear, q, qd, qdd, qddd, qdddd)
    d, d_d, d_dd = gear_deflection(gear, tau_g, tau_g_d, tau_g_dd)
    q_m = np.atleast_2d(q) + d
    qd_m = np.atleast_2d(qd) + d_d
    qdd_m = np.atleast_2d(qdd) + d_dd
    ia = dynamics.parameter_vector()[ROTOR_INERTIA_SLICE]
    torque = ia * qdd_m + motor_friction(dynamics, gear, qd_m) + tau_g
    return ElasticReference(q_m, qd_m, qdd_m, torque, tau_g, d)
