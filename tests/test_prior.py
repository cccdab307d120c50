import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from box_core import Prior
from tests.matrices import degenerate, well_conditioned


def test_fit_matches_numpy_mean_and_ddof1_covariance():
    D = well_conditioned(40, 6, seed=3)
    prior = Prior.fit(D)
    np.testing.assert_allclose(prior.mean, D.mean(axis=0))
    np.testing.assert_allclose(prior.cov, np.cov(D, rowvar=False, ddof=1))


@settings(max_examples=40, deadline=None)
@given(n=st.integers(3, 30), m=st.integers(1, 12), seed=st.integers(0, 10_000),
       held=st.integers(0, 29))
def test_leave_one_out_equals_refitting_without_the_row(n, m, seed, held):
    D = well_conditioned(n, m, seed)
    i = held % n
    loo = Prior.fit(D).leave_one_out(i)
    refit = Prior.fit(np.delete(D, i, axis=0))
    np.testing.assert_allclose(loo.mean, refit.mean, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(loo.cov, refit.cov, rtol=1e-9, atol=1e-9)


def test_fold_rows_and_diagonal_match_the_explicit_fold_covariance():
    D = degenerate(25, 9, seed=1, constant=2, duplicate=2, rank=3)
    prior = Prior.fit(D)
    rows = np.array([0, 7, 24])
    folds = prior.folds(rows)
    cols = np.array([3, 0, 8])
    got = folds.cov_rows(cols)
    for b, (i, j) in enumerate(zip(rows, cols, strict=True)):
        cov = Prior.fit(np.delete(D, i, axis=0)).cov
        np.testing.assert_allclose(got[b], cov[j], atol=1e-12)
        np.testing.assert_allclose(folds.diag()[b], np.diag(cov), atol=1e-12)


def test_jitter_is_relative_to_the_largest_prior_variance():
    D = well_conditioned(50, 4, seed=0)
    small, big = Prior.fit(D).batch(), Prior.fit(1000 * D).batch()
    assert big.jitter()[0] == pytest.approx(1e6 * small.jitter()[0])
    constant = Prior.fit(np.ones((5, 3))).batch()
    assert constant.jitter()[0] > 0  # still positive when every column is constant


@pytest.mark.parametrize("bad, message", [
    (np.array([[1.0, np.nan], [2.0, 3.0]]), "NaN"),
    (np.array([[1.0, np.inf], [2.0, 3.0]]), "inf"),
    (np.ones((1, 3)), "at least 2 rows"),
    (np.ones(4), "2-D"),
])
def test_fit_rejects_bad_matrices(bad, message):
    with pytest.raises(ValueError, match=message):
        Prior.fit(bad)


def test_leave_one_out_needs_three_rows():
    with pytest.raises(ValueError, match="at least 3 rows"):
        Prior.fit(np.ones((2, 3))).folds([0])


def test_the_prior_is_unaffected_by_later_edits_to_the_callers_matrix():
    D = well_conditioned(20, 4, seed=1)
    prior = Prior.fit(D)
    expected = prior.leave_one_out(3).mean.copy()
    D[:] = 0.0
    np.testing.assert_array_equal(prior.leave_one_out(3).mean, expected)
