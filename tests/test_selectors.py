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


@settings(max_examples=15, deadline=None)
@given(m=st.integers(2, 15), seed=st.integers(0, 10_000))
def test_pembo_compounded_equals_the_authors_iterative_procedure(m, seed):
    # 2m + 2 rows: the compounded factor grows to about e over m tries
    D = well_conditioned(2 * m + 2, m, seed)
    train, truth = D[:-1], D[-1]
    assert (run(make_selector("pembo_compounded", train), truth, m)
            == reference.pembo_compounded_order(train, truth, m))


def test_pembo_zeta_is_the_published_schedule_where_defined():
    # zeta_t of Wang, Kim and Kaelbling's code, written out for N = 1000, t = 5, delta = 0.01
    N, t, delta = 1000, 5, 0.01
    L6 = np.log(6 / delta)
    iota = np.sqrt(6 * (N - 2 + t + 2 * np.sqrt(t * L6) + 2 * L6) / (delta * N * (N - t - 2)))
    b = L6 / (N - t - 1)
    expected = (iota + np.sqrt(2 * np.log(3 / delta))) / np.sqrt(1 - 2 * np.sqrt(b))
    assert pembo_zeta(t, N, delta) == pytest.approx(expected, rel=1e-12)
    assert pembo_zeta(0, N) == pytest.approx(reference.pembo_zeta(0, N), rel=1e-12)


@pytest.mark.parametrize("N", [2, 3, 10, 27, 28, 40, 1000])
def test_pembo_zeta_is_finite_continuous_and_non_decreasing_past_its_domain(N):
    z = [pembo_zeta(t, N) for t in range(N + 50)]
    assert np.isfinite(z).all()
    assert (np.diff(z) >= -1e-12).all()
    # continuation: the boundary value is reached, never exceeded by a jump
    assert z == pytest.approx([reference.pembo_zeta(t, N) for t in range(N + 50)], rel=1e-12)


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
    times = np.random.default_rng(1).uniform(0.1, 2.0, size=D.shape)
    sel = make_selector(name, train, features=features, true_scores=truth, seed=1,
                        times=times[:-1], true_times=times[-1])
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
    assert got == reference.doo_order(D[0], feats, 15, (0, 0), lam=0.5,
                                      unit=np.abs(D[1:]).max())


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
    (9, -1.0, "index 9 out of range"), (-1, -1.0, "index -1 out of range"),
    (0, float("nan"), "score must be finite"), (0, "x", "score must be a finite number"),
])
def test_bad_updates_are_refused(index, score, message):
    sel = make_selector("box", well_conditioned(10, 4, seed=0))
    with pytest.raises(ValueError, match=message):
        sel.update(index, score)


def test_a_constraint_cannot_be_reported_twice():
    sel = make_selector("box", well_conditioned(10, 4, seed=0))
    sel.update(2, -1.0)
    with pytest.raises(ValueError, match="index 2: that constraint was already tried"):
        sel.update(2, -1.0)


def feasibility_matrix(n, m, seed):
    """Scores with failures at -10, feasibility correlated across columns, and times that
    differ by column and by outcome (failures cheap, like the planners here)."""
    D = degenerate(n, m, seed, constant=1, duplicate=0, rank=3)
    rng = np.random.default_rng(seed)
    F = D > -10
    T = np.where(F, rng.uniform(0.5, 3.0, size=(n, m)), rng.uniform(0.01, 0.3, size=(n, m)))
    return D, F, T * rng.uniform(0.5, 2.0, size=m)


@settings(max_examples=25, deadline=None)
@given(n=st.integers(6, 40), m=st.integers(2, 25), seed=st.integers(0, 10_000),
       mismatch=st.sampled_from([0.0, 0.1, 0.5]), prior_rows=st.sampled_from([0.5, 1.0, 4.0]),
       time_rows=st.sampled_from([0.5, 5.0]))
def test_eips_order_equals_its_direct_implementation(n, m, seed, mismatch, prior_rows,
                                                     time_rows):
    D, F, T = feasibility_matrix(n, m, seed)
    train, truth = D[:-1], D[-1]
    sel = make_selector("eips", train, times=T[:-1], feasible=F[:-1], mismatch=mismatch,
                        prior_rows=prior_rows, time_rows=time_rows)
    expected = reference.eips_order(train, F[:-1], T[:-1], truth, m, prior_rows=prior_rows,
                                    mismatch=mismatch, time_rows=time_rows)
    assert run(sel, truth, m) == expected


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_eips_stops_updating_negligible_rows_and_keeps_the_direct_order(seed):
    # 150 tries on 59 training rows: most rows mismatch the instance more than 20 times,
    # so their weights fall below the cutoff and stay there (once all do, the rows' matrix
    # is let go); the direct implementation keeps multiplying them all the way down
    D, F, T = feasibility_matrix(60, 150, seed)
    train, truth = D[:-1], D[-1]
    sel = make_selector("eips", train, times=T[:-1], feasible=F[:-1])
    expected = reference.eips_order(train, F[:-1], T[:-1], truth, 150)
    assert run(sel, truth, 150) == expected
    policy = sel._policy
    frozen = (policy._w[0] > 0) & ~policy._live[0]
    assert frozen.sum() >= 45 and (policy._w[0][frozen] < 1e-18).all()
    assert (policy._FL is None) == (policy._changing == 0)


def test_eips_tries_the_cheaper_of_two_equally_likely_constraints_first():
    # both columns always feasible with the same scores; column 0 takes 10 s, column 1 1 s
    D = np.column_stack([np.linspace(-2, -1, 20)] * 2)
    T = np.column_stack([np.full(20, 10.0), np.full(20, 1.0)])
    assert make_selector("box", D).propose() == 0
    assert make_selector("eips", D, times=T, feasible=np.ones_like(D, bool)).propose() == 1


def test_eips_learns_from_a_failure_which_constraint_will_work():
    # instances of two kinds: 60 % feasible only at column 0, 40 % only at column 1;
    # column 2 is never feasible.  After column 0 fails, column 1 is certain.
    kind_a = np.tile([-1.0, -10.0, -10.0], (12, 1))
    kind_b = np.tile([-10.0, -1.0, -10.0], (8, 1))
    D = np.vstack([kind_a, kind_b])
    sel = make_selector("eips", D, feasible=D > -10)
    assert sel.propose() == 0
    sel.update(0, -10.0)
    assert sel.propose() == 1


def test_eips_expects_the_cost_that_instances_like_this_one_paid():
    # Columns 0 and 1 are feasible on the same half of the rows of both kinds.  Column 0
    # fails in 0.01 s on kind A and in 1000 s on kind B (the planner's budget), column 1
    # in 1 s on both; column 2 is infeasible on kind A only, so trying it tells the kinds
    # apart.  Over all rows column 0's failures cost more (geometric mean 3.2 s): with no
    # history eips prefers column 1, after column 2 failed (kind A) column 0.
    rows = []
    for kind in ("a", "b"):
        for r in range(20):
            ok = r % 2 == 0
            rows.append(([-1.0 if ok else -10.0] * 2 + [-10.0 if kind == "a" else -1.0],
                         [1.0 if ok else (0.01 if kind == "a" else 1000.0),
                          1.0, 0.01]))
    D = np.array([r[0] for r in rows])
    T = np.array([r[1] for r in rows])
    fresh = make_selector("eips", D, times=T, feasible=D > -10)
    fresh._policy.tried[0, 2] = True  # compare columns 0 and 1 only
    assert fresh.propose() == 1
    sel = make_selector("eips", D, times=T, feasible=D > -10, mismatch=0.0)
    sel.update(2, -10.0)
    assert sel.propose() == 0


def test_fastest_tries_the_quickest_feasible_constraint_first():
    D, F, T = feasibility_matrix(30, 12, seed=3)
    truth, times = D[-1], T[-1]
    sel = make_selector("fastest", D[:-1], feasible=F[:-1], true_scores=truth,
                        true_times=times)
    order = run(sel, truth, 12)
    ok = np.flatnonzero(F[-1])
    assert order[:ok.size] == sorted(ok, key=lambda j: (times[j], j))
    with pytest.raises(ValueError, match="needs true_times"):
        make_selector("fastest", D[:-1], true_scores=truth)


@pytest.mark.parametrize("index", [2.7, 2.0, "1", None, True, np.float64(1.0)])
def test_a_non_integer_index_is_refused_naming_the_argument(index):
    sel = make_selector("box", well_conditioned(10, 4, seed=0))
    with pytest.raises(ValueError, match="^index must be an integer"):
        sel.update(index, -1.0)
    assert not sel.tried.any() and sel.history == []


def test_numpy_integer_indices_are_accepted():
    sel = make_selector("box", well_conditioned(10, 4, seed=0))
    sel.update(np.int64(3), -1.0)
    assert sel.history == [(3, -1.0)]
