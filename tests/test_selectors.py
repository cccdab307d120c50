import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from box_core import SELECTORS, make_selector
from box_core.selectors import pembo_zeta
from tests import reference
from tests.matrices import degenerate, well_conditioned


def run(selector, truth, k):
    order = []
    for _ in range(k):
        j = selector.propose()
        selector.update(j, truth[j])
        order.append(j)
    return order


@settings(max_examples=30, deadline=None)
@given(m=st.integers(2, 20), seed=st.integers(0, 10_000), c=st.sampled_from([0.0, 1.0, 1.96, 4.0]))
def test_box_order_equals_direct_eq2_on_well_conditioned_matrices(m, seed, c):
    D = well_conditioned(10 * m, m, seed)
    train, truth = D[:-1], D[-1]
    fast = run(make_selector("box", train, c=c), truth, m)
    assert fast == reference.box_order(train, truth, m, c=c)


@settings(max_examples=15, deadline=None)
@given(m=st.integers(2, 15), seed=st.integers(0, 10_000))
def test_pembo_order_equals_direct_implementation(m, seed):
    D = well_conditioned(10 * m, m, seed)
    train, truth = D[:-1], D[-1]
    assert run(make_selector("pembo", train), truth, m) == reference.pembo_order(train, truth, m)


def test_pembo_coefficient_grows_with_t_and_exceeds_its_limit():
    L = np.log(4 / 0.01)
    z = [pembo_zeta(t, 1000, 0.01) for t in (1, 10, 100)]
    assert z[0] < z[1] < z[2]
    assert z[0] > np.sqrt(2 * L)


degenerate_cases = st.builds(
    degenerate,
    n=st.integers(3, 12), m=st.integers(2, 40), seed=st.integers(0, 10_000),
    constant=st.integers(0, 5), duplicate=st.integers(0, 5), rank=st.integers(1, 3),
)


@settings(max_examples=40, deadline=None)
@given(D=degenerate_cases, name=st.sampled_from(sorted(SELECTORS)))
def test_every_selector_gives_valid_non_repeating_proposals_on_degenerate_matrices(D, name):
    train, truth = D[:-1], D[-1]
    m = D.shape[1]
    features = np.random.default_rng(0).normal(size=(m, 3))
    sel = make_selector(name, train, features=features, true_scores=truth, seed=1)
    order = run(sel, truth, m)
    assert sorted(order) == list(range(m))
    with pytest.raises(RuntimeError, match="all"):
        sel.propose()


@pytest.mark.parametrize("name", ["box", "pembo", "static"])
def test_ties_go_to_the_lowest_index(name):
    # Columns 1 and 3 are identical; columns 0 and 2 are constant at the failure value.
    base = well_conditioned(30, 2, seed=4)
    D = np.column_stack([np.full(30, -10.0), base[:, 0] + 5, np.full(30, -10.0), base[:, 0] + 5,
                         base[:, 1]])
    order = run(make_selector(name, D[:-1]), D[-1], 5)
    assert order.index(1) < order.index(3)
    assert order.index(0) < order.index(2)


def test_all_constant_matrix_is_tried_left_to_right():
    D = np.full((6, 5), -3.0)
    assert run(make_selector("box", D[:-1]), D[-1], 5) == [0, 1, 2, 3, 4]


def test_static_follows_the_training_means():
    D = well_conditioned(50, 8, seed=9)
    assert run(make_selector("static", D), D[0], 8) == list(np.argsort(-D.mean(axis=0)))


def test_oracle_tries_the_best_constraint_first():
    D = well_conditioned(20, 6, seed=2)
    truth = D[0]
    assert run(make_selector("oracle", D[1:], true_scores=truth), truth, 6) == list(
        np.argsort(-truth))


def test_rand_and_doo_are_reproducible_from_their_seed():
    D = well_conditioned(20, 12, seed=3)
    feats = np.random.default_rng(1).normal(size=(12, 2))
    for name in ("rand", "doo"):
        a = run(make_selector(name, D[1:], features=feats, seed=7), D[0], 12)
        b = run(make_selector(name, D[1:], features=feats, seed=7), D[0], 12)
        c = run(make_selector(name, D[1:], features=feats, seed=8), D[0], 12)
        assert a == b
        assert a != c


def test_doo_matches_its_lipschitz_bound_definition():
    D = well_conditioned(20, 15, seed=6)
    feats = np.random.default_rng(2).normal(size=(15, 3))
    got = run(make_selector("doo", D[1:], features=feats, seed=(0, 0), lam=0.5), D[0], 15)
    assert got == reference.doo_order(D[0], feats, 15, (0, 0), lam=0.5)


def test_update_accepts_constraints_other_than_the_proposal():
    D = well_conditioned(30, 5, seed=1)
    sel = make_selector("static", D)
    first = sel.propose()
    other = (first + 1) % 5
    sel.update(other, -1.0)
    assert sel.propose() == first  # still the best untried by mean
    assert sel.tried[other] and not sel.tried[first]


@pytest.mark.parametrize("call, message", [
    (lambda D: make_selector("nope", D), "unknown selector"),
    (lambda D: make_selector("box", D, lam=1.0), "unknown parameter"),
    (lambda D: make_selector("doo", D), "needs constraint features"),
    (lambda D: make_selector("oracle", D), "needs true_scores"),
    (lambda D: make_selector("doo", D, features=np.ones((3, 2))), "one row per constraint"),
    (lambda D: make_selector("box", D, c=-1.0), "c must be"),
    (lambda D: make_selector("pembo", D, delta=2.0), "delta must"),
    (lambda D: make_selector("box", D[:1]), "at least 2 rows"),
])
def test_bad_selector_arguments_are_named(call, message):
    with pytest.raises(ValueError, match=message):
        call(well_conditioned(10, 4, seed=0))


@pytest.mark.parametrize("index, score, message", [
    (9, -1.0, "out of range"), (-1, -1.0, "out of range"), (0, float("nan"), "finite"),
])
def test_bad_updates_are_refused(index, score, message):
    sel = make_selector("box", well_conditioned(10, 4, seed=0))
    with pytest.raises(ValueError, match=message):
        sel.update(index, score)


def test_a_constraint_cannot_be_reported_twice():
    sel = make_selector("box", well_conditioned(10, 4, seed=0))
    sel.update(2, -1.0)
    with pytest.raises(ValueError, match="already tried"):
        sel.update(2, -1.0)
