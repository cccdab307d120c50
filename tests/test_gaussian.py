import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from box_core import Prior
from box_core.gaussian import GaussianPosterior, argmax_untried
from tests import reference
from tests.matrices import degenerate, well_conditioned


@settings(max_examples=40, deadline=None)
@given(m=st.integers(2, 15), seed=st.integers(0, 10_000), data=st.data())
def test_incremental_posterior_equals_direct_solve(m, seed, data):
    D = well_conditioned(4 * m + 5, m, seed)
    prior = Prior.fit(D)
    cols = data.draw(st.permutations(range(m)))[: data.draw(st.integers(1, m))]
    truth = np.random.default_rng(seed).normal(size=m)
    post = GaussianPosterior(prior.batch(), capacity=1)  # also exercises buffer growth
    for j in cols:
        post.observe(np.array([j]), np.array([truth[j]]))
    mean, var = reference.posterior(prior.mean, prior.cov, list(cols), truth[list(cols)])
    untried = np.setdiff1d(np.arange(m), cols)
    np.testing.assert_allclose(post.mean[0, untried], mean[untried], rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(post.var[0, untried], var[untried], rtol=1e-6, atol=1e-7)


def test_posterior_stays_finite_on_rank_deficient_priors():
    D = degenerate(8, 30, seed=2, constant=10, duplicate=5, rank=2)
    post = GaussianPosterior(Prior.fit(D).batch())
    rng = np.random.default_rng(0)
    for j in rng.permutation(30):
        post.observe(np.array([j]), np.array([rng.normal()]))
        assert np.isfinite(post.mean).all() and np.isfinite(post.var).all()
    assert (post.std() >= 0).all()


def test_batched_instances_do_not_interfere():
    D = well_conditioned(60, 7, seed=5)
    prior = Prior.fit(D)
    rows = np.array([3, 10, 42])
    batch = GaussianPosterior(prior.folds(rows))
    singles = [GaussianPosterior(prior.folds([r])) for r in rows]
    plan = np.array([[0, 6, 2], [1, 1, 5], [4, 0, 3]])  # columns per step, per row
    for cols in plan:
        batch.observe(cols, D[rows, cols])
        for b, post in enumerate(singles):
            post.observe(cols[b:b + 1], D[rows[b:b + 1], cols[b:b + 1]])
    for b, post in enumerate(singles):
        np.testing.assert_allclose(batch.mean[b], post.mean[0], atol=1e-12)
        np.testing.assert_allclose(batch.var[b], post.var[0], atol=1e-12)


def test_argmax_untried_skips_tried_and_breaks_ties_to_lowest_index():
    values = np.array([[3.0, 5.0, 5.0, 1.0], [2.0, 2.0, 2.0 + 1e-12, 0.0]])
    tried = np.array([[False, True, False, False], [False, False, False, False]])
    np.testing.assert_array_equal(argmax_untried(values, tried, np.ones(2)), [2, 0])
