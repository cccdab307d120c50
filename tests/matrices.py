"""Score matrices for tests: well-conditioned ones and the degenerate shapes of real data."""

from __future__ import annotations

import numpy as np


def well_conditioned(n: int, m: int, seed: int) -> np.ndarray:
    """n >> m rows from a correlated Gaussian: full-rank, no ties, like eq. 2 assumes."""
    rng = np.random.default_rng(seed)
    mix = rng.normal(size=(m, m)) / np.sqrt(m) + np.eye(m)
    return rng.normal(size=(n, m)) @ mix + rng.normal(size=m)


def degenerate(n: int, m: int, seed: int, *, constant: int, duplicate: int, rank: int):
    """A matrix with ``constant`` never-feasible columns (all at the failure value),
    ``duplicate`` columns copied from others, and the rest of rank at most ``rank``.

    Entries are mostly failures (-10) like real grasp matrices; feasible ones are -1..-5.
    """
    constant = min(constant, m - 1)
    duplicate = min(duplicate, m - constant - 1)
    rng = np.random.default_rng(seed)
    latent = rng.normal(size=(n, rank)) @ rng.normal(size=(rank, m))
    feasible = latent > 0.8
    D = np.where(feasible, -1.0 - 4.0 * rng.random((n, m)), -10.0)
    D[:, :constant] = -10.0
    for j in range(duplicate):
        D[:, m - 1 - j] = D[:, constant + j % (m - constant - duplicate)]
    return D
