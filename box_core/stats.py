"""Small statistics helpers shared by the evaluator and its reports.

Every interval here is a percentile bootstrap over rows (instances), never a Student-t
interval: times are heavy-tailed and never negative, and a t interval of a mean time over a
few dozen instances can reach below zero, which no mean time can.  A percentile bootstrap
interval of a mean lies within the observed values, so the interval of a mean time is never
negative and the interval of a mean score never leaves the scores' range.  The resamples use
a fixed seed: the same data always give the same interval.
"""

from __future__ import annotations

import math

import numpy as np

#: Bootstrap resamples behind every interval.
BOOTSTRAP_RESAMPLES = 2000

#: The interval method, as reports and summaries name it.
INTERVAL_METHOD = "percentile bootstrap"

#: One sentence for reports and table captions saying how intervals are computed.
INTERVAL_NOTE = (
    f"Intervals are {INTERVAL_METHOD} intervals ({BOOTSTRAP_RESAMPLES} resamples of the "
    "instances, fixed seed; ratios resample the instances in pairs): an interval of a mean "
    "time lies within the observed times, so it is never negative."
)

#: Resampled means computed per batch are at most this many weights (bounded memory).
_BATCH_ENTRIES = 1 << 22


def mean_ci(values, level: float = 0.95) -> tuple[float, float, float]:
    """Mean and its two-sided percentile bootstrap interval, ignoring NaN.

    Returns (nan, nan, nan) for no values and (mean, nan, nan) for a single value.
    """
    x = np.asarray(values, dtype=np.float64).ravel()
    x = x[~np.isnan(x)]
    if x.size == 0:
        return (math.nan, math.nan, math.nan)
    mean = float(x.mean())
    if x.size == 1:
        return (mean, math.nan, math.nan)
    lo, hi = _percentiles(bootstrap_means(x[:, None])[:, 0], level)
    return (mean, lo, hi)


def mean_ci_columns(values: np.ndarray, level: float = 0.95):
    """Column-wise :func:`mean_ci` of a complete (rows x columns) array: three arrays.

    The rows are resampled together, so the band of a curve is that of whole instances.
    """
    x = np.asarray(values, dtype=np.float64)
    mean = x.mean(axis=0)
    if x.shape[0] < 2:
        nan = np.full_like(mean, np.nan)
        return mean, nan, nan
    boot = bootstrap_means(x)
    tail = (1 - _checked(level)) / 2 * 100
    lo, hi = np.percentile(boot, [tail, 100 - tail], axis=0)
    return mean, np.minimum(lo, mean), np.maximum(hi, mean)


def paired_ratio(times, ref, level: float = 0.95) -> tuple[float, float, float]:
    """mean(times) / mean(ref) over rows where both are not NaN, with a paired bootstrap
    interval: (ratio, low, high), NaN when no row has both."""
    times, ref = np.asarray(times, dtype=np.float64), np.asarray(ref, dtype=np.float64)
    both = ~np.isnan(times) & ~np.isnan(ref)
    a, b = times[both], ref[both]
    if a.size == 0 or b.sum() <= 0:
        return (math.nan, math.nan, math.nan)
    ratio = float(a.mean() / b.mean())
    means = bootstrap_means(np.column_stack([a, b]))
    with np.errstate(divide="ignore", invalid="ignore"):
        boot = means[:, 0] / means[:, 1]
    lo, hi = _percentiles(boot[np.isfinite(boot)], level)
    return (ratio, lo, hi)


def bootstrap_means(x: np.ndarray, resamples: int = BOOTSTRAP_RESAMPLES,
                    seed: int = 0) -> np.ndarray:
    """Column means of ``resamples`` bootstrap resamples of the rows of ``x`` (n x c):
    a (resamples x c) array.  Resample r weights row i by how often it was drawn, so the
    memory used is bounded whatever n."""
    n = x.shape[0]
    rng = np.random.default_rng(seed)
    batch = max(1, min(resamples, _BATCH_ENTRIES // max(n, 1)))
    out = np.empty((resamples, x.shape[1]))
    for start in range(0, resamples, batch):
        size = min(batch, resamples - start)
        drawn = rng.integers(0, n, size=(size, n)) + n * np.arange(size)[:, None]
        weights = np.bincount(drawn.ravel(), minlength=size * n).reshape(size, n)
        out[start:start + size] = weights @ x / n
    return out


def _percentiles(boot: np.ndarray, level: float) -> tuple[float, float]:
    if boot.size == 0:
        return (math.nan, math.nan)
    tail = (1 - _checked(level)) / 2 * 100
    lo, hi = np.percentile(boot, [tail, 100 - tail])
    return (float(lo), float(hi))


def _checked(level: float) -> float:
    if not 0 < level < 1:
        raise ValueError(f"level must lie in (0, 1), got {level}")
    return level
