"""planner=trajopt: the optimiser on a 2-D model, and on the Panda through pybullet."""

import json
import subprocess
import sys

import numpy as np
import pytest

from pipeline.domains import load_domain
from pipeline.planning import PlannerSettings, Status, interpolate, path_is_free
from pipeline.planning.trajopt import TrajOpt, TrajOptOptions, optimise
from pipeline.sim import panda as P
from pipeline.sim.fast_distance import bounded
from tests.replay import child_env

START, GOAL = np.array([0.0, 0.0]), np.array([1.0, 0.0])
#: TrajOpt with its wall-clock safety net out of reach: on a loaded machine a call must not
#: become "timeout" (the only machine-dependent status) and break a determinism check
TRAJOPT = {"name": "trajopt", "wall_cap_s": 1e6}
LIMITS = ([-2.0, -2.0], [2.0, 2.0])


def disc(centre, radius, query=0.05):
    centre = np.asarray(centre, float)

    def contacts(q):
        v = q - centre
        n = np.linalg.norm(v)
        if n - radius >= query:
            return np.zeros(0), np.zeros((0, 2))
        return np.array([n - radius]), (v / n)[None]

    return contacts


def dense_clearance(trajectory, centre, radius):
    dense = np.vstack([interpolate(a, b, 1e-3) for a, b in zip(trajectory[:-1], trajectory[1:],
                                                                strict=True)])
    return float((np.linalg.norm(dense - centre, axis=1) - radius).min())


def test_without_obstacles_the_result_is_the_evenly_spaced_straight_line():
    res = optimise(START, GOAL, *LIMITS, disc([5.0, 5.0], 0.1))
    assert res.converged and res.iterations == 0
    np.testing.assert_allclose(res.trajectory[:, 0], np.linspace(0, 1, 20), atol=1e-12)
    np.testing.assert_allclose(res.trajectory[:, 1], 0.0, atol=1e-12)


@pytest.mark.parametrize("centre", [[0.5, 0.01], [0.5, -0.05], [0.3, 0.03]])
def test_a_disc_on_the_straight_line_is_avoided_with_the_margin(centre):
    opts = TrajOptOptions(margin=0.02)
    res = optimise(START, GOAL, *LIMITS, disc(centre, 0.2), opts)
    assert res.converged
    assert dense_clearance(res.trajectory, np.asarray(centre), 0.2) >= 0.02 - 1e-6
    np.testing.assert_array_equal(res.trajectory[0], START)
    np.testing.assert_array_equal(res.trajectory[-1], GOAL)
    steps = np.linalg.norm(np.diff(res.trajectory, axis=0), axis=1)
    assert 1.0 < steps.sum() < 1.6  # around the disc, not a wild detour


def test_joint_limits_hold_even_when_the_way_round_is_outside_them():
    res = optimise(START, GOAL, [-2.0, -0.1], [2.0, 2.0], disc([0.5, -0.05], 0.2))
    assert (res.trajectory[:, 1] >= -0.1 - 1e-12).all()
    assert res.converged and dense_clearance(res.trajectory, np.array([0.5, -0.05]), 0.2) > 0


def test_a_goal_inside_an_obstacle_leaves_the_trajectory_in_collision():
    res = optimise(START, GOAL, *LIMITS, disc([1.0, 0.0], 0.3))
    assert dense_clearance(res.trajectory, np.array([1.0, 0.0]), 0.3) < 0


def test_the_optimiser_is_deterministic():
    runs = [optimise(START, GOAL, *LIMITS, disc([0.5, 0.01], 0.2)) for _ in range(2)]
    assert runs[0].trajectory.tobytes() == runs[1].trajectory.tobytes()


# -- on the Panda ----------------------------------------------------------------------------
TARGET = {"size": [0.04, 0.04, 0.12], "position": [0.42, -0.3, 0.061], "yaw": 0.0}
SWING = P.HOME + np.array([1.2, 0, 0, 0, 0, 0, 0])  # the first joint turns by 1.2 rad


@pytest.fixture(scope="module")
def domain():
    return load_domain("grasp_arm", planner=TRAJOPT)


@pytest.fixture(scope="module")
def blocked_swing(domain):
    """A scene with a box where the hand passes half-way along the straight swing."""
    probe = domain.build_scene({"domain": "grasp_arm", "seed": 0, "target": TARGET,
                                "obstacles": []})
    mid, _ = probe.arms[0].tcp_pose(P.HOME + 0.5 * (SWING - P.HOME))
    probe.close()
    box = {"size": [0.08, 0.08, 0.08], "position": [float(v) for v in mid], "yaw": 0.0}
    scene = domain.build_scene({"domain": "grasp_arm", "seed": 0, "target": TARGET,
                                "obstacles": [box]})
    yield scene.arms[0]
    scene.close()


def test_the_panda_goes_round_a_box_on_its_straight_path(blocked_swing):
    arm = blocked_swing
    assert not arm.collides_at(P.HOME) and not arm.collides_at(SWING)
    assert not path_is_free(np.array([P.HOME, SWING]), arm.check, 0.01)
    res = TrajOpt(PlannerSettings(name="trajopt")).plan(arm, P.HOME, SWING)
    assert res.status is Status.OK and res.path.shape == (20, 7)
    assert path_is_free(res.path, arm.check, 0.01)
    assert res.length > np.linalg.norm(SWING - P.HOME)
    again = TrajOpt(PlannerSettings(name="trajopt")).plan(arm, P.HOME, SWING)
    assert again.path.tobytes() == res.path.tobytes()


def test_a_blocked_goal_is_infeasible(blocked_swing):
    arm = blocked_swing
    inside = P.HOME + 0.5 * (SWING - P.HOME)  # the hand inside the box
    res = TrajOpt(PlannerSettings(name="trajopt")).plan(arm, P.HOME, inside)
    assert not res.feasible and res.status in (Status.NOT_CONVERGED, Status.PATH_IN_COLLISION)


def test_enclosed_object_is_infeasible_for_every_grasp(domain):
    from tests.test_grasp_arm import ENCLOSED

    statuses = {domain.plan(ENCLOSED, j, seed=j).status for j in range(0, 162, 2)}
    assert Status.OK not in statuses


def test_domain_results_are_identical_in_another_process(domain):
    """Bitwise, in a fresh process with one BLAS thread (as a Dask worker) planning the
    calls in the reverse order, after this module's earlier tests planned other things
    here with one BLAS thread per core (docs/reproducibility.md: TrajOpt's plans once
    differed by about 1e-7 between such processes)."""
    inst = domain.sample_instance(3)
    calls = [(j, domain.plan(inst, j, seed=j)) for j in range(0, 162, 9)]
    assert any(r.feasible for _, r in calls)
    code = (
        "import json, sys; from pipeline.domains import load_domain; "
        f"d = load_domain('grasp_arm', planner={TRAJOPT!r}); inst = json.loads(sys.argv[1]); "
        "print(json.dumps([[int(d.plan(inst, j, seed=j).status), "
        "d.plan(inst, j, seed=j).path.tolist()] for j in json.loads(sys.argv[2])]))")
    out = subprocess.run([sys.executable, "-c", code, json.dumps(inst),
                          json.dumps([j for j, _ in calls][::-1])],
                         capture_output=True, text=True, check=True,
                         env=child_env({"OPENBLAS_NUM_THREADS": "1"})).stdout
    other = json.loads(out.strip().splitlines()[-1])[::-1]
    for (_, r), (status, path) in zip(calls, other, strict=True):
        assert int(r.status) == status
        assert r.path.tolist() == path


def test_planar_refuses_trajopt():
    with pytest.raises(ValueError, match="trajopt"):
        load_domain("planar", planner="trajopt")


def test_bad_trajopt_settings_are_refused_naming_the_key():
    with pytest.raises(ValueError, match="trajopt_waypoints"):
        load_domain("grasp_arm", planner={"name": "trajopt", "trajopt_waypoints": 2})
    with pytest.raises(ValueError, match="trajopt_"):
        load_domain("grasp_base", planner={"name": "trajopt", "trajopt_margin": -1.0})


# -- the fast paths give today's answers (issue 27, item 3) ---------------------------------
#: TrajOpt's module before its speed-up (bounded distances, the certified
#: re-check): the answers of every setting must stay what they were
BEFORE = "4e14f96"


def _through(goals, count=25):
    """Configurations on straight lines from home to ``goals`` (the arm sweeps through
    what stands around it) and at the goals."""
    t = np.linspace(0.0, 1.0, count)[:, None]
    return np.vstack([P.HOME + t * (g - P.HOME) for g in goals])


def _assert_same_contacts(model, states, query=0.05):
    full = model.distance_model(query)
    fast = bounded(model, query)
    asked = fast.close_mask(states)
    assert asked.mean() < 0.5  # most bodies are left out ...
    # the links' bounding spheres only save the tests of their spheres: without them
    # (infinite radii), the same bodies are asked
    robot = list(fast._robot)
    assert np.isfinite(robot[4]).all()
    robot[4] = np.full_like(robot[4], np.inf)
    fast._robot = tuple(robot)
    assert np.array_equal(fast.close_mask(states), asked)
    for q, got in zip(states, fast.many(states), strict=True):
        want = full(q)
        assert got[0].tobytes() == want[0].tobytes() and got[1].tobytes() == want[1].tobytes()
    assert sum(len(full(q)[0]) for q in states) > 20  # ... and the lines pass close to some


def test_bounded_distances_are_the_full_models_bit_for_bit(domain):
    import pybullet as pb

    spec = domain.sample_instance(3)
    scene = domain.build_scene(spec)
    try:
        arm = scene.arms[0]
        rng = np.random.default_rng(0)
        goals = rng.uniform(P.LOWER, P.UPPER, (10, 7))
        # a body that is neither a box nor a Panda: always asked
        ball = pb.createMultiBody(0, pb.createCollisionShape(
            pb.GEOM_SPHERE, radius=0.05, physicsClientId=arm.client),
            basePosition=[0.4, 0.2, 0.6], physicsClientId=arm.client)
        states = _through(goals)
        _assert_same_contacts(arm, states)
        assert bounded(arm, 0.05).close_mask(states)[:, arm.obstacles().index(ball)].all()
    finally:
        scene.close()


def test_bounded_distances_of_the_mobile_arm_are_the_full_models_bit_for_bit():
    from pipeline.sim.mobile import UnladenArm
    from tests.test_mobile_domains import FACING, OPEN_TABLE

    base = load_domain("grasp_base")
    scene = base.build_scene(OPEN_TABLE)
    try:
        scene.robot.set_base(FACING)
        goals = np.random.default_rng(1).uniform(P.LOWER, P.UPPER, (10, 7))
        model = UnladenArm(scene.robot)
        _assert_same_contacts(model, _through(goals))
    finally:
        scene.close()


def test_the_bounded_model_is_kept_while_the_world_is_and_remade_when_it_moves(domain):
    """A grasp_arm arm keeps its bounded distance model while its scene's world key holds
    (one per instance, not one per TrajOpt call); once the other arm moves, a new one
    reads the world afresh and answers as a model made from scratch."""
    from pipeline.sim.fast_distance import BoundedDistances

    scene = domain.scene(domain.check_instance(domain.sample_instance(5)))
    arm, other = scene.arms
    first = bounded(arm, 0.05)
    assert bounded(arm, 0.05) is first
    assert bounded(arm, 0.08) is not first  # another query distance: another model
    states = _through(np.random.default_rng(2).uniform(P.LOWER, P.UPPER, (4, 7)))
    other.set(P.HOME + 0.4)
    try:
        moved = bounded(arm, 0.05)
        assert moved is not first
        fresh = BoundedDistances(arm, 0.05)
        for got, want in zip(moved.many(states), fresh.many(states), strict=True):
            assert got[0].tobytes() == want[0].tobytes()
            assert got[1].tobytes() == want[1].tobytes()
    finally:
        other.set(P.HOME)  # the module's scene, as the other tests expect it


def _before():
    """TrajOpt's module at BEFORE (from git), or None where git or the revision is missing."""
    import importlib.util
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    try:
        source = subprocess.run(["git", "-C", str(root), "show",
                                 f"{BEFORE}:pipeline/planning/trajopt.py"],
                                capture_output=True, check=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    name = "tests._trajopt_before_speedup"
    module = importlib.util.module_from_spec(importlib.util.spec_from_loader(name, None))
    sys.modules[name] = module
    exec(compile(source, "trajopt_before_speedup.py", "exec"), module.__dict__)
    return name


def _entries(name):
    """A sample of entries of ``name``: (instance, constraint, seed)."""
    if name == "grasp_arm":
        d = load_domain("grasp_arm")
        return [(d.sample_instance(s), j, j) for s in (11, 12) for j in range(0, 162, 6)]
    d = load_domain("grasp_base")
    specs = [d.sample_instance(s) for s in range(4)]
    theta = [r.constraint for r in (d.raw_plan(s, seed=k) for k, s in enumerate(specs))
             if r.plan.feasible]
    assert theta
    return [(s, row, 3 * i + j) for i, s in enumerate(specs) for j, row in enumerate(theta)]


@pytest.mark.parametrize("name", ["grasp_arm", "grasp_base"])
def test_answers_are_those_of_collision_exact_and_of_the_code_before(name, monkeypatch):
    """The default's fast paths (bounded distances, the certified re-check, the direct
    L-BFGS-B loop, memoised operators) change no bit of an answer: the same status, step,
    checks and path as ``planner.collision=exact`` and as TrajOpt's code at BEFORE."""
    from pipeline.planning import registry

    entries = _entries(name)

    def answers(planner):
        d = load_domain(name, planner=planner)
        out = [d.plan(spec, row, seed=seed) for spec, row, seed in entries]
        d.close()
        return [(int(r.status), r.step, r.checks, None if r.path is None else r.path.tobytes())
                for r in out]

    new = answers(TRAJOPT)
    assert sum(a[0] == int(Status.OK) for a in new) >= 3  # TrajOpt ran and succeeded
    assert answers({**TRAJOPT, "collision": "exact"}) == new
    before = _before()
    if before is None:
        pytest.skip(f"git revision {BEFORE} not available: compared with exact only")
    monkeypatch.setitem(registry.PLANNERS, "trajopt", f"{before}:TrajOpt")
    assert answers(TRAJOPT) == new
