"""Resumable planning tries (issue 26, item 3): a call paused at check caps and resumed
gives the result of one uninterrupted call (status, checks, failed step, path bit for bit,
length), for RRT-Connect (and the other OMPL algorithms of RESUMABLE) on the planar robot
and on grasp_arm and grasp_base entries, feasible and budget-exhausting, also with other
tries run between its slices; calls that cannot pause make the whole call in their first
advance."""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest

from pipeline.domains import load_domain
from pipeline.planning import Status
from pipeline.planning.ompl_adapter import ALGORITHMS, RESUMABLE, OmplSearch
from pipeline.planning.ompl_planner import OmplPlanner
from pipeline.planning.resumable import WholeTry
from pipeline.planning.rrt_connect import RRTConnect
from pipeline.planning.settings import OmplSettings, RRTConnectSettings
from tests.test_ompl_planners import GOAL, START, scene

CAPS = (1, 7, 50, 500)


def assert_same(resumed, whole):
    assert resumed.status == whole.status
    assert resumed.checks == whole.checks
    assert resumed.step == whole.step
    assert resumed.path.shape == whole.path.shape
    assert np.array_equal(resumed.path, whole.path)  # bit for bit
    assert resumed.length == whole.length or (np.isnan(resumed.length)
                                              and np.isnan(whole.length))


def sliced(make_try, cap: int):
    """Advance a fresh try ``make_try()`` by ``cap`` checks at a time (an allowance it
    has already used makes a slice that pauses at once); (result, pauses)."""
    entry = make_try()
    pauses = 0
    while (result := entry.advance(cap * (pauses + 1))) is None:
        pauses += 1
    assert entry.advance(1) is result and entry.done  # an ended try keeps its result
    return result, pauses


def interleaved(tries: list, cap: int, between=lambda: None) -> list:
    """Advance several tries in turn, ``cap`` checks each time, until all ended;
    ``between()`` runs after each round."""
    results = [None] * len(tries)
    k = 0
    while any(r is None for r in results):
        k += 1
        for i, t in enumerate(tries):
            if results[i] is None:
                results[i] = t.advance(cap * k)
        between()
    return results


# -- one motion --------------------------------------------------------------------------

@pytest.mark.parametrize("max_checks", [1500, 20000])  # budgets exhausted / feasible
def test_rrt_connect_resumed_equals_uninterrupted_on_the_planar_robot(max_checks):
    planner = RRTConnect(RRTConnectSettings(collision="exact", max_checks=max_checks))
    for seed in range(4):
        whole = planner.plan(scene(), START, GOAL, seed=seed)
        assert whole.status is (Status.OK if max_checks == 20000 else Status.BUDGET_EXHAUSTED)
        for cap in CAPS:
            resumed, pauses = sliced(partial(planner.start, scene(), START, GOAL, seed), cap)
            assert_same(resumed, whole)
            if cap == 1:  # an iteration here takes up to a few hundred checks
                assert pauses >= 5


def test_a_paused_try_has_used_its_allowance_and_not_its_budget():
    planner = RRTConnect(RRTConnectSettings(collision="exact"))
    search = planner.start(scene(), START, GOAL, 1)
    for allowance in (3, 10, 40, 200):
        assert search.advance(allowance) is None
        assert allowance <= search.checks < planner.settings.max_checks


@pytest.mark.parametrize("algorithm", RESUMABLE)
def test_each_resumable_ompl_algorithm_resumes_exactly(algorithm):
    planner = OmplPlanner(OmplSettings(algorithm=algorithm, collision="exact"))
    assert planner.resumable
    for seed in range(3):
        whole = planner.plan(scene(), START, GOAL, seed=seed)
        assert whole.feasible
        for cap in (7, 50):
            assert_same(sliced(partial(planner.start, scene(), START, GOAL, seed), cap)[0],
                        whole)


@pytest.mark.parametrize("algorithm", ["BKPIECE1", "LBKPIECE1"])
def test_other_ompl_algorithms_plan_the_whole_call_in_the_first_advance(algorithm):
    """The KPIECE variants with two trees alternate them by a flag local to ``solve``:
    paused and resumed, they take another path (so they are not in RESUMABLE)."""
    planner = OmplPlanner(OmplSettings(algorithm=algorithm, collision="exact"))
    assert algorithm in ALGORITHMS and not planner.resumable
    whole = planner.plan(scene(), START, GOAL, seed=0)
    attempt = planner.start(scene(), START, GOAL, 0)
    assert isinstance(attempt, WholeTry)
    assert_same(attempt.advance(1), whole)
    resumed, _ = sliced(partial(OmplSearch, planner, scene(), START, GOAL, 0), 7)
    assert resumed.checks != whole.checks


def test_two_interleaved_tries_each_equal_their_uninterrupted_run():
    planner = RRTConnect(RRTConnectSettings(collision="exact"))
    seeds = (3, 11)
    wholes = [planner.plan(scene(), START, GOAL, seed=s) for s in seeds]
    for cap in (1, 7, 50):
        tries = [planner.start(scene(), START, GOAL, s) for s in seeds]
        for resumed, whole in zip(interleaved(tries, cap), wholes, strict=True):
            assert_same(resumed, whole)


# -- one score entry ---------------------------------------------------------------------

#: (instance seed, grasp) entries of the default grasp_arm: feasible after 400 to 1900
#: checks, a pre-grasp in collision, no IK solution
ENTRIES = ((3, 52), (0, 85), (4, 68), (5, 67), (0, 150), (0, 0))


@pytest.fixture(scope="module")
def grasp_arm():
    domain = load_domain("grasp_arm")
    yield domain
    domain.close()


@pytest.fixture(scope="module")
def tight_grasp_arm():
    """A budget that most entries exhaust."""
    domain = load_domain("grasp_arm", planner={"name": "rrt_connect", "max_checks": 500})
    yield domain
    domain.close()


@pytest.mark.parametrize("which", ["grasp_arm", "tight_grasp_arm"])
def test_grasp_arm_entries_resumed_equal_uninterrupted(which, request):
    domain = request.getfixturevalue(which)
    statuses = set()
    for i, j in ENTRIES:
        inst, seed = domain.sample_instance(i), 1000 * i + j
        whole = domain.plan(inst, j, seed)
        statuses.add(whole.status)
        for cap in CAPS:
            assert_same(sliced(partial(domain.start_try, inst, j, seed), cap)[0], whole)
    expected = Status.OK if which == "grasp_arm" else Status.BUDGET_EXHAUSTED
    assert {expected, Status.GOAL_IN_COLLISION, Status.NO_IK} <= statuses


def test_interleaved_grasp_arm_entries_of_different_instances(grasp_arm):
    """Slices of tries on two instances alternate, so the domain's scene is reloaded before
    every slice (the planner's robot model is remade) and one call runs in between."""
    entries = ((5, 67), (0, 85), (4, 68))
    insts = {i: grasp_arm.sample_instance(i) for i, _ in entries}
    wholes = [grasp_arm.plan(insts[i], j, 1000 * i + j) for i, j in entries]
    for cap in (7, 500):
        tries = [grasp_arm.start_try(insts[i], j, 1000 * i + j) for i, j in entries]
        # another planning call between the slices
        results = interleaved(tries, cap, lambda: grasp_arm.plan(insts[0], 81, 5))
        for resumed, whole in zip(results, wholes, strict=True):
            assert_same(resumed, whole)


def test_a_grasp_arm_try_goes_on_after_the_domain_closed_its_scene():
    domain = load_domain("grasp_arm")
    try:
        inst = domain.sample_instance(5)
        whole = domain.plan(inst, 67, 5067)
        attempt = domain.start_try(inst, 67, 5067)
        allowance = 0
        while (result := attempt.advance(allowance)) is None:
            domain.close()  # the next slice finds a new pybullet client
            allowance += 100
        assert allowance > 0
        assert_same(result, whole)
    finally:
        domain.close()


#: grasp_base constraints (base pose, grasp features, rounded): RAWPLANNER's on instances
#: 0-3; entry (i, i) is feasible, most others find no IK solution
BASE_GRASPS = ([-1.21, 1.4164, -0.7507, 0.7071, 0.7071, 0.0, 1.5708, -0.02],
               [-0.7745, 1.6987, -2.829, -1.0, -0.0, 0.0, 0.7854, -0.02],
               [0.5817, -0.9814, 2.8772, -0.7071, 0.7071, 0.0, 1.5708, -0.02],
               [0.3993, 0.0655, -1.4384, -0.7071, 0.7071, 0.0, 1.5708, 0.02])


def base_grasps(domain) -> list[list[float]]:
    """:data:`BASE_GRASPS` with the exact features of the nearest of the domain's grasps."""
    feats = np.stack([g.features[1:] for g in domain.grasps])
    return [row[:3] + list(feats[np.argmin(np.abs(feats - row[3:]).sum(axis=1))])
            for row in BASE_GRASPS]


@pytest.mark.parametrize("max_checks", [20000, 500])
def test_grasp_base_entries_resumed_equal_uninterrupted(max_checks):
    domain = load_domain("grasp_base", planner={"name": "rrt_connect",
                                                "max_checks": max_checks})
    thetas = base_grasps(domain)
    try:
        statuses = set()
        for i in range(4):
            inst = domain.sample_instance(i)
            for k, theta in enumerate(thetas):
                whole = domain.plan(inst, theta, 10 * i + k)
                statuses.add(whole.status)
                for cap in CAPS:
                    resumed, _ = sliced(partial(domain.start_try, inst, theta, 10 * i + k), cap)
                    assert_same(resumed, whole)
        expected = Status.OK if max_checks == 20000 else Status.BUDGET_EXHAUSTED
        assert {expected, Status.NO_IK} <= statuses
        # slices of tries on different instances alternate: the scene is reloaded and the
        # base parked elsewhere between them
        insts = [domain.sample_instance(i) for i in range(4)]
        wholes = [domain.plan(insts[i], thetas[i], i) for i in range(4)]
        for cap in (7, 200):
            tries = [domain.start_try(insts[i], thetas[i], i) for i in range(4)]
            for resumed, whole in zip(interleaved(tries, cap), wholes, strict=True):
                assert_same(resumed, whole)
    finally:
        domain.close()


def test_a_domain_without_its_own_try_plans_the_whole_entry_in_the_first_advance():
    domain = load_domain("planar")
    inst, via = domain.sample_instance(2), [5.0, 8.0]
    whole = domain.plan(inst, via, 4)
    attempt = domain.start_try(inst, via, 4)
    assert isinstance(attempt, WholeTry)
    assert_same(attempt.advance(1), whole)
    assert whole.checks > 1


def test_grasp_arm_with_trajopt_or_noop_is_not_resumable():
    for planner, status in (("trajopt", None), ("noop", Status.SKIPPED)):
        domain = load_domain("grasp_arm", planner=planner)
        try:
            inst = domain.sample_instance(3)
            attempt = domain.start_try(inst, 52, 3052)
            assert isinstance(attempt, WholeTry)
            result = attempt.advance(1)
            assert_same(result, domain.plan(inst, 52, 3052))
            assert status is None or result.status is status
        finally:
            domain.close()


def test_bad_input_is_refused_when_the_try_starts(grasp_arm):
    with pytest.raises(ValueError, match="out of range"):
        grasp_arm.start_try(grasp_arm.sample_instance(0), 999, 0)
