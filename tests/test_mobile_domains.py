"""The mobile-manipulation domains: grasp_base (paper §V-B) and pick_place (§V-C)."""

import json
import subprocess
import sys

import numpy as np
import pytest

from pipeline.domains import InstanceError, load_domain
from pipeline.domains.grasp_base import BaseGrasp
from pipeline.domains.pick_place import GOAL_TABLE, PickPlaceDomain, rod_grasps
from pipeline.planning import PlanResult, Status, path_is_free
from pipeline.sim import panda as P

TARGET = {"size": [0.04, 0.04, 0.12], "position": [0.8, 0.0, 0.461], "yaw": 0.0}
OPEN_TABLE = {"seed": 0, "target": TARGET, "obstacles": []}
FACING = [0.2, 0.0, 0.0]  # a base pose 60 cm in front of the target, facing it
TOP_GRASP = [0.0, 0.0, -1.0, 0.0, 0.0]  # approach straight down, no rotation, depth 0


def _ring(cx, cy, half, height):
    """Four walls and a lid around (cx, cy) on a table top at 0.40 m."""
    t, z = 0.01, 0.40
    parts = [([2 * half, t, height], [cx, cy + half, z + height / 2]),
             ([2 * half, t, height], [cx, cy - half, z + height / 2]),
             ([t, 2 * half, height], [cx + half, cy, z + height / 2]),
             ([t, 2 * half, height], [cx - half, cy, z + height / 2]),
             ([2 * half + t, 2 * half + t, t], [cx, cy, z + height + t / 2])]
    return [{"size": s, "position": p, "yaw": 0.0} for s, p in parts]


ENCLOSED = {"seed": 0, "target": TARGET, "obstacles": _ring(0.8, 0.0, 0.12, 0.3)}


@pytest.fixture(scope="module")
def grasp_base():
    return load_domain("grasp_base", raw_base_samples=5)


@pytest.fixture(scope="module")
def pick_place():
    return load_domain("pick_place")


@pytest.fixture(scope="module")
def open_route(pick_place):
    """RAWPLANNER's solution and extracted θ on an instance without obstacles."""
    spec = {"seed": 0, "rod_length": 0.7, "obstacles": []}
    raw = pick_place.raw_plan(spec, seed=3)
    assert raw.plan.feasible, raw.plan.status
    return spec, raw


# -- grasp_base ------------------------------------------------------------------------------
def test_grasp_base_an_unobstructed_target_is_feasible_from_a_base_pose_facing_it(grasp_base):
    plan = grasp_base.plan(OPEN_TABLE, FACING + TOP_GRASP, seed=1)
    assert plan.feasible, (plan.status, plan.step)
    assert plan.score == -plan.length < 0
    raw = grasp_base.raw_plan(OPEN_TABLE, seed=2)
    assert raw.plan.feasible and raw.tries >= 1
    theta = grasp_base.constraint(raw.constraint)  # the extracted θ is a usable constraint
    assert np.linalg.norm(theta.pose[:2] - TARGET["position"][:2]) <= P.REACH
    assert grasp_base.plan(OPEN_TABLE, raw.constraint, seed=5).feasible


def test_grasp_base_an_enclosed_target_is_infeasible_and_the_failing_step_is_named(grasp_base):
    plan = grasp_base.plan(ENCLOSED, FACING + TOP_GRASP, seed=1)
    assert plan.status in (Status.NO_IK, Status.GOAL_IN_COLLISION) and plan.step == "ik"
    raw = grasp_base.raw_plan(ENCLOSED, seed=2)
    assert not raw.plan.feasible and np.isnan(raw.constraint).all()
    inside_table = grasp_base.plan(OPEN_TABLE, [1.0, 0.0, 0.0] + TOP_GRASP, seed=1)
    assert inside_table.status is Status.START_IN_COLLISION and inside_table.step == "base"


def test_grasp_base_paths_recheck_free_and_end_at_the_pregrasp(grasp_base):
    from pipeline.domains.grasps import pregrasp_pose

    checked = 0
    for seed in range(4):
        spec = grasp_base.sample_instance(seed)
        raw = grasp_base.raw_plan(spec, seed=seed)
        plan = grasp_base.plan(spec, raw.constraint, seed=seed) if raw.plan.feasible else None
        if plan is None or not plan.feasible:  # IK's random restarts differ from RAW's
            continue
        checked += 1
        theta = grasp_base.constraint(raw.constraint)
        scene = grasp_base.build_scene(spec)
        try:
            scene.robot.set_base(theta.pose)
            assert path_is_free(plan.path, scene.robot.arm_check, 0.005)
            pos, _ = scene.robot.arm.tcp_pose(plan.path[-1])
            target = grasp_base.check_instance(spec).target
            want, _ = pregrasp_pose(target, theta.grasp, grasp_base.config.pregrasp_offset)
            assert np.linalg.norm(pos - want) < 0.006
        finally:
            scene.close()
    assert checked >= 2


def test_grasp_base_is_deterministic_across_call_order_and_processes(grasp_base):
    spec = grasp_base.sample_instance(4)
    raw = grasp_base.raw_plan(spec, seed=9)
    again = grasp_base.raw_plan(spec, seed=9)
    np.testing.assert_array_equal(raw.constraint, again.constraint)
    first = grasp_base.plan(spec, FACING + TOP_GRASP, seed=11)
    grasp_base.plan(grasp_base.sample_instance(5), FACING + TOP_GRASP, seed=3)  # in between
    second = grasp_base.plan(spec, FACING + TOP_GRASP, seed=11)
    assert first.status == second.status and first.checks == second.checks
    np.testing.assert_array_equal(first.path, second.path)
    code = ("import json,sys; from pipeline.domains import load_domain; "
            "d = load_domain('grasp_base', raw_base_samples=5); "
            "r = d.raw_plan(d.sample_instance(4), seed=9); "
            "print(json.dumps([float(v) for v in r.constraint]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    np.testing.assert_array_equal(json.loads(out.strip().splitlines()[-1]), raw.constraint)


def test_grasp_base_refuses_bad_constraints_and_specs(grasp_base):
    with pytest.raises(ValueError, match="81 grasps"):
        grasp_base.constraint([0.0, 0.0, 0.0, 0.3, 0.3, 0.3, 0.0, 0.0])  # no such grasp
    with pytest.raises(ValueError, match="feature row"):
        grasp_base.constraint([0.0, np.nan, 0.0] + TOP_GRASP)
    with pytest.raises(InstanceError, match="target"):
        grasp_base.check_instance({"seed": 0, "obstacles": []})
    assert isinstance(grasp_base.constraint(FACING + TOP_GRASP), BaseGrasp)


@pytest.mark.parametrize("margin", [0.0, 0.01, 0.05])
def test_rectangles_far_apart_are_answered_as_the_separating_axes_answer(margin):
    """``rectangles_overlap`` answers rectangles whose circumcircles lie far apart without
    the separating-axis test, and always as that test does: rectangles of pick_place's
    obstacle sizes and of a table's, every turn, centres up to twice the bound's distance
    apart (√2 × (circumradii + margin); overlapping and apart pairs within it, apart ones
    beyond it)."""
    from pipeline.domains.geometry import (
        _far_apart,
        rectangle,
        rectangles_overlap,
        separating_axes_overlap,
    )

    rng = np.random.default_rng(17)
    seen = set()
    for _ in range(20_000):
        sizes = rng.uniform(0.03, 0.15, (2, 2)) * (10.0 if rng.random() < 0.1 else 1.0)
        a = rectangle(rng.uniform(-1, 1, 2), sizes[0], rng.uniform(-np.pi, np.pi))
        reach = np.sqrt(2.0) * (np.hypot(*sizes[0]) / 2 + np.hypot(*sizes[1]) / 2 + margin)
        direction = rng.uniform(-np.pi, np.pi)
        centre = a.mean(axis=0) + rng.uniform(0.0, 2.0 * reach) * np.array(
            [np.cos(direction), np.sin(direction)])
        b = rectangle(centre, sizes[1], rng.uniform(-np.pi, np.pi))
        got = rectangles_overlap(a, b, margin)
        assert got == separating_axes_overlap(a, b, margin)
        seen.add((_far_apart(a, b, margin), got))
    assert seen == {(True, False), (False, False), (False, True)}


def test_grasp_base_instances_have_the_configured_obstacles_without_overlaps():
    from pipeline.domains.geometry import rectangle, rectangles_overlap

    domain = load_domain("grasp_base", obstacles=7)
    spec = domain.sample_instance(3)
    assert len(spec["obstacles"]) == 7 and spec == domain.sample_instance(3)
    boxes = [spec["target"], *spec["obstacles"]]
    rects = [rectangle(b["position"], b["size"], b["yaw"]) for b in boxes]
    assert not any(rectangles_overlap(a, b) for k, a in enumerate(rects) for b in rects[k + 1:])
    with pytest.raises(ValueError, match="reach_radius"):
        load_domain("grasp_base", reach_radius=0.0)


def test_grasp_base_with_trajopt_plans_the_same_kind_of_entry():
    domain = load_domain("grasp_base", planner="trajopt")
    plan = domain.plan(OPEN_TABLE, FACING + TOP_GRASP, seed=1)
    assert plan.feasible, (plan.status, plan.step)
    scene = domain.build_scene(OPEN_TABLE)
    try:
        scene.robot.set_base(FACING)
        assert path_is_free(plan.path, scene.robot.arm_check, 0.01)
    finally:
        scene.close()


# -- pick_place ------------------------------------------------------------------------------
def test_pick_place_grasps_are_81_and_features_round_trip(pick_place):
    grasps = rod_grasps()
    assert len({tuple(g.features) for g in grasps}) == 81
    row = np.concatenate([grasps[40].features, [2.1, 0.0, 0.0], [1.3, 0.0, 0.0],
                          [-0.6, 0.0, 0.0]])
    theta = pick_place.constraint(row)
    np.testing.assert_array_equal(theta.features, row)
    with pytest.raises(ValueError, match="12 numbers"):
        pick_place.constraint(row[:11])


def test_pick_place_an_open_instance_is_solved_and_its_theta_replans(pick_place, open_route):
    spec, raw = open_route
    theta = pick_place.constraint(raw.constraint)
    assert theta.placement[0] > 0 > theta.subgoal[0]  # placed in the far room, k_sg before
    plan = pick_place.plan(spec, raw.constraint, seed=4)
    assert plan.feasible, (plan.status, plan.step)
    assert set(plan.segments) == {"pick_path", "base_path", "place_path"}
    drive = plan.segments["base_path"]
    assert drive[0, 0] < 0 < drive[-1, 0]  # the base path goes through the door


def test_pick_place_paths_recheck_free_and_put_the_rod_at_the_placement(pick_place, open_route):
    spec, raw = open_route
    plan = pick_place.plan(spec, raw.constraint, seed=4)
    checked = pick_place.recheck(spec, raw.constraint, plan, resolution=0.005)
    assert checked == {"pick_path": True, "base_path": True, "place_path": True,
                       "placed": True}
    # and the re-check can fail: the same plan with an obstacle on its base path
    blocker = {"size": [0.2, 0.2, 1.2], "position": [*plan.segments["base_path"][-1, :2], 0.6],
               "yaw": 0.0}
    blocked = dict(spec, obstacles=[blocker])
    assert pick_place.recheck(blocked, raw.constraint, plan)["base_path"] is False


def test_pick_place_a_full_goal_table_is_infeasible_at_the_placement(pick_place, open_route):
    _, raw = open_route
    t = GOAL_TABLE
    tiles = [{"size": [0.2, 0.2, 0.1], "position": [float(x), float(y), t.height + 0.051],
              "yaw": 0.0}
             for x in np.arange(t.centre[0] - 0.25, t.centre[0] + 0.26, 0.25)
             for y in np.arange(t.centre[1] - 0.9, t.centre[1] + 0.91, 0.225)]
    full = {"seed": 1, "rod_length": 0.7, "obstacles": tiles}
    plan = pick_place.plan(full, raw.constraint, seed=4)
    assert plan.status is Status.GOAL_IN_COLLISION and plan.step == "placement"
    few = load_domain("pick_place", raw_grasps=2, raw_placements=2)
    raw_full = few.raw_plan(full, seed=1)
    assert not raw_full.plan.feasible and np.isnan(raw_full.constraint).all()


def test_pick_place_is_deterministic_across_call_order(pick_place, open_route):
    spec, raw = open_route
    first = pick_place.plan(spec, raw.constraint, seed=8)
    pick_place.plan(pick_place.sample_instance(2), raw.constraint, seed=1)  # in between
    second = pick_place.plan(spec, raw.constraint, seed=8)
    assert first.status == second.status and first.checks == second.checks
    np.testing.assert_array_equal(first.path, second.path)
    fresh = PickPlaceDomain(pick_place.config, pick_place.planner)  # empty carry cache
    np.testing.assert_array_equal(fresh.plan(spec, raw.constraint, seed=8).path, first.path)


def test_pick_place_instance_parameters_are_overridable():
    domain = load_domain("pick_place", rod_lengths=[0.6], obstacles=5, door_width=1.2)
    spec = domain.sample_instance(0)
    assert spec["rod_length"] == 0.6 and len(spec["obstacles"]) == 5
    for bad in ({"door_width": 0.3}, {"rod_lengths": []}, {"base_max_checks": 0}):
        with pytest.raises(ValueError, match="domain"):
            load_domain("pick_place", **bad)
    with pytest.raises(ValueError, match="trajopt"):
        load_domain("pick_place", planner="trajopt")
    with pytest.raises(InstanceError, match="rod_length"):
        domain.check_instance({"seed": 0, "rod_length": 5.0, "obstacles": []})


def test_renders_are_non_empty_images(grasp_base, pick_place, open_route, tmp_path):
    spec, raw = open_route
    plan = pick_place.plan(spec, raw.constraint, seed=4)
    out = pick_place.render(spec, plan, tmp_path / "pp.png", constraint=raw.constraint)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 20_000
    assert plan.feasible  # a plan read back from disk (stage=solve's best) has no segments
    bare = PlanResult(Status.OK, path=plan.path, length=plan.length)
    again = pick_place.render(spec, bare, tmp_path / "pp2.png", constraint=raw.constraint)
    from matplotlib.image import imread

    assert np.array_equal(imread(again), imread(out))
    plan = grasp_base.plan(OPEN_TABLE, FACING + TOP_GRASP, seed=1)
    out = grasp_base.render(OPEN_TABLE, plan, tmp_path / "gb.png",
                            constraint=FACING + TOP_GRASP)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 20_000


def test_quaternions_round_trip_including_half_turns():
    """Half turns (w = 0) lost their axis's signs before Shepperd's method; grasps with
    the hand pointing down are such rotations."""
    import pybullet as pb
    from scipy.spatial.transform import Rotation

    from pipeline.sim.world import quaternion

    axes = np.random.default_rng(0).normal(size=(200, 3))
    half_turns = Rotation.from_rotvec(np.pi * axes / np.linalg.norm(axes, axis=1)[:, None])
    for R in [*Rotation.random(200, random_state=1).as_matrix(), *half_turns.as_matrix()]:
        back = np.reshape(pb.getMatrixFromQuaternion(quaternion(R)), (3, 3))
        np.testing.assert_allclose(back, R, atol=1e-12)


@pytest.mark.parametrize("name", ["grasp_base", "pick_place"])
def test_pipeline_stores_the_failing_step_and_replays_entries(name, tmp_path):
    """A small ``python -m pipeline stage=generate`` run: the step array names the domain's
    steps, is -1 exactly where an entry is feasible, and an entry planned again from its
    stored seed gives the stored result."""
    import zarr

    from pipeline.worker import entry_seed
    from tests.pipeline_runs import env

    store = tmp_path / f"{name}.zarr"
    cmd = [sys.executable, "-m", "pipeline", "stage=generate", f"domain={name}",
           "instances.n=8", "constraints.m=6", "store.block_instances=4",
           "store.block_constraints=3", "progress=false", "cluster.n_workers=2",
           f"store.path={store}"]
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, env=env(),
                          timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    g = zarr.open_group(store, mode="r", use_consolidated=False)
    domain = load_domain(name)
    step = g["scores/step"]
    assert step.attrs["flag_meanings"].split() == list(domain.steps)
    feasible, steps, status = g["scores/feasible"][...], step[...], g["scores/status"][...]
    assert ((steps == -1) == feasible).all() and (steps < len(domain.steps)).all()
    assert feasible.any() and not feasible.all()
    theta, seeds = g["constraints/theta"][...], g["instances/seed"][...]
    specs = g["instances/spec"][...]
    for i, j in [(0, 0), *zip(*np.nonzero(~feasible), strict=True)][:3]:
        plan = domain.plan(json.loads(str(specs[i])), theta[j],
                           seed=entry_seed(0, int(seeds[i]), int(j)))
        assert int(plan.status) == status[i, j]
        assert (domain.steps.index(plan.step) if plan.step else -1) == steps[i, j]


def test_pick_place_step_orders_agree_on_every_outcome_and_cheap_first_checks_less(
        pick_place, open_route):
    _, raw = open_route
    cheap = load_domain("pick_place", step_order="cheap_first")
    thetas = [raw.constraint] + [cheap.raw_plan(cheap.sample_instance(s), seed=s).constraint
                                 for s in (1, 2)]
    specs = [pick_place.sample_instance(s) for s in (1, 2, 3)]
    refuted = {"paper": 0, "cheap_first": 0}
    for spec in specs:
        for row in thetas:
            if np.isnan(row).any():
                continue
            a, b = pick_place.plan(spec, row, seed=5), cheap.plan(spec, row, seed=5)
            assert a.feasible == b.feasible
            if a.feasible:
                np.testing.assert_array_equal(a.path, b.path)
                assert a.length == b.length
            else:
                refuted["paper"] += a.checks
                refuted["cheap_first"] += b.checks
    assert refuted["cheap_first"] < refuted["paper"]
    with pytest.raises(ValueError, match="step_order"):
        load_domain("pick_place", step_order="fastest")
