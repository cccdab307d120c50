"""How BOX depends on its training data and on C: learning curves and nested tuning of C.

The paper fixes the UCB coefficient C = 1.96 and suggests choosing it by cross-validation.
:func:`tune_c` does that without letting a test row influence its own C: the rows are split
into folds; for each fold, C is chosen by leave-one-out on the *other* folds only, then the
fold's rows are run with the prior of the other folds and that C.

Times here are planning time only (``measure_overhead=False``), so the figures are
deterministic for a given seed.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from box_core.loocv import holdout, loocv
from box_core.stats import mean_ci

DEFAULT_FRACTIONS = (0.1, 0.25, 0.5, 1.0)
DEFAULT_C_GRID = (0.0, 0.5, 1.0, 1.96, 3.0, 5.0)


@dataclass(frozen=True)
class CurvePoint:
    """Mean time to first feasible plan (with its interval) of one selector at one size."""

    selector: str
    fraction: float
    n_train: int
    rows: int  # held-out (row, repeat) pairs with a feasible constraint that were found
    mean: float
    low: float
    high: float


def _matrix_args(times, feasible, features, failure_rule, forbidden=None):
    """Everything here reads times to the first feasible plan only: rows stop there."""
    return {"times": times, "feasible": feasible, "features": features,
            "failure_rule": failure_rule, "measure_overhead": False, "forbidden": forbidden,
            "until_feasible": True}


def _take(a, rows):
    return None if a is None else np.asarray(a)[rows]


def learning_curve(
    scores,
    *,
    times=None,
    feasible=None,
    features=None,
    selectors: Sequence[str] = ("box", "static"),
    fractions: Iterable[float] = DEFAULT_FRACTIONS,
    repeats: int = 5,
    test_fraction: float = 0.2,
    seed: int = 0,
    failure_rule: str = "magnitude",
    level: float = 0.95,
    forbidden=None,
) -> list[CurvePoint]:
    """Time to first feasible plan versus the number of training rows.

    Each repeat draws a random test set (``test_fraction`` of the rows) and, for every
    fraction f, trains on the first f of the remaining rows in a random order (nested:
    a larger fraction adds rows).  Times of the eligible test rows are pooled over repeats;
    the interval is a percentile bootstrap over those (:mod:`box_core.stats`; repeats share
    rows, so it is a little narrow).  ``forbidden``: as in :func:`~box_core.loocv.loocv`.
    """
    D = np.asarray(scores)
    n = D.shape[0]
    fractions = tuple(float(f) for f in fractions)
    if not fractions or any(not 0 < f <= 1 for f in fractions):
        raise ValueError(f"fractions must lie in (0, 1], got {fractions}")
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    if not 0 < test_fraction < 1:
        raise ValueError(f"test_fraction must lie in (0, 1), got {test_fraction}")
    n_test = max(1, round(test_fraction * n))
    if n - n_test < 2:
        raise ValueError(f"{n} rows are too few for a learning curve (need >= {n_test + 2})")
    pooled = {(s, f): [] for s in selectors for f in fractions}
    sizes = {}
    for r in range(repeats):
        order = np.random.default_rng([seed, r]).permutation(n)
        test, pool = order[:n_test], order[n_test:]
        for f in fractions:
            train = pool[:max(2, round(f * pool.size))]
            sizes[f] = train.size
            res = holdout(D, train, test, selectors=tuple(selectors), seed=seed,
                          **_matrix_args(times, feasible, features, failure_rule, forbidden))
            for s in selectors:
                pooled[s, f].append(res.first_feasible_time[s][res.eligible])
    points = []
    for s in selectors:
        for f in fractions:
            values = np.concatenate(pooled[s, f])
            mean, lo, hi = mean_ci(values, level)
            points.append(CurvePoint(s, f, sizes[f], int((~np.isnan(values)).sum()),
                                     mean, lo, hi))
    return points


@dataclass(frozen=True)
class CTuning:
    """BOX with C tuned by nested cross-validation, against BOX with a fixed C.

    ``sensitivity[c] = (mean, low, high)``: leave-one-out on all rows with that C
    (what the figure shows; it does use every row, so it is descriptive, not a tuning).
    ``chosen[f]``: the C chosen for fold f from the other folds only.
    ``tuned`` / ``fixed``: per-row times to first feasible plan of the eligible rows, with
    the tuned C and with ``fixed_c``, each row run with the prior of the other folds.
    """

    grid: tuple[float, ...]
    fixed_c: float
    sensitivity: dict[float, tuple[float, float, float]]
    chosen: tuple[float, ...]
    tuned: np.ndarray
    fixed: np.ndarray

    def summary(self, level: float = 0.95) -> dict:
        return {"grid": list(self.grid), "fixed_c": self.fixed_c,
                "chosen": list(self.chosen),
                "tuned": mean_ci(self.tuned, level), "fixed": mean_ci(self.fixed, level),
                "sensitivity": {str(c): v for c, v in self.sensitivity.items()}}


def _mean_time(scores, rows, times, feasible, features, failure_rule, c, seed,
               forbidden) -> float:
    res = loocv(np.asarray(scores)[rows], selectors="box", params={"box": {"c": c}},
                seed=seed, **_matrix_args(_take(times, rows), _take(feasible, rows),
                                          features, failure_rule, _take(forbidden, rows)))
    t = res.first_feasible_time["box"][res.eligible]
    return float(np.nanmean(t)) if np.isfinite(t).any() else np.inf


def tune_c(
    scores,
    *,
    times=None,
    feasible=None,
    features=None,
    grid: Iterable[float] = DEFAULT_C_GRID,
    fixed_c: float = 1.96,
    folds: int = 5,
    seed: int = 0,
    failure_rule: str = "magnitude",
    level: float = 0.95,
    forbidden=None,
) -> CTuning:
    """Nested cross-validation of BOX's C (see the module docstring), plus its sensitivity;
    ``forbidden`` as in :func:`~box_core.loocv.loocv`."""
    D = np.asarray(scores)
    n = D.shape[0]
    grid = tuple(float(c) for c in grid)
    if not grid or any(c < 0 or not np.isfinite(c) for c in grid):
        raise ValueError(f"the C grid must hold finite values >= 0, got {grid}")
    if not 2 <= folds <= n // 3:
        raise ValueError(f"folds must lie between 2 and n / 3 = {n // 3}, got {folds}")
    every = np.arange(n)
    sensitivity = {}
    for c in grid:
        res = loocv(D, selectors="box", params={"box": {"c": c}}, seed=seed,
                    **_matrix_args(times, feasible, features, failure_rule, forbidden))
        sensitivity[c] = mean_ci(res.first_feasible_time["box"][res.eligible], level)
    parts = np.array_split(np.random.default_rng([seed, 7]).permutation(n), folds)
    chosen, tuned, fixed = [], [], []
    for part in parts:
        train = np.setdiff1d(every, part)
        costs = [_mean_time(D, train, times, feasible, features, failure_rule, c, seed,
                            forbidden) for c in grid]
        best = grid[int(np.argmin(costs))]  # ties: the first, i.e. the smallest C
        chosen.append(best)
        for c, out in ((best, tuned), (fixed_c, fixed)):
            res = holdout(D, train, part, selectors="box", params={"box": {"c": c}}, seed=seed,
                          **_matrix_args(times, feasible, features, failure_rule, forbidden))
            out.append(res.first_feasible_time["box"][res.eligible])
    return CTuning(grid=grid, fixed_c=float(fixed_c), sensitivity=sensitivity,
                   chosen=tuple(chosen), tuned=np.concatenate(tuned),
                   fixed=np.concatenate(fixed))
