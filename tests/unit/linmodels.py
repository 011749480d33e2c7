"""Shared test fixtures: random linear-Gaussian models and a neutral SideInfo."""

import numpy as np

from navlab.filters import SideInfo


def random_model(rng, n, m):
    """A random stable-ish (F, Q, H, R) with positive-definite Q and R."""
    F = np.eye(n) + 0.1 * rng.standard_normal((n, n))
    A = rng.standard_normal((n, n))
    Q = 0.05 * A @ A.T + 0.01 * np.eye(n)
    H = rng.standard_normal((m, n))
    C = rng.standard_normal((m, m))
    R = 0.5 * C @ C.T + 0.1 * np.eye(m)
    return F, Q, H, R


def side(B, m):
    """Side information of a clean epoch (only the oracle reads it)."""
    return SideInfo(np.ones((B, m)), np.zeros((B, m)), np.zeros((B, m), bool))
