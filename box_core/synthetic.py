"""Synthetic score matrices shaped like real planning data, for demos, tests and benchmarks.

Real matrices (the authors' 1800 x 162 grasp-and-arm data) are mostly infeasible, have only
a few dozen columns that are ever feasible, and owe their correlations to latent instance
*types* (object on the table or on the shelf, which side is cluttered): instances of one
type succeed with the same constraints.  This generator reproduces that structure.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True, eq=False)
class SyntheticData:
    scores: np.ndarray  # (n, m) negated path lengths; NaN-free, arbitrary where infeasible
    feasible: np.ndarray  # (n, m) bool
    times: np.ndarray  # (n, m) seconds per planning call
    features: np.ndarray  # (m, p) constraint features
    types: np.ndarray  # (n,) latent type of each instance

    def save(self, path) -> None:
        """Write an .npz archive atomically: a crash never leaves half a file at ``path``."""
        path = Path(path)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        with open(tmp, "wb") as f:
            np.savez_compressed(f, scores=self.scores, feasible=self.feasible,
                                times=self.times, features=self.features)
        os.replace(tmp, path)


def score_matrix(
    n: int = 1800,
    m: int = 162,
    *,
    types: int = 12,
    useful: int = 50,
    per_type: int = 4,
    p_good: float = 0.95,
    p_other: float = 0.005,
    features: int = 6,
    seed: int = 0,
) -> SyntheticData:
    """Sample a matrix: ``useful`` columns are ever feasible, the others never.

    Each latent type favours its own ``per_type`` useful columns (feasible with probability
    ``p_good``); any other useful column succeeds with probability ``p_other``.  Feasible
    calls take about 15 ms, failed ones about 60 ms (IK failures are cheap, exhausted
    planning budgets are not).
    """
    if not (1 <= useful <= m and 1 <= per_type <= useful and types >= 1 and n >= 1):
        raise ValueError("need 1 <= per_type <= useful <= m, types >= 1 and n >= 1")
    rng = np.random.default_rng(seed)
    useful_cols = rng.choice(m, size=useful, replace=False)
    kind = rng.integers(types, size=n)
    prob = np.zeros((types, m))
    prob[:, useful_cols] = p_other
    # Types favour disjoint groups of columns while there are enough useful columns, as
    # top grasps serve objects on the table and side grasps objects on the shelf.
    pool = rng.permutation(np.tile(useful_cols, -(-types * per_type // useful)))
    for z in range(types):
        prob[z, pool[z * per_type:(z + 1) * per_type]] = p_good
    feasible = rng.random((n, m)) < prob[kind]
    base = rng.uniform(2.0, 6.0, size=m)  # typical joint-space path length per constraint
    type_shift = rng.normal(0.0, 0.5, size=(types, m))
    length = np.maximum(0.3, base + type_shift[kind] + rng.normal(0.0, 0.3, size=(n, m)))
    scores = np.where(feasible, -length, 0.0)
    times = np.where(
        feasible,
        0.015 * length / 4.0 * rng.lognormal(0.0, 0.3, size=(n, m)),
        rng.choice([0.002, 0.12], size=(n, m), p=[0.5, 0.5]) * rng.lognormal(0.0, 0.2, (n, m)),
    )
    theta = rng.normal(size=(m, features))
    return SyntheticData(scores=scores, feasible=feasible, times=times, features=theta, types=kind)
