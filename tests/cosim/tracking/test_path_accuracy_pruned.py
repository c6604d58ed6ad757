"""The pruned distance-to-polyline of the ISO 9283 path accuracy equals, bit for bit, the
full search over every segment of the window (the former implementation, kept here)."""
import numpy as np
import pytest

from cosim.tracking.metrics import AT_WINDOW_SAMPLES, candidate_kernel, distance_to_polyline, path_accuracy


@pytest.fixture(params=[False, True], ids=["numpy", "compiled"])
def compiled(request):
    """Both candidate searches: numpy, and the C one (skipped only without a compiler and without
    $COSIM_NATIVE=require, which .ci/run sets: there a missing build fails)."""
    if request.param and candidate_kernel() is None:
        pytest.skip("no C compiler: the numpy search runs")
    return request.param


def full_window(points: np.ndarray, polyline: np.ndarray, window: int = AT_WINDOW_SAMPLES) -> np.ndarray:
    n = polyline.shape[0]
    if n == 1:
        return np.linalg.norm(points - polyline[0], axis=1)
    a = polyline[:-1]
    ab = polyline[1:] - a
    ab2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    out = np.empty(points.shape[0])
    offsets = np.arange(-window, window + 1)
    for start in range(0, points.shape[0], 2048):
        idx = np.arange(start, min(start + 2048, points.shape[0]))
        seg = np.clip(idx[:, None] + offsets[None, :], 0, n - 2)
        ap = points[idx][:, None, :] - a[seg]
        u = np.clip(np.einsum("ijk,ijk->ij", ap, ab[seg]) / ab2[seg], 0.0, 1.0)
        d = ap - u[..., None] * ab[seg]
        out[idx] = np.sqrt(np.einsum("ijk,ijk->ij", d, d).min(axis=1))
    return out


@pytest.mark.parametrize("seed", range(12))
def test_pruned_equals_full_window(seed, compiled):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 1000))
    step = rng.uniform(1e-4, 1.0)
    polyline = np.cumsum(rng.normal(size=(n, 3)) * step, axis=0)
    if seed % 3 == 0:  # a path that turns back on itself, points far off
        polyline[n // 2:] = polyline[n // 2:][::-1]
    points = polyline + rng.normal(size=(n, 3)) * rng.uniform(0.0, 5.0) * step
    window = int(rng.integers(1, 200)) if seed % 2 else AT_WINDOW_SAMPLES
    assert np.array_equal(distance_to_polyline(points, polyline, window, compiled=compiled),
                          full_window(points, polyline, window))


def test_iso_like_path_accuracy_per_segment():
    t = np.linspace(0.0, 1.0, 2001)
    commanded = np.column_stack([t, np.sin(3 * t) * 0.1, np.zeros_like(t)])
    measured = commanded + np.column_stack([np.zeros_like(t), 1e-4 * np.cos(40 * t), 2e-5 * np.ones_like(t)])
    segment = (t > 0.5).astype(int)
    at = path_accuracy(measured, commanded, segment)
    for k in (0, 1):
        mask = segment == k
        assert at[k] == float(full_window(measured[mask], commanded[mask]).max())


@pytest.mark.parametrize("lag", [0, 3, 18, 60])
def test_lagging_points_equal_full_window(lag, compiled):
    """Measured points trailing their commanded ones by ``lag`` samples (the standard cascade's
    case: the own segment is far, the nearest midpoint near): the second, tighter bound keeps
    the minimum the same number."""
    n = 3000
    s = np.linspace(0.0, 3.0, n)
    polyline = np.column_stack([0.5 * np.cos(s / 0.5), 0.5 * np.sin(s / 0.5), 0.05 * s])
    rng = np.random.default_rng(lag)
    points = np.vstack([polyline[:1].repeat(lag, 0), polyline[:n - lag]]) + 5e-5 * rng.normal(size=(n, 3))
    assert np.array_equal(distance_to_polyline(points, polyline, compiled=compiled), full_window(points, polyline))


def full_window_nan(points: np.ndarray, polyline: np.ndarray, window: int = AT_WINDOW_SAMPLES) -> np.ndarray:
    """The full search where segments are not finite: they are never the nearest (NaN only when
    the point or its own segment is NaN), as the pruned search has always treated them."""
    n = polyline.shape[0]
    a = polyline[:-1]
    ab = polyline[1:] - a
    ab2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    out = np.empty(points.shape[0])
    for i in range(points.shape[0]):
        seg = np.unique(np.clip(i + np.arange(-window, window + 1), 0, n - 2))
        ap = points[i] - a[seg]
        u = np.clip(np.einsum("ij,ij->i", ap, ab[seg]) / ab2[seg], 0.0, 1.0)
        d = ap - u[:, None] * ab[seg]
        d2 = np.einsum("ij,ij->i", d, d)
        own = d2[seg == min(i, n - 2)][0]
        out[i] = np.sqrt(own if np.isnan(own) else np.nanmin(d2))
    return out


@pytest.mark.parametrize("seed", range(6))
def test_points_and_segments_of_other_counts_and_nan(seed, compiled):
    """More or fewer points than polyline vertices, and NaN vertices (a failed run's set-points):
    the same numbers as the full search."""
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(2, 400))
    m = int(rng.integers(1, 500))
    polyline = np.cumsum(rng.normal(size=(n, 3)) * 1e-3, axis=0)
    points = polyline[np.minimum(np.arange(m), n - 1)] + rng.normal(size=(m, 3)) * 2e-3
    window = int(rng.integers(1, 60))
    if seed % 2:
        polyline[rng.integers(0, n, size=max(1, n // 20))] = np.nan
        points[rng.integers(0, m, size=max(1, m // 30))] = np.nan
    got = distance_to_polyline(points, polyline, window, compiled=compiled)
    assert np.array_equal(got, full_window_nan(points, polyline, window), equal_nan=True)
    if not seed % 2:
        assert np.array_equal(got, full_window(points, polyline, window))
