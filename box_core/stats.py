"""Small statistics helpers shared by the evaluator and its reports."""

from __future__ import annotations

import math

import numpy as np
from scipy import stats


def mean_ci(values, level: float = 0.95) -> tuple[float, float, float]:
    """Mean and its two-sided Student-t confidence interval, ignoring NaN.

    Returns (nan, nan, nan) for no values and (mean, nan, nan) for a single value.
    """
    x = np.asarray(values, dtype=np.float64)
    x = x[~np.isnan(x)]
    if x.size == 0:
        return (np.nan, np.nan, np.nan)
    mean = float(x.mean())
    if x.size == 1:
        return (mean, np.nan, np.nan)
    half = stats.t.ppf(0.5 + level / 2, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size)
    return (mean, float(mean - half), float(mean + half))


def mean_ci_columns(values: np.ndarray, level: float = 0.95):
    """Column-wise :func:`mean_ci` of a complete (rows x columns) array: three arrays."""
    x = np.asarray(values, dtype=np.float64)
    n = x.shape[0]
    mean = x.mean(axis=0)
    if n < 2:
        nan = np.full_like(mean, np.nan)
        return mean, nan, nan
    half = stats.t.ppf(0.5 + level / 2, n - 1) * x.std(axis=0, ddof=1) / np.sqrt(n)
    return mean, mean - half, mean + half


#: Resamples of the paired bootstrap behind ratio intervals (fixed seed: the same data
#: always give the same interval).
BOOTSTRAP_RESAMPLES = 2000


def paired_ratio(times, ref, level: float = 0.95) -> tuple[float, float, float]:
    """mean(times) / mean(ref) over rows where both are not NaN, with a paired bootstrap
    interval: (ratio, low, high), NaN when no row has both."""
    times, ref = np.asarray(times, dtype=np.float64), np.asarray(ref, dtype=np.float64)
    both = ~np.isnan(times) & ~np.isnan(ref)
    a, b = times[both], ref[both]
    if a.size == 0 or b.sum() <= 0:
        return (math.nan, math.nan, math.nan)
    ratio = float(a.mean() / b.mean())
    rng = np.random.default_rng(0)
    idx = rng.integers(0, a.size, size=(BOOTSTRAP_RESAMPLES, a.size))
    with np.errstate(divide="ignore", invalid="ignore"):
        boot = a[idx].mean(axis=1) / b[idx].mean(axis=1)
    tail = (1 - level) / 2 * 100
    lo, hi = np.nanpercentile(boot, [tail, 100 - tail])
    return (ratio, float(lo), float(hi))
