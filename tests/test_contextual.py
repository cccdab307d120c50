"""CONTEXTUAL: against a direct implementation, its fallback to BOX, nested tuning that
never sees the held-out row, the simulation of capped tries, and its input checks."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import box_core
from box_core import contextual, gaussian
from box_core.failure import failure_value, fill_failures
from box_core.selectors import score_unit, standardise
from box_core.tries import FAILED, FEASIBLE, PAUSED, outcome_of_try
from tests import reference


def problem(n, m, q, seed, budget=1000):
    """Scores (NaN where infeasible), feasibility, times, checks (budget-exhausted
    entries at the budget, infeasible) and instance features that predict feasibility."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, q))
    logit = 3 * X @ rng.normal(size=(q, m)) + rng.normal(size=m)
    F = rng.random((n, m)) < 1 / (1 + np.exp(-logit))
    F[:, 0] |= rng.random(n) < 0.2
    checks = np.where(F, rng.integers(0, budget, size=(n, m)),
                      np.where(rng.random((n, m)) < 0.3, budget, rng.integers(0, 50, (n, m))))
    T = (checks + 1) * rng.uniform(1e-5, 2e-5, size=(n, m))
    S = np.where(F, -rng.uniform(1, 3, size=(n, m)), np.nan)
    return S, F, T, checks, X


def internal(S, F):
    """The scores every selector sees (documented: failures filled, standardised)."""
    D = fill_failures(np.nan_to_num(S), F, failure_value(np.nan_to_num(S), F))
    return standardise(D, score_unit(D))


def reference_tries(S, F, T, C, X, i, ends, cap, mask, **params):
    """The direct implementation's tries on row i, in the features ``mask`` that tuning
    selected for it (none: BOX)."""
    Dn = internal(S, F)
    rest = np.delete(np.arange(S.shape[0]), i)
    X = X[:, mask.astype(bool)] if mask.any() else None
    return reference.contextual_tries(
        Dn[rest], F[rest], T[rest], None if C is None else C[rest],
        None if X is None else X[rest], None if X is None else X[i], Dn[i], F[i], T[i],
        None if C is None else C[i], ends, cap=cap, **params)


@pytest.mark.parametrize("seed", range(4))
def test_uncapped_orders_equal_the_direct_implementation(seed):
    S, F, T, C, X = problem(30, 7, 3, seed)
    res = box_core.loocv(S, times=T, feasible=F, selectors=("contextual",),
                         params={"contextual": {"k": 5, "mismatch": 0.2}},
                         instance_features=X, measure_overhead=False)
    for i in range(S.shape[0]):
        mask = res.settings["contextual"]["feature_mask"][i]
        expected = reference_tries(S, F, T, None, X, i, 7, math.inf, mask, k=5, mismatch=0.2)
        assert res.order["contextual"][i].tolist() == [j for j, *_ in expected]
    assert res.settings["contextual"]["feature_mask"].any(axis=1).mean() >= 0.5  # the model ran


def test_the_neighbour_tables_are_built_once_per_evaluation(monkeypatch):
    # batches of 3 held-out rows, settings fixed (no tuning): every batch reads the same
    # training outcomes, so their (n, m * blocks) table is built once, and without a cap
    # it keeps only the two blocks the model reads; the orders are the direct ones
    S, F, T, C, X = problem(30, 7, 3, seed=1)
    built, build = [], contextual._entry_tables

    def counted(*args):
        built.append(build(*args))
        return built[-1]

    monkeypatch.setattr(contextual, "_entry_tables", counted)
    monkeypatch.setattr(contextual.Contextual, "fold_batch",
                        classmethod(lambda cls, n, m, k: min(n, 3)))
    params = {"k": 5, "mismatch": 0.2, "select_features": 0}
    res = box_core.loocv(S, times=T, feasible=F, selectors=("contextual",),
                         params={"contextual": params}, instance_features=X,
                         measure_overhead=False)
    assert len(built) == 1 and built[0][1] == (1, 4) and built[0][2].shape == (30, 14)
    for i in (0, 13, 29):
        expected = reference_tries(S, F, T, None, X, i, 7, math.inf, np.ones(3), k=5,
                                   mismatch=0.2)
        assert res.order["contextual"][i].tolist() == [j for j, *_ in expected]


def test_capped_tries_outnumbering_the_columns_keep_the_direct_order(monkeypatch):
    # every column tried to its end, paused ones resumed: more steps than columns, past
    # the point where the posterior's narrowed product is checked on random numbers
    S, F, T, C, X = problem(40, 24, 3, seed=0)
    steps = []
    check = gaussian.GaussianPosterior._exact_slots
    monkeypatch.setattr(gaussian.GaussianPosterior, "_exact_slots",
                        lambda self, t: steps.append(t) or check(self, t))
    name, params = "contextual_capped", {"k": 5, "cap_quantile": 0.5}
    res = box_core.loocv(S, times=T, feasible=F, selectors=(name,), checks=C,
                         params={name: params}, instance_features=X, measure_overhead=False)
    assert max(steps) > 24
    for i in (0, 21, 39):
        cap = res.settings[name]["cap"][i]
        mask = res.settings[name]["feature_mask"][i]
        expected = reference_tries(S, F, T, C, X, i, 24, cap, mask, k=5)
        got = res.order[name][i]
        assert got[got >= 0].tolist() == [j for j, *_ in expected]


def test_capped_tries_equal_the_direct_implementation():
    paused = sum(capped_tries_against_the_direct_implementation(seed) for seed in range(4))
    assert paused  # the examples exercise pauses and resumptions


def capped_tries_against_the_direct_implementation(seed):
    """Checks one example; returns how many tries were paused."""
    S, F, T, C, X = problem(30, 7, 3, seed)
    res = box_core.loocv(S, times=T, feasible=F, selectors=("contextual_capped",),
                         params={"contextual_capped": {"k": 6, "cap_quantile": 0.5}},
                         instance_features=X, checks=C, measure_overhead=False, k=5)
    name = "contextual_capped"
    paused = 0
    for i in range(S.shape[0]):
        cap = res.settings[name]["cap"][i]
        mask = res.settings[name]["feature_mask"][i]
        expected = reference_tries(S, F, T, C, X, i, 5, cap, mask, k=6)
        got = res.order[name][i]
        used = got >= 0
        assert got[used].tolist() == [j for j, *_ in expected]
        allowance = res.allowance.get(name, np.full(got.shape, np.inf))
        cost = res.try_time.get(name, T[i, np.maximum(got, 0)][None, :].repeat(30, 0))
        assert allowance[i, used].tolist() == [a for _, a, *_ in expected]
        assert cost[i, used] == pytest.approx([c for _, _, c, _ in expected])
        outcomes = [o for *_, o in expected]
        paused += outcomes.count(PAUSED)
        if FEASIBLE in outcomes:
            upto = outcomes.index(FEASIBLE)
            assert res.first_feasible_step[name][i] == upto
            assert res.first_feasible_time[name][i] == pytest.approx(
                sum(c for _, _, c, _ in expected[:upto + 1]))
    assert res.settings[name]["feature_mask"].any(axis=1).mean() >= 0.5  # the model ran
    return paused


def test_without_instance_features_it_is_box():
    S, F, T, C, X = problem(20, 8, 2, 1)
    names = ("box", "contextual", "contextual_capped")
    for feats in (None, np.zeros((20, 0))):
        res = box_core.loocv(S, times=T, feasible=F, selectors=names, checks=C,
                             instance_features=feats, measure_overhead=False)
        for name in names[1:]:
            np.testing.assert_array_equal(res.order[name], res.order["box"])
            np.testing.assert_array_equal(res.first_feasible_time[name],
                                          res.first_feasible_time["box"])
    live = box_core.make_selector("contextual", internal(S, F)[:-1])
    box = box_core.make_selector("box", internal(S, F)[:-1])
    truth = internal(S, F)[-1]
    for _ in range(8):
        j = box.propose()
        assert live.propose() == j
        box.update(j, truth[j])
        live.update(j, truth[j])


def test_without_a_cap_the_capped_selector_is_the_uncapped_one():
    S, F, T, C, X = problem(20, 8, 3, 2)
    res = box_core.loocv(S, times=T, feasible=F, selectors=("contextual", "contextual_capped"),
                         params={"contextual": {"k": 5},
                                 "contextual_capped": {"k": 5, "cap_quantile": 1.0}},
                         instance_features=X, checks=C, measure_overhead=False)
    np.testing.assert_array_equal(res.order["contextual_capped"], res.order["contextual"])
    assert np.isinf(res.allowance.get("contextual_capped", np.full(1, np.inf))).all()


def test_the_held_out_row_never_influences_its_own_settings():
    S, F, T, C, X = problem(60, 10, 3, 3)
    names = ("contextual", "contextual_capped")
    base = box_core.loocv(S, times=T, feasible=F, selectors=names, instance_features=X,
                          checks=C, measure_overhead=False, seed=5)
    groups = contextual.tuning_groups(60, 5)
    assert np.unique(groups).size == contextual.GROUPS
    rng = np.random.default_rng(0)
    for i in (0, 17, 42):
        S2, F2, T2, C2, X2 = S.copy(), F.copy(), T.copy(), C.copy(), X.copy()
        F2[i] = rng.random(10) < 0.5
        S2[i] = np.where(F2[i], -rng.uniform(0.5, 9, 10), np.nan)
        T2[i] = rng.uniform(0, 1, 10)
        C2[i] = rng.integers(0, 1000, 10)
        X2[i] = rng.normal(scale=10, size=3)
        other = box_core.loocv(S2, times=T2, feasible=F2, selectors=names,
                               instance_features=X2, checks=C2, measure_overhead=False, seed=5)
        same = groups == groups[i]  # every row tuned on the rows outside i's group
        for name in names:
            for key, values in base.settings[name].items():
                np.testing.assert_array_equal(other.settings[name][key][same], values[same])
    # and what each row got is what tuning on the rows outside its group gives
    Dn = internal(S, F)
    for g in (0, 3):
        rows = np.flatnonzero(groups != g)
        want = contextual.tune(contextual.ContextualCapped, Dn[rows], F[rows], T[rows],
                               C[rows].astype(float), X[rows], {}, seed=5)
        for key, value in want.items():
            assert (base.settings["contextual_capped"][key][groups == g] == value).all()


def test_holdout_tunes_on_the_training_rows_and_matches_the_live_selector():
    S, F, T, C, X = problem(40, 9, 3, 4)
    Dn = internal(S, F)
    top = np.unravel_index(np.abs(Dn).argmax(), Dn.shape)[0]
    test = 39 if top != 39 else 38
    train = np.setdiff1d(np.arange(40), [test])
    res = box_core.holdout(Dn, train, [test], times=T, feasible=F, checks=C,
                           selectors=("contextual", "contextual_capped"),
                           instance_features=X, measure_overhead=False, seed=0)
    live = box_core.make_selector("contextual", Dn[train], times=T[train], feasible=F[train],
                                  instance_features=X[train], new_instance_features=X[test])
    order = []
    for _ in range(9):
        j = live.propose()
        order.append(j)
        live.update(j, Dn[test, j])
    assert order == res.order["contextual"][0].tolist()
    want = contextual.tune(contextual.Contextual, Dn[train], F[train], T[train], None,
                           X[train], {}, seed=0)
    assert res.settings["contextual"]["k"][0] == want["k"]
    want = contextual.tune(contextual.ContextualCapped, Dn[train], F[train], T[train],
                           C[train].astype(float), X[train], {}, seed=0)
    assert res.settings["contextual_capped"]["cap"][0] == want["cap"]


def test_features_that_predict_feasibility_make_it_faster_than_box():
    # feasibility of each column depends on one feature only: the neighbours know it
    S, F, T, C, X = problem(200, 12, 2, 7)
    res = box_core.loocv(S, times=T, feasible=F, selectors=("box", "contextual"),
                         instance_features=X, measure_overhead=False)
    box = np.nanmean(res.first_feasible_time["box"])
    assert np.nanmean(res.first_feasible_time["contextual"]) < box


def test_tuning_is_training_time_not_each_instance_s_overhead():
    """Nested tuning stands in for the one tuning a live selector does on its training
    rows before any instance (as BOX's prior fit); it once went into every held-out row's
    first step and made CONTEXTUAL look slower than BOX on the main job's store."""
    S, F, T, C, X = problem(120, 10, 2, 3)
    res = box_core.loocv(S, times=T, feasible=F, selectors=("box", "contextual"),
                         instance_features=X)
    tuning = res.tuning_seconds["contextual"]
    assert tuning > 0 and set(res.tuning_seconds) == {"contextual"}
    # a nested leave-one-out over every group's training rows against one pass over the
    # held-out rows: tens of times more work, so the difference is no matter of noise
    assert res.overhead["contextual"][:, 0].sum() < tuning / 4
    steps = res.first_feasible_step["contextual"]
    found = steps >= 0
    spent = np.array([res.overhead["contextual"][i, :steps[i] + 1].sum()
                      for i in np.flatnonzero(found)])
    extra = res.first_feasible_time["contextual"] - res.first_feasible_planning_time["contextual"]
    assert extra[found] == pytest.approx(spent)


def test_capped_costs_on_a_hand_built_example():
    # three entries of one instance: a plan after 100 checks, a failure after 40, and one
    # that exhausts a budget of 1000 checks; each took 1 ms per 100 checks, cap 50
    need = np.array([100, 40, 1000])
    feas = np.array([True, False, False])
    times = need / 100 * 1e-3
    out, cost = outcome_of_try(need, np.zeros(3), 50.0, feas, times)
    assert out.tolist() == [PAUSED, FAILED, PAUSED]
    assert cost == pytest.approx([0.5e-3, 0.4e-3, 0.5e-3])  # 50 of 100, all 40, 50 of 1000
    out, cost = outcome_of_try(need, np.full(3, 50.0), math.inf, feas, times)
    assert out.tolist() == [FEASIBLE, FAILED, FAILED]
    assert cost[[0, 2]] == pytest.approx([0.5e-3, 9.5e-3])  # what was left
    out, cost = outcome_of_try(np.array([0]), np.zeros(1), 50.0, np.array([False]),
                               np.array([2e-4]))
    assert (out, cost) == ([FAILED], pytest.approx([2e-4]))  # refuted before any check


def test_a_3_by_3_leave_one_out_of_capped_tries():
    # row 2 plans only at column 0, after 900 of 1000 checks; the others plan at 1 quickly
    S = np.array([[np.nan, -1.0, np.nan], [np.nan, -1.5, np.nan], [-2.0, np.nan, np.nan]])
    F = ~np.isnan(S)
    C = np.array([[1000, 10, 1000], [1000, 20, 1000], [900, 1000, 1000]])
    T = C * 1e-5
    X = np.array([[0.0], [0.1], [5.0]])
    res = box_core.loocv(S, times=T, feasible=F, selectors=("contextual_capped",), checks=C,
                         instance_features=X, measure_overhead=False,
                         params={"contextual_capped": {"k": 1, "cap_quantile": 0.5,
                                                       "select_features": 0}})
    name = "contextual_capped"
    for i in range(3):
        used = res.order[name][i] >= 0
        costs = res.try_time[name][i, used]
        step = res.first_feasible_step[name][i]
        assert res.first_feasible_time[name][i] == pytest.approx(costs[:step + 1].sum())
        # every try costs its share: allowance over need, or what was left to the end
        granted = {}
        for j, allow, cost in zip(res.order[name][i, used], res.allowance[name][i, used],
                                  costs, strict=True):
            upto = min(allow, C[i, j])
            assert cost == pytest.approx(T[i, j] * (upto - granted.get(j, 0)) / C[i, j])
            granted[j] = allow
    # each row is its own tuning group here; row 2's cap is the median of rows 0 and 1's
    # successful checks (15), which pauses its plan at column 0 and later resumes it
    assert res.settings[name]["cap"][2] == 15
    assert list(res.order[name][2]).count(0) == 2
    assert res.first_feasible_time[name][2] >= T[2, 0]


@pytest.mark.parametrize("kwargs, message", [
    ({"instance_features": np.zeros((5, 2))}, "instance_features must have one row"),
    ({"instance_features": np.full((6, 2), np.nan)}, "instance_features contains"),
    ({"checks": np.zeros((6, 3))}, "checks has shape"),
    ({"checks": -np.ones((6, 4))}, "whole numbers >= 0"),
    ({"checks": np.full((6, 4), 0.5)}, "whole numbers >= 0"),
    ({"checks": np.ones((6, 4), bool)}, "checks must hold whole numbers"),
    ({"params": {"contextual": {"k": 0}}}, "k must be an integer"),
    ({"params": {"contextual": {"mismatch": 2.0}}}, "mismatch must lie"),
])
def test_bad_inputs_are_named(kwargs, message):
    S, F, T, C, X = problem(6, 4, 2, 0)
    args = {"times": T, "feasible": F, "selectors": ("contextual",),
            "instance_features": X, **kwargs}
    with pytest.raises(ValueError, match=message):
        box_core.loocv(S, **args)


def test_live_bad_inputs_are_named():
    S, F, T, C, X = problem(8, 4, 2, 0)
    D = internal(S, F)
    with pytest.raises(ValueError, match="new_instance_features must have shape"):
        box_core.make_selector("contextual", D, instance_features=X,
                               new_instance_features=np.zeros(3))
    with pytest.raises(ValueError, match="new_instance_features .* is needed"):
        box_core.make_selector("contextual", D, instance_features=X)
    with pytest.raises(ValueError, match="needs instance_features"):
        box_core.make_selector("contextual", D, new_instance_features=X[0])
    with pytest.raises(ValueError, match="cap_quantile must be"):
        box_core.make_selector("contextual_capped", D, instance_features=X,
                               new_instance_features=X[0], cap_quantile=-1)


def test_feature_selection_keeps_the_features_that_predict_feasibility():
    rng = np.random.default_rng(11)
    n, m = 300, 12
    signal = rng.normal(size=(n, 2))
    F = (signal @ rng.normal(size=(2, m)) + 0.3 * rng.normal(size=(n, m))) > 0.5
    X = np.column_stack([rng.normal(size=n), signal[:, 0], rng.normal(size=(n, 2)) * 50,
                         signal[:, 1], np.ones(n)])
    assert contextual.select_features(F, X).tolist() == [False, True, False, False, True,
                                                         False]
    assert not contextual.select_features(F, rng.normal(size=(n, 3))).any()


@pytest.mark.parametrize("constant", [0, 5])
def test_a_skipped_observation_leaves_the_posterior_as_it_was(constant):
    # a paused try observes nothing: the posterior is the one of the other observations
    from box_core.gaussian import GaussianPosterior
    from box_core.prior import Prior

    rng = np.random.default_rng(constant)
    D = rng.normal(size=(30, 12))
    D[:, :constant] = 1.0  # inert columns: the compact layout of W where 5 of 12
    prior = Prior.fit(D)
    rows = np.arange(8)
    batch = GaussianPosterior(prior.folds(rows), capacity=4)
    cols = np.array([rng.permutation(12)[:6] for _ in rows])
    skip = rng.random((8, 6)) < 0.4
    for t in range(6):
        batch.observe(cols[:, t], D[rows, cols[:, t]], skip=skip[:, t])
    for b in rows:
        alone = GaussianPosterior(prior.folds([b]), capacity=4)
        for t in np.flatnonzero(~skip[b]):
            alone.observe(cols[b, t:t + 1], D[[b], cols[b, t:t + 1]])
        np.testing.assert_allclose(batch.mean[b], alone.mean[0], atol=1e-9)
        np.testing.assert_allclose(batch.var[b], alone.var[0], atol=1e-9)


@pytest.mark.parametrize("selectors", [("box", "contextual", "static", "contextual_capped"),
                                       ("contextual", "contextual_capped")])
@pytest.mark.parametrize("n", [60, 70])
def test_tuned_selectors_in_a_second_process_give_the_same_result(second_takes_odd_pieces,
                                                                  selectors, n):
    """The two processes share the pieces of work: each of the 10 tuning groups of the
    tuned selectors, and the others' rows (in halves from 64 rows on), costliest first;
    the second process surely takes the odd ones, and the results merged are the one
    process's."""
    S, F, T, C, X = problem(n, 8, 2, 5)
    kw = dict(times=T, feasible=F, instance_features=X, checks=C, measure_overhead=False,
              selectors=selectors)
    one, two = box_core.loocv(S, **kw), box_core.loocv(S, **kw, workers=2)
    plain = len(selectors) - 2
    pieces = 10 + plain * (2 if n >= 64 else 1)
    assert set(range(1, pieces, 2)) <= set(second_takes_odd_pieces[0])
    assert two.selectors == one.selectors and list(two.order) == list(one.order)
    np.testing.assert_array_equal(two.time_grid, one.time_grid)
    for name in one.selectors:
        for field in ("order", "first_feasible_time", "best_score"):
            np.testing.assert_array_equal(getattr(two, field)[name], getattr(one, field)[name])
    for name, chosen in one.settings.items():
        for key, values in chosen.items():
            np.testing.assert_array_equal(two.settings[name][key], values)
    assert set(two.tuning_seconds) == {"contextual", "contextual_capped"}
    train, test = np.arange(0, n, 2), np.arange(1, n, 2)
    h1 = box_core.holdout(S, train, test, **kw)
    h2 = box_core.holdout(S, train, test, **kw, workers=2)
    assert len(second_takes_odd_pieces) == (2 if plain else 1)  # one group: one piece
    for name in h1.selectors:
        np.testing.assert_array_equal(h2.order[name], h1.order[name])
        for key, values in h1.settings.get(name, {}).items():
            np.testing.assert_array_equal(h2.settings[name][key], values)


def test_the_second_process_needs_no_main_guard_in_the_caller():
    """Code piped to ``python -`` (no script file, no ``__main__`` guard) can ask for it:
    the child never imports the caller's main module."""
    code = ("import numpy as np, box_core\n"
            "from tests.test_contextual import problem\n"
            "S, F, T, C, X = problem(40, 6, 2, 1)\n"
            "r = box_core.loocv(S, times=T, feasible=F, instance_features=X, checks=C,\n"
            "                  selectors=('box', 'contextual'), workers=2,\n"
            "                  measure_overhead=False)\n"
            "print(sorted(r.tuning_seconds), r.order['contextual'].shape)\n")
    res = subprocess.run([sys.executable, "-"], input=code, capture_output=True, text=True,
                         cwd=Path(__file__).resolve().parents[1], check=False)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "['contextual'] (40, 6)"
