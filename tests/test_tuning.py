"""Hold-out evaluation, learning curves and nested tuning of BOX's C."""

import numpy as np
import pytest

import box_core
from box_core import synthetic
from tests.matrices import degenerate


@pytest.fixture(scope="module")
def data():
    return synthetic.score_matrix(60, 24, useful=10, per_type=3, seed=2)


def test_holdout_on_all_other_rows_is_the_leave_one_out_fold():
    D = degenerate(30, 12, 1, constant=3, duplicate=2, rank=4)
    names = ("box", "static", "rand", "pembo")
    full = box_core.loocv(D, selectors=names, measure_overhead=False)
    for i in (0, 7, 29):
        train = np.delete(np.arange(30), i)
        one = box_core.holdout(D, train, [i], selectors=names, measure_overhead=False)
        for s in names:
            np.testing.assert_array_equal(one.order[s][0], full.order[s][i])


def test_holdout_uses_only_the_training_rows_for_its_prior(data):
    train, test = np.arange(0, 40), np.arange(40, 60)
    a = box_core.holdout(data.scores, train, test, feasible=data.feasible,
                         selectors="static", measure_overhead=False)
    expected = np.argsort(-box_core.fill_failures(
        data.scores, data.feasible, a.failure_value)[train].mean(axis=0), kind="stable")
    assert (a.order["static"] == expected).all()
    changed = data.scores.copy()
    changed[test] = changed[test][::-1]  # test rows' own scores do not move the prior
    b = box_core.holdout(changed, train, test, feasible=data.feasible[np.r_[train, test[::-1]]],
                         selectors="static", measure_overhead=False)
    assert (b.order["static"] == a.order["static"]).all()


@pytest.mark.parametrize("train, test, message", [
    ([0], [1, 2], "at least 2"),
    ([0, 1], [], "empty"),
    ([0, 1, 2], [2, 3], "share rows"),
    ([0, 1, 99], [3], "lie in"),
    ([0, 1, 1], [3], "repeated"),
])
def test_holdout_refuses_bad_splits(data, train, test, message):
    with pytest.raises(ValueError, match=message):
        box_core.holdout(data.scores, np.array(train, dtype=int), np.array(test, dtype=int),
                         feasible=data.feasible, selectors="box")


def test_learning_curve_points_grow_in_training_rows_and_are_reproducible(data):
    kwargs = dict(times=data.times, feasible=data.feasible, fractions=(0.1, 0.5, 1.0),
                  repeats=3, seed=4)
    a = box_core.learning_curve(data.scores, **kwargs)
    b = box_core.learning_curve(data.scores, **kwargs)
    assert a == b
    box = [p for p in a if p.selector == "box"]
    assert [p.n_train for p in box] == [5, 24, 48]  # 48 rows left after 12 test rows
    for p in a:
        assert p.low <= p.mean <= p.high
        assert p.rows > 0


def test_learning_curve_with_more_data_helps_static_on_typed_instances(data):
    points = box_core.learning_curve(data.scores, times=data.times, feasible=data.feasible,
                                     selectors=("static",), fractions=(0.05, 1.0), repeats=5)
    small, full = points
    assert full.mean < small.mean


def test_tuned_c_of_a_fold_does_not_depend_on_that_fold(data):
    kwargs = dict(times=data.times, feasible=data.feasible, grid=(0.0, 1.0, 5.0), folds=3)
    a = box_core.tune_c(data.scores, **kwargs)
    parts = np.array_split(np.random.default_rng([0, 7]).permutation(60), 3)
    scores = data.scores.copy()
    feasible = data.feasible.copy()
    scores[parts[0]] = scores[parts[0]][:, ::-1]  # scramble fold 0's own rows
    feasible[parts[0]] = feasible[parts[0]][:, ::-1]
    b = box_core.tune_c(scores, **{**kwargs, "feasible": feasible})
    assert b.chosen[0] == a.chosen[0]
    assert len(a.chosen) == 3 and set(a.chosen) <= {0.0, 1.0, 5.0}
    assert set(a.sensitivity) == {0.0, 1.0, 5.0}


def test_a_single_value_grid_reproduces_the_fixed_c(data):
    t = box_core.tune_c(data.scores, times=data.times, feasible=data.feasible, grid=(1.96,),
                        folds=3)
    np.testing.assert_array_equal(t.tuned, t.fixed)
    assert t.chosen == (1.96, 1.96, 1.96)


def test_tune_c_refuses_bad_grids_and_folds(data):
    with pytest.raises(ValueError, match="grid"):
        box_core.tune_c(data.scores, feasible=data.feasible, grid=(-1.0,))
    with pytest.raises(ValueError, match="folds"):
        box_core.tune_c(data.scores, feasible=data.feasible, folds=1)
