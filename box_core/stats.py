"""Small statistics helpers shared by the evaluator and its reports.

Every interval here is a bootstrap interval over rows (instances) computed by
:func:`scipy.stats.bootstrap`, never a Student-t interval: times are heavy-tailed and never
negative, and a t interval of a mean time over a few dozen instances can reach below zero,
which no mean time can.

- A mean gets the percentile interval.  It lies within the observed values, so the interval
  of a mean time is never negative and that of a mean score never leaves the scores' range.
- A ratio of two means measured on the same instances (a selector's mean time over BOX's)
  resamples the instances in pairs and gets the BCa (bias-corrected and accelerated)
  interval: ratios of heavy-tailed means are skewed, which BCa corrects for.  Where BCa is
  undefined (every resampled ratio equal, or all on one side of the estimate) the percentile
  interval of the same resamples is returned instead.

The resamples come from a generator with a fixed seed: the same data always give the same
interval.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

# scipy.stats is imported by the functions that use it: importing it takes about half a
# second, which every process importing box_core (a planning worker, the box command) paid

#: Bootstrap resamples behind every interval.
BOOTSTRAP_RESAMPLES = 2000

#: Seed of the generator behind every interval.
BOOTSTRAP_SEED = 0

#: How the interval of a mean and that of a ratio of paired means are computed.
MEAN_INTERVAL_METHOD = "percentile bootstrap"
RATIO_INTERVAL_METHOD = "paired BCa bootstrap"

#: The interval methods, as tables and summaries name them in captions.
INTERVAL_METHOD = (f"{MEAN_INTERVAL_METHOD} for means, {RATIO_INTERVAL_METHOD} for ratios "
                   "(scipy.stats.bootstrap)")

#: One sentence for reports and table captions saying how intervals are computed.
INTERVAL_NOTE = (
    f"Intervals come from scipy.stats.bootstrap ({BOOTSTRAP_RESAMPLES} resamples of the "
    f"instances, fixed seed): {MEAN_INTERVAL_METHOD} intervals for means, which lie within "
    "the observed times, so an interval of a mean time is never negative; "
    f"{RATIO_INTERVAL_METHOD} intervals for ratios of mean times, which resample the "
    "instances in pairs and correct for the skew of a ratio."
)

#: Values a statistic sees per batch of resamples are at most this many (bounded memory).
_BATCH_ENTRIES = 1 << 18


def mean_ci(values, level: float = 0.95) -> tuple[float, float, float]:
    """Mean and its two-sided percentile bootstrap interval, ignoring NaN.

    Returns (nan, nan, nan) for no values and (mean, nan, nan) for a single value.
    """
    from scipy import stats
    level = _checked(level)
    x = np.asarray(values, dtype=np.float64).ravel()
    x = x[~np.isnan(x)]
    if x.size == 0:
        return (math.nan, math.nan, math.nan)
    mean = float(x.mean())
    if x.size == 1:
        return (mean, math.nan, math.nan)
    res = stats.bootstrap((x,), np.mean, **_options(x.size, level, "percentile"))
    low, high = res.confidence_interval
    # Resampled means of equal values can differ from the mean in the last bit (summation
    # order); the interval is held around the mean so that low <= mean <= high always.
    return (mean, min(float(low), mean), max(float(high), mean))


def mean_ci_columns(values: np.ndarray, level: float = 0.95):
    """Column-wise :func:`mean_ci` of a complete (rows x columns) array: three arrays.

    The rows are resampled together, so the band of a curve is that of whole instances.
    scipy resamples row *indices* (as it does itself for ``paired=True``) and the statistic
    turns each resample into column means with one matrix product: the same interval as
    ``bootstrap((values.T,), np.mean, axis=-1)`` (tests check it) at a fiftieth of the cost,
    since the (columns x resamples x rows) array of resampled values is never formed.
    """
    from scipy import stats
    level = _checked(level)
    x = np.asarray(values, dtype=np.float64)
    mean = x.mean(axis=0)
    if x.shape[0] < 2:
        nan = np.full_like(mean, np.nan)
        return mean, nan, nan
    res = stats.bootstrap((np.arange(x.shape[0]),), _ColumnMeans(x),
                          **_options(x.shape[0], level, "percentile"))
    low, high = (np.asarray(v, dtype=np.float64) for v in res.confidence_interval)
    return mean, np.minimum(low, mean), np.maximum(high, mean)


def paired_ratio(times, ref, level: float = 0.95) -> tuple[float, float, float]:
    """mean(times) / mean(ref) over rows where both are not NaN, with a paired BCa bootstrap
    interval: (ratio, low, high).

    (nan, nan, nan) when no row has both or ref's mean is not positive; (ratio, nan, nan)
    for a single such row (no interval from one instance).
    """
    level = _checked(level)
    times, ref = np.asarray(times, dtype=np.float64), np.asarray(ref, dtype=np.float64)
    both = ~np.isnan(times) & ~np.isnan(ref)
    a, b = times[both], ref[both]
    if a.size == 0 or b.sum() <= 0:
        return (math.nan, math.nan, math.nan)
    ratio = float(a.mean() / b.mean())
    if a.size == 1:
        return (ratio, math.nan, math.nan)
    low, high = ratio_interval(a, b, level)
    return (ratio, low, high)


def ratio_interval(a: np.ndarray, b: np.ndarray, level: float = 0.95) -> tuple[float, float]:
    """The paired BCa bootstrap interval of mean(a) / mean(b) (complete, equal-length
    arrays of at least two rows), or the percentile interval of the same resamples where
    BCa is undefined."""
    from scipy import stats
    options = _options(a.size, level, "BCa")
    with warnings.catch_warnings(), np.errstate(divide="ignore", invalid="ignore"):
        warnings.simplefilter("ignore", stats.DegenerateDataWarning)
        res = stats.bootstrap((a, b), _ratio_of_means, paired=True, **options)
    low, high = res.confidence_interval
    if math.isfinite(low) and math.isfinite(high):
        return (float(low), float(high))
    # BCa needs resamples on both sides of the estimate; without them (a constant ratio,
    # or a ratio at the edge of its resamples) the percentile interval is still defined.
    boot = res.bootstrap_distribution
    finite = _Distribution(boot[np.isfinite(boot)])
    if finite.bootstrap_distribution.size == 0:
        return (math.nan, math.nan)
    options.update(method="percentile", n_resamples=0)
    res = stats.bootstrap((a, b), _ratio_of_means, paired=True, bootstrap_result=finite,
                          **options)
    low, high = res.confidence_interval
    return (float(low), float(high))


def _ratio_of_means(a, b, axis=-1):
    return np.mean(a, axis=axis) / np.mean(b, axis=axis)


class _ColumnMeans:
    """Statistic of :func:`mean_ci_columns`: resampled row indices (..., n) to the column
    means of those rows, with the resamples last: (columns, ...)."""

    def __init__(self, x: np.ndarray):
        self.x = x

    def __call__(self, rows: np.ndarray, axis: int = -1) -> np.ndarray:
        rows = np.asarray(rows)
        lead, n = rows.shape[:-1], rows.shape[-1]
        flat = rows.reshape(-1, n)
        count = flat.shape[0]
        offsets = flat + self.x.shape[0] * np.arange(count)[:, None]
        weights = np.bincount(offsets.ravel(), minlength=count * self.x.shape[0])
        means = weights.reshape(count, self.x.shape[0]) @ self.x / n  # (count, columns)
        return np.moveaxis(means.reshape(*lead, self.x.shape[1]), -1, 0)


class _Distribution:
    """A bootstrap distribution handed back to scipy.stats.bootstrap (``bootstrap_result``)."""

    def __init__(self, values: np.ndarray):
        self.bootstrap_distribution = values


def _options(n: int, level: float, method: str) -> dict:
    return {"confidence_level": level, "n_resamples": BOOTSTRAP_RESAMPLES, "method": method,
            "vectorized": True, "batch": max(1, min(BOOTSTRAP_RESAMPLES, _BATCH_ENTRIES // n)),
            "rng": np.random.default_rng(BOOTSTRAP_SEED)}


def _checked(level: float) -> float:
    if not 0 < level < 1:
        raise ValueError(f"level must lie in (0, 1), got {level}")
    return level
