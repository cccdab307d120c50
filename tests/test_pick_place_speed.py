"""The faster pick_place (issue 27, item 1) answers as ``planner.collision=exact`` does:
whole entries planned block by block, edges and single configurations checked by the
compiled scan, the geometric refinements it trusts (convex hulls, box faces), the memos of
worlds and robots, the shortcutter's random pairs, and the pick IK outcomes kept per grasp.
Behaviour only; the timings are ``benchmarks/bench_pick_place.py``'s."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pybullet as pb
import pytest
from scipy.optimize import nnls

from pipeline import worker
from pipeline.domains import load_domain
from pipeline.domains.pick_place.world import ROOMS, placed_rod
from pipeline.planning.base import Robot, check_order, interpolate
from pipeline.planning.shortcut import Pairs as _Pairs
from pipeline.sim import collide
from pipeline.sim import fast_check as FC
from pipeline.sim import panda as P
from pipeline.sim.mobile import MobileArm, MobilePanda, UnladenArm
from pipeline.sim.world import add_box, connect
from tests import replay

COLUMNS = ("status", "feasible", "step", "checks", "length", "score")


def _store():
    return next(s for s in replay.stored()["stores"] if s["store"] == "pick_place.zarr")


def _spec(collision: str, order: str = "paper") -> dict:
    store = _store()
    config = {k: v for k, v in store["domain"].items() if k != "name"}
    config["step_order"] = order
    return {"name": "pick_place", "config": config,
            "planner": {**store["planner"], "collision": collision, "wall_cap_s": 1e6}}


def _block(collision: str, order: str = "paper") -> dict:
    """Every (instance, constraint) of the replay store's pick_place entries, as one
    worker block."""
    store = _store()
    specs = [json.dumps(inst) for inst in store["instances"]]
    seeds = [inst["seed"] for inst in store["instances"]]
    arrays, _ = worker.score_block(_spec(collision, order), 0, specs, seeds,
                                   np.array(store["theta"]), 0)
    return arrays


def _assert_same(a: dict, b: dict) -> None:
    for k in COLUMNS:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)  # NaN == NaN here


@pytest.mark.parametrize("order", ["paper", "cheap_first"])
def test_entries_equal_exact_ones(order):
    """36 entries (6 instances × 6 constraints, a block as a worker plans it): status,
    feasibility, failed step, checks, length and score bit for bit."""
    fast, exact = _block("spheres", order), _block("exact", order)
    _assert_same(fast, exact)
    assert fast["feasible"].sum() >= 3 and (~fast["feasible"]).sum() >= 3


# -- edges and single configurations -------------------------------------------------------

@pytest.fixture(scope="module")
def carrying():
    """pick_place's scene with the rod held in a carry configuration, at a place pose."""
    domain = load_domain("pick_place", planner={"name": "rrt_connect", "collision": "exact"})
    store = _store()
    inst = domain.check_instance(store["instances"][1])
    theta = domain.constraint(store["theta"][0])
    domain.scene(inst)
    carry, _ = domain.carry(inst, theta.grasp)
    assert carry is not None
    yield domain, inst, theta, carry
    domain.close()


def test_grasp_at_a_configuration_places_the_rod_as_setting_the_arm_first(carrying):
    """``grasp(rod, tcp_obj, q)`` (one arm reset: the scene's ``hold``) leaves the arm, the
    rod's pybullet pose and its pose in the base frame bit for bit as setting the arm to q
    and then grasping where it stands."""
    domain, inst, theta, carry = carrying
    robot, rod = domain.robot, domain._scene.rod
    tcp_obj = theta.grasp.rod_in_hand(inst.rod_length)
    seen = []
    for one_reset in (False, True):
        domain.reset(inst)
        robot.set_base(theta.place_pose)
        if one_reset:
            robot.grasp(rod, tcp_obj, carry)
        else:
            robot.set_arm(carry)
            robot.grasp(rod, tcp_obj)
        position, orientation = pb.getBasePositionAndOrientation(
            rod, physicsClientId=robot.client)
        seen.append((robot._current_q().tobytes(), position, orientation,
                     robot.held_in_base.tobytes()))
    domain.reset(inst)
    assert seen[0] == seen[1]


class _Recorder:
    """An exact check that records the configurations it was asked about."""

    def __init__(self, exact):
        self.exact, self.asked = exact, []

    def __call__(self, q):
        self.asked.append(np.array(q, copy=True))
        return self.exact(q)


def _edges(rng, lo, hi, count, resolution):
    for k in range(count):
        a = rng.uniform(lo, hi)
        b = a + (rng.uniform(lo, hi) - a) * rng.uniform(0.02, 1.0)
        steps = len(interpolate(a, b, resolution))
        yield a, b, (10**6 if k % 3 else int(rng.integers(1, steps + 1)))


def _compare(model, exact_model, edges, resolution):
    """The certified model's check_motion against the generic one (interpolate, then check
    row by row) on the exact model: answers, counts and the configurations the exact
    check saw, bit for bit (each path with the checker's memory of exact answers
    emptied first); and single configurations."""
    checker = model.checker
    original = checker.exact
    rec = _Recorder(original)
    checker.exact = rec
    asked_fast, asked_generic = [], []
    try:
        for a, b, limit in edges:
            rec.asked = []
            checker._asked.clear()
            fast = model.check_motion(a, b, resolution, limit)
            asked_fast.append(rec.asked)
            rec.asked = []
            checker._asked.clear()
            generic = Robot.check_motion(model, a, b, resolution, limit)
            asked_generic.append(rec.asked)
            assert fast == generic == Robot.check_motion(exact_model, a, b, resolution, limit)
            rec.asked = []
            assert model.check(b[None]) == exact_model.check(b[None])
    finally:
        checker.exact = original
    for x, y in zip(asked_fast, asked_generic, strict=True):
        assert len(x) == len(y)
        for u, v in zip(x, y, strict=True):
            assert u.tobytes() == v.tobytes()  # the very states interpolate makes
    assert checker.stats["exact"] + checker.stats["proved"] > 0  # collisions were met
    assert checker.stats["rows"] > 5 * checker.stats["exact"]


def test_arm_motions_with_the_rod_held_equal_the_generic_check(carrying):
    domain, inst, theta, carry = carrying
    domain.reset(inst)
    domain.hold(inst, theta.grasp, carry)
    domain.robot.set_base(theta.place_pose)
    exact = MobileArm(domain.robot)
    model = FC.certified(exact)
    assert model.checker.certified
    lo, hi = np.maximum(P.LOWER, carry - 1.2), np.minimum(P.UPPER, carry + 1.2)
    _compare(model, exact, _edges(np.random.default_rng(1), lo, hi, 60, 0.01), 0.01)


def test_arm_motions_at_the_start_equal_the_generic_check(carrying):
    domain, inst, *_ = carrying
    scene = domain.reset(inst)
    model = FC.certified(scene.arm)
    assert model.checker.certified
    lo, hi = np.maximum(P.LOWER, P.HOME - 1.5), np.minimum(P.UPPER, P.HOME + 1.5)
    _compare(model, scene.arm, _edges(np.random.default_rng(2), lo, hi, 60, 0.01), 0.01)


def test_base_motions_with_the_rod_held_equal_the_generic_check(carrying):
    domain, inst, theta, carry = carrying
    domain.reset(inst)
    domain.hold(inst, theta.grasp, carry)
    s = domain.config.psi_scale
    scene = domain.scene_of()
    lo, hi = scene.base.lower, scene.base.upper
    model = FC.certified(scene.base)
    assert model.checker.certified
    _compare(model, scene.base, _edges(np.random.default_rng(3), lo, hi, 80, 0.04), 0.04)
    assert s > 0


# -- the geometry the scan trusts ----------------------------------------------------------

def _distance(A: np.ndarray, B: np.ndarray) -> float:
    """Distance between the convex hulls of the point sets A and B: the least norm of a
    convex combination of the points of A - B (non-negative least squares, the sum of the
    weights held at 1 by a heavy extra row)."""
    D = (A[:, None, :] - B[None, :, :]).reshape(-1, 3)
    heavy = 1e4
    M = np.vstack([D.T, heavy * np.ones(len(D))])
    w, _ = nnls(M, np.concatenate([np.zeros(3), [heavy]]), maxiter=10_000)
    return float(np.linalg.norm(D.T @ (w / w.sum())))


def _corners(c, R, h):
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3)
    return c + (signs * h) @ R.T


def test_a_hull_shown_apart_is_apart():
    """_apart is a proof: whenever it says two sets are at least ``gap`` apart (a hull and
    a box, or two hulls, from one array of vertices or from two), they are; and it shows
    most pairs that are clearly apart."""
    rng = np.random.default_rng(4)
    F = np.hstack([np.eye(3), np.zeros((3, 1))])
    shown = clear = 0
    for _ in range(100):
        A = rng.normal(size=(16, 3)) * rng.uniform(0.02, 0.1, 3)
        R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        R[:, 0] *= np.sign(np.linalg.det(R))
        h, c = rng.uniform(0.01, 0.3, 3), rng.normal(size=3) * 0.25
        box = _corners(c, R, h)
        d = _distance(A, box)
        B = box + rng.normal(size=(8, 3)) * 0.005
        hulls = np.concatenate([A, B])
        d2 = _distance(A, B)
        for gap in (0.0025, 0.01):
            if collide._apart(F, A, 0, len(A), F, A, 0, 0, c, R, h, gap):
                assert d >= gap - 1e-9
                shown += 1
            one = collide._apart(F, hulls, 0, 16, F, hulls, 16, 24, c, R, h, gap)
            assert collide._apart(F, A, 0, 16, F, B, 0, 8, c, R, h, gap) == one
            if one:
                assert d2 >= gap - 1e-9
            clear += d > gap + 1e-4
    assert shown >= 0.95 * clear


def test_a_box_face_gap_means_no_pybullet_contact():
    """Box against box, pybullet's contacts are exact on the face axes: boxes _face_gap
    puts BOX_GAP apart never touch, and boxes that interpenetrate have no gap."""
    client = connect()
    try:
        table = add_box(client, (0.8, 2.4, 0.4), (2.1, 0.0, 0.2))
        rod = add_box(client, (0.7, 0.04, 0.04), (2.1, 0.0, 0.5), movable=True)
        tc, tR, th = np.array([2.1, 0.0, 0.2]), np.eye(3), np.array([0.4, 1.2, 0.2])
        rng = np.random.default_rng(5)
        gapped = touching = 0
        for _ in range(400):
            yaw, tilt = rng.uniform(-np.pi, np.pi), rng.normal(0, 0.05)
            q = pb.getQuaternionFromEuler([tilt, 0.0, yaw])
            R = np.asarray(pb.getMatrixFromQuaternion(q)).reshape(3, 3)
            h = np.array([0.35, 0.02, 0.02])
            low = (_corners(np.zeros(3), R, h)[:, 2]).min()
            c = np.array([rng.uniform(1.8, 2.4), rng.uniform(-1, 1),
                          0.4 - low + rng.uniform(-2e-3, 2e-3)])
            pb.resetBasePositionAndOrientation(rod, c.tolist(), q, physicsClientId=client)
            pb.performCollisionDetection(physicsClientId=client)
            contact = any(p[8] < 0 for p in pb.getContactPoints(bodyA=rod, bodyB=table,
                                                                 physicsClientId=client))
            gap = collide._face_gap(c, R, h, tc, tR, th)
            if gap >= FC.BOX_GAP:
                gapped += 1
                assert not contact
            if contact:
                touching += 1
                assert gap < 0
        assert gapped > 50 and touching > 50
    finally:
        pb.disconnect(physicsClientId=client)


# -- memos -----------------------------------------------------------------------------------

def test_the_world_key_follows_the_world(carrying):
    domain, inst, theta, carry = carrying
    scene = domain.reset(inst)
    key = scene.world_key()
    assert scene.world_key() == key
    domain.robot.set_base(theta.place_pose)  # the robot moves: not the world
    domain.robot.set_arm(carry)
    assert scene.world_key() == key
    from pipeline.domains.pick_place.world import placed_rod

    scene.put_rod(placed_rod(inst.rod_length, theta.placement))
    assert scene.world_key() != key
    domain.hold(inst, theta.grasp, carry)  # held: the rod is the robot's
    held = scene.world_key()
    assert held != key and held[2] is None
    other = domain.check_instance(_store()["instances"][2])
    domain.scene(other)
    assert scene.world_key()[:2] != key[:2]
    domain.scene(inst)


def test_remembered_worlds_are_the_worlds_read_afresh(carrying):
    """Under a world key, the checker's world is the world World.read finds now."""
    domain, inst, theta, carry = carrying

    def boxes(world):
        order = np.lexsort(world.box_c.T)
        return world.box_c[order], world.box_h[order], world.box_R[order]

    for setup in ("start", "held at k_b"):
        scene = domain.reset(inst)
        if setup != "start":
            domain.hold(inst, theta.grasp, carry)
            domain.robot.set_base(theta.place_pose)
        for _ in range(2):  # read, then remembered
            model = FC.certified(scene.arm)
            skip = {domain.robot.body} | ({scene.rod} if setup != "start" else set())
            fresh = FC.World.read(scene.client_id, skip)
            for x, y in zip(boxes(model.checker.world), boxes(fresh), strict=True):
                np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("restore", [True, False])
def test_shortcut_pairs_are_numpys_and_leave_the_generator_as_numpy_does(restore):
    """The same pairs either way; restored, the generator goes on as numpy's would (not
    restored, as a planning call's own generator, which it then drops, is left)."""
    for seed in range(60):
        ours, theirs = np.random.default_rng([seed, 1]), np.random.default_rng([seed, 1])
        pairs = _Pairs(ours, restore)
        for k in range(1 + seed % 45):
            n = 3 + (7919 * k + seed) % 70
            assert pairs.draw(n) == tuple(int(v) for v in sorted(
                theirs.choice(n, size=2, replace=False)))
        pairs.close()
        if restore:
            assert ours.bit_generator.state == theirs.bit_generator.state
            assert ours.random() == theirs.random()


def test_check_order_in_the_scan_is_the_planners():
    for k in range(1, 300):
        np.testing.assert_array_equal(collide._check_order(k, k), check_order(k))


# -- what the scan leaves out, and motions answered again ------------------------------------

def test_parts_left_out_of_the_scan_never_touch():
    """Group pairs (and robot box, group pairs) that SphereRobot.build leaves out of the
    scan ride on one frame and stay apart in every configuration; the others are kept."""
    client = connect()
    try:
        arm = P.Panda(client, (0.0, 0.0, 0.0))
        groups, _, pairs, _ = FC._panda_parts(frozenset(arm.ignored_pairs))
    finally:
        pb.disconnect(physicsClientId=client)
    left_out = [p for p in pairs if FC._rigidly_apart(groups[p[0]], groups[p[1]])]
    assert left_out and len(left_out) < len(pairs)
    robot = FC.SphereRobot.build(groups, pairs)
    assert len(robot.pair_a) == len(pairs) - len(left_out)
    frames = FC._arm_frames_fn(np.eye(4))(np.random.default_rng(4).uniform(
        P.LOWER, P.UPPER, (200, 7)))
    for a, b in left_out:
        assert groups[a][0] == groups[b][0]
        F = frames[:, groups[a][0]]
        ca = np.einsum("nij,kj->nki", F[:, :, :3], groups[a][1]) + F[:, None, :, 3]
        cb = np.einsum("nij,kj->nki", F[:, :, :3], groups[b][1]) + F[:, None, :, 3]
        gap = (np.linalg.norm(ca[:, :, None] - cb[:, None], axis=3)
               - groups[a][2][:, None] - groups[b][2][None])
        assert gap.min() > FC.RIGID_GAP
    # a box on the hand's frame next to the fingers is kept, one far from it is left out
    hand = next(g for g in groups if g[0] == 7)
    near = (7, np.eye(4), np.full(3, 0.05))
    lifted = np.eye(4)
    lifted[2, 3] = 2.0
    far = (7, lifted, np.full(3, 0.05))
    assert not FC._box_rigidly_apart(near, hand) and FC._box_rigidly_apart(far, hand)


def test_a_base_edge_looks_at_every_box_its_root_sphere_reaches(carrying):
    """The boxes _planar_candidates leaves out are missed by the root sphere at every
    state of the edge (the per-row test would leave them out too)."""
    domain, inst, theta, carry = carrying
    domain.reset(inst)
    domain.hold(inst, theta.grasp, carry)
    scene = domain.scene_of()
    model = FC.certified(scene.base)
    robot, world = model.checker.robot, model.checker.world
    rng = np.random.default_rng(5)
    lo, hi = scene.base.lower, scene.base.upper
    left_out = 0
    for _ in range(60):
        a = rng.uniform(lo, hi)
        b = a + (rng.uniform(lo, hi) - a) * rng.uniform(0.05, 1.0)
        kept = set(collide._planar_candidates(a, b, robot.root_c, robot.root_r, world.box_c,
                                              world.box_e).tolist())
        states = interpolate(a, b, 0.04)
        frames = np.empty((len(states), 1, 3, 4))
        collide.planar_frames(states, domain.config.psi_scale, frames)
        centres = frames[:, 0, :, :3] @ robot.root_c + frames[:, 0, :, 3]
        for m in set(range(len(world.box_c))) - kept:
            left_out += 1
            for c in centres:
                assert collide._off_aabb(c[0], c[1], c[2], robot.root_r, world.box_c[m],
                                         world.box_e[m])
    assert left_out > 0


def _recorded_base(carrying):
    """(scene, certified base model, its checker, the recorder now its exact check) with
    the rod held in carry."""
    domain, inst, theta, carry = carrying
    domain.reset(inst)
    domain.hold(inst, theta.grasp, carry)
    scene = domain.scene_of()
    model = FC.certified(scene.base)
    rec = _Recorder(model.checker.exact)
    model.checker.exact = rec
    return scene, model, model.checker, rec


def test_a_motion_refuted_by_geometry_is_answered_again_without_pybullet(carrying):
    """Asked again (shortcutting redraws blocked pairs), with the same or a smaller limit,
    a motion that geometry alone refuted gets the generic check's answer and count, and
    pybullet is not asked; motions pybullet decided are checked again."""
    scene, model, checker, rec = _recorded_base(carrying)
    again = checked_again = 0
    try:
        for a, b, _ in _edges(np.random.default_rng(6), scene.base.lower, scene.base.upper,
                              80, 0.04):
            rec.asked = []
            first = model.check_motion(a, b, 0.04, 10**6)
            refuted = (a.tobytes(), b.tobytes(), 0.04) in checker._refuted
            assert not (refuted and rec.asked)
            for limit in (10**6, first[1], max(1, first[1] - 1), 1):
                rec.asked = []
                checker._asked.clear()  # pybullet's answers remembered: next test
                answer = model.check_motion(a, b, 0.04, limit)
                asked = rec.asked
                assert answer == Robot.check_motion(scene.base, a, b, 0.04, limit)
                if refuted:
                    assert not asked
                    again += 1
                checked_again += bool(asked)
    finally:
        checker.exact = rec.exact
    assert again > 20 and checked_again > 0


def test_pybullets_answers_are_remembered_only_under_fresh_contacts(carrying):
    """Under fresh contacts an exact answer is a function of the configuration: a row
    asked again gets it from the checker's memory (the same answer and count), and
    pybullet is not asked again; under cached contacts every row is asked again."""
    scene, model, checker, rec = _recorded_base(carrying)
    remembered = 0
    try:
        for a, b, _ in _edges(np.random.default_rng(6), scene.base.lower, scene.base.upper,
                              80, 0.04):
            first = model.check_motion(a, b, 0.04, 10**6)
            rec.asked = []
            before = checker.stats["remembered"]
            assert model.check_motion(a, b, 0.04, 10**6) == first
            assert not rec.asked
            remembered += checker.stats["remembered"] - before
    finally:
        checker.exact = rec.exact
    assert remembered > 0
    cached = load_domain("pick_place", contacts="cached")
    try:
        cached.scene(cached.check_instance(cached.sample_instance(1)))
        assert FC.certified(cached.scene_of().base).checker._asked is None
        assert FC.certified(cached.scene_of().arm).checker._asked is None
    finally:
        cached.close()


def test_a_configuration_settled_by_geometry_is_answered_again_without_pybullet(carrying):
    """A single configuration the pre-check cleared or proved colliding gets the exact
    check's answer when asked again, and pybullet is not asked the second time."""
    domain, inst, *_ = carrying
    scene = domain.reset(inst)
    model = FC.certified(scene.arm)
    checker = model.checker
    rec = _Recorder(checker.exact)
    checker.exact = rec
    rng = np.random.default_rng(7)
    settled = 0
    try:
        for q in rng.uniform(np.maximum(P.LOWER, P.HOME - 1.5),
                             np.minimum(P.UPPER, P.HOME + 1.5), (150, 7)):
            rec.asked = []
            first = model.check(q[None])
            by_geometry = not rec.asked
            rec.asked = []
            assert model.check(q[None]) == first == scene.arm.check(q[None])
            assert not (by_geometry and rec.asked)
            settled += by_geometry
    finally:
        checker.exact = rec.exact
    assert settled > 0
    assert checker.stats["proved"] > 0


# -- what the steps before a planning call settle on the planner's models --------------------

def test_the_planners_models_are_remembered_per_pose_load_and_world(carrying):
    """The arm's certified model is the same object again while the base pose, the held
    rod (and how it is held) and the world are the same, the base's while the arm state,
    the rod and the world are; another one where any of them differs.  A robot in a scene
    that gives no world key gets a new model every call."""
    domain, inst, theta, carry = carrying
    robot, scene = domain.robot, domain.reset(inst)
    arm = FC.certified(scene.arm)
    assert FC.certified(scene.arm) is arm
    assert FC.certified(MobileArm(robot)) is arm  # the same kind of model
    assert FC.certified(UnladenArm(robot)) is not arm  # another kind
    robot.set_base(theta.place_pose)
    assert FC.certified(scene.arm) is not arm
    robot.set_base(domain.start_pose)
    assert FC.certified(scene.arm) is arm
    scene.put_rod(placed_rod(inst.rod_length, theta.placement))  # the world changed
    assert FC.certified(scene.arm) is not arm
    domain.reset(inst)
    assert FC.certified(scene.arm) is arm
    domain.hold(inst, theta.grasp, carry)
    robot.set_base(domain.start_pose)
    held = FC.certified(scene.arm)
    assert held is not arm and FC.certified(scene.arm) is held
    base = FC.certified(scene.base)
    assert FC.certified(scene.base) is base
    robot.set_arm(carry + 0.01)
    assert FC.certified(scene.base) is not base
    robot.set_arm(carry)
    assert FC.certified(scene.base) is base
    other = next(g for g in domain.grasps if g is not theta.grasp)
    robot.grasp(scene.rod, other.rod_in_hand(inst.rod_length))  # held another way
    assert FC.certified(scene.base) is not base
    client = connect()
    try:
        bare = MobileArm(MobilePanda(client, contacts="fresh"))
        assert FC.certified(bare) is not FC.certified(bare)
    finally:
        pb.disconnect(client)


def _spheres_and_exact():
    """pick_place with planner.collision=spheres and =exact (fresh contacts, the default),
    each with its scene made."""
    store = _store()
    made = [load_domain("pick_place", planner={"name": "rrt_connect", "collision": c})
            for c in ("spheres", "exact")]
    for domain in made:
        domain.scene(domain.check_instance(store["instances"][0]))
    return made


def test_ik_solutions_checked_on_the_planners_model_are_pybullets():
    """Under spheres and fresh contacts, IK checks its solutions on the arm planner's model;
    every pick and place IK outcome (solution, checks, status) equals the one checked by
    pybullet alone, on every instance and grasp of the replay store, and the model
    settled some solutions without pybullet."""
    fast, exact = _spheres_and_exact()
    settled = 0
    try:
        for spec in _store()["instances"]:
            outcomes = []
            for domain in (fast, exact):
                inst = domain.check_instance(spec)
                domain.scene(inst)
                got = []
                for k, g in enumerate(domain.grasps):
                    domain.reset(inst)
                    got.append(domain.pick_ik(inst, g, k))
                    carry, _ = domain.carry(inst, g)
                    theta = domain.constraint(_store()["theta"][k % len(_store()["theta"])])
                    if carry is not None:
                        domain.reset(inst)
                        domain.hold(inst, g, carry)
                        domain.robot.set_base(theta.place_pose)
                        got.append(domain.place_ik(inst, dataclasses.replace(theta, grasp=g), k))
                outcomes.append(got)
            for a, b in zip(*outcomes, strict=True):
                assert a.status == b.status and a.checks == b.checks
                assert (a.q is None) == (b.q is None)
                assert a.q is None or a.q.tobytes() == b.q.tobytes()
            settled += sum(len(m.checker._settled) for m in fast.robot._models.items.values())
        assert exact.ik_collides() is None
    finally:
        fast.close()
        exact.close()
    assert settled > 0


def test_base_poses_settled_on_the_base_planners_model_are_pybullets():
    """The base-pose step's check under spheres and fresh contacts: the base planner's
    model settles what geometry decides (free and colliding poses both met), pybullet
    the rest, and every answer is pybullet's at the pose itself; under exact it is
    pybullet's check."""
    fast, exact = _spheres_and_exact()
    try:
        inst = fast.check_instance(_store()["instances"][0])
        g = fast.grasps[0]
        carry, _ = fast.carry(inst, g)
        assert carry is not None
        fast.hold(inst, g, carry)
        collides = fast.base_pose_collides()
        checker = FC.certified(fast.scene_of().base).checker
        rng = np.random.default_rng(11)
        x0, x1, y0, y1 = ROOMS
        for pose in rng.uniform([x0, y0, -np.pi], [x1, y1, np.pi], (300, 3)):
            assert collides(pose) == fast.robot.base_collides(pose)
        assert set(checker._settled.values()) == {True, False}
        assert exact.base_pose_collides() == exact.robot.base_collides
    finally:
        fast.close()
        exact.close()


# -- pick IK kept per grasp ------------------------------------------------------------------

def test_solve_ik_runs_every_start_in_turn_and_says_when_it_drew_one():
    """solve_ik's damped IK (home, then the random starts) answers as Panda.ik over all of
    ik_starts; ``seeded`` is True exactly where the start from home gave no solution the
    check accepts.  The check here refuses a shoulder turned left, so both occur."""
    from pipeline.domains.ik import solve_ik

    client = connect()
    try:
        arm = P.Panda(client, (0.0, 0.0, 0.0))
        rng = np.random.default_rng(5)
        seeded = []

        def refused(q):
            return q[0] > 0.3
        for k in range(60):
            pos, orn = arm.tcp_pose(rng.uniform(P.LOWER, P.UPPER))
            if np.linalg.norm(pos - arm.shoulder) > P.REACH:
                continue  # refused before any IK run (tests/test_wrist_reach.py)
            for seed in ([k, 7], [k, 8]):
                out = solve_ik(arm, pos, orn, seed, 4, "damped", refused)
                q, checks, reached = arm.ik(pos, orn, P.ik_starts(seed, 4), collides=refused)
                assert (out.q is None) == (q is None) and out.checks == checks
                assert out.q is None or out.q.tobytes() == q.tobytes()
                assert out.found or out.status.name == ("GOAL_IN_COLLISION" if reached
                                                        else "NO_IK")
                home, _, _ = arm.ik(pos, orn, [P.HOME], collides=refused)
                assert out.seeded == (home is None)
                seeded.append(out.seeded)
        assert any(seeded) and not all(seeded)
    finally:
        pb.disconnect(client)


def _pick_outcomes(domain, instances, grasps, seeds, forget=None):
    """Pick IK outcomes (solution bytes, checks, status) of ``domain`` for every instance ×
    grasp × seed, the scene reset before each as the pick step does; ``forget``: an
    instance loaded between two calls, so that nothing kept survives."""
    out = []
    for spec in instances:
        inst = domain.check_instance(spec)
        for g in grasps:
            for seed in seeds:
                if forget is not None:
                    domain.scene(domain.check_instance(forget))
                domain.scene(inst)
                domain.reset(inst)
                ik = domain.pick_ik(inst, g, seed)
                out.append((None if ik.q is None else ik.q.tobytes(), ik.checks, ik.status))
    return out


def _ik_runs(domain) -> list:
    """A list that gets one item per IK run of ``domain``'s robot (made with its scene)."""
    robot, runs = domain.robot, []
    method = robot.ik
    robot.ik = lambda *a, **k: runs.append(1) or method(*a, **k)
    return runs


@pytest.mark.parametrize("contacts", ["fresh", "cached"])
def test_pick_ik_outcomes_kept_per_grasp_are_the_ones_computed_afresh(contacts):
    """Every constraint of an instance with the same grasp asks the same pick IK; under
    fresh contacts its outcome is kept while the scene stays, and each kept outcome equals
    the one a domain computes afresh (another instance loaded before each call) for
    another seed, with fewer IK runs; under cached contacts nothing is kept (as many IK
    runs as afresh)."""
    store = _store()
    instances, seeds = store["instances"][:2], [3, 11, 12]
    made = [load_domain("pick_place", planner={"name": "rrt_connect"}, contacts=contacts)
            for _ in range(2)]
    try:
        for domain in made:
            domain.scene(domain.check_instance(instances[0]))
        keeping, afresh = made
        grasps = keeping.grasps[::7]
        runs, afresh_runs = _ik_runs(keeping), _ik_runs(afresh)
        kept = _pick_outcomes(keeping, instances, grasps, seeds)
        assert kept == _pick_outcomes(afresh, instances, grasps, seeds,
                                      forget=store["instances"][2])
        assert sum(1 for q, _, _ in kept if q is not None) >= 3 * len(seeds)
        if contacts == "fresh":
            assert len(runs) < len(afresh_runs)
        else:
            assert len(runs) == len(afresh_runs)
    finally:
        for domain in made:
            domain.close()


@pytest.mark.parametrize("content", [b"not an npz", None])
def test_the_benchmark_refuses_an_entries_file_it_cannot_use_in_one_line(tmp_path, content):
    """``bench_pick_place.py --entries``: a file that is not one it wrote, or a folder that
    does not exist, is refused with one line and exit code 2, the file left as it was."""
    import subprocess
    import sys
    from pathlib import Path

    path = tmp_path / "e.npz" if content is not None else tmp_path / "no" / "e.npz"
    if content is not None:
        path.write_bytes(content)
    script = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_pick_place.py"
    done = subprocess.run([sys.executable, str(script), "--entries", str(path)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and done.stdout == ""
    assert len(done.stderr.strip().splitlines()) == 1 and str(path) in done.stderr
    assert content is None or path.read_bytes() == content


# -- RAWPLANNER ------------------------------------------------------------------------------

def _pybullet_state(robot) -> bytes:
    """Every pose and joint position of the mobile robot and the rod it holds, as bytes."""
    c = robot.client
    poses = [pb.getBasePositionAndOrientation(b, physicsClientId=c)
             for b in (robot.platform, robot.body, robot.held)]
    joints = pb.getJointStates(robot.body, P.ARM_JOINTS, physicsClientId=c)
    return np.array([v for p in poses for part in p for v in part]
                    + [j[0] for j in joints]).tobytes()


def test_raw_planners_put_off_holds_and_moves_leave_pybullet_as_doing_them():
    """RAWPLANNER's draws hold the rod and move the base to every pose; ``_Standing`` puts
    that off until pybullet is asked.  After any run of holds and moves, its update leaves
    pybullet bit for bit as doing each step does (a second scene of the same instance),
    including the rod's pose, which depends on where the last hold was made."""
    from pipeline.domains.pick_place.raw import _Standing
    done, put_off = (load_domain("pick_place", planner={"name": "rrt_connect"})
                     for _ in range(2))
    try:
        inst = done.check_instance(_store()["instances"][0])
        for domain in (done, put_off):
            domain.scene(inst)
        g = done.grasps[0]
        carry, _ = done.carry(inst, g)
        assert carry is not None
        put_off.carry(inst, g)
        stand = _Standing(put_off, inst, g, carry)
        rng = np.random.default_rng(5)
        x0, x1, y0, y1 = ROOMS
        updates = 0
        for _ in range(30):
            for _ in range(int(rng.integers(1, 6))):
                done.hold(inst, g, carry)
                stand.hold()
                if rng.random() < 0.8:
                    pose = rng.uniform([x0, y0, -np.pi], [x1, y1, np.pi])
                    done.robot.set_base(pose)
                    stand.move(pose)
            before = _pybullet_state(put_off.robot)
            stand.update()
            updates += before != _pybullet_state(put_off.robot)
            assert _pybullet_state(put_off.robot) == _pybullet_state(done.robot)
        assert updates > 20  # the steps were put off, and brought up to date
    finally:
        done.close()
        put_off.close()


@pytest.mark.parametrize("instance", [5004, 5011, 40])
def test_raw_planner_answers_as_with_exact_checks(instance):
    """RAWPLANNER's base poses k_b are checked by the base model's geometry where it settles
    them (``base_pose_collides``), and the robot is left at each pose drawn, as pybullet's
    check leaves it: the placements drawn next are checked with the robot standing there,
    so a robot left only at the free ones changes later draws (instance 5011 shows it), and
    one left nowhere solves the place IK elsewhere.  Status, tries, checks, score and
    constraint equal ``exact``'s bit for bit."""
    found = {}
    for collision in ("spheres", "exact"):
        domain = load_domain("pick_place", planner={"name": "rrt_connect",
                                                    "collision": collision})
        try:
            seed = worker.entry_seed(0, instance, worker.RAW_ENTRY)
            raw = domain.raw_plan(domain.sample_instance(instance), seed=seed)
        finally:
            domain.close()
        found[collision] = (int(raw.plan.status), raw.tries, raw.plan.checks,
                            np.float64(raw.plan.score).tobytes(),
                            None if raw.constraint is None else raw.constraint.tobytes())
    assert found["spheres"] == found["exact"]
