"""The sphere-certified checker (planner.collision=spheres): its geometry covers the robot,
it answers as the exact checker does, and the paths it lets through are free."""

import numpy as np
import pybullet as pb
import pytest
from scipy.spatial import Delaunay

from pipeline import configs
from pipeline.domains import load_domain
from pipeline.planning import PlannerSettings
from pipeline.planning.base import check_order, interpolate, path_is_free
from pipeline.sim import collide
from pipeline.sim import fast_check as FC
from pipeline.sim import panda as P
from pipeline.sim import spheres as S
from pipeline.sim.mobile import MobileArm, MobileBase
from pipeline.sim.world import add_box, connect


@pytest.fixture(scope="module")
def lone_arm():
    client = connect()
    arm = P.Panda(client, (0.1, -0.2, 0.3))
    arm.set_base((0.1, -0.2, 0.3), 0.7)
    yield client, arm
    pb.disconnect(physicsClientId=client)


def _domain(name, collision, **config):
    return load_domain(name, planner={"name": "rrt_connect", "collision": collision}, **config)


@pytest.fixture(scope="module")
def grasp_arm():
    return {c: _domain("grasp_arm", c) for c in ("spheres", "exact")}


def _edges(rng, lower, upper, count, resolution):
    """Random edges as the planner checks them: interpolated, in check order."""
    for _ in range(count):
        a, b = rng.uniform(lower, upper), rng.uniform(lower, upper)
        b = a + (b - a) * rng.uniform(0.05, 1.0)
        states = interpolate(a, b, resolution)
        yield states[check_order(len(states))]


# -- geometry --------------------------------------------------------------------------------
def test_forward_kinematics_matches_pybullet(lone_arm):
    client, arm = lone_arm
    Q = np.random.default_rng(0).uniform(P.LOWER, P.UPPER, (20, 7))
    frames = S.arm_frames(Q, FC.base_link_frame(client, arm.body))
    fast = FC._arm_frames_fn(FC.base_link_frame(client, arm.body))(Q)
    np.testing.assert_allclose(fast, frames, atol=1e-12)
    for link in (0, 3, 6, 8, 9, 10, 11):
        T = S.link_frame(frames, link)
        for n, q in enumerate(Q):
            arm.set(q)
            state = pb.getLinkState(arm.body, link, computeForwardKinematics=True,
                                    physicsClientId=client)
            R = np.asarray(pb.getMatrixFromQuaternion(state[5])).reshape(3, 3)
            np.testing.assert_allclose(T[n, :3, 3], state[4], atol=1e-6)
            np.testing.assert_allclose(T[n, :3, :3], R, atol=1e-6)


def test_spheres_hold_every_point_of_every_collision_hull():
    """Points drawn inside each link's convex hull (pybullet's collision shape) lie in one
    of the link's spheres (margin 0)."""
    model = S.panda_spheres(margin=0.0)
    offsets = S.fixed_offsets()
    rng = np.random.default_rng(1)
    for link, (path, origin) in S.panda_chain().meshes.items():
        T = offsets[link] @ origin
        verts = S._mesh_vertices(path) @ T[:3, :3].T + T[:3, 3]
        lo, hi = verts.min(axis=0), verts.max(axis=0)
        cloud = rng.uniform(lo, hi, (20000, 3))
        inside = cloud[Delaunay(verts).find_simplex(cloud) >= 0]
        points = np.concatenate([verts, inside])
        m = model.links == link
        d = np.linalg.norm(points[:, None] - model.centres[m][None], axis=2) - model.radii[m]
        assert d.min(axis=1).max() <= 1e-9, f"link {link}"


def test_inner_spheres_lie_inside_their_collision_hulls():
    """Points of every inner sphere (its centre and 200 points on its surface) are inside
    the convex hull of its link's collision mesh, and the fingers' and the base link's are
    not needed: the base link's contacts are not collisions."""
    inner = S.panda_inner_spheres()
    offsets = S.fixed_offsets()
    rng = np.random.default_rng(2)
    directions = rng.normal(size=(200, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    assert -1 not in set(inner.links.tolist()) and len(inner.radii) > 50
    for link, (path, origin) in S.panda_chain().meshes.items():
        m = inner.links == link
        if not m.any():
            continue
        T = offsets[link] @ origin
        hull = Delaunay(S._mesh_vertices(path) @ T[:3, :3].T + T[:3, 3])
        for c, r in zip(inner.centres[m], inner.radii[m], strict=True):
            points = np.concatenate([c[None], c + (r - 1e-9) * directions])
            assert np.all(hull.find_simplex(points) >= 0), f"link {link}"


def test_proven_arm_collisions_are_pybullet_collisions(grasp_arm):
    """Wherever an inner sphere reaches the proof depth into a box, pybullet reports a
    collision (random configurations of both arms on several instances)."""
    domain = grasp_arm["exact"]
    rng = np.random.default_rng(9)
    proved = 0
    for arm, _, checker in _arms(domain, 40, 6):
        proved += _proven_collisions(arm, checker, rng.uniform(P.LOWER, P.UPPER, (250, 7)),
                                     lambda f, n, c=checker: c.robot.surely_hits(f, n, c.world))
    assert proved > 100


def _proven_collisions(arm, checker, Q, proof) -> int:
    """How many rows of Q ``proof(frames, n)`` proves colliding, each one asserted a
    pybullet collision."""
    frames, proved = checker.frames(Q), 0
    for n, q in enumerate(Q):
        if proof(frames, n):
            proved += 1
            assert arm.collides_at(q), q.tolist()
    arm.set(P.HOME)
    return proved


def test_every_pybullet_contact_is_flagged_by_the_pre_check(grasp_arm):
    """Conservativeness: on an instance with obstacles and the other arm, every
    configuration with a pybullet contact (with a box, the other arm or itself) is one the
    pre-check cannot clear."""
    domain = grasp_arm["exact"]
    rng = np.random.default_rng(3)
    contacts = 0
    for seed in (0, 1):
        scene = domain.scene(domain.check_instance(domain.sample_instance(seed)))
        arm = scene.arms[seed % 2]
        checker = FC.arm_checker(scene.client_id, arm.body, arm.ignored_pairs, arm.collides_at)
        assert checker.certified
        Q = np.concatenate([rng.uniform(P.LOWER, P.UPPER, (300, 7)),
                            np.clip(P.HOME + rng.normal(0, 0.7, (300, 7)), P.LOWER, P.UPPER)])
        flagged = checker.uncertain(Q)
        colliding = np.array([arm.collides_at(q) for q in Q])
        arm.set(P.HOME)
        contacts += colliding.sum()
        assert not np.any(colliding & ~flagged)
        assert flagged.mean() < 0.6  # and it clears a good share of the rest
    assert contacts > 50


def _arms(domain, first: int, count: int):
    """(an arm, the other arm, the arm's sphere checker) on ``count`` instances from seed
    ``first``, the arms taking turns."""
    for seed in range(count):
        scene = domain.scene(domain.check_instance(domain.sample_instance(first + seed)))
        arm = scene.arms[seed % 2]
        yield arm, scene.arms[1 - seed % 2], FC.certified(arm).checker


def _toward(rng, arm, other, n: int) -> np.ndarray:
    """n configurations of ``arm`` around home, its first joint turned towards ``other``
    (the other arm's side of the table)."""
    toward = np.arctan2(*(other.shoulder - arm.shoulder)[1::-1])
    Q = np.clip(P.HOME + rng.normal(0, 0.8, (n, 7)), P.LOWER, P.UPPER)
    Q[:, 0] = np.clip(toward - arm.base_yaw + rng.normal(0, 0.4, n), P.LOWER[0], P.UPPER[0])
    return Q


def test_the_other_arms_hulls_clear_only_what_pybullet_clears(grasp_arm):
    """Where the arm's spheres touch the other arm's, the two links' collision hulls
    decide (at least both margins apart: clear): every configuration they clear is free
    for pybullet, and they clear many the spheres alone would send to pybullet."""
    import dataclasses

    domain = grasp_arm["exact"]
    rng = np.random.default_rng(12)
    cleared = 0
    for arm, other, checker in _arms(domain, 60, 4):
        world = checker.world
        assert len(world.og_hull) and np.all(world.og_hlo < world.og_hhi)
        spheres_only = dataclasses.replace(world, og_hull=None, og_hlo=None, og_hhi=None)
        Q = _toward(rng, arm, other, 1000)
        frames, wrist = checker.frames(Q), checker._pre(Q)  # the wrist table's doubts
        before = checker.robot.uncertain(frames, spheres_only, wrist)
        after = checker.robot.uncertain(frames, world, wrist)
        assert not np.any(after & ~before)  # the hulls only ever clear
        for q in Q[before & ~after]:
            assert not arm.collides_at(q), q.tolist()
            cleared += 1
        arm.set(P.HOME)
    assert cleared > 50
    # under cached contacts a pybullet check left out could change a later answer
    # (docs/contacts.md): there every row the spheres doubt is asked as before
    cached = _domain("grasp_arm", "spheres", contacts="cached")
    scene = cached.scene(cached.check_instance(cached.sample_instance(60)))
    world = FC.certified(scene.arms[0]).checker.world
    assert len(world.og_r) and not len(world.og_hull) and np.all(world.og_hlo == world.og_hhi)
    assert not len(world.oin_r) and np.all(world.og_ilo == world.og_ihi)


def test_proven_collisions_with_the_other_arm_are_pybullet_collisions(grasp_arm):
    """An inner sphere of the arm overlapping one of the other arm's by the proof depth is
    a collision for pybullet (configurations reaching towards the other arm)."""
    domain = grasp_arm["exact"]
    rng = np.random.default_rng(14)
    proved = 0
    for arm, other, checker in _arms(domain, 80, 3):
        assert len(checker.world.oin_r)
        proved += _proven_collisions(arm, checker, _toward(rng, arm, other, 600),
                                     lambda f, n, c=checker: c.robot._hits_robot(f, n, c.world))
    assert proved > 50


def test_ik_checks_its_solutions_as_pybullet_does(grasp_arm):
    """grasp_arm's IK checks a solution on the planner's model under the sphere pre-check
    and fresh contacts (the same answers as pybullet's), and with pybullet itself under
    planner.collision=exact or cached contacts."""
    domain = grasp_arm["spheres"]
    scene = domain.scene(domain.check_instance(domain.sample_instance(5)))
    arm = scene.arms[1]
    collides = domain.ik_collides(arm)
    assert collides is not None
    rng = np.random.default_rng(15)
    Q = np.concatenate([rng.uniform(P.LOWER, P.UPPER, (150, 7)),
                        np.clip(P.HOME + rng.normal(0, 0.7, (150, 7)), P.LOWER, P.UPPER)])
    answers = [collides(q) for q in Q]
    assert answers == [arm.collides_at(q) for q in Q] and 0 < sum(answers) < len(Q)
    arm.set(P.HOME)
    exact = grasp_arm["exact"]
    assert exact.ik_collides(exact.scene(exact.check_instance(
        exact.sample_instance(5))).arms[1]) is None
    cached = _domain("grasp_arm", "spheres", contacts="cached")
    assert cached.ik_collides(cached.scene(cached.check_instance(
        cached.sample_instance(5))).arms[1]) is None


def test_wrist_hulls_clear_only_what_pybullet_clears(grasp_arm):
    """Where the wrist table may hold a contact, the wrist pairs' spheres and hulls decide
    as for the other link pairs: every configuration they clear is free for pybullet,
    and they clear many the table alone would send to pybullet."""
    from pipeline.sim import collide

    domain = grasp_arm["exact"]
    rng = np.random.default_rng(21)
    cleared = 0
    for arm, _, checker in _arms(domain, 70, 3):
        kind, psi, step, table, chain, packed, memo = checker._motion_args()
        assert len(chain[3])  # fresh contacts: the wrist pairs are given to the scan
        table_only = (*chain[:3], collide.NO_CHAIN[3])
        # wrist angles near the limits, where the hand folds onto the forearm
        Q = rng.uniform(P.LOWER, P.UPPER, (1500, 7))
        Q[:, 5] = rng.choice([P.LOWER[5], P.UPPER[5]], 1500) + rng.normal(0, 0.4, 1500)
        Q = np.clip(Q, P.LOWER, P.UPPER)
        table.uncertain(Q)  # every cell these fall into is known
        for q in Q:
            before, after = (collide.edge_first(q, q, 1.0, 1, 0, kind, psi, step, table.state,
                                                ch, packed, None)[1] == 1
                             for ch in (table_only, chain))
            assert after or not before  # the hulls only ever clear
            if after and not before:
                assert not arm.collides_at(q), q.tolist()
                cleared += 1
        arm.set(P.HOME)
    assert cleared > 50
    cached = _domain("grasp_arm", "spheres", contacts="cached")  # as for the other arm
    scene = cached.scene(cached.check_instance(cached.sample_instance(70)))
    assert not len(FC.certified(scene.arms[0]).checker._motion_args()[4][3])


# -- same answers as the exact checker -------------------------------------------------------
def _same_answers(checker, exact, edges):
    for states in edges:
        assert checker(states) == exact(states)


def test_arm_checker_answers_and_counts_as_the_exact_one(grasp_arm):
    domain = grasp_arm["exact"]
    scene = domain.scene(domain.check_instance(domain.sample_instance(4)))
    arm = scene.arms[0]
    try:
        model = FC.certified(arm)
        assert isinstance(model, FC.CertifiedRobot) and model.checker.certified
        _same_answers(model.check, arm.check,
                      _edges(np.random.default_rng(5), P.LOWER, P.UPPER, 40, 0.01))
        assert model.checker.stats["exact"] < model.checker.stats["rows"] / 5
    finally:
        arm.set(P.HOME)


@pytest.fixture(scope="module")
def carrying():
    """pick_place with the rod held in a carry configuration, at the start."""
    domain = _domain("pick_place", "exact")
    inst = domain.check_instance(domain.sample_instance(1))
    domain.scene(inst)
    for g in domain.grasps:
        carry, _ = domain.carry(inst, g)
        if carry is not None:
            domain.hold(inst, g, carry)
            return domain, domain.robot
    pytest.fail("no carry configuration")


def test_arm_checker_with_a_held_rod_answers_as_the_exact_one(carrying):
    domain, robot = carrying
    model = FC.certified(MobileArm(robot))
    assert isinstance(model, FC.CertifiedRobot) and model.checker.certified
    rng = np.random.default_rng(6)
    q0 = FC.arm_state(robot.client, robot.body)
    lo, hi = np.maximum(P.LOWER, q0 - 1.0), np.minimum(P.UPPER, q0 + 1.0)
    _same_answers(model.check, robot.arm_check, _edges(rng, lo, hi, 25, 0.01))
    robot.set_arm(q0)


def test_base_checker_with_a_held_rod_answers_as_the_exact_one(carrying):
    domain, robot = carrying
    s = domain.config.psi_scale
    lo, hi = np.array([-2.9, -1.5, -np.pi * s]), np.array([2.9, 1.5, np.pi * s])
    exact = MobileBase(robot, s, lo, hi)
    model = FC.certified(exact)
    assert isinstance(model, FC.CertifiedRobot) and model.checker.certified
    _same_answers(model.check, exact.check, _edges(np.random.default_rng(7), lo, hi, 40, 0.04))
    assert model.checker.stats["exact"] < model.checker.stats["rows"] / 5
    assert model.checker.stats["proved"] > 0  # the platform ran into furniture: no pybullet


def _arm_checker(scenes, which):
    """The sphere checker of an arm (``which``: the held rod's or grasp_arm's first arm,
    next to the other arm), its arm put back by the caller."""
    if which == "held rod":
        domain, robot = scenes["carrying"]
        return FC.certified(MobileArm(robot)).checker, None
    domain = scenes["grasp_arm"]["exact"]
    arm = domain.scene(domain.check_instance(domain.sample_instance(4))).arms[0]
    return FC.certified(arm).checker, arm


@pytest.fixture(scope="module")
def scenes(carrying, grasp_arm):
    return {"carrying": carrying, "grasp_arm": grasp_arm}


def _long_motions(rng, count):
    """Arm motions up to a whole joint range long, some within a radian of the start."""
    for k in range(count):
        a = rng.uniform(P.LOWER, P.UPPER)
        far = rng.uniform(P.LOWER, P.UPPER)
        near = np.clip(a + rng.uniform(-1.0, 1.0, 7), P.LOWER, P.UPPER)
        yield a, (far if k % 2 else near)


@pytest.mark.parametrize("which", ["held rod", "next to another arm"])
def test_arm_motions_scan_alike_segment_by_segment_and_row_by_row(scenes, which):
    """An arm motion's scan gives the same (rows, first row in doubt, proof) whether it
    clears rows a segment at a time (the default) or one by one: for whole motions,
    budgets that stop inside them, and scans resumed after a row in doubt."""
    checker, arm = _arm_checker(scenes, which)
    try:
        kind, psi, step, table, chain, packed, memo = checker._motion_args()
        rng = np.random.default_rng(11)
        scanned = 0
        for a, b in _long_motions(rng, 60):
            table.uncertain(interpolate(a, b, 0.01))  # every wrist cell known
            for limit in (10_000, int(rng.integers(2, 60))):
                start = 0
                while True:
                    got = [collide.edge_first(a, b, 0.01, limit, start, kind, psi, step,
                                              table.state, chain, packed, memo, segment=n)
                           for n in (collide.SEGMENT, 0)]
                    assert got[0] == got[1], (a, b, limit, start)
                    steps, k, proved = got[0]
                    scanned += k - start
                    if proved or k >= min(steps, limit):
                        break
                    start = k + 1
        assert scanned > 2_000
    finally:
        if arm is not None:
            arm.set(P.HOME)


@pytest.mark.parametrize("which", ["held rod", "next to another arm"])
def test_a_segment_cleared_at_once_is_cleared_by_the_row_test_row_by_row(scenes, which):
    """Where the grown test of a segment clears it, the scan's row test clears each of its
    rows (the rows' own frames, every box near every part): the bound holds.  Both
    answers occur."""
    checker, arm = _arm_checker(scenes, which)
    try:
        robot, world = checker.robot, checker.world
        base, origins = checker._motion_args()[4][:2]
        G, R, B = len(robot.grp_r), len(robot.rbox_T), len(world.box_c)
        lever_g, lever_b = np.empty((G, 7)), np.empty((R, 7))
        for g in range(G):
            collide._levers(origins, robot.grp_frame[g], robot.grp_c[g], robot.grp_r[g],
                            lever_g[g])
        for b in range(R):
            collide._levers(origins, robot.rbox_frame[b], np.ascontiguousarray(
                robot.rbox_T[b, :, 3]), robot.rbox_r[b], lever_b[b])
        near_g = np.tile(np.arange(B), (G, 1))
        near_b = np.tile(np.arange(B), (R, 1))
        q, dq, fm = np.empty(7), np.empty(7), np.empty((8, 3, 4))
        dg, db = np.empty(G), np.empty(R)
        scratch = (np.empty((G, 3)), np.empty((len(robot.sph_r), 3)), np.empty((3, 3)),
                   np.empty(3), np.empty(3))
        cleared = tried = 0
        for a, b in _long_motions(np.random.default_rng(12), 40):
            steps = int(np.ceil(np.max(np.abs(b - a)) / 0.01))
            for j in range(0, -(-steps // collide.SEGMENT), 3):
                collide._segment_motion(j, collide.SEGMENT, steps, a, b - a, base, origins,
                                        robot.grp_frame, robot.rbox_frame, lever_g, lever_b,
                                        q, dq, fm, dg, db)
                tried += 1
                if not collide._segment_clear(
                        fm, dg, db, lever_g, lever_b, dq, robot.grp_frame, robot.grp_c,
                        robot.grp_r, robot.grp_lo, robot.grp_hi, robot.grp_world, robot.sph_c,
                        robot.sph_r, robot.pair_a, robot.pair_b, robot.rbox_frame,
                        robot.rbox_T, robot.rbox_h, robot.rbox_r, robot.rbox_pair_b,
                        robot.rbox_pair_g, world.box_c, world.box_R, world.box_h,
                        world.box_e, near_g, np.full(G, B), near_b, np.full(R, B),
                        world.og_c, world.og_r, world.og_lo, world.og_hi, world.sph_c,
                        world.sph_r, world.og_all, *scratch):
                    continue
                cleared += 1
                rows = np.arange(j * collide.SEGMENT, min((j + 1) * collide.SEGMENT, steps))
                states = a + ((rows + 1) / steps)[:, None] * (b - a)
                assert not robot.uncertain(checker.frames(states), world).any(), (a, b, j)
        assert 0 < cleared < tried
    finally:
        if arm is not None:
            arm.set(P.HOME)


def test_base_model_is_made_once_per_carried_state(carrying):
    """The base checker's robot model depends on what the robot carries and how, not on
    where the base stands: pybullet's kinematics put the held rod a little differently
    (about 1e-7 m) in the base frame at every base pose where it is taken up, which must
    not make a model per planning call."""
    domain, robot = carrying
    s = domain.config.psi_scale
    lo, hi = np.array([-2.9, -1.5, -np.pi * s]), np.array([2.9, 1.5, np.pi * s])
    start = robot.pose.copy()
    models = []
    try:
        for pose in np.random.default_rng(8).uniform([-2.0, -1.0, -np.pi], [2.0, 1.0, np.pi],
                                                       (6, 3)):
            robot.set_base(pose)
            robot.grasp(robot.held, robot.held_in_tcp.copy())  # taken up again here
            model = FC.certified(MobileBase(robot, s, lo, hi))
            assert model.checker.certified
            models.append(model.checker.robot)
    finally:
        robot.set_base(start)
        robot.grasp(robot.held, robot.held_in_tcp.copy())
    assert all(m is models[0] for m in models)


def test_a_proven_box_collision_is_one_for_pybullet(lone_arm):
    """Boxes placed at a chosen depth of interpenetration (bisection along a random
    direction, random orientations): wherever the separating-axis depth reaches the proof
    depth pybullet reports penetration, and wherever it is clearly negative, none."""
    from pipeline.sim import collide

    client, _ = lone_arm
    rng = np.random.default_rng(12)
    proved = 0
    for trial in range(400):
        ha, hb = rng.uniform(0.01, 0.35, 3), rng.uniform(0.01, 0.35, 3)
        qa, qb = (q / np.linalg.norm(q) for q in rng.normal(size=(2, 4)))
        Ra, Rb = FC._matrices(np.stack([qa, qb]))
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        target = rng.uniform(-0.004, 0.004)
        lo, hi = 0.0, 2.0
        for _ in range(50):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if collide._box_overlap(
                np.zeros(3), Ra, ha, mid * u, Rb, hb) > target else (lo, mid)
        depth = collide._box_overlap(np.zeros(3), Ra, ha, lo * u, Rb, hb)
        a = add_box(client, 2 * ha, (5.0, 5.0, 5.0), movable=True)
        b = add_box(client, 2 * hb, (5.0, 5.0, 5.0))
        try:
            pb.resetBasePositionAndOrientation(a, [5.0, 5.0, 5.0], qa.tolist(),
                                               physicsClientId=client)
            pb.resetBasePositionAndOrientation(b, (np.array([5.0, 5.0, 5.0]) + lo * u).tolist(),
                                               qb.tolist(), physicsClientId=client)
            pb.performCollisionDetection(physicsClientId=client)
            penetrates = any(p[8] < 0 for p in pb.getContactPoints(a, b, physicsClientId=client))
        finally:
            pb.removeBody(a, physicsClientId=client)
            pb.removeBody(b, physicsClientId=client)
        if depth >= FC.PROOF_DEPTH:
            proved += 1
            assert penetrates, (trial, depth)
        elif depth < -FC.PROOF_DEPTH:
            assert not penetrates, (trial, depth)
    assert proved > 100


def test_a_scene_it_cannot_model_is_checked_exactly(lone_arm):
    client, arm = lone_arm
    sphere = pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_SPHERE, radius=0.1,
                                                           physicsClientId=client),
                                basePosition=[0.6, -0.2, 0.6], physicsClientId=client)
    try:
        model = FC.certified(arm)
        assert not model.checker.certified
        _same_answers(model.check, arm.check,
                      _edges(np.random.default_rng(8), P.LOWER, P.UPPER, 10, 0.05))
    finally:
        pb.removeBody(sphere, physicsClientId=client)


def test_unknown_robots_are_left_alone():
    class Disc:
        lower, upper = np.zeros(2), np.ones(2)

        def check(self, states):
            return True, len(states)

    disc = Disc()
    assert FC.certified(disc) is disc


# -- planning with it ------------------------------------------------------------------------
def _same_plan(a, b):
    assert (a.status, a.step, a.checks) == (b.status, b.step, b.checks)
    assert (a.path is None) == (b.path is None)
    if a.path is not None:
        np.testing.assert_array_equal(a.path, b.path)


def test_grasp_arm_entries_equal_exact_ones_and_paths_recheck_free(grasp_arm):
    fast, exact = grasp_arm["spheres"], grasp_arm["exact"]
    spec = fast.sample_instance(7)
    feasible = 0
    for j in range(0, 162, 3):
        a, b = fast.plan(spec, j, seed=j), exact.plan(spec, j, seed=j)
        _same_plan(a, b)
        if a.feasible:
            feasible += 1
            scene = exact.build_scene(spec)
            try:
                arm = scene.arms[fast.constraint(j).arm]
                assert path_is_free(a.path, arm.check, 0.01)
            finally:
                scene.close()
    assert feasible >= 3


@pytest.mark.parametrize("name", ["grasp_base", "pick_place"])
def test_mobile_entries_equal_exact_ones_and_paths_recheck_free(name):
    fast, exact = _domain(name, "spheres"), _domain(name, "exact")
    spec = fast.sample_instance(3)
    raw = fast.raw_plan(spec, seed=11)
    assert raw.plan.feasible
    specs = [spec] * 4 + [fast.sample_instance(4)]
    feasible = 0
    for k, s in enumerate(specs):
        a, b = fast.plan(s, raw.constraint, seed=k), exact.plan(s, raw.constraint, seed=k)
        _same_plan(a, b)
        if not a.feasible:
            continue
        feasible += 1
        if name == "pick_place":
            assert all(fast.recheck(s, raw.constraint, a, resolution=0.005).values())
        else:
            scene = exact.build_scene(s)
            try:
                scene.robot.set_base(fast.constraint(raw.constraint).pose)
                assert path_is_free(a.path, scene.robot.arm_check, 0.01)
            finally:
                scene.close()
    assert feasible >= 1


# -- the setting -----------------------------------------------------------------------------
def test_the_setting_is_validated_and_not_part_of_a_stores_identity():
    assert PlannerSettings().collision == "spheres"
    with pytest.raises(ValueError, match="planner.collision"):
        PlannerSettings(collision="fast")
    cfg = {"domain": {"name": "planar"}, "seed": 0, "instances": {"n": 2},
           "constraints": {"m": 2}, "store": {"block_instances": 1, "block_constraints": 1}}
    a = configs.identity({**cfg, "planner": {"name": "rrt_connect", "collision": "spheres"}})
    b = configs.identity({**cfg, "planner": {"name": "rrt_connect", "collision": "exact"}})
    c = configs.identity({**cfg, "planner": {"name": "rrt_connect"}})
    assert a == b == c


def test_boxes_touching_the_platform_make_a_mobile_checker_exact():
    from pipeline.domains.mobile_world import MobileScene

    scene = MobileScene([])
    try:
        arm = MobileArm(scene.robot)
        assert FC.certified(arm).checker.certified
        add_box(scene.client_id, (0.2, 0.2, 0.2), (0.3, 0.0, 0.1))  # into the platform
        assert not FC.certified(arm).checker.certified
    finally:
        scene.close()


def _numpy_quaternion(R):
    """The quaternion of the previous revision (numpy scalars), kept as the reference."""
    t = np.trace(R)
    k = int(np.argmax([t, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        w = np.sqrt(1 + t) / 2
        q = [(R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w),
             (R[1, 0] - R[0, 1]) / (4 * w), w]
    else:
        i = k - 1
        j, m = (i + 1) % 3, (i + 2) % 3
        v = np.sqrt(max(0.0, 1 + 2 * R[i, i] - t)) / 2
        q = [0.0, 0.0, 0.0, (R[m, j] - R[j, m]) / (4 * v)]
        q[i] = v
        q[j] = (R[j, i] + R[i, j]) / (4 * v)
        q[m] = (R[m, i] + R[i, m]) / (4 * v)
    q = np.asarray(q)
    return q / np.linalg.norm(q)


def test_quaternions_are_bitwise_those_of_the_previous_revision():
    """Stored entries replay only if pybullet gets the very same poses."""
    from scipy.spatial.transform import Rotation

    from pipeline.sim.world import quaternion, rot_z

    rng = np.random.default_rng(9)
    mats = list(Rotation.random(3000, random_state=10).as_matrix())
    mats += [rot_z(a) for a in rng.uniform(-4, 4, 3000)]
    mats += [np.diag(d) for d in ([1.0, -1, -1], [-1.0, 1, -1], [-1.0, -1, 1], [1.0, 1, 1])]
    for R in mats:
        np.testing.assert_array_equal(quaternion(R), _numpy_quaternion(R))


def test_the_shipped_wrist_table_agrees_with_pybullet(lone_arm):
    """Cells of the table in the package, recomputed: a free cell must be free."""
    from pipeline.sim import wrist

    _, arm = lone_arm
    table = FC.wrist_table(arm.ignored_pairs)
    if not (table.state != 0).all():
        pytest.skip("the shipped wrist table does not match this pybullet/model (its stamp "
                    "differs); cells are computed lazily instead")
    upper = table.lower + wrist.STEP * (np.array(table.state.shape) - 1)
    fresh = wrist.WristTable(table.pairs, table.lower, upper, table.bound)
    fresh.state[:] = 0
    rng = np.random.default_rng(12)
    cells = rng.integers(0, table.state.shape, (300, 2))
    for i, k in cells:
        free = fresh._free(table.lower + wrist.STEP * np.array([i, k]))
        assert (table.state[i, k] == 1) == free
    fresh.close()


def test_group_bounds_are_bitwise_the_per_group_ones():
    """SphereRobot.build computes every group's bounding sphere and reach at once; they
    must be the very numbers of the one-group-at-a-time formulas it used before, or the
    scan's answers could move.  A group without spheres is refused (its bounds would be
    another group's)."""
    rng = np.random.default_rng(4)
    for _ in range(200):
        sizes = rng.integers(1, 12, size=rng.integers(1, 14))
        groups = [(int(rng.integers(0, 8)), rng.normal(size=(k, 3)) * rng.uniform(0.01, 2),
                   rng.uniform(0.001, 0.2, size=k), True) for k in sizes]
        lo = np.cumsum([0, *sizes])
        centres = np.concatenate([g[1] for g in groups])
        radii = np.concatenate([g[2] for g in groups])
        gc, gr = FC._group_bounds(centres, radii, lo)
        for g, (_, c, r, _) in enumerate(groups):
            centre, radius = FC._bounding(c, r)
            np.testing.assert_array_equal(gc[g], centre)
            assert gr[g] == radius
        reach = rng.uniform(0, 1, size=8)
        boxes = [(0, np.eye(4), np.full(3, 0.05))]
        root = FC._root([g[0] for g in groups], boxes, reach, (centres, radii, lo))
        for g, (frame, c, r, _) in enumerate(groups):  # the formula, one group at a time
            extent = reach[frame] + float((np.linalg.norm(c, axis=1) + r).max())
            assert root[3][g] == extent + 1e-6  # (_root's own margin)
    with pytest.raises(ValueError, match="at least one sphere"):
        FC.SphereRobot.build([(0, np.zeros((1, 3)), np.array([0.1]), True),
                              (1, np.zeros((0, 3)), np.zeros(0), True)])


def test_path_lengths_are_bitwise_those_of_the_norm_formula():
    """A stored entry's length and score replay only if path_length gives the same
    numbers as the formula the stores were made with."""
    from pipeline.planning import path_length

    rng = np.random.default_rng(5)
    for _ in range(500):
        path = rng.normal(size=(int(rng.integers(2, 300)), int(rng.integers(1, 11))))
        path *= rng.uniform(0.01, 10)
        assert path_length(path) == float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
    assert path_length(np.zeros((1, 7))) == 0.0
    assert path_length([[0.0, 0.0], [3.0, 4.0]]) == 5.0


_NO_MORE_KERNELS = """
import json, sys
import numpy as np
from numba.core.registry import CPUDispatcher
from pipeline import worker
from pipeline.sim import collide, fast_check
from tests import replay

fast_check.compile_kernels()
from pipeline.sim import compiled_rrt
kernels = {f"{m.__name__}.{n}": k for m in (collide, compiled_rrt) for n in dir(m)
           if isinstance(k := getattr(m, n), CPUDispatcher)}
before = {n: len(k.signatures) for n, k in kernels.items()}
for store in replay.stored()["stores"]:
    if store["store"] not in ("grasp_arm.zarr", "grasp_base.zarr", "pick_place.zarr"):
        continue
    config = {k: v for k, v in store["domain"].items() if k != "name"}
    spec = {"name": store["domain"]["name"], "config": config,
            "planner": {**store["planner"], "collision": "spheres"}}
    worker.score_block(spec, 0, [json.dumps(i) for i in store["instances"][:3]],
                       [i["seed"] for i in store["instances"][:3]], np.array(store["theta"]), 0)
# several rows in one check (a path recheck): the pre-check's proofs run on the robot's own
# arrays, not on the packed copies the scan takes
from pipeline.domains.cache import domain_for
from pipeline.sim.panda import LOWER, UPPER
store = next(s for s in replay.stored()["stores"] if s["store"] == "grasp_arm.zarr")
domain = domain_for({"name": "grasp_arm", "config": {}, "planner": store["planner"]})
scene = domain.scene(domain.check_instance(store["instances"][0]))
rows = np.random.default_rng(0).uniform(LOWER, UPPER, (200, 7))
model = fast_check.certified(scene.arms[0])
while len(rows):
    ok, used = model.check(rows)
    rows = rows[used:]
print(json.dumps({n: [str(s) for s in k.signatures[before[n]:]] for n, k in kernels.items()
                  if len(k.signatures) > before[n]}))
"""


def test_planning_compiles_no_kernel_that_compile_kernels_did_not():
    """compile_kernels runs before a planning call's wall-clock cap starts so that numba
    never compiles inside one; that holds only if planning calls the kernels (the scan's
    and the compiled RRT-Connect's) with the argument types it compiled (a read-only
    array is another type).  A fresh process
    plans replay entries of the three Panda domains after compile_kernels."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    done = subprocess.run([sys.executable, "-c", _NO_MORE_KERNELS], cwd=root,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert json.loads(done.stdout.strip().splitlines()[-1]) == {}
