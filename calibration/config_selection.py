"""Optimal measurement configurations for geometric calibration (paper section 3.3).

The paper's exchange algorithm over a candidate set ``Pi`` of N configurations,
each with its identification Jacobian ``Theta_j`` (k x p, k = 3 or 6 measured pose
components, p identifiable parameters), maximising an observation index of
``Lambda = sum_{j in xi} Theta_j^T Theta_j`` (eq. 15-17):

1. random non-singular start of ``n_start`` configurations;
2. remove and replace: remove the configuration whose removal lowers the index
   least, add the candidate that raises it most; repeat while this improves;
3. add the best single candidate until ``n_select`` configurations are chosen or
   no addition increases the index;
4. final remove and replace: every configuration of the subset is tried for
   removal with its best replacement; the best improving exchange over all
   (member, candidate) pairs is executed, until none improves.

Several restarts from seeded random starts; the best subset wins.

Cost of one exhaustive search (best addition to Lambda, or best exchange over the B
bases Lambda - Theta_i^T Theta_i): one p x p eigen-decomposition per base, GEMMs
rotating all candidate Jacobians into the 4 lowest eigenvectors of each base, then
upper bounds of increasing cost and tightness for every (candidate, base) pair:
Rayleigh quotients, a closed-form 3 x 3 Rayleigh-Ritz value, an 8 x 8 Rayleigh-Ritz
value; exact p x p eigenvalue problems only for pairs whose bound still beats the
best exact value found so far (visited in order of decreasing bound). The result is
the exact argmax of the exhaustive search (ties aside); ``benchmarks/bench_calibration.py``
measures it against brute force. D-optimality is exact from the determinant lemma.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from threadpoolctl import threadpool_limits

from calibration.observability import ObservationIndex, get_index

RELATIVE_IMPROVEMENT = 1e-9
"""An exchange or addition counts as an improvement when it raises the index by more
than this fraction of its current value (guards against cycling on round-off)."""

SINGULAR_RATIO = 1e-12
"""Lambda counts as singular when lambda_min <= SINGULAR_RATIO * lambda_max."""

MAX_START_ATTEMPTS = 200
"""Random starts drawn before giving up on finding a non-singular one."""

BLAS_THREADS = 1
"""BLAS/LAPACK threads during a selection. The work is many small problems (batched
30 x 30 eigen-decompositions, GEMMs with ~200 columns): one thread is as fast on an
idle machine, and on a loaded one multi-threaded OpenBLAS spins: measured on the
campaign set under load 10 on 2 cores, 20 s CPU / 68 s wall with the default threads
against 4.3 s CPU / 9.4 s wall with one."""


class ConfigurationSelectionError(ValueError):
    """The selection problem is malformed (shapes, sizes) or has no non-singular start."""


@dataclass(frozen=True)
class SelectionResult:
    """Outcome of :func:`select_configurations`.

    ``indices``: chosen candidate indices (sorted ascending), ``index_value``: their
    observation index, ``restart_values``: the best index of each restart,
    ``exchanges``: executed remove-and-replace exchanges over all restarts,
    ``exact_evaluations``: p x p eigenvalue problems solved for candidates,
    ``ritz_evaluations``: 8 x 8 Rayleigh-Ritz bounds computed,
    ``candidate_sweeps``: exhaustive best-addition searches, ``elapsed_s`` wall time,
    ``cpu_s`` CPU time of this process (s).
    """

    indices: np.ndarray
    index_name: str
    index_value: float
    restart_values: tuple[float, ...]
    exchanges: int
    exact_evaluations: int
    ritz_evaluations: int
    candidate_sweeps: int
    elapsed_s: float
    cpu_s: float
    stats: dict = field(default_factory=dict)


RITZ_DIMENSION = 8
"""Lowest eigenvectors of the current Lambda whose span gives the second bound (an
8 x 8 Rayleigh-Ritz eigenproblem, only for candidates that pass the first bound);
enlarged to the eigenvalues below CLUSTER_FACTOR * lambda_min plus 2."""

CLUSTER_FACTOR = 3.0


class _Search:
    """Exhaustive searches over one candidate set (holds counters)."""

    def __init__(self, jacobians: np.ndarray, index: ObservationIndex) -> None:
        self.theta = jacobians
        self.n, self.k, self.p = jacobians.shape
        self.flat = jacobians.reshape(self.n * self.k, self.p)
        self.theta_k = np.ascontiguousarray(np.moveaxis(jacobians, 1, 0))
        self.gram = np.einsum("nkp,nkq->npq", jacobians, jacobians)
        self.index = index
        self.r = min(RITZ_DIMENSION, self.p)
        self.exact_evaluations = 0
        self.ritz_evaluations = 0
        self.sweeps = 0

    def information(self, subset: np.ndarray) -> np.ndarray:
        block = self.theta[subset].reshape(-1, self.p)
        return block.T @ block

    def value(self, lam: np.ndarray) -> float:
        return float(self.index.value(np.linalg.eigvalsh(lam)))

    def exact(self, bases: np.ndarray, which: np.ndarray, cand: np.ndarray, sign: float = 1.0) -> np.ndarray:
        """Index of ``bases[which] + sign * Theta_cand^T Theta_cand`` (elementwise)."""
        self.exact_evaluations += len(cand)
        return self.index.value(np.linalg.eigvalsh(bases[which] + sign * self.gram[cand]))

    def removal_values(self, lam: np.ndarray, subset: np.ndarray) -> np.ndarray:
        """Index value of ``lam`` without each member of ``subset`` (len(subset),)."""
        return self.exact(lam[None], np.zeros(len(subset), dtype=int), subset, sign=-1.0)

    def best_pair(self, bases: np.ndarray, excluded: np.ndarray, threshold: float = -np.inf) -> tuple[int, int, float]:
        """Best (base b, candidate j) maximising the index of ``bases[b] + Theta_j^T
        Theta_j`` over candidates not ``excluded`` (boolean mask (N,)), considering
        only values above ``threshold``. Returns (b, j, value) or (-1, -1, -inf).

        ``bases`` (B, p, p): B = 1 for an addition, the subset minus each member for
        an exchange search.
        """
        self.sweeps += 1
        nb = bases.shape[0]
        d, v = np.linalg.eigh(bases)
        singular = d[:, 0] <= SINGULAR_RATIO * np.maximum(d[:, -1], 1e-300)
        if self.index.bound_is_exact:
            return self._best_pair_lemma(bases, d, v, singular, excluded, threshold)
        bound, high = self._stage_one_bounds(d, v, nb, threshold)
        bound[:, singular] = np.inf  # no bound from a singular base: evaluate exactly
        bound[excluded] = -np.inf
        flat_bound = bound.ravel()
        pairs = np.flatnonzero(flat_bound > threshold)
        pairs = pairs[np.argsort(-flat_bound[pairs], kind="stable")]
        best = (-1, -1, -np.inf)
        limit = threshold
        # the Ritz space covers the cluster of small eigenvalues (an optimised design
        # has several nearly equal ones; a smaller space would give loose bounds)
        cluster = int(np.max(np.sum(d < CLUSTER_FACTOR * np.maximum(d[:, :1], 1e-300), axis=1)))
        r = min(self.p, max(self.r, cluster + 2))
        vr = np.ascontiguousarray(v[:, :, :r])
        start, block = 0, 64
        while start < len(pairs):
            chunk = pairs[start:start + block]
            chunk = chunk[flat_bound[chunk] > limit]
            if len(chunk) == 0:
                break
            start, block = start + block, min(2 * block, 1024)
            cand, base = np.divmod(chunk, nb)
            if r < self.p:
                # Rayleigh-Ritz on the span of the r lowest eigenvectors of each base
                wr = np.matmul(self.theta[cand], vr[base])
                ritz = np.matmul(np.swapaxes(wr, 1, 2), wr)
                ritz[:, np.arange(r), np.arange(r)] += d[base, :r]
                low_r = np.linalg.eigvalsh(ritz)[:, 0]
                self.ritz_evaluations += len(chunk)
                tight = self.index.upper_bound_from_extremes(low_r, high[cand, base])
                tight[singular[base]] = np.inf
            else:
                tight = flat_bound[chunk]
            order = np.argsort(-tight, kind="stable")
            cand, base, tight = cand[order], base[order], tight[order]
            for s0 in range(0, len(cand), 16):
                if tight[s0] <= limit:
                    break
                sl = slice(s0, s0 + 16)
                keep = tight[sl] > limit
                c_j, c_b = cand[sl][keep], base[sl][keep]
                vals = self.exact(bases, c_b, c_j)
                i = int(np.argmax(vals))
                if vals[i] > limit:
                    best = (int(c_b[i]), int(c_j[i]), float(vals[i]))
                    limit = vals[i]
        return best

    def _stage_one_bounds(self, d: np.ndarray, v: np.ndarray, nb: int,
                          threshold: float) -> tuple[np.ndarray, np.ndarray]:
        """Cheap bounds for every (candidate, base) pair, shapes (N, B): an upper bound
        of the index (Rayleigh quotients of the 4 lowest eigenvectors of each base, then,
        where that still exceeds ``threshold``, the closed-form 3 x 3 Rayleigh-Ritz value
        on the 3 lowest) and a lower bound of lambda_max (Rayleigh quotient of the
        highest eigenvector)."""
        low_cols = min(4, self.p)
        cols = np.arange(low_cols)
        if self.index.uses_lambda_max:
            cols = np.r_[cols, self.p - 1]
        c = len(cols)
        vc = np.ascontiguousarray(np.moveaxis(v[:, :, cols], 0, 1).reshape(self.p, nb * c))
        sq = np.zeros((self.n, nb, c))
        cross = np.zeros((3, self.n, nb)) if low_cols >= 3 else None
        for kk in range(self.k):
            w = (self.theta_k[kk] @ vc).reshape(self.n, nb, c)
            sq += w * w
            if cross is not None:
                cross[0] += w[:, :, 0] * w[:, :, 1]
                cross[1] += w[:, :, 0] * w[:, :, 2]
                cross[2] += w[:, :, 1] * w[:, :, 2]
        diag = d[:, cols][None] + sq
        high = np.maximum(diag[:, :, -1], d[None, :, -1])
        low = diag[:, :, :low_cols].min(axis=2)
        if cross is not None:
            live = self.index.upper_bound_from_extremes(low, high) > threshold
            dl = diag[live]
            ritz3 = _smallest_eigenvalue_3x3(dl[:, 0], dl[:, 1], dl[:, 2], cross[0][live], cross[1][live],
                                             cross[2][live])
            low[live] = np.minimum(low[live], ritz3)
        return self.index.upper_bound_from_extremes(low, high), high

    def _best_pair_lemma(self, bases, d, v, singular, excluded, threshold) -> tuple[int, int, float]:
        best = (-1, -1, -np.inf)
        for b in range(bases.shape[0]):
            if singular[b]:
                cand = np.flatnonzero(~excluded)
                vals = self.exact(bases, np.full(len(cand), b), cand)
            else:
                w = (self.flat @ v[b]).reshape(self.n, self.k, self.p)
                vals = self.index.upper_bound(d[b], w)[~excluded]
                cand = np.flatnonzero(~excluded)
            if len(cand) == 0:
                continue
            i = int(np.argmax(vals))
            if vals[i] > max(threshold, best[2]):
                best = (b, int(cand[i]), float(vals[i]))
        return best

    def best_addition(self, lam: np.ndarray, excluded: np.ndarray) -> tuple[int, float]:
        """Candidate maximising the index of ``lam + Theta_j^T Theta_j``; (j, value)."""
        _, j, val = self.best_pair(lam[None], excluded)
        return j, val


def _smallest_eigenvalue_3x3(a00, a11, a22, a01, a02, a12) -> np.ndarray:
    """Smallest eigenvalue of symmetric 3 x 3 matrices given elementwise (closed form,
    trigonometric), raised by a round-off margin so it stays an upper bound of the
    exact value when used for pruning."""
    q = (a00 + a11 + a22) / 3.0
    p1 = a01**2 + a02**2 + a12**2
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = np.sqrt((b00**2 + b11**2 + b22**2 + 2.0 * p1) / 6.0)
    safe = np.where(p > 0.0, p, 1.0)
    det = (b00 * (b11 * b22 - a12**2) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02))
    r = np.clip(det / (2.0 * safe**3), -1.0, 1.0)
    phi = np.arccos(r) / 3.0
    smallest = np.where(p > 0.0, q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0), q)
    return smallest + 1e-9 * (np.abs(q) + p)


def _improves(new: float, old: float) -> bool:
    return new > old + RELATIVE_IMPROVEMENT * abs(old)


def _random_start(search: _Search, n_start: int, rng: np.random.Generator) -> np.ndarray:
    for _ in range(MAX_START_ATTEMPTS):
        subset = rng.choice(search.n, size=n_start, replace=False)
        d = np.linalg.eigvalsh(search.information(subset))
        if d[0] > SINGULAR_RATIO * d[-1]:
            return subset
    raise ConfigurationSelectionError(
        f"no non-singular random start of {n_start} configurations found in "
        f"{MAX_START_ATTEMPTS} attempts: the candidate Jacobians (p = {search.p} "
        "parameters) are rank-deficient; reduce to the identifiable parameters first"
    )


def _exchange(search: _Search, subset: np.ndarray, value: float, all_removals: bool,
              max_exchanges: int) -> tuple[np.ndarray, float, int]:
    """Remove-and-replace until no exchange improves the index.

    ``all_removals=False`` (step 2): remove the member whose removal lowers the index
    least and add the best candidate. ``all_removals=True`` (step 4): every member is
    tried for removal, each with its best replacement; the best improving exchange
    of all is executed.
    """
    exchanges = 0
    while exchanges < max_exchanges:
        lam = search.information(subset)
        excluded = np.zeros(search.n, dtype=bool)
        excluded[subset] = True
        blocks = search.gram[subset]
        if all_removals:
            positions = np.arange(len(subset))
        else:
            positions = np.array([int(np.argmax(search.removal_values(lam, subset)))])
        bases = lam[None] - blocks[positions]
        b, j, _ = search.best_pair(bases, excluded, threshold=value + RELATIVE_IMPROVEMENT * abs(value))
        if j < 0:
            break
        subset = subset.copy()
        subset[positions[b]] = j
        new = search.value(search.information(subset))
        if not _improves(new, value):
            break
        value = new
        exchanges += 1
    return subset, value, exchanges


def _one_restart(search: _Search, n_select: int, n_start: int, rng: np.random.Generator,
                 max_exchanges: int) -> tuple[np.ndarray, float, int]:
    subset = _random_start(search, n_start, rng)
    value = search.value(search.information(subset))
    subset, value, ex2 = _exchange(search, subset, value, False, max_exchanges)
    while len(subset) < n_select:
        excluded = np.zeros(search.n, dtype=bool)
        excluded[subset] = True
        j, new = search.best_addition(search.information(subset), excluded)
        if j < 0 or not _improves(new, value):
            break
        subset = np.append(subset, j)
        value = new
    subset, value, ex4 = _exchange(search, subset, value, True, max_exchanges)
    return subset, value, ex2 + ex4


def select_configurations(
    jacobians: np.ndarray,
    n_select: int,
    *,
    index: str = "min_eigenvalue",
    n_start: int | None = None,
    restarts: int = 5,
    seed: int = 0,
    max_exchanges: int = 10_000,
) -> SelectionResult:
    """Choose ``n_select`` of the N candidate configurations (paper's four steps).

    ``jacobians``: (N, k, p) identification Jacobians of the candidates, already
    reduced to the identifiable parameters and weighted (rows divided by the
    measurement noise, so Lambda is the inverse parameter covariance);
    ``index``: an observation-index name of
    :data:`calibration.observability.OBSERVATION_INDICES`;
    ``n_start``: size of the random start (default ``max(ceil(p/k) + 1, n_select // 2)``);
    ``restarts``: independent runs from seeded random starts (``seed``).
    """
    theta = np.ascontiguousarray(jacobians, dtype=float)
    if theta.ndim != 3 or not np.all(np.isfinite(theta)):
        raise ConfigurationSelectionError(
            f"argument 'jacobians': expected a finite array of shape (N, k, p), got shape "
            f"{np.shape(jacobians)}"
        )
    n, k, p = theta.shape
    minimum = -(-p // k)
    if not minimum <= n_select <= n:
        raise ConfigurationSelectionError(
            f"argument 'n_select' = {n_select}: expected between ceil(p/k) = {minimum} "
            f"(p = {p} parameters, k = {k} rows per configuration) and the {n} candidates"
        )
    if n_start is None:
        n_start = max(minimum + 1, n_select // 2)
    n_start = min(n_start, n_select)
    if n_start < minimum:
        raise ConfigurationSelectionError(
            f"argument 'n_start' = {n_start}: expected at least ceil(p/k) = {minimum}"
        )
    if restarts < 1:
        raise ConfigurationSelectionError(f"argument 'restarts' = {restarts}: expected >= 1")
    search = _Search(theta, get_index(index))
    rng = np.random.default_rng(seed)
    t0, c0 = time.perf_counter(), time.process_time()
    best_subset, best_value, values, exchanges = None, -np.inf, [], 0
    with threadpool_limits(limits=BLAS_THREADS, user_api="blas"):
        for _ in range(restarts):
            subset, value, ex = _one_restart(search, n_select, n_start, rng, max_exchanges)
            values.append(value)
            exchanges += ex
            if value > best_value:
                best_subset, best_value = subset, value
    elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
    return SelectionResult(
        indices=np.sort(best_subset),
        index_name=index,
        index_value=float(best_value),
        restart_values=tuple(float(v) for v in values),
        exchanges=exchanges,
        exact_evaluations=search.exact_evaluations,
        ritz_evaluations=search.ritz_evaluations,
        candidate_sweeps=search.sweeps,
        elapsed_s=elapsed,
        cpu_s=cpu,
        stats={"n_candidates": n, "rows_per_configuration": k, "parameters": p,
               "n_start": n_start, "restarts": restarts, "seed": seed},
    )


def linear_scan_indices(n_candidates: int, n_select: int) -> np.ndarray:
    """The paper's baseline: ``n_select`` configurations taken evenly from the
    candidate list (first and last included)."""
    if not 1 <= n_select <= n_candidates:
        raise ConfigurationSelectionError(
            f"argument 'n_select' = {n_select}: expected between 1 and {n_candidates}"
        )
    return np.unique(np.round(np.linspace(0, n_candidates - 1, n_select)).astype(int))


def random_selection_values(jacobians: np.ndarray, n_select: int, *, index: str = "min_eigenvalue",
                            draws: int = 100, seed: int = 0) -> np.ndarray:
    """Observation index of ``draws`` uniformly random subsets of ``n_select``
    candidates (the random-selection baseline), shape (draws,)."""
    theta = np.asarray(jacobians, dtype=float)
    rng = np.random.default_rng(seed)
    idx = get_index(index)
    subsets = np.array([rng.choice(theta.shape[0], n_select, replace=False) for _ in range(draws)])
    blocks = theta[subsets].reshape(draws, -1, theta.shape[2])
    lams = np.einsum("dmp,dmq->dpq", blocks, blocks)
    return idx.value(np.linalg.eigvalsh(lams))
