"""Per-node functions of the PtP transcription with exact first and second derivatives, compiled.

At every node of ``planners.ptp_optimal`` the problem needs, for the scaled node vector
``v = [x (18) = (q/s_q, qd/s_qd, qdd/s_qdd), jerk before / s_jerk (6), jerk after / s_jerk (6)]``
and the scales ``s = [s_q, s_qd, s_qdd, s_jerk, s_tau, s_rate]`` (36), the outputs

    o = [tau / s_tau (6), rate_before / s_rate (6), rate_after / s_rate (6), tau^T tau (1)]

where ``tau = ID(q, qd, qdd)`` (the arm's RNEA, ``robot.symbolic``, plus friction
``fv qd + fc tanh(qd / v_s)``, with the 78 dynamic parameters, the 4 payload values and
the Coulomb smoothing velocity v_s as INPUTS ``dp`` (83), so one compiled library serves
every arm, payload and friction model of the same kinematic structure) and
``rate_* = d tau_s / dt = drift(q, qd, qdd) + M(q) jerk_*`` is the exact derivative of the
torque without the Coulomb term on either side of the node (the jerk jumps at nodes).

Three CasADi functions are generated from these SX expressions:

* ``ptp_node_f(v, s, dp) -> o`` (19);
* ``ptp_node_j(v, s, dp) -> nonzeros of d o[:18] / d v`` (column order of ``jacobian_sparsity``);
* ``ptp_node_e(v, s, dp) -> d (tau^T tau) / d v[:18]`` (18, the energy gradient);
* ``ptp_node_h(v, s, dp, lam) -> nonzeros of triu(d^2 (lam^T o) / d v^2)`` (``hessian_sparsity``).

Building the symbolic Hessian takes a few seconds and evaluating it in CasADi's virtual
machine about 4x longer than compiled C, so the three functions are compiled once with
gcc (CasADi code generation) by the project's native layer (:mod:`native`, per-user
cache), keyed by a SHA-256 of the kinematic structure and this module's
``NODE_CODE_VERSION``. Without a C compiler the SX functions are used as they are
(slower, same results; ``COSIM_NATIVE=require`` makes that an error).
"""
from __future__ import annotations

import dataclasses
import hashlib
import os
import time
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

import native
from robot.dynamics import COULOMB_SLICE, N_PARAMETERS, VISCOUS_SLICE
from robot.symbolic import ChainStructure, inverse_dynamics_expression
from robot.joints import N_JOINTS

N_NODE_INPUTS = 30
N_NODE_OUTPUTS = 19
N_SCALES = 36
N_DYNAMIC_PARAMETERS = N_PARAMETERS + 5
NODE_CODE_VERSION = "ptp-nodes-3"
"""Change when the node expressions change (part of the cache key)."""
CFLAGS: tuple[str, ...] = ("-O0", "-fPIC", "-shared", "-std=c99")
"""gcc flags of the node library: -O0 compiles in ~10 s; -O1 code runs ~1.7x faster but
takes minutes to compile the 68k-instruction Hessian (docs/explanation/planners.md)."""
NAMES = ("ptp_node_f", "ptp_node_j", "ptp_node_h", "ptp_node_e")


@dataclass(frozen=True)
class NodeFunctions:
    """The three node functions and the sparsity of the Jacobian and triu Hessian (19 x 30, 30 x 30)."""

    f: ca.Function
    j: ca.Function
    h: ca.Function
    e: ca.Function
    jacobian_sparsity: ca.Sparsity
    hessian_sparsity: ca.Sparsity
    compiled: bool
    library: Path | None
    build_time_s: float


def _expressions(structure: ChainStructure) -> tuple[list, ca.SX, ca.SX, ca.SX]:
    v = ca.SX.sym("v", N_NODE_INPUTS)
    s = ca.SX.sym("s", N_SCALES)
    dp = ca.SX.sym("dp", N_DYNAMIC_PARAMETERS)
    s_q, s_qd, s_qdd, s_jerk, s_tau, s_rate = (s[6 * i: 6 * i + 6] for i in range(6))
    q, qd, qdd = s_q * v[0:6], s_qd * v[6:12], s_qdd * v[12:18]
    jerk_before, jerk_after = s_jerk * v[18:24], s_jerk * v[24:30]
    p, payload, smoothing = dp[:N_PARAMETERS], dp[N_PARAMETERS:N_PARAMETERS + 4], dp[N_PARAMETERS + 4]
    # the Coulomb smoothing velocity is an input too (the structure's value is not used)
    friction_free = dataclasses.replace(structure, coulomb_smoothing_velocity=1.0)
    tau = ca.vertcat(*inverse_dynamics_expression(friction_free, q, qd, qdd, p, payload, include_friction=False))
    tau = tau + p[VISCOUS_SLICE] * qd + p[COULOMB_SLICE] * ca.tanh(qd / smoothing)
    smooth = tau - p[COULOMB_SLICE] * ca.tanh(qd / smoothing)
    # d tau_s/dt = d tau_s/d(q, qd) (qd, qdd) + M(q) jerk, with v the (scaled) symbols
    drift = ca.jtimes(smooth, v[0:12], ca.vertcat(qd / s_q, qdd / s_qd))
    before = ca.jtimes(tau, v[12:18], jerk_before / s_qdd)
    after = ca.jtimes(tau, v[12:18], jerk_after / s_qdd)
    out = ca.vertcat(tau / s_tau, (drift + before) / s_rate, (drift + after) / s_rate, ca.sumsqr(tau))
    return out, v, s, dp


def _symbolic_functions(structure: ChainStructure) -> tuple[ca.Function, ca.Function, ca.Function]:
    out, v, s, dp = _expressions(structure)
    lam = ca.SX.sym("lam", N_NODE_OUTPUTS)
    jac = ca.jacobian(out[:18], v)
    energy_gradient = ca.gradient(out[18], v[:18])
    hess = ca.triu(ca.hessian(ca.dot(lam, out), v)[0])
    opts = {"cse": True}
    f = ca.Function(NAMES[0], [v, s, dp], [out], ["v", "s", "dp"], ["o"], opts)
    j = ca.Function(NAMES[1], [v, s, dp], [ca.vertcat(*jac.nonzeros())], ["v", "s", "dp"], ["jac_nz"], opts)
    h = ca.Function(NAMES[2], [v, s, dp, lam], [ca.vertcat(*hess.nonzeros())], ["v", "s", "dp", "lam"],
                    ["hess_nz"], opts)
    e = ca.Function(NAMES[3], [v, s, dp], [energy_gradient], ["v", "s", "dp"], ["grad_tau2"], opts)
    # sparsities travel with the library as a small text file
    _SPARSITY_CACHE[id(f)] = (jac.sparsity(), hess.sparsity())
    return f, j, h, e


_SPARSITY_CACHE: dict[int, tuple[ca.Sparsity, ca.Sparsity]] = {}


def _structure_key(structure: ChainStructure) -> str:
    digest = hashlib.sha256()
    digest.update(NODE_CODE_VERSION.encode())
    digest.update(ca.__version__.encode())
    for arrays in (structure.rotations, structure.translations, structure.axes):
        for arr in arrays:
            digest.update(np.ascontiguousarray(arr, dtype=float).tobytes())
    digest.update(np.asarray(structure.parents, dtype=np.int64).tobytes())
    digest.update(np.ascontiguousarray(structure.gravity, dtype=float).tobytes())
    digest.update(" ".join(CFLAGS).encode())
    return digest.hexdigest()[:16]


def _sparsity_to_text(sp: ca.Sparsity) -> str:
    rows, cols = sp.get_triplet()
    return f"{sp.size1()} {sp.size2()}\n" + " ".join(map(str, rows)) + "\n" + " ".join(map(str, cols)) + "\n"


def _sparsity_from_text(text: str) -> ca.Sparsity:
    lines = text.splitlines()
    n1, n2 = (int(x) for x in lines[0].split())
    rows = [int(x) for x in lines[1].split()]
    cols = [int(x) for x in lines[2].split()]
    return ca.Sparsity.triplet(n1, n2, rows, cols)


def _build(structure: ChainStructure, key: str, made: dict) -> Path:
    """The compiled library of the node functions (generated only when not cached)."""

    def generate(folder: Path) -> list[Path]:
        functions = _symbolic_functions(structure)
        sparsities = _SPARSITY_CACHE.pop(id(functions[0]))
        made["functions"], made["sparsities"] = functions, sparsities
        source = folder / "ptp_nodes.c"
        generator = ca.CodeGenerator(source.name, {"with_header": False})
        for function in functions:
            generator.add(function)
        generator.generate(str(folder) + os.sep)
        (folder / "ptp_nodes.so.sparsity").write_text(_sparsity_to_text(sparsities[0])
                                                      + _sparsity_to_text(sparsities[1]))
        return [source]

    return native.build("ptp_nodes", generate=generate, key=key.encode(), cflags=CFLAGS)


def _load(library: Path) -> tuple[tuple[ca.Function, ...], tuple[ca.Sparsity, ca.Sparsity]]:
    native.check_private(library.parent)
    native.check_private(library)
    text = library.with_name(library.name + ".sparsity").read_text().splitlines()
    jac = _sparsity_from_text("\n".join(text[0:3]))
    hess = _sparsity_from_text("\n".join(text[3:6]))
    return tuple(ca.external(name, str(library)) for name in NAMES), (jac, hess)


_LOADED: dict[tuple[str, bool], NodeFunctions] = {}


def node_functions(structure: ChainStructure, compile_code: bool = True) -> NodeFunctions:
    """The node functions of ``structure`` (compiled and cached when possible; kept per process)."""
    key = _structure_key(structure)
    if (key, compile_code) not in _LOADED:
        _LOADED[(key, compile_code)] = _node_functions(structure, key, compile_code)
    return _LOADED[(key, compile_code)]


def _node_functions(structure: ChainStructure, key: str, compile_code: bool) -> NodeFunctions:
    start = time.perf_counter()
    made: dict = {}
    if compile_code and native.mode() != "off":
        try:
            library = _build(structure, key, made)
            (f, j, h, e), (jsp, hsp) = _load(library)
            return NodeFunctions(f, j, h, e, jsp, hsp, True, library, time.perf_counter() - start)
        except (native.NativeBuildError, OSError, RuntimeError) as exc:
            native.fallback("PtP node functions", exc)
    if "functions" in made:
        (f, j, h, e), (jsp, hsp) = made["functions"], made["sparsities"]
    else:
        f, j, h, e = _symbolic_functions(structure)
        jsp, hsp = _SPARSITY_CACHE.pop(id(f))
    return NodeFunctions(f, j, h, e, jsp, hsp, False, None, time.perf_counter() - start)
