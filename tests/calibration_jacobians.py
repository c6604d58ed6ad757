"""Shared by the calibration selection tests: random stacks of identification Jacobians."""
from __future__ import annotations

import numpy as np


def correlated_jacobians(n: int, k: int, p: int, seed: int = 0) -> np.ndarray:
    """``n`` random ``k x p`` Jacobians (shape ``(n, k, p)``) from ``default_rng(seed)``.

    The columns are mixed (correlated) and scaled per configuration by factors between
    e^-1.5 and e^1, so the conditioning of a subset depends strongly on which configurations
    it holds.
    """
    rng = np.random.default_rng(seed)
    mix = np.eye(p) + 0.8 * rng.standard_normal((p, p)) / np.sqrt(p)
    scale = np.exp(rng.uniform(-1.5, 1.0, size=(n, 1, p)))
    return (rng.standard_normal((n, k, p)) * scale) @ mix
