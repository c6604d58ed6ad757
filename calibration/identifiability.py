"""Which geometric error parameters a calibration can identify (paper eq. 20-25).

The stacked identification Jacobian ``Theta`` (rows: measured pose components of
many configurations; columns: the 39 error parameters) is column-scaled to unit
column norms (metres and radians mixed otherwise; columns below
:data:`ZERO_COLUMN_TOLERANCE` of the largest are zero) and decomposed by a QR
factorisation with column pivoting (LAPACK ``geqp3`` via scipy), which is rank
revealing: ``Theta S P = Q R`` with ``|R_11| >= |R_22| >= ...``. The numerical rank
is the number of diagonal entries ``|R_ii| > RANK_TOLERANCE * |R_00|``. The first
``rank`` pivoted columns are the identifiable parameters ``p_1``; every other
column is (up to round-off) a linear combination of them,
``Theta_2 = Theta_1 kappa`` with ``kappa = R_11^-1 R_12`` (eq. 25, mapped back to
natural units), so the data can only determine the *base* parameters
``p_b = p_1 + kappa p_2`` (eq. 22). Identifying ``p_1`` with ``p_2 = 0`` gives the
same flange poses as any ``(p_1, p_2)`` with the same ``p_b``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

RANK_TOLERANCE = 1e-8
"""Relative threshold on the pivoted R diagonal (unit-norm columns): a parameter is
identifiable when its column keeps more than 1e-8 of the largest column's norm after
projection on the columns chosen before it. Exactly dependent columns of this model
leave ~1e-15 (round-off); the weakest independent ones keep ~1e-3, so the rank does
not depend on the tolerance anywhere between about 1e-13 and 1e-4."""

ZERO_COLUMN_TOLERANCE = 1e-9
"""A column whose norm is below 1e-9 of the largest column norm is treated as zero
(the parameter has no first-order effect on the measurements, e.g. the encoder
offset of axis 6 on the position of a flange origin that lies on axis 6). Natural
units keep column norms comparable: m per m for lengths, m per rad (a lever arm of
about 1 m) for angles."""

KAPPA_REPORT_THRESHOLD = 1e-9
"""|kappa| entries (unit-norm columns) below this are round-off and not reported."""


class IdentifiabilityError(ValueError):
    """The Jacobian stack or the parameter names are malformed."""


@dataclass(frozen=True)
class Dependency:
    """A dropped parameter and the identifiable ones it merges into.

    ``coefficients[name]`` is kappa in natural units: a value ``x`` of the dropped
    parameter has the same effect on every measurement as ``coefficients[name] * x``
    added to the identifiable parameter ``name``. ``residual``: relative norm of
    ``Theta_2 - Theta_1 kappa`` for this column (round-off when truly dependent).
    """

    parameter: str
    coefficients: dict[str, float]
    residual: float

    def describe(self) -> str:
        if not self.coefficients:
            return f"{self.parameter}: no effect on the measurements (zero column)"
        terms = " + ".join(f"{c:+.4g}*{n}" for n, c in self.coefficients.items())
        return f"{self.parameter} = {terms} (merged; residual {self.residual:.1e})"


@dataclass(frozen=True)
class IdentifiabilityReport:
    """Result of :func:`identifiable_parameters`.

    ``identifiable``: indices into the full parameter vector, in parameter order;
    ``names``: all parameter names; ``r_diagonal``: |R_ii| / |R_00| in pivot order;
    ``pivot_order``: column indices in pivot order; ``kappa``: (rank, dropped)
    matrix in natural units (rows: ``identifiable`` in pivot order... see
    ``dependencies`` for a readable form); ``rank_tolerance``; ``measured_rows``:
    rows of Theta; ``gap``: ratio of the last kept to the first dropped diagonal.
    """

    names: tuple[str, ...]
    identifiable: np.ndarray
    dropped: np.ndarray
    pivot_order: np.ndarray
    r_diagonal: np.ndarray
    dependencies: tuple[Dependency, ...]
    rank_tolerance: float
    measured_rows: int
    column_scale: np.ndarray

    @property
    def rank(self) -> int:
        return int(self.identifiable.size)

    @property
    def identifiable_names(self) -> tuple[str, ...]:
        return tuple(self.names[i] for i in self.identifiable)

    @property
    def dropped_names(self) -> tuple[str, ...]:
        return tuple(self.names[i] for i in self.dropped)

    @property
    def gap(self) -> float:
        """|R| diagonal of the last identifiable over the first dropped column (> 1e6
        means a clear numerical rank)."""
        if self.rank == len(self.names) or self.rank == 0:
            return float("inf")
        last = self.r_diagonal[self.rank - 1]
        first = self.r_diagonal[self.rank]
        return float(last / first) if first > 0 else float("inf")

    def as_dict(self) -> dict:
        """JSON-friendly summary."""
        return {
            "rank": self.rank,
            "total": len(self.names),
            "identifiable": list(self.identifiable_names),
            "dropped": list(self.dropped_names),
            "dependencies": {d.parameter: d.coefficients for d in self.dependencies},
            "explanations": [d.describe() for d in self.dependencies],
            "rank_tolerance": self.rank_tolerance,
            "rank_gap": self.gap,
            "r_diagonal_pivot_order": {
                self.names[j]: float(r) for j, r in zip(self.pivot_order, self.r_diagonal)
            },
            "measured_rows": self.measured_rows,
        }


def identifiable_parameters(
    jacobians: np.ndarray,
    names: tuple[str, ...] | list[str],
    *,
    rank_tolerance: float = RANK_TOLERANCE,
) -> IdentifiabilityReport:
    """Rank-revealing QR of the stacked Jacobians (n, k, P) or (m, P).

    ``names``: the P parameter names. Use many (>= 50) well-spread configurations;
    rows may be weighted (e.g. divided by the measurement noise) beforehand.
    """
    theta = np.asarray(jacobians, dtype=float)
    if theta.ndim not in (2, 3):
        raise IdentifiabilityError(
            f"argument 'jacobians': expected shape (n, k, P) or (m, P), got {theta.shape}"
        )
    theta = theta.reshape(-1, theta.shape[-1])
    m, n_par = theta.shape
    if len(names) != n_par:
        raise IdentifiabilityError(
            f"argument 'names': expected {n_par} names (one per Jacobian column), got {len(names)}"
        )
    if not np.all(np.isfinite(theta)):
        raise IdentifiabilityError("argument 'jacobians': contains NaN or infinite entries")
    if m < n_par:
        raise IdentifiabilityError(
            f"argument 'jacobians': {m} rows cannot reveal the rank of {n_par} columns; "
            "stack more configurations"
        )
    scale = np.linalg.norm(theta, axis=0)
    scale = np.where(scale > ZERO_COLUMN_TOLERANCE * max(float(scale.max()), 1e-300), scale, 0.0)
    safe = np.where(scale > 0.0, scale, 1.0)
    scaled = np.where(scale > 0.0, theta / safe, 0.0)
    _, r, piv = scipy.linalg.qr(scaled, mode="economic", pivoting=True)
    diag = np.abs(np.diag(r))
    ref = diag[0] if diag.size and diag[0] > 0 else 1.0
    rel = diag / ref
    rank = int(np.sum(rel > rank_tolerance))
    kept, dropped = piv[:rank], piv[rank:]
    kappa_scaled = scipy.linalg.solve_triangular(r[:rank, :rank], r[:rank, rank:])
    deps = []
    for col, j in enumerate(dropped):
        if scale[j] == 0.0:
            deps.append(Dependency(names[j], {}, 0.0))
            continue
        coeffs = {}
        for row in np.argsort(piv[:rank]):
            i = kept[row]
            ks = kappa_scaled[row, col]
            if abs(ks) > KAPPA_REPORT_THRESHOLD:
                coeffs[names[i]] = float(ks * scale[j] / scale[i])
        resid = scaled[:, kept] @ kappa_scaled[:, col] - scaled[:, j]
        deps.append(Dependency(names[j], coeffs, float(np.linalg.norm(resid))))
    return IdentifiabilityReport(
        names=tuple(names),
        identifiable=np.sort(kept),
        dropped=np.sort(dropped),
        pivot_order=piv,
        r_diagonal=rel,
        dependencies=tuple(sorted(deps, key=lambda d: names.index(d.parameter))),
        rank_tolerance=rank_tolerance,
        measured_rows=m,
        column_scale=scale,
    )
