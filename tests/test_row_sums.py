"""Products read in column tiles (box_core.row_sums) and BOX's posterior conditioned when
read (contextual.DeferredPosterior) give the numbers of the plain computation, bit for bit:
the product of the whole table, and conditioning at every try."""

from __future__ import annotations

import copy
import pickle
import sys

import numpy as np
import pytest
from scipy import sparse

import box_core
from box_core import Prior, contextual, row_sums, selectors
from box_core.gaussian import GaussianPosterior
from box_core.selectors import TrainingOutcomes
from box_core.tries import FAILED, FEASIBLE, PAUSED
from tests.matrices import well_conditioned
from tests.test_contextual import problem
from tests.test_eips_narrow import case as eips_narrow_case


def weights(B, n, per_row, rng, order="sorted"):
    """A CSR (B, n) of nonzero weights, ``per_row`` per row at distinct columns, in
    ascending column order or in the order a neighbour list has them ("ranked")."""
    cols = np.stack([rng.choice(n, per_row, replace=False) for _ in range(B)])
    if order == "sorted":
        cols.sort(axis=1)
    data = rng.uniform(-1.0, 1.0, size=cols.shape) * 10.0 ** rng.integers(-8, 3, cols.shape)
    indptr = np.arange(B + 1) * per_row
    return sparse.csr_matrix((data.ravel(), cols.ravel(), indptr), shape=(B, n))


@pytest.mark.parametrize("width", [90, 85])  # the last tile 6 columns wide, or 1
@pytest.mark.parametrize("order", ["sorted", "ranked"])
@pytest.mark.parametrize("B,per_row", [(1, 3), (7, 40), (60, 25), (200, 37)])
def test_tiled_products_are_the_whole_tables_bit_for_bit(monkeypatch, width, order, B,
                                                         per_row):
    monkeypatch.setattr(row_sums, "TILE_BYTES", 8 * 50 * 7)  # 7 columns per tile
    rng = np.random.default_rng(B * per_row)
    rows = rng.normal(size=(50, width)) * np.exp(rng.normal(size=(50, width)) * 5)
    rows[rng.random(rows.shape) < 0.4] = 0.0
    table = row_sums.RowTable(rows)
    W = weights(B, 50, per_row, rng, order)
    got = table.weighted(W)
    assert got.shape == (B, width)
    np.testing.assert_array_equal(got, np.asarray(W @ rows))
    # tiles only past TILES_PAST nonzeros per table row
    assert (table._tiles is not None) == (W.nnz > row_sums.TILES_PAST * 50)


def test_a_table_narrower_than_a_tile_is_never_tiled():
    rng = np.random.default_rng(0)
    rows = rng.normal(size=(40, 30))
    table = row_sums.RowTable(rows)
    W = weights(100, 40, 20, rng)
    np.testing.assert_array_equal(table.weighted(W), np.asarray(W @ rows))
    assert table._tiles is None


def contextual_case():
    S, F, T, C, X = problem(40, 12, 3, seed=2)
    return S, dict(times=T, feasible=F, checks=C, instance_features=X,
                   params={"contextual_capped": {"k": 6}})


def eips_case():  # one whose weight changes take the sparse product (most are dense)
    return eips_narrow_case("feasible")


@pytest.mark.parametrize("name,make", [("contextual_capped", contextual_case),
                                       ("eips", eips_case)])
def test_evaluations_are_the_same_whatever_the_tiles(monkeypatch, name, make):
    # tiles of 3 columns against the default, which is one tile at this size: the same
    # orders and times; and the tiled path did run
    S, kwargs = make()
    args = dict(selectors=(name,), measure_overhead=False, **kwargs)
    plain = box_core.loocv(S, **args)
    monkeypatch.setattr(row_sums, "TILE_BYTES", 8 * S.shape[0] * 3)
    tiled_calls = []
    weighted = row_sums.RowTable.weighted

    def counted(self, W):
        tiled_calls.append(W.nnz > row_sums.TILES_PAST * self.rows.shape[0])
        return weighted(self, W)

    monkeypatch.setattr(row_sums.RowTable, "weighted", counted)
    tiled = box_core.loocv(S, **args)
    assert any(tiled_calls)
    for field in ("order", "first_feasible_step", "first_feasible_planning_time",
                  "best_score"):
        np.testing.assert_array_equal(getattr(tiled, field)[name],
                                      getattr(plain, field)[name], err_msg=field)


def test_a_deferred_posterior_conditions_on_the_queue_when_read():
    # the same observations, paused tries and batch changes, read at a few points: the
    # deferred posterior's numbers are the eager one's, and nothing is conditioned before
    # a read
    D = well_conditioned(50, 9, seed=4)
    prior = Prior.fit(D)
    rows = np.array([2, 11, 30, 41])
    eager = GaussianPosterior(prior.folds(rows), capacity=2)
    inner = GaussianPosterior(prior.folds(rows), capacity=2)
    deferred = contextual.DeferredPosterior(inner)
    np.testing.assert_array_equal(deferred.inert, eager.inert)
    rng = np.random.default_rng(1)
    live = rows.copy()
    for step in range(7):
        cols = rng.permutation(9)[:live.size]
        skip = rng.random(live.size) < 0.3 if step % 2 else None
        for post in (eager, deferred):
            post.observe(cols, D[live, cols], skip=skip)
        assert inner.t == 0 or step > 3  # queued until the first read (below)
        if step == 3:
            np.testing.assert_array_equal(deferred.mean, eager.mean)
            assert inner.t == 4
        if step == 4:
            for post in (eager, deferred):
                post.keep(np.array([0, 2, 3]))
            live = live[[0, 2, 3]]
    np.testing.assert_array_equal(deferred.mean, eager.mean)
    np.testing.assert_array_equal(deferred.var, eager.var)
    np.testing.assert_array_equal(deferred.std(), eager.std())
    np.testing.assert_array_equal(deferred.scale, eager.scale)


def test_a_deferred_posterior_copies_and_pickles_with_its_queue():
    D = well_conditioned(30, 6, seed=1)
    prior = Prior.fit(D)
    rows = np.array([1, 2])
    eager = GaussianPosterior(prior.folds(rows))
    deferred = contextual.DeferredPosterior(GaussianPosterior(prior.folds(rows)))
    for post in (eager, deferred):
        post.observe(np.array([0, 3]), np.array([0.1, -0.2]))
    for other in (copy.deepcopy(deferred), pickle.loads(pickle.dumps(deferred))):
        np.testing.assert_array_equal(other.mean, eager.mean)


def test_runs_to_the_first_plan_condition_box_only_where_its_bounds_are_read(monkeypatch):
    # CONTEXTUAL reads BOX's bounds before a plan only where no candidate has a positive
    # rate: a run that stops at the first plan conditions only the tries before such reads
    S, F, T, C, X = problem(40, 12, 3, seed=3)
    observed = []
    observe = GaussianPosterior.observe
    monkeypatch.setattr(GaussianPosterior, "observe",
                        lambda self, *a, **k: observed.append(1) or observe(self, *a, **k))
    args = dict(times=T, feasible=F, instance_features=X, selectors=("contextual",),
                params={"contextual": {"k": 6, "select_features": 0}},
                measure_overhead=False)
    first = box_core.loocv(S, until_feasible=True, **args)
    assert not observed
    full = box_core.loocv(S, **args)
    assert observed  # after the first plan BOX chooses: its posterior is conditioned
    np.testing.assert_array_equal(first.first_feasible_step["contextual"],
                                  full.first_feasible_step["contextual"])


@pytest.mark.parametrize("name,params", [
    ("contextual", {"k": 6, "select_features": 0}),
    ("contextual_capped", {"k": 6, "cap_quantile": 0.5, "select_features": 0}),
])
@pytest.mark.parametrize("constant", [0, 3])
def test_box_after_the_first_plan_at_the_posteriors_columns_is_the_full_choice(
        monkeypatch, name, params, constant):
    # With forbidden columns and constant (inert) ones, paused tries and resumptions: the
    # choice read at the posterior's own columns (the default, which forgets the columns
    # tried) gives the orders of the posterior that keeps every column, where the choice
    # is made over all m columns.
    S, F, T, C, X = problem(40, 24, 3, seed=5)
    S[:, :constant], F[:, :constant] = np.nan, False
    rng = np.random.default_rng(6)
    hide = rng.random(S.shape) < 0.15
    hide[:, -1] = False  # every row keeps a column
    args = dict(times=T, feasible=F, checks=C, instance_features=X, selectors=(name,),
                params={name: params}, forbidden=hide, measure_overhead=False)
    read_at = []
    at = contextual.argmax_untried_at
    monkeypatch.setattr(contextual, "argmax_untried_at",
                        lambda *a: read_at.append(1) or at(*a))
    default = box_core.loocv(S, **args)
    monkeypatch.setattr(selectors, "_posterior", lambda ctx, drop: GaussianPosterior(
        ctx.prior, capacity=ctx.horizon or 16, skip_inert=ctx.skip_inert,
        drop_observed=False))
    kept = len(read_at)
    full = box_core.loocv(S, **args)
    assert kept and len(read_at) == kept  # the default read the columns; the other did not
    for field in ("order", "first_feasible_step", "first_feasible_planning_time",
                  "best_score"):
        np.testing.assert_array_equal(getattr(default, field)[name],
                                      getattr(full, field)[name], err_msg=field)


def test_a_weight_change_adds_what_the_whole_batchs_product_adds():
    # NeighbourModel.observe multiplies only the instances whose weights changed: their
    # sums are what adding the product of every instance's changes (zero rows included)
    # gives, and the others' sums stay as they were
    S, F, T, C, X = problem(40, 12, 3, seed=4)
    Dn = np.nan_to_num(S)
    rows = np.arange(8)
    outcomes = TrainingOutcomes.of(Dn, F, T, rows, C)
    model = contextual.NeighbourModel(outcomes, X, X[rows], k=6, mismatch=0.1,
                                      prior_rows=1.0, cap=float(np.median(C)))
    rng = np.random.default_rng(0)
    moved = 0
    for _ in range(4):
        sums, weights_before = model._sums.copy(), model._w.copy()
        who = np.flatnonzero(rng.random(8) < 0.6)
        cols = rng.integers(0, 12, size=who.size)
        outcome = rng.choice([FAILED, FEASIBLE, PAUSED], size=who.size)
        model.observe(who, cols, outcome, np.zeros(who.size, dtype=bool))
        change = model._w - weights_before
        moved += int((change != 0).any(axis=1).sum())
        full = sparse.csr_matrix((change[change != 0], model._nb[change != 0],
                                  np.concatenate([[0], np.cumsum((change != 0).sum(1))])),
                                 shape=(8, 40))
        np.testing.assert_array_equal(model._sums, sums + np.asarray(full @ model._A.rows))
    assert 0 < moved < 4 * 8  # some instances changed, not all of them every time


def test_policies_that_share_a_table_get_larger_batches_and_the_same_result(monkeypatch):
    # with a budget of a few instances per batch, EIPS and CONTEXTUAL (shares_tables) run
    # in batches SHARED_TABLE_BATCH_FACTOR times larger than BOX's where rows stop at
    # their best, and in BOX's through every try; every result is what one batch of all
    # rows gives.  holdout: CONTEXTUAL's rows are one tuning group, one piece of work, as
    # every other selector's (the budget is per piece: loocv's tuning groups are pieces)
    D, kwargs = eips_narrow_case("feasible")
    X = np.random.default_rng(2).normal(size=(D.shape[0], 3))
    train, test = np.arange(4), np.arange(4, D.shape[0])
    names = ("box", "eips", "contextual")
    args = dict(selectors=names, instance_features=X, until_best=True,
                params={"contextual": {"k": 6, "select_features": 0}},
                measure_overhead=False, **kwargs)
    whole = box_core.holdout(D, train, test, **args)
    loocv_module = sys.modules["box_core.loocv"]
    per = selectors.Box.bytes_per_instance(D.shape[1], D.shape[1], D.shape[1])
    monkeypatch.setattr(loocv_module, "MIN_BATCH_BYTES", 0)
    monkeypatch.setattr(loocv_module, "BATCH_BYTES_PER_ENTRY", 2 * per / (test.size * D.shape[1]))
    sizes = {name: [] for name in names}
    for name in names:
        cls = selectors.SELECTORS[name]
        init = cls.__init__

        def counted(self, ctx, *a, _name=name, _cls=cls, _init=init, **k):
            if type(self) is _cls:  # not the base class's part of another's
                sizes[_name].append(ctx.size)
            _init(self, ctx, *a, **k)

        monkeypatch.setattr(cls, "__init__", counted)
    split = box_core.holdout(D, train, test, **args)
    factor = loocv_module.SHARED_TABLE_BATCH_FACTOR
    assert max(sizes["box"]) == 2
    assert max(sizes["eips"]) == max(sizes["contextual"]) == 2 * factor
    for name in names:
        sizes[name].clear()
    box_core.holdout(D, train, test, **{**args, "until_best": False})  # W's plain budget
    assert max(sizes["eips"]) == max(sizes["contextual"]) == max(sizes["box"]) == 2
    for field in ("order", "first_feasible_step", "first_feasible_planning_time",
                  "best_score"):
        for name in names:
            np.testing.assert_array_equal(getattr(split, field)[name],
                                          getattr(whole, field)[name], err_msg=field)
