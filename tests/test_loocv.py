import numpy as np
import pytest

from box_core import loocv, make_selector
from box_core.failure import failure_value, fill_failures
from tests import reference
from tests.matrices import degenerate, well_conditioned

ALL = ("box", "static", "rand", "doo", "pembo", "oracle")


def features_for(m, seed=0):
    return np.random.default_rng(seed).normal(size=(m, 3))


def test_orders_equal_the_naive_refit_per_fold_implementation():
    D = well_conditioned(40, 8, seed=11)
    feats = features_for(8)
    result = loocv(D, selectors=ALL, features=feats, seed=3, k=6)
    for name in ALL:
        naive = reference.loocv_orders(D, name, 6, seed=3, features=feats)
        np.testing.assert_array_equal(result.order[name], naive, err_msg=name)


def test_each_fold_is_the_live_selector_trained_on_the_other_rows():
    D = degenerate(14, 20, seed=5, constant=4, duplicate=3, rank=2)
    feats = features_for(20)
    result = loocv(D, selectors=ALL, features=feats, seed=9)
    for i in (0, 6, 13):
        train, truth = np.delete(D, i, axis=0), D[i]
        for name in ALL:
            sel = make_selector(name, train, features=feats, seed=(9, i), true_scores=truth)
            order = []
            for _ in range(20):
                j = sel.propose()
                sel.update(j, truth[j])
                order.append(j)
            assert list(result.order[name][i]) == order, (name, i)


def test_time_to_first_feasible_sums_the_times_of_the_tries_up_to_it():
    rng = np.random.default_rng(0)
    D = degenerate(30, 12, seed=1, constant=3, duplicate=2, rank=2)
    feasible = D > -10
    times = rng.uniform(0.01, 1.0, size=D.shape)
    res = loocv(D, times=times, feasible=feasible, features=features_for(12), seed=0,
                measure_overhead=False)
    for name in res.selectors:
        for i in range(30):
            order = res.order[name][i]
            hits = np.flatnonzero(feasible[i, order])
            if hits.size == 0:
                assert res.first_feasible_step[name][i] == -1
                assert np.isnan(res.first_feasible_time[name][i])
            else:
                step = hits[0]
                assert res.first_feasible_step[name][i] == step
                expected = times[i, order[: step + 1]].sum()
                assert res.first_feasible_time[name][i] == pytest.approx(expected)
    assert np.array_equal(res.eligible, feasible.any(axis=1))


def test_overhead_is_measured_separately_and_added_to_times():
    D = well_conditioned(20, 6, seed=2)
    res = loocv(D, selectors=("box", "static"))
    for name in res.selectors:
        assert (res.overhead[name] >= 0).all() and res.overhead[name].sum() > 0
        found = res.first_feasible_step[name] >= 0
        extra = res.first_feasible_time[name] - res.first_feasible_planning_time[name]
        assert (extra[found] > 0).all()


def test_default_feasibility_is_any_score_above_the_matrix_minimum():
    D = degenerate(12, 7, seed=4, constant=2, duplicate=0, rank=2)
    res = loocv(D, selectors=("static",))
    explicit = loocv(D, feasible=D > D.min(), selectors=("static",), failure_rule="magnitude")
    assert res.failure_value == D.min()
    np.testing.assert_array_equal(res.first_feasible_step["static"],
                                  explicit.first_feasible_step["static"])


def test_infeasible_entries_get_the_failure_value_before_fitting():
    D = well_conditioned(25, 5, seed=8) - 10
    feasible = np.random.default_rng(1).random(D.shape) < 0.5
    raw = np.where(feasible, D, 123.0)  # garbage where infeasible must not matter
    res = loocv(raw, feasible=feasible, selectors=("box",), measure_overhead=False)
    d = failure_value(raw, feasible)
    filled = fill_failures(raw, feasible, d)
    again = loocv(filled, feasible=feasible, selectors=("box",), measure_overhead=False)
    assert res.failure_value == d
    np.testing.assert_array_equal(res.order["box"], again.order["box"])


def test_short_horizons_may_miss_and_report_it():
    D = np.full((5, 6), -10.0)
    D[:, 5] = -1.0  # only the last column is ever feasible; STATIC tries it first, RAND may not
    res = loocv(D, selectors=("static", "rand"), k=2, seed=0)
    assert res.order["static"].shape == (5, 2)
    assert (res.first_feasible_step["static"] == 0).all()
    missed = ~(res.order["rand"] == 5).any(axis=1)
    assert missed.any()  # with seed 0 some folds do not reach column 5 in two tries
    assert np.isnan(res.first_feasible_time["rand"][missed]).all()
    assert (res.first_feasible_step["rand"][missed] == -1).all()


def test_best_score_curves_rise_from_the_failure_value_to_the_best_tried():
    D = degenerate(20, 10, seed=3, constant=2, duplicate=1, rank=2)
    res = loocv(D, selectors=("box", "rand"), features=features_for(10), measure_overhead=False)
    assert res.time_grid[0] == 0
    for name in res.selectors:
        curve = res.best_score[name]
        assert (np.diff(curve, axis=1) >= 0).all()
        np.testing.assert_array_equal(curve[:, 0], res.failure_value)
        np.testing.assert_array_equal(curve[:, -1], D.max(axis=1))  # k = m: all tried by the end
    np.testing.assert_array_equal(res.optimal_score, D.max(axis=1))


def test_results_are_deterministic_without_measured_overhead():
    D = degenerate(15, 9, seed=7, constant=2, duplicate=2, rank=3)
    kw = dict(selectors=("box", "rand", "doo", "pembo"), features=features_for(9),
              measure_overhead=False)
    a, b = loocv(D, seed=1, **kw), loocv(D, seed=1, **kw)
    c = loocv(D, seed=2, **kw)
    for name in a.selectors:
        np.testing.assert_array_equal(a.order[name], b.order[name])
        np.testing.assert_array_equal(a.best_score[name], b.best_score[name])
    assert not np.array_equal(a.order["rand"], c.order["rand"])


def test_summary_reports_the_computed_means_and_ratios():
    D = degenerate(40, 15, seed=2, constant=3, duplicate=2, rank=2)
    times = np.random.default_rng(3).uniform(0.1, 1.0, D.shape)
    res = loocv(D, times=times, features=features_for(15), measure_overhead=False)
    summary = res.summary()
    box = res.first_feasible_time["box"][res.eligible]
    for name in res.selectors:
        line = summary.line(name)
        mine = res.first_feasible_time[name][res.eligible]
        assert line.mean_time == pytest.approx(np.nanmean(mine))
        assert line.ci_low < line.mean_time < line.ci_high
        assert line.speedup == pytest.approx(np.nanmean(mine) / np.nanmean(box))
        assert line.speedup_low <= line.speedup <= line.speedup_high
        assert name in str(summary)
    assert summary.to_dict()["selectors"][0]["name"] == "box"


@pytest.mark.parametrize("kwargs, message", [
    ({"scores": np.array([[1.0, np.nan]] * 4)}, "NaN"),
    ({"scores": np.array([[1.0, -np.inf]] * 4)}, "inf"),
    ({"scores": np.ones((2, 3))}, "at least 3 rows"),
    ({"times": np.ones((5, 3))}, "times has shape"),
    ({"times": -np.ones((4, 3))}, "times must be >= 0"),
    ({"feasible": np.ones((4, 2), bool)}, "feasible has shape"),
    ({"feasible": np.full((4, 3), 7)}, "boolean"),
    ({"features": np.ones((2, 2)), "selectors": ("doo",)}, "one row per constraint"),
    ({"selectors": ("doo",)}, "needs constraint features"),
    ({"selectors": ("box", "magic")}, "unknown selector"),
    ({"selectors": ("box", "box")}, "duplicates"),
    ({"selectors": ()}, "empty"),
    ({"k": 4}, "k must be"),
    ({"k": 0}, "k must be"),
    ({"params": {"doo": {"lam": 2.0}}}, "not evaluated"),
    ({"params": {"box": {"lam": 2.0}}}, "unknown parameter"),
    ({"scores": np.full((4, 3), 2.0)}, "no entry can be told feasible"),
    ({"failure_rule": "paper"}, "unknown failure rule"),
    ({"time_grid": [1.0, 0.5]}, "time_grid"),
])
def test_bad_input_is_named(kwargs, message):
    args = {"scores": well_conditioned(4, 3, seed=0), "selectors": ("box",)}
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        loocv(args.pop("scores"), **args)
