"""Base (identifiable) dynamic parameters by QR decomposition of the regressor (paper eq. 20-25).

The joint torques are linear in the 78 standard parameters of :mod:`robot.dynamics`,
``tau = Theta(q, qd, qdd) p`` (eq. 18), but many columns of ``Theta`` are zero (the
parameter never acts on a joint torque, e.g. the mass of link 1) or linear
combinations of others (e.g. ``Iyy2`` acts exactly like ``Izz1 - Ixx2``). Only the
base parameters ``p_b = p_1 + kappa p_2`` (eq. 22) are identifiable.

How they are found here:

1. ``Theta`` is stacked over :data:`DEFAULT_STATES` random joint states (q uniform in
   the position limits, qd and qdd uniform in +-the velocity and acceleration limits,
   seeded) - 1200 rows by 78 columns. The dependencies are structural (they come
   from the kinematic chain), so any generic set of states reveals the same ones.
2. Every column is scaled to unit norm (masses, first moments and inertias have
   different units); columns below :data:`ZERO_COLUMN_TOLERANCE` of the largest are
   zero (parameters without effect).
3. A QR factorisation WITH column pivoting (LAPACK ``geqp3``, rank revealing) gives
   the numerical rank: the number of ``|R_ii| > RANK_TOLERANCE * |R_00|``.
4. The independent columns ``Theta_1`` are then picked in the natural parameter
   order (link 1 before link 2, ``m`` before ``mx`` ... before ``Izz``, then rotor
   inertia and friction): a column is kept when its part orthogonal to the columns
   kept before it (the |R_jj| of an unpivoted QR of the kept columns) exceeds
   ``RANK_TOLERANCE`` of its own norm. This is the choice of the classical symbolic regrouping (a proximal
   parameter absorbs distal ones: ``Izz1 + Izz2 + Izz3 + Ia1``, ``mz2 + 0.625 m3 +
   ...``), so the base parameters read like a textbook table. The number kept must
   equal the rank of step 3 (checked).
5. ``kappa = R_11^-1 R_12`` (eq. 25) from the unpivoted QR of ``[Theta_1 Theta_2]``,
   mapped back to natural units; entries below :data:`KAPPA_ZERO_TOLERANCE` are
   round-off. Its entries here are sums and products of the link lengths (0.625 m,
   0.925 m, ...), so they are printed as short exact decimals where they are.

On the nominal RX130L-class model: 78 standard parameters, 11 zero columns, rank 53
(41 inertial incl. 5 separate rotor inertias, 12 friction); the pivoted diagonal
drops from 0.49 (last kept) to 8e-16 (first dropped), so the rank is the same for
any tolerance between about 1e-14 and 1e-2.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from fractions import Fraction
import dataclasses
from functools import lru_cache
from typing import Any

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike
from threadpoolctl import threadpool_limits

from identification.errors import IdentificationError
from robot.dynamics import (COULOMB_SLICE, N_PARAMETERS, PARAMETER_NAMES, PARAMETER_UNITS, ROTOR_INERTIA_SLICE,
                            RobotDynamics)
from robot.parameters import RobotParameters, load_parameters

DEFAULT_STATES = 200
"""Random joint states stacked for the QR decomposition (6 rows each)."""
DEFAULT_SEED = 20130101
"""Seed of the random states (any generic set gives the same structure)."""
RANK_TOLERANCE = 1e-8
"""Relative threshold on |R_ii| of unit-norm columns; measured gap on this model 0.49 -> 8e-16."""
ZERO_COLUMN_TOLERANCE = 1e-10
"""A column below this fraction of the largest column norm is a parameter without effect."""
KAPPA_ZERO_TOLERANCE = 1e-9
"""|kappa| entries (natural units) below this are round-off and set to 0."""
MAX_DECIMALS = 8
"""Coefficients are printed as exact decimals with at most this many digits when they are
within 1e-11 (relative) of one; else as a small fraction, else with 6 significant digits."""


class BaseParameterError(IdentificationError):
    """A base-parameter request or a parameter vector is malformed."""


@dataclass(frozen=True)
class Term:
    """One standard parameter inside a base parameter: ``coefficient * name``."""

    name: str
    coefficient: float
    text: str  # the coefficient as printed ("1", "0.390625", "-1", "1/3", "0.123457")


@dataclass(frozen=True)
class BaseParameters:
    """The base parameter set of one kinematic structure.

    ``independent``: indices (into the 78-vector) of ``p_1``, natural order;
    ``dependent``: indices of ``p_2`` (regrouped or without effect);
    ``kappa``: (n_base, n_dependent) in natural units, ``Theta_2 = Theta_1 kappa``;
    ``zero_columns``: indices of parameters without any effect on the torques;
    ``pivot_diagonal``: |R_ii| / |R_00| of the pivoted QR (rank revealing);
    ``gap``: last kept over first dropped pivoted diagonal entry;
    ``kappa_residual``: max |Theta_2 - Theta_1 kappa| relative to the largest column norm.
    """

    independent: np.ndarray
    dependent: np.ndarray
    kappa: np.ndarray
    zero_columns: np.ndarray
    pivot_diagonal: np.ndarray
    gap: float
    kappa_residual: float
    rank_tolerance: float
    n_states: int
    seed: int
    names: tuple[str, ...] = PARAMETER_NAMES
    units: tuple[str, ...] = PARAMETER_UNITS
    combination: np.ndarray = field(init=False, repr=False)
    structure: Any = field(default=None, compare=False, repr=False)
    """the RobotDynamics whose kinematic structure the regressor uses (None: the nominal arm)"""
    fixed_names: tuple[str, ...] | None = field(default=None, compare=False, repr=False)
    """base-parameter names kept from the grouping this one was regrouped from (:func:`regrouped_on`)"""
    pattern: np.ndarray | None = field(default=None, compare=False, repr=False)
    """which standard parameters each base parameter held in that grouping (bool, n_base x 78)"""

    def __post_init__(self) -> None:
        combination = np.zeros((self.independent.size, len(self.names)))
        combination[np.arange(self.independent.size), self.independent] = 1.0
        combination[:, self.dependent] = self.kappa
        combination.setflags(write=False)
        object.__setattr__(self, "combination", combination)

    # -- sizes and names ------------------------------------------------------------
    @property
    def count(self) -> int:
        """Number of base parameters (the rank of the regressor)."""
        return int(self.independent.size)

    @property
    def base_names(self) -> tuple[str, ...]:
        """Name of each base parameter: its leading standard parameter, with an ``R``
        suffix (``regrouped``) when others are merged into it (``Izz1R``); a grouping carried over
        to another geometry (:func:`regrouped_on`) keeps the original names."""
        if self.fixed_names is not None:
            return self.fixed_names
        return tuple(self.names[j] + ("R" if len(terms) > 1 else "")
                     for j, terms in zip(self.independent, self.terms()))

    @property
    def base_units(self) -> tuple[str, ...]:
        """Unit of each base parameter (that of its leading standard parameter)."""
        return tuple(self.units[j] for j in self.independent)

    def terms(self) -> list[list[Term]]:
        """Per base parameter, the standard parameters it combines with their coefficients."""
        out = []
        for row in self.combination:
            terms = []
            for j in np.flatnonzero(row):
                terms.append(Term(self.names[j], float(row[j]), format_coefficient(float(row[j]))))
            out.append(terms)
        return out

    def definitions(self) -> list[str]:
        """Readable definition of each base parameter, e.g. ``Izz1 + Izz2 + Izz3 + Ia1``."""
        out = []
        for terms in self.terms():
            text = ""
            for k, term in enumerate(terms):
                c = term.text
                sign = "-" if c.startswith("-") else "+"
                magnitude = c.lstrip("-")
                body = term.name if magnitude == "1" else f"{magnitude}*{term.name}"
                text += (("-" if sign == "-" else "") + body) if k == 0 else f" {sign} {body}"
            out.append(text)
        return out

    def report(self) -> str:
        """A table: base parameter name, unit, definition; then what is unidentifiable."""
        lines = [f"{self.count} base parameters of {len(self.names)} standard ones "
                 f"(QR of {6 * self.n_states} x {len(self.names)} stacked regressor, rank tolerance "
                 f"{self.rank_tolerance:g}, gap {self.gap:.2g}):"]
        width = max(len(n) for n in self.base_names)
        for name, unit, text in zip(self.base_names, self.base_units, self.definitions()):
            lines.append(f"  {name:<{width}}  [{unit}]  = {text}")
        zero = [self.names[j] for j in self.zero_columns]
        merged = [self.names[j] for j in self.dependent if j not in set(self.zero_columns.tolist())]
        lines.append(f"no effect on the torques ({len(zero)}): {', '.join(zero)}")
        lines.append(f"merged into base parameters ({len(merged)}): {', '.join(merged)}")
        return "\n".join(lines)

    # -- maps between standard and base parameters -------------------------------------
    def base_values(self, parameter_vector: ArrayLike) -> np.ndarray:
        """``p_b = p_1 + kappa p_2`` (eq. 22) of a 78-vector (payload folded in if any)."""
        p = _vector(parameter_vector, len(self.names), "parameter_vector")
        return self.combination @ p

    def base_regressor(self, regressor: ArrayLike) -> np.ndarray:
        """``Theta_1``: the independent columns of a regressor (..., 78) -> (..., n_base)."""
        y = np.asarray(regressor, dtype=float)
        if y.shape[-1] != len(self.names):
            raise BaseParameterError(f"regressor has {y.shape[-1]} columns, expected {len(self.names)}")
        return y[..., self.independent]

    def full_parameters(self, base_values: ArrayLike, reference: ArrayLike,
                        scale: ArrayLike | None = None) -> np.ndarray:
        """A 78-vector ``p`` with ``base_values(p) == base_values`` closest to ``reference``.

        Minimises ``sum(((p - reference) / scale)^2)`` subject to the base relation (a
        minimum-norm correction). ``scale`` (78,) defaults to ``|reference|`` plus a
        floor per unit (0.1 kg, 0.01 kg m, 0.001 kg m^2, 0.1 N m s/rad, 0.1 N m), so
        each parameter moves in proportion to its size and masses stay positive for
        moderate corrections. Parameters without effect keep their reference values.
        Any 78-vector with the same base values gives the same torques: use it to build
        a :class:`robot.dynamics.RobotDynamics` (with payload zero, the identified base
        parameters already contain the payload).
        """
        pb = _vector(base_values, self.count, "base_values")
        ref = _vector(reference, len(self.names), "reference")
        s = default_scale(ref) if scale is None else _vector(scale, len(self.names), "scale")
        if np.any(s <= 0.0):
            raise BaseParameterError("scale: expected 78 positive numbers")
        if self.pattern is None:
            k = self.combination * s  # K S
            correction = np.linalg.lstsq(k, pb - self.combination @ ref, rcond=None)[0]
            return ref + s * correction
        # a regrouped grouping: its small geometric couplings (mx2 - 0.0009 m3) would let the
        # minimum-norm step move a mass by kilograms to fit a first moment; correct along the
        # original grouping and repeat (converges like the couplings, 1e-3 per pass)
        k = self.combination * self.pattern * s
        p = ref.copy()
        for _ in range(6):
            p = p + s * np.linalg.lstsq(k, pb - self.combination @ p, rcond=None)[0]
        return p

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description: names, definitions, terms, tolerances."""
        return {
            "count": self.count,
            "standard_parameters": len(self.names),
            "rank_tolerance": self.rank_tolerance,
            "pivot_gap": self.gap,
            "kappa_residual": self.kappa_residual,
            "states": self.n_states,
            "seed": self.seed,
            "base_parameters": [
                {"name": name, "unit": unit, "definition": text,
                 "terms": {t.name: t.coefficient for t in terms}}
                for name, unit, text, terms in zip(self.base_names, self.base_units, self.definitions(),
                                                   self.terms())
            ],
            "no_effect": [self.names[j] for j in self.zero_columns],
            "merged": [self.names[j] for j in self.dependent if j not in set(self.zero_columns.tolist())],
        }


def default_scale(reference: np.ndarray) -> np.ndarray:
    """|reference| plus a per-unit floor (kg 0.1, kg m 0.01, kg m^2 0.001, N m s/rad 0.1, N m 0.1)."""
    floor = {"kg": 0.1, "kg m": 0.01, "kg m^2": 1e-3, "N m s/rad": 0.1, "N m": 0.1}
    return np.abs(reference) + np.array([floor[u] for u in PARAMETER_UNITS])


def format_coefficient(value: float) -> str:
    """A kappa coefficient as text: exact short decimal, small fraction, or 6 digits."""
    if value == 0.0:
        return "0"
    tol = 1e-11 * max(1.0, abs(value))
    for digits in range(MAX_DECIMALS + 1):
        r = round(value, digits)
        if abs(value - r) <= tol:
            text = f"{r:.{digits}f}"
            return text.rstrip("0").rstrip(".") if "." in text else text
    frac = Fraction(value).limit_denominator(64)
    if abs(value - float(frac)) <= tol:
        return f"{frac.numerator}/{frac.denominator}"
    return f"{value:.6g}"


def random_states(parameters: RobotParameters, n_states: int, seed: int) -> tuple[np.ndarray, ...]:
    """``n_states`` joint states (q, qd, qdd), each (n, 6): uniform in the limits (seeded)."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(parameters.position_lower, parameters.position_upper, (n_states, 6))
    qd = rng.uniform(-1.0, 1.0, (n_states, 6)) * parameters.velocity_limit
    qdd = rng.uniform(-1.0, 1.0, (n_states, 6)) * parameters.acceleration_limit
    return q, qd, qdd


def compute_base_parameters(dynamics: RobotDynamics | None = None, *, n_states: int = DEFAULT_STATES,
                            seed: int = DEFAULT_SEED, rank_tolerance: float = RANK_TOLERANCE) -> BaseParameters:
    """QR analysis of the regressor of ``dynamics`` (default: the nominal arm), see module doc."""
    if isinstance(n_states, bool) or not isinstance(n_states, int) or n_states * 6 < N_PARAMETERS:
        raise BaseParameterError(f"n_states = {n_states!r}, expected an integer >= {math.ceil(N_PARAMETERS / 6)}")
    if not (isinstance(rank_tolerance, float) and 0.0 < rank_tolerance < 1.0):
        raise BaseParameterError(f"rank_tolerance = {rank_tolerance!r}, expected a float in (0, 1)")
    given = dynamics is not None
    dynamics = dynamics or RobotDynamics()
    q, qd, qdd = random_states(dynamics.parameters, n_states, seed)
    theta = dynamics.regressor_batch(q, qd, qdd).reshape(-1, N_PARAMETERS)
    base = base_parameters_of(theta, rank_tolerance=rank_tolerance, n_states=n_states, seed=seed)
    # the regressor of this structure (a calibrated arm's geometry differs from the nominal one)
    return dataclasses.replace(base, structure=dynamics) if given else base


@threadpool_limits.wrap(limits=1, user_api="blas")
def base_parameters_of(theta: np.ndarray, *, rank_tolerance: float = RANK_TOLERANCE, n_states: int = 0,
                       seed: int = -1, names: tuple[str, ...] = PARAMETER_NAMES,
                       units: tuple[str, ...] = PARAMETER_UNITS) -> BaseParameters:
    """The base-parameter structure of a stacked regressor ``theta`` (rows, P)."""
    theta = np.asarray(theta, dtype=float)
    if theta.ndim != 2 or theta.shape[1] != len(names) or theta.shape[0] < theta.shape[1]:
        raise BaseParameterError(f"theta has shape {theta.shape}, expected (rows >= {len(names)}, {len(names)})")
    if not np.all(np.isfinite(theta)):
        raise BaseParameterError("theta: expected finite numbers")
    norms = np.linalg.norm(theta, axis=0)
    zero = norms <= ZERO_COLUMN_TOLERANCE * norms.max()
    scale = np.where(zero, 1.0, norms)
    scaled = np.where(zero, 0.0, theta / scale)

    # rank-revealing QR with column pivoting (eq. 20)
    r_pivot = scipy.linalg.qr(scaled, mode="r", pivoting=True)[0]
    diag = np.abs(np.diag(r_pivot)) / abs(r_pivot[0, 0])
    rank = int(np.sum(diag > rank_tolerance))
    gap = float(diag[rank - 1] / max(diag[rank], 1e-300)) if rank < diag.size else math.inf

    # independent columns in natural order: unpivoted QR, keep columns that add a direction
    independent = _natural_order_independent(scaled, ~zero, rank_tolerance)
    dependent = np.flatnonzero(~np.isin(np.arange(len(names)), independent))
    if independent.size != rank:
        raise BaseParameterError(
            f"the natural-order selection kept {independent.size} columns but the pivoted QR has rank {rank}; "
            f"the regressor is numerically ambiguous at rank_tolerance = {rank_tolerance:g}")

    # kappa = R11^-1 R12 (eq. 23-25) on the reordered scaled columns, back to natural units
    r = np.linalg.qr(scaled[:, np.concatenate((independent, dependent))], mode="r")
    nb = independent.size
    kappa_scaled = scipy.linalg.solve_triangular(r[:nb, :nb], r[:nb, nb:])
    kappa = kappa_scaled / scale[independent][:, None] * scale[dependent][None, :]
    kappa[:, zero[dependent]] = 0.0
    kappa[np.abs(kappa) < KAPPA_ZERO_TOLERANCE] = 0.0
    residual = np.abs(theta[:, dependent] - theta[:, independent] @ kappa).max() / norms.max()
    for array in (independent, dependent, kappa, diag):
        array.setflags(write=False)
    zero_idx = np.flatnonzero(zero)
    zero_idx.setflags(write=False)
    return BaseParameters(independent, dependent, kappa, zero_idx, diag, gap, float(residual), rank_tolerance,
                          n_states, seed, tuple(names), tuple(units))


def _natural_order_independent(scaled: np.ndarray, candidates: np.ndarray, tolerance: float) -> np.ndarray:
    """Columns (unit norm) kept in order when their part orthogonal to the kept ones exceeds
    ``tolerance``: the unpivoted QR of the kept columns, done column by column with
    re-orthogonalisation so dropped columns leave no round-off direction behind."""
    basis = np.zeros((scaled.shape[0], 0))
    kept = []
    for j in np.flatnonzero(candidates):
        v = scaled[:, j].copy()
        for _ in range(2):
            v -= basis @ (basis.T @ v)
        norm = np.linalg.norm(v)
        if norm > tolerance:
            kept.append(j)
            basis = np.column_stack((basis, v / norm))
    return np.array(kept, dtype=int)


REGROUP_SPAN_TOLERANCE = 1e-5
"""Relative least-squares residual (unit-norm columns) below which a dependent column counts as
in the span of the independent ones in :func:`regrouped_on` (measured on a true robot: in the span
1e-7 and below, out of it 6e-4 and more)."""


REGROUP_ZERO_TOLERANCE = 1e-6
"""Regrouping coefficients of unit-norm columns below this are round-off of the least squares in
:func:`regrouped_on` (the geometric errors' couplings are 1e-4 and larger)."""


def regrouped_on(base: BaseParameters, dynamics: RobotDynamics, *, n_states: int = DEFAULT_STATES,
                 seed: int = DEFAULT_SEED) -> BaseParameters:
    """``base``'s grouping (the same independent, dependent and zero columns, names and
    definitions) with the regrouping coefficients kappa of another kinematic structure
    (``dynamics``, e.g. a calibrated arm whose link lengths differ from the nominal ones by
    mm): kappa = the least-squares fit over random states of each dependent column by the
    independent columns it is grouped with nominally; ``kappa_residual`` says how far the grouping is from exact on that
    structure (the calibrated geometry breaks some of the nominal symmetries slightly). The
    result's regressor is that structure's (``structure``)."""
    q, qd, qdd = random_states(dynamics.parameters, n_states, seed)
    theta = dynamics.regressor_batch(q, qd, qdd).reshape(-1, len(base.names))
    norms = np.linalg.norm(theta, axis=0)
    scale = np.where(norms > 0.0, norms, 1.0)
    ind, dep = np.asarray(base.independent), np.asarray(base.dependent)
    kappa = np.zeros_like(np.asarray(base.kappa))
    independent = theta[:, ind] / scale[ind]
    # velocity-only columns (rotor inertia, friction) cannot stand in for a link column: only
    # round-off would put a link parameter into them
    drive_train = np.isin(ind, np.arange(ROTOR_INERTIA_SLICE.start, COULOMB_SLICE.stop))
    for k, column in enumerate(dep):
        target = theta[:, column] / scale[column]
        nominal_rows = np.flatnonzero(np.asarray(base.kappa)[:, k])
        allowed = np.flatnonzero(~drive_train | np.isin(np.arange(ind.size), nominal_rows))
        # a dependent column still in the span of the independent ones (m3..m6: the geometric errors
        # add couplings such as mx2 - 0.0009 m3) is regrouped on all of them; one that the calibrated
        # geometry moves out of the span (my3, Ia2: relative residual 6e-4, 5e-3) only on the columns
        # it is grouped with nominally - a fit on all would smear it over unrelated parameters
        coef = np.zeros(ind.size)
        coef[allowed], *_ = np.linalg.lstsq(independent[:, allowed], target, rcond=None)
        if np.linalg.norm(independent @ coef - target) > REGROUP_SPAN_TOLERANCE:
            coef = np.zeros(ind.size)
            if nominal_rows.size:
                coef[nominal_rows], *_ = np.linalg.lstsq(independent[:, nominal_rows], target, rcond=None)
        coef[np.abs(coef) < REGROUP_ZERO_TOLERANCE] = 0.0  # least-squares round-off, not a coupling
        kappa[:, k] = coef / scale[ind] * scale[column]
    kappa[:, np.isin(dep, base.zero_columns)] = 0.0
    kappa[np.abs(kappa) < KAPPA_ZERO_TOLERANCE] = 0.0
    residual = float(np.abs(theta[:, dep] - theta[:, ind] @ kappa).max() / norms.max())
    kappa.setflags(write=False)
    pattern = base.combination != 0.0
    pattern.setflags(write=False)
    return dataclasses.replace(base, kappa=kappa, kappa_residual=residual, structure=dynamics,
                               fixed_names=base.base_names, pattern=pattern)


@lru_cache(maxsize=1)
def nominal_base_parameters() -> BaseParameters:
    """The base parameters of the nominal arm's structure (cached)."""
    return compute_base_parameters(RobotDynamics(parameters=load_parameters()))


def _vector(value: ArrayLike, length: int, name: str) -> np.ndarray:
    out = np.asarray(value, dtype=float).reshape(-1) if np.ndim(value) <= 1 else None
    if out is None or out.shape != (length,) or not np.all(np.isfinite(out)):
        shape = np.shape(value)
        raise BaseParameterError(f"{name} has shape {shape}, expected {length} finite numbers")
    return out
