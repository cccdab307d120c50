"""box_core.stats: its intervals are scipy.stats.bootstrap's, and degenerate data give what
callers expect (no interval, or a point interval, never an exception or a warning)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy import stats

import box_core
from box_core.stats import (
    BOOTSTRAP_RESAMPLES,
    BOOTSTRAP_SEED,
    INTERVAL_METHOD,
    INTERVAL_NOTE,
    RATIO_INTERVAL_METHOD,
    mean_ci,
    mean_ci_columns,
    paired_ratio,
)


def direct(data, statistic, method, **kw):
    """scipy.stats.bootstrap called as its documentation shows, with box_core's settings."""
    res = stats.bootstrap(data, statistic, method=method, n_resamples=BOOTSTRAP_RESAMPLES,
                          rng=np.random.default_rng(BOOTSTRAP_SEED), **kw)
    return res.confidence_interval


def ratio_of_means(a, b, axis=-1):
    return np.mean(a, axis=axis) / np.mean(b, axis=axis)


@pytest.fixture
def times():
    rng = np.random.default_rng(7)
    ref = rng.lognormal(-3, 2, 300)  # heavy-tailed, as planning times are
    return ref * rng.lognormal(0.4, 0.6, ref.size), ref


def test_mean_interval_is_scipy_s_percentile_interval(times):
    x = times[0]
    mean, low, high = mean_ci(x, 0.9)
    ci = direct((x,), np.mean, "percentile", confidence_level=0.9)
    assert mean == x.mean() and (low, high) == (ci.low, ci.high)


def test_ratio_interval_is_scipy_s_paired_bca_interval(times):
    a, b = times
    ratio, low, high = paired_ratio(a, b)
    ci = direct((a, b), ratio_of_means, "BCa", paired=True)
    assert ratio == pytest.approx(a.mean() / b.mean(), rel=1e-12)
    assert (low, high) == (ci.low, ci.high)
    percentile = direct((a, b), ratio_of_means, "percentile", paired=True)
    assert (low, high) != (percentile.low, percentile.high)  # BCa, not percentile
    assert 1 < low < ratio < high


def test_ratio_uses_only_rows_both_solved(times):
    a, b = times[0].copy(), times[1].copy()
    a[::5], b[1::7] = np.nan, np.nan
    both = ~np.isnan(a) & ~np.isnan(b)
    ci = direct((a[both], b[both]), ratio_of_means, "BCa", paired=True)
    assert paired_ratio(a, b)[1:] == (ci.low, ci.high)


def test_column_band_is_scipy_s_interval_of_each_column():
    rng = np.random.default_rng(3)
    curves = rng.normal(size=(120, 30)).cumsum(axis=1)
    mean, low, high = mean_ci_columns(curves)
    ci = direct((curves.T,), np.mean, "percentile", axis=-1)
    np.testing.assert_allclose(low, ci.low, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(high, ci.high, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(mean, curves.mean(axis=0))


def test_same_data_give_the_same_intervals(times):
    a, b = times
    assert mean_ci(a) == mean_ci(a.copy())
    assert paired_ratio(a, b) == paired_ratio(a.copy(), b.copy())
    for x, y in zip(mean_ci_columns(np.column_stack(times)),
                    mean_ci_columns(np.column_stack(times)), strict=True):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("values, expected", [
    ([], (math.nan,) * 3),
    ([np.nan, np.nan], (math.nan,) * 3),
    ([0.25], (0.25, math.nan, math.nan)),
    ([np.nan, 0.25], (0.25, math.nan, math.nan)),
    ([0.25] * 9, (0.25, 0.25, 0.25)),
])
def test_degenerate_means(values, expected):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = mean_ci(values)
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("a, b, expected", [
    ([], [], (math.nan,) * 3),
    ([np.nan, 1.0], [1.0, np.nan], (math.nan,) * 3),  # no row with both
    ([1.0, 2.0], [0.0, 0.0], (math.nan,) * 3),  # no positive reference mean
    ([3.0], [1.5], (2.0, math.nan, math.nan)),  # one instance: no interval
    ([0.3] * 6, [0.1] * 6, (3.0, 3.0, 3.0)),  # constant: BCa undefined, a point
    ([0.1, 0.4, 0.2], [0.1, 0.4, 0.2], (1.0, 1.0, 1.0)),  # BOX against itself
])
def test_degenerate_ratios(a, b, expected):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = paired_ratio(np.array(a), np.array(b))
    np.testing.assert_allclose(got, expected, rtol=1e-12)


def test_degenerate_columns():
    mean, low, high = mean_ci_columns(np.ones((1, 4)))
    assert mean.tolist() == [1.0] * 4 and np.isnan(low).all() and np.isnan(high).all()
    mean, low, high = mean_ci_columns(np.full((5, 3), 2.0))
    assert low.tolist() == high.tolist() == mean.tolist() == [2.0] * 3


def test_level_outside_zero_one_is_refused(times):
    for fn, args in ((mean_ci, times[:1]), (paired_ratio, times),
                     (mean_ci_columns, (np.column_stack(times),))):
        with pytest.raises(ValueError, match="level"):
            fn(*args, level=1.0)


def test_captions_name_the_methods():
    assert "BCa" in INTERVAL_METHOD and "percentile" in INTERVAL_METHOD
    assert "scipy.stats.bootstrap" in INTERVAL_NOTE and RATIO_INTERVAL_METHOD in INTERVAL_NOTE
    rng = np.random.default_rng(0)
    scores = -rng.uniform(0.5, 2.0, (12, 5))
    feasible = rng.uniform(size=scores.shape) < 0.5
    feasible[:, 0] = True
    summary = box_core.loocv(scores, times=rng.uniform(0.01, 1, scores.shape),
                             feasible=feasible, selectors=("box", "static"),
                             measure_overhead=False).summary()
    assert INTERVAL_METHOD in str(summary)
