"""The compiled RRT-Connect (pipeline.sim.compiled_rrt) is OMPL's search: its random
numbers are OMPL's (the generators, the sampler's seed, the samples), and whole score
entries planned with it equal those planned through OMPL bit for bit (status, failed step,
checks, length, score), in every domain whose checks are the sphere checker's, with budgets
that run out, under both contact settings.  Its speed is benchmarks/bench_pick_place.py's."""

from __future__ import annotations

import json

import numpy as np
import pytest
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from pipeline import worker
from pipeline.domains import load_domain
from pipeline.planning import Status
from pipeline.planning.ompl_adapter import _Problem, ompl_seed
from pipeline.planning.rrt_connect import RRTConnect
from pipeline.sim import compiled_rrt as C
from tests import replay

COLUMNS = ("status", "feasible", "step", "checks", "length", "score")


def test_mersenne_twister_is_the_standard_one():
    """std::mt19937(seed)'s outputs are the reference generator's (numpy's MT19937 with
    the reference seeding), past the first regeneration of its state."""
    for seed in (1, 5489, 999999999):
        mt = np.empty(625, dtype=np.int64)
        C.mt_seed(seed, mt)
        bits = np.random.MT19937(0)
        bits._legacy_seeding(seed)
        expected = bits.random_raw(1500)
        assert [C.mt_next(mt) for _ in range(1500)] == expected.tolist()


def _ompl_samples(first_seed: int, lower, upper, count: int) -> list[list[float]]:
    """The states OMPL's RRT-Connect samples first, seen through its checks: an unbounded
    range (so each sample is checked as drawn), every edge refused."""
    d = len(lower)
    seen = []

    class Refuse(ob.MotionValidator):
        def checkMotion(self, s1, s2):  # noqa: N802 (OMPL's name)
            seen.append(("edge", list(s1[0:d]), list(s2[0:d])))
            return False

    previous = ou.getLogLevel()
    ou.setLogLevel(ou.LogLevel.LOG_NONE)
    try:
        ou.RNG.setSeed(first_seed)
        space = ob.RealVectorStateSpace(d)
        bounds = ob.RealVectorBounds(d)
        for i in range(d):
            bounds.setLow(i, lower[i])
            bounds.setHigh(i, upper[i])
        space.setBounds(bounds)
        setup = og.SimpleSetup(space)
        si = setup.getSpaceInformation()
        setup.setStateValidityChecker(lambda s: seen.append(("state", list(s[0:d]))) or True)
        validator = Refuse(si)
        si.setMotionValidator(validator)
        ends = []
        for q in (lower, upper):
            state = space.allocState()
            for i in range(d):
                state[i] = 0.5 * (q[i] + (lower[i] + upper[i]) / 2)
            ends.append(state)
        setup.setStartAndGoalStates(ends[0], ends[1])
        planner = og.RRTConnect(si)
        planner.setRange(1e9)
        setup.setPlanner(planner)
        calls = [0]

        def stop():
            calls[0] += 1
            return calls[0] > count

        setup.solve(ob.PlannerTerminationCondition(stop))
    finally:
        ou.setLogLevel(previous)
    start = seen[0][1]  # the start's and the goal's checks come first
    samples = []  # start tree: the edge start → sample; goal tree: the sample's own check
    for event in seen[2:]:
        if event[0] == "state":
            samples.append(event[1])
        elif event[1] == start:
            samples.append(event[2])
    return samples


@pytest.mark.parametrize("d", [3, 7])
def test_the_samples_are_ompls(d):
    """The sampler's seed (the seed generator's draw after OMPL's other RNG objects) and
    the uniform draws: OMPL's first samples, bit for bit, for several seeds."""
    rng = np.random.default_rng(d)
    lower = rng.uniform(-3, 0, d).tolist()
    upper = (np.array(lower) + rng.uniform(0.5, 4, d)).tolist()
    for seed in (0, 1, 77, 123456):
        first = ompl_seed(seed)
        expected = _ompl_samples(first, lower, upper, 9)
        assert len(expected) >= 8
        mt = np.empty(625, dtype=np.int64)
        C.mt_seed(C.sampler_seed(first), mt)
        ours = [[(upper[i] - lower[i]) * C.uniform01(mt) + lower[i] for i in range(d)]
                for _ in expected]
        assert ours == expected


# -- whole entries ------------------------------------------------------------------------

def _replay_block(name: str, **planner):
    """The replay store's entries of domain ``name`` as one worker block, the store's own
    config (``planner`` overrides the planner's keys)."""
    store = next(s for s in replay.stored()["stores"] if s["domain"]["name"] == name)
    config = {k: v for k, v in store["domain"].items() if k != "name"}
    spec = {"name": name, "config": config,
            "planner": {**store["planner"], "wall_cap_s": 1e6, **planner}}
    return (spec, [json.dumps(i) for i in store["instances"]],
            [i["seed"] for i in store["instances"]], np.array(store["theta"]))


def _both(monkeypatch, spec, specs, seeds, theta) -> tuple[dict, dict]:
    """The block planned with the compiled search, then through OMPL."""
    fast, _ = worker.score_block(spec, 0, specs, seeds, theta, 0)
    monkeypatch.setattr(RRTConnect, "compiled", False)
    ompl, _ = worker.score_block(spec, 0, specs, seeds, theta, 0)
    monkeypatch.setattr(RRTConnect, "compiled", True)
    return fast, ompl


@pytest.mark.parametrize("domain,planner", [
    ("grasp_arm", {}),
    ("grasp_arm", {"max_checks": 500}),  # most entries run out mid-edge
    ("grasp_base", {}),
    ("grasp_base", {"max_checks": 300}),
    ("pick_place", {}),
])
def test_entries_equal_ompls(monkeypatch, domain, planner):
    spec, specs, seeds, theta = _replay_block(domain, **planner)
    fast, ompl = _both(monkeypatch, spec, specs, seeds, theta)
    for k in COLUMNS:
        np.testing.assert_array_equal(fast[k], ompl[k], err_msg=k)  # NaN == NaN here
    assert fast["checks"].max() > 100  # planning calls ran
    if "max_checks" in planner:
        assert (fast["status"] == int(Status.BUDGET_EXHAUSTED)).any()
    else:
        assert fast["feasible"].any()


def test_trees_that_outgrow_their_arrays(monkeypatch):
    """Trees start with room for C.NODES states and double when full (the search pauses
    for Python to make room, then goes on): with room for two at first, the same entries."""
    monkeypatch.setattr(C, "NODES", 2)
    spec, specs, seeds, theta = _replay_block("grasp_base")
    fast, ompl = _both(monkeypatch, spec, specs, seeds, theta)
    for k in COLUMNS:
        np.testing.assert_array_equal(fast[k], ompl[k], err_msg=k)
    assert fast["feasible"].any()


def test_entries_equal_ompls_under_cached_contacts(monkeypatch):
    """Under ``domain.contacts=cached`` pybullet's answers depend on what it checked
    before: the same calls in the same order give the same entries."""
    spec, specs, seeds, theta = _replay_block("pick_place")
    spec["config"]["contacts"] = "cached"
    fast, ompl = _both(monkeypatch, spec, specs, seeds, theta)
    for k in COLUMNS:
        np.testing.assert_array_equal(fast[k], ompl[k], err_msg=k)


def test_the_compiled_search_plans_where_the_sphere_checker_checks(monkeypatch):
    """grasp_arm's default (spheres) plans with it; ``planner.collision=exact``, whose
    checks are pybullet's alone, through OMPL."""
    made = []
    real = RRTConnect.problem

    def recording(self, *args):
        problem = real(self, *args)
        made.append(type(problem))
        return problem

    monkeypatch.setattr(RRTConnect, "problem", recording)
    for collision, expected in (("spheres", C.CompiledRRTConnect), ("exact", _Problem)):
        made.clear()
        domain = load_domain("grasp_arm", planner={"name": "rrt_connect",
                                                    "collision": collision})
        try:
            assert domain.plan(domain.sample_instance(3), 52, 3052).feasible
        finally:
            domain.close()
        assert made and set(made) == {expected}


def test_the_wall_clock_cap_ends_a_long_search():
    """The compiled search looks at the termination condition every CLOCK_CHECKS checks
    (OMPL: every iteration): a cap already passed ends a search of about 1900 checks as
    "timeout", long before its end."""
    domain = load_domain("grasp_arm", planner={"name": "rrt_connect", "wall_cap_s": 1e-9})
    try:
        capped = domain.plan(domain.sample_instance(5), 67, 5067)
    finally:
        domain.close()
    whole = load_domain("grasp_arm")
    try:
        uncapped = whole.plan(whole.sample_instance(5), 67, 5067)
    finally:
        whole.close()
    assert uncapped.feasible and uncapped.checks > 4 * C.CLOCK_CHECKS
    assert capped.status == Status.TIMEOUT
    assert capped.checks < 2 * C.CLOCK_CHECKS
