"""The leave-one-out fast path gives what the unoptimised path gives, bit for bit.

The fast path (the default of ``loocv`` and ``holdout``) stops updating a held-out row once
its later proposals are fixed, lists them at once, skips the arithmetic of constant
("inert") columns and keeps BOX's W narrow.  ``fast=False`` runs every row through every
step with nothing skipped, which is what box_core did before; ``tests/reference.py`` keeps
the posterior of that code verbatim.
"""

import importlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from box_core import SELECTORS, Prior, holdout, loocv
from box_core.gaussian import GaussianPosterior, argmax_sequence, argmax_untried
from box_core.loocv import _holdout, _loocv
from box_core.synthetic import score_matrix
from tests import reference
from tests.matrices import degenerate, well_conditioned

ALL = tuple(sorted(SELECTORS))
DEFAULTS = dict(times=None, feasible=None, selectors=ALL, k=None, features=None, seed=0,
                params=None, failure_rule="magnitude", time_grid=None,
                measure_overhead=False, forbidden=None)
FIELDS = ("order", "first_feasible_step", "first_feasible_time",
          "first_feasible_planning_time", "best_score")


def unoptimised(scores, **kwargs):
    return _loocv(scores, fast=False, **{**DEFAULTS, **kwargs})


def assert_same(fast, slow):
    assert fast.selectors == slow.selectors and fast.k == slow.k
    assert fast.failure_value == slow.failure_value
    np.testing.assert_array_equal(fast.time_grid, slow.time_grid)
    np.testing.assert_array_equal(fast.eligible, slow.eligible)
    np.testing.assert_array_equal(fast.optimal_score, slow.optimal_score)
    for name in fast.selectors:
        for field in FIELDS:
            np.testing.assert_array_equal(getattr(fast, field)[name],
                                          getattr(slow, field)[name], err_msg=(name, field))


def with_outcomes(D, seed):
    """Feasibility and times for a matrix whose failures sit at its minimum."""
    rng = np.random.default_rng(seed)
    F = D > D.min()
    T = np.where(F, rng.uniform(0.5, 3.0, D.shape), rng.uniform(0.01, 0.3, D.shape))
    return F, T


def features_for(m, seed=0):
    return np.random.default_rng(seed).normal(size=(m, 3))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(6, 30), m=st.integers(2, 24),
       constant=st.integers(0, 12), duplicate=st.integers(0, 4), rank=st.integers(1, 4),
       short=st.booleans(), hide=st.booleans(), mismatch=st.sampled_from([0.0, 0.1]),
       c=st.sampled_from([0.0, 1.96]))
def test_fast_path_equals_the_unoptimised_one_on_degenerate_matrices(
        seed, n, m, constant, duplicate, rank, short, hide, mismatch, c):
    # constant (never feasible) and duplicate columns, rank deficiency, rows without any
    # feasible entry, k < m, forbidden columns: every selector, every measure
    D = degenerate(n, m, seed, constant=constant, duplicate=duplicate, rank=rank)
    D[0, -1] = -2.0  # at least one feasible entry
    F, T = with_outcomes(D, seed)
    rng = np.random.default_rng(seed)
    forbidden = None
    if hide:
        forbidden = rng.random(D.shape) < 0.15
        forbidden[np.arange(n), rng.integers(m, size=n)] = False  # every row keeps a column
    allowed = m - (0 if forbidden is None else int(forbidden.sum(axis=1).max()))
    k = max(1, allowed // 2) if short else None
    kw = dict(times=T, feasible=F, features=features_for(m, seed), seed=seed, k=k,
              forbidden=forbidden, params={"eips": {"mismatch": mismatch}, "box": {"c": c}})
    assert_same(loocv(D, selectors=ALL, measure_overhead=False, **kw), unoptimised(D, **kw))


@pytest.mark.parametrize("useful", [3, 8, 30])
def test_fast_path_equals_the_unoptimised_one_on_synthetic_planning_data(useful):
    # mostly infeasible, a few useful columns, the rest never feasible (the paper's shape)
    data = score_matrix(60, 40, types=4, useful=useful, per_type=2, seed=useful)
    feasible = data.feasible.copy()
    feasible[::7] = False  # rows with no feasible entry
    kw = dict(times=data.times, feasible=feasible, features=data.features, seed=1)
    fast = loocv(data.scores, selectors=ALL, measure_overhead=False, **kw)
    assert_same(fast, unoptimised(data.scores, **kw))
    assert not fast.eligible[::7].any()


def test_fast_path_equals_the_unoptimised_one_with_ties_everywhere():
    # columns equal in pairs and blocks of equal constants: orders decided by the tie rule
    rng = np.random.default_rng(4)
    base = np.where(rng.random((25, 5)) < 0.3, -rng.uniform(1, 3, (25, 5)), -10.0)
    D = np.concatenate([base, base, np.full((25, 6), -10.0), base[:, :2]], axis=1)
    F, T = with_outcomes(D, 4)
    T[:] = 1.0  # equal times too
    kw = dict(times=T, feasible=F, features=np.zeros((D.shape[1], 2)), seed=2)
    assert_same(loocv(D, selectors=ALL, measure_overhead=False, **kw), unoptimised(D, **kw))


def test_fast_path_equals_the_unoptimised_one_without_constant_columns():
    D = well_conditioned(30, 9, seed=3)
    kw = dict(features=features_for(9), seed=5, k=7)
    assert_same(loocv(D, selectors=ALL, measure_overhead=False, **kw), unoptimised(D, **kw))


def test_fast_path_of_holdout_equals_the_unoptimised_one():
    D = degenerate(40, 18, seed=8, constant=7, duplicate=2, rank=3)
    F, T = with_outcomes(D, 8)
    train, test = np.arange(0, 40, 3), np.setdiff1d(np.arange(40), np.arange(0, 40, 3))
    kw = dict(DEFAULTS, times=T, feasible=F, features=features_for(18), seed=4)
    fast = holdout(D, train, test, **kw)
    assert_same(fast, _holdout(D, train, test, fast=False, **kw))


def test_fast_path_of_a_subset_of_rows_equals_the_whole_evaluation():
    D = degenerate(30, 16, seed=9, constant=6, duplicate=1, rank=2)
    F, T = with_outcomes(D, 9)
    kw = dict(times=T, feasible=F, features=features_for(16), seed=3)
    whole = loocv(D, selectors=ALL, measure_overhead=False, **kw)
    rows = np.array([2, 11, 29])
    part = _loocv(D, rows=rows, **{**DEFAULTS, **kw})
    for name in ALL:
        np.testing.assert_array_equal(part.order[name], whole.order[name][rows])


def test_fast_path_agrees_with_the_naive_refit_per_fold_where_orders_are_determined():
    # well-conditioned columns plus never-feasible ones: BOX's skipped updates of the
    # constant columns are the same as conditioning on them with direct solves
    rng = np.random.default_rng(12)
    D = np.concatenate([well_conditioned(40, 6, seed=12), np.full((40, 4), -50.0)], axis=1)
    D = D[:, rng.permutation(10)]
    res = loocv(D, selectors=("box", "pembo", "static"), k=6, measure_overhead=False)
    for name in res.selectors:
        np.testing.assert_array_equal(res.order[name], reference.loocv_orders(D, name, 6),
                                      err_msg=name)


def sequences(seed, B, m, inert_cols, steps):
    """Columns per step for B instances (each a permutation), and their scores."""
    rng = np.random.default_rng(seed)
    D = well_conditioned(3 * m + 5, m, seed)
    D[:, inert_cols] = 0.25  # constant columns
    order = np.stack([rng.permutation(m)[:steps] for _ in range(B)], axis=1)  # (steps, B)
    return D, order


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), m=st.integers(5, 60), B=st.integers(1, 9),
       frac=st.floats(0.0, 0.95), held=st.booleans())
def test_posterior_is_bit_for_bit_the_one_that_conditions_on_everything(seed, m, B, frac,
                                                                        held):
    inert_cols = np.random.default_rng(seed).random(m) < frac
    D, order = sequences(seed, B, m, np.flatnonzero(inert_cols), m)
    prior = Prior.fit(D)
    batch = prior.folds(np.arange(B)) if held else prior.batch(B)
    new = GaussianPosterior(batch, capacity=2)
    plain = GaussianPosterior(batch, capacity=2, skip_inert=False)
    old = reference.BatchedPosterior(batch, capacity=2)
    assert plain.inert.sum() == 0 and (new.inert == inert_cols).all()
    rows = np.arange(B)
    for cols in order:
        scores = D[rows, cols]
        for post in (new, plain, old):
            post.observe(cols, scores)
        for post in (new, plain):
            # == treats 0.0 and -0.0 alike: the zeros the fast path never computes
            assert np.array_equal(post.mean, old.mean) and np.array_equal(post.var, old.var)


def test_narrow_w_falls_back_to_all_columns_where_blas_would_round_otherwise(monkeypatch):
    # pretend BLAS rounds the narrow product differently for some t: those steps spread
    # W back to all m columns, and nothing changes
    seed, m, B = 5, 40, 6
    D, order = sequences(seed, B, m, np.arange(0, 40, 3), m)
    batch = Prior.fit(D).folds(np.arange(B))
    old = reference.BatchedPosterior(batch)
    monkeypatch.setattr(GaussianPosterior, "_exact",
                        lambda self, t: self._cols is None or t < 9 or t % 3 == 0)
    new = GaussianPosterior(batch)
    assert new._cols is not None  # narrow
    for cols in order:
        scores = D[np.arange(B), cols]
        new.observe(cols, scores)
        old.observe(cols, scores)
        assert np.array_equal(new.mean, old.mean) and np.array_equal(new.var, old.var)


def test_settled_instances_leave_the_batch_and_the_rest_go_on():
    D = degenerate(16, 12, seed=2, constant=6, duplicate=0, rank=2)
    prior = Prior.fit(D)
    post = GaussianPosterior(prior.folds(np.arange(8)))
    old = reference.BatchedPosterior(prior.folds(np.arange(8)))
    rng = np.random.default_rng(0)
    order = np.stack([rng.permutation(12) for _ in range(8)], axis=1)
    kept = np.arange(8)
    for t, cols in enumerate(order):
        post.observe(cols[kept], D[kept, cols[kept]])
        old.observe(cols, D[np.arange(8), cols])
        assert np.array_equal(post.mean, old.mean[kept])
        if t in (3, 7):
            drop = np.array([0, 2]) if t == 3 else np.array([1])
            keep = np.setdiff1d(np.arange(kept.size), drop)
            post.keep(keep)
            kept = kept[keep]


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), m=st.integers(1, 40), levels=st.integers(1, 6),
       near=st.booleans(), scale=st.sampled_from([0.0, 1e-3, 1.0, 1e6]))
def test_argmax_sequence_is_argmax_untried_called_once_per_step(seed, m, levels, near,
                                                                scale):
    rng = np.random.default_rng(seed)
    B = 4
    values = rng.choice(rng.normal(size=levels) * 10.0 ** rng.integers(-3, 4), size=(B, m))
    if near:  # values within and just beyond the tie tolerance of each other
        values = values * (1 + rng.choice([0, 1e-10, 5e-10, 2e-9, 1e-8], size=(B, m)))
    tried = rng.random((B, m)) < 0.3
    tried[:, 0] = False
    steps = int((~tried).sum(axis=1).min())
    scales = np.full(B, scale)
    got = argmax_sequence(values, tried, scales, steps)
    np.testing.assert_array_equal(got, reference.argmax_sequence(values, tried, scales, steps))
    mask = tried.copy()  # and box_core's own argmax, step by step
    for t in range(steps):
        j = argmax_untried(values, mask, scales)
        np.testing.assert_array_equal(got[:, t], j)
        mask[np.arange(B), j] = True


@pytest.mark.parametrize("hide", [False, True])
def test_until_feasible_gives_every_first_feasible_value_of_the_full_run(hide):
    """Rows that stop at their first plan (what C's tuning and the learning curves ask
    for) leave every first-feasible value as the full run has it, bit for bit, and their
    orders are the full run's up to that try."""
    data = score_matrix(80, 40, types=4, useful=10, per_type=2, seed=11)
    feasible = data.feasible.copy()
    feasible[::9] = False  # rows with no plan run to the end
    forbidden = np.random.default_rng(3).random(feasible.shape) < 0.05 if hide else None
    kw = dict(times=data.times, feasible=feasible, features=data.features, seed=2,
              selectors=ALL, measure_overhead=False, forbidden=forbidden)
    train, test = np.arange(0, 80, 4), np.setdiff1d(np.arange(80), np.arange(0, 80, 4))
    for run in (lambda **a: loocv(data.scores, **a),
                lambda **a: holdout(data.scores, train, test, **a)):
        full, short = run(**kw), run(**kw, until_feasible=True)
        for name in ALL:
            for field in ("first_feasible_step", "first_feasible_time",
                          "first_feasible_planning_time"):
                np.testing.assert_array_equal(getattr(short, field)[name],
                                              getattr(full, field)[name], err_msg=(name, field))
            step = full.first_feasible_step[name]
            for i, s in enumerate(step):
                upto = s + 1 if s >= 0 else full.k
                assert short.order[name][i, :upto].tolist() == full.order[name][i, :upto].tolist()
                assert (short.order[name][i, upto:] == -1).all()
        assert (short.order["box"] == -1).sum() > 0.5 * short.order["box"].size  # stopped early


def test_until_feasible_without_constant_columns_stops_rows_too():
    D = well_conditioned(30, 9, seed=3)  # no column settles: the fast loop still drops rows
    kw = dict(features=features_for(9), seed=5, selectors=ALL, measure_overhead=False)
    full, short = loocv(D, **kw), loocv(D, **kw, until_feasible=True)
    for name in ALL:
        np.testing.assert_array_equal(short.first_feasible_time[name],
                                      full.first_feasible_time[name], err_msg=name)
        np.testing.assert_array_equal(short.first_feasible_step[name],
                                      full.first_feasible_step[name], err_msg=name)


def _untried_agree(new, old, tried) -> bool:
    """Posterior means and variances equal at the columns not yet observed (where BOX reads
    them; a posterior that drops observed columns keeps nothing there)."""
    return (np.array_equal(new.mean[~tried], old.mean[~tried])
            and np.array_equal(new.var[~tried], old.var[~tried]))


@pytest.mark.parametrize("m, exact_every", [(70, None), (45, None), (70, 3)])
def test_dropping_observed_columns_keeps_the_posterior_of_the_rest(monkeypatch, m,
                                                                   exact_every):
    """``drop_observed``: W forgets the columns observed so far and narrows as they add up
    (BOX never reads them again); the untried columns' posterior is the one that keeps
    everything, bit for bit.  ``exact_every``: pretend BLAS rounds the narrowed product
    otherwise at all but every third step, which then spreads W back to all columns."""
    if exact_every:
        monkeypatch.setattr(GaussianPosterior, "_exact_slots",
                            lambda self, t: self._W.shape[2] == m or t % exact_every == 0)
    seed, B = 7, 5
    D, order = sequences(seed, B, m, np.array([], dtype=int), m - 1)
    batch = Prior.fit(D).folds(np.arange(B))
    old = reference.BatchedPosterior(batch, capacity=2)
    new = GaussianPosterior(batch, capacity=2, drop_observed=True)
    assert new.slots is not None
    tried = np.zeros((B, m), dtype=bool)
    rows = np.arange(B)
    widths = set()
    for cols in order:
        scores = D[rows, cols]
        new.observe(cols, scores)
        old.observe(cols, scores)
        tried[rows, cols] = True
        widths.add(new._W.shape[2])
        assert _untried_agree(new, old, tried)
    assert min(widths) < m // 2  # W did narrow


def test_box_that_drops_tried_columns_equals_the_unoptimised_path():
    """No constant column (as on a real store, every constraint feasible somewhere), so
    W keeps every column and BOX's tried ones are dropped: the same orders, times and
    scores as the unoptimised path, with hidden columns and all m tries."""
    n, m = 36, 66
    D = well_conditioned(n, m, seed=21)
    rng = np.random.default_rng(21)
    F = rng.random((n, m)) < 0.3
    T = rng.uniform(0.01, 1.0, (n, m))
    hide = np.zeros((n, m), dtype=bool)
    hide[np.arange(n), rng.integers(0, m, n)] = True
    kw = dict(times=T, feasible=F, forbidden=hide, seed=6)
    names = ("box", "pembo", "pembo_compounded")
    assert_same(loocv(D, selectors=names, measure_overhead=False, **kw),
                unoptimised(D, selectors=names, **kw))


@pytest.mark.parametrize("where", ["loocv", "holdout"])
def test_rows_split_between_two_processes_give_the_same_result(second_takes_odd_pieces,
                                                             where):
    """``workers=2`` where no selector tunes: the two processes share each selector's rows
    in halves, and every array of the result is the one process's, bit for bit."""
    module = importlib.import_module("box_core.loocv")  # the package's loocv is the function
    n, m = 2 * module.HALVES_MIN_ROWS + 6, 24
    D = well_conditioned(n, m, seed=4)
    F, T = with_outcomes(D, 4)
    names = ("box", "static", "rand", "doo", "pembo")
    kw = dict(times=T, feasible=F, features=features_for(m), seed=8, measure_overhead=False,
              selectors=names)
    if where == "loocv":
        one, two = loocv(D, **kw), loocv(D, **kw, workers=2)
    else:
        train, test = np.arange(4), np.arange(4, n)
        one, two = holdout(D, train, test, **kw), holdout(D, train, test, **kw, workers=2)
    taken = second_takes_odd_pieces
    assert len(taken) == 1  # one process, then two
    assert set(range(1, 2 * len(names), 2)) <= set(taken[0])  # the odd pieces
    assert_same(two, one)
    np.testing.assert_array_equal(two.first_feasible_step["box"],
                                  one.first_feasible_step["box"])


def _assert_until_best_agrees(short, full):
    """``short`` (until_best, run on ``full``'s time grid) has every first-feasible value
    and every best-score curve of ``full``, and ``full``'s orders up to where it stopped."""
    for name in full.selectors:
        for field in ("first_feasible_step", "first_feasible_time",
                      "first_feasible_planning_time", "best_score"):
            np.testing.assert_array_equal(getattr(short, field)[name],
                                          getattr(full, field)[name], err_msg=(name, field))
        made = short.order[name] >= 0
        assert (made[:, :-1] >= made[:, 1:]).all()  # a prefix per row, -1 after it
        np.testing.assert_array_equal(short.order[name][made], full.order[name][made],
                                      err_msg=name)


@pytest.mark.parametrize("hide", [False, True])
def test_until_best_gives_every_curve_and_first_feasible_value_of_the_full_run(hide):
    """Rows that stop once they have a plan and their optimal score (what stage evaluate
    stores and the figures read) leave every first-feasible value and best-score curve as
    the full run has them, bit for bit on the same time grid, and most of BOX's steps
    undone; the default grid still reaches the longest time a row's tries can take."""
    data = score_matrix(80, 40, types=4, useful=10, per_type=2, seed=11)
    feasible = data.feasible.copy()
    feasible[::9] = False  # rows with no plan stop at their best failure
    forbidden = np.random.default_rng(3).random(feasible.shape) < 0.05 if hide else None
    kw = dict(times=data.times, feasible=feasible, features=data.features, seed=2,
              selectors=ALL, measure_overhead=False, forbidden=forbidden)
    train, test = np.arange(0, 80, 4), np.setdiff1d(np.arange(80), np.arange(0, 80, 4))
    for run in (lambda **a: loocv(data.scores, **a),
                lambda **a: holdout(data.scores, train, test, **a),
                lambda **a: _loocv(data.scores, fast=False, **{**DEFAULTS, **a})):
        full = run(**kw)
        short = run(**kw, until_best=True, time_grid=full.time_grid)
        _assert_until_best_agrees(short, full)
        assert (short.order["box"] == -1).sum() > 0.5 * short.order["box"].size
        grid = run(**kw, until_best=True).time_grid  # as far as the full run's, or further
        assert grid[0] == full.time_grid[0] and grid[1] == full.time_grid[1]
        assert grid[-1] >= full.time_grid[-1] * (1 - 1e-9)


def test_until_best_with_capped_tries_and_a_second_process():
    """The contextual selectors (tuned, capped tries simulated from stored checks) stop
    their rows the same way, in one process or two."""
    from tests.test_contextual import problem

    S, F, T, C, X = problem(70, 8, 2, 5)
    kw = dict(times=T, feasible=F, instance_features=X, checks=C, measure_overhead=False,
              selectors=("box", "contextual", "contextual_capped", "eips", "static"))
    full = loocv(S, **kw)
    for workers in (1, 2):
        short = loocv(S, **kw, until_best=True, time_grid=full.time_grid, workers=workers)
        _assert_until_best_agrees(short, full)
        assert (short.order["contextual_capped"] == -1).any()


def test_pieces_of_work_are_listed_costliest_first():
    """``workers=2``'s pieces: each tuning group, and each other selector's rows in halves
    from HALVES_MIN_ROWS rows on (whole with one process or fewer rows), sorted by cost
    per row times rows, the order both processes take them in (ties keep their order)."""
    module = importlib.import_module("box_core.loocv")
    costs = {"eips": 4.3, "box": 1.0, "static": 0.05, "contextual": 3.1}

    def cost(names):
        return sum(costs[n] for n in names)

    groups = [(np.arange(g, 100, 10), np.arange(100)) for g in range(10)]
    pieces = module._pieces(("contextual",), ("static", "box", "eips"), groups, 100, 2, cost)
    assert [(names, rows.size) for names, rows, _ in pieces] == (
        [(("eips",), 50)] * 2 + [(("box",), 50)] * 2 + [(("contextual",), 10)] * 10
        + [(("static",), 50)] * 2)
    assert [rows[0] for names, rows, _ in pieces if names == ("eips",)] == [0, 50]
    assert [train is None for *_, train in pieces] == [True] * 4 + [False] * 10 + [True] * 2
    for workers, rows in ((1, 100), (2, module.HALVES_MIN_ROWS - 1)):
        whole = module._pieces((), ("box",), [], rows, workers, cost)
        assert len(whole) == 1 and whole[0][1].size == rows
