"""pybullet's cached contacts depend on the check history; pipeline.sim.contacts does not."""

import numpy as np
import pybullet as pb
import pytest

from pipeline.sim import contacts
from pipeline.sim.panda import HOME, LOWER, UPPER, Panda
from pipeline.sim.world import add_box, connect

TABLE = (0.6, 0.6, 0.6)  # full size, centred at the origin: top face at z = 0.3
ROD = (0.4, 0.04, 0.04)  # contact breaking threshold about 4 mm (2 % of its radius)
#: the rod 1.5 mm deep in the table's top, its end 2 mm over the table's edge ...
SUNK = (0.3 + 0.2 - 0.002, 0.0, 0.3 + 0.02 - 0.0015)
#: ... then slid 2.5 mm along x: its end 0.5 mm beyond the edge, nothing touches
BESIDE = (0.3 + 0.2 + 0.0005, 0.0, 0.3 + 0.02 - 0.0015)
FAR = (2.0, 0.0, 0.3)


def _scene():
    client = connect()
    add_box(client, TABLE, (0.0, 0.0, 0.0))
    rod = add_box(client, ROD, FAR, movable=True)
    return client, rod


def _put(client, body, position):
    pb.resetBasePositionAndOrientation(body, position, [0, 0, 0, 1], physicsClientId=client)


@pytest.fixture
def scene():
    client, rod = _scene()
    yield client, rod
    pb.disconnect(client)


def test_cached_contacts_report_a_penetration_that_is_not_there(scene):
    client, rod = scene
    _put(client, rod, SUNK)
    assert contacts.cached_collides(client, rod)
    _put(client, rod, BESIDE)
    assert contacts.cached_collides(client, rod)  # the stale points of the sunk pose
    depth = min(pt[8] for pt in pb.getContactPoints(bodyA=rod, physicsClientId=client))
    assert depth == pytest.approx(-0.0015, abs=1e-5)
    gap = [pt[8] for pt in pb.getClosestPoints(rod, 0, 0.01, physicsClientId=client)]
    assert min(gap) == pytest.approx(0.0005, abs=1e-4)  # fresh: 0.5 mm apart
    assert not contacts.collides(client, rod)
    other, other_rod = _scene()  # the same pose in a client with no history
    _put(other, other_rod, BESIDE)
    assert not contacts.cached_collides(other, other_rod)
    pb.disconnect(other)


@pytest.mark.parametrize("history", [[], [FAR], [SUNK], [SUNK, FAR], [BESIDE, SUNK]])
@pytest.mark.parametrize("target, expected", [(BESIDE, False), (SUNK, True)])
def test_fresh_answer_ignores_the_history(scene, history, target, expected):
    client, rod = scene
    for position in history:
        _put(client, rod, position)
        contacts.collides(client, rod)
    _put(client, rod, target)
    assert contacts.collides(client, rod) is expected


def arm_scene(**panda):
    """A Panda (``panda``: its keyword arguments) in a client of its own, near a box."""
    client = connect()
    arm = Panda(client, [0.0, 0.0, 0.0], **panda)
    add_box(client, (0.3, 0.8, 0.4), (0.55, 0.0, 0.2))
    return client, arm


def walk_near_a_box(answer) -> list[bool]:
    """A 150-step random walk of the arm of :func:`arm_scene` near its box: at every step
    ``answer(q)`` (the check under test, on an arm of its own) must be the plain answer in
    a client where every check is the first (its manifolds flushed by moving the arm away
    and back).  Returns the answers; the walk touches the box and leaves it."""
    f, first = arm_scene()
    base = pb.getBasePositionAndOrientation(first.body, physicsClientId=f)
    rng = np.random.default_rng(1)
    q, answers = HOME.copy(), []
    for _ in range(150):
        q = np.clip(q + rng.normal(0.0, 0.08, 7), LOWER, UPPER)
        answers.append(answer(q))
        assert answers[-1] == first.collides_at(q)
        pb.resetBasePositionAndOrientation(first.body, [50.0, 0.0, 0.0], base[1],
                                           physicsClientId=f)
        pb.performCollisionDetection(physicsClientId=f)
        pb.resetBasePositionAndOrientation(first.body, *base, physicsClientId=f)
    pb.disconnect(f)
    assert 10 < sum(answers) < 140
    return answers


def test_panda_answers_agree_with_a_client_without_history():
    """The fresh answer (self-collision on, base link ignored) on the walk of
    :func:`walk_near_a_box`."""
    c, arm = arm_scene()
    not_base = lambda pt: pt[3] == -1  # noqa: E731

    def fresh(q) -> bool:
        arm.set(q)
        return contacts.collides(c, arm.body, not_base)

    walk_near_a_box(fresh)
    pb.disconnect(c)


def test_box_pairs_are_confirmed_like_pybullets_box_test(scene):
    """Rod poses around the table's top edge, each checked with no history (the rod moved
    away first, so the pair and its manifold are gone): the separating-axis confirmation
    equals pybullet's box-box contacts, where GJK (``getClosestPoints``), which rounds the
    boxes' edges by the collision margin, calls some overlapping poses apart."""
    client, rod = scene
    rng = np.random.default_rng(0)
    same = gjk_apart = overlapping = 0
    for _ in range(400):
        position = np.array(BESIDE) + rng.normal(0.0, [0.003, 0.05, 0.002])
        turn = pb.getQuaternionFromEuler(rng.normal(0.0, 0.05, 3))
        pb.resetBasePositionAndOrientation(rod, FAR, [0, 0, 0, 1], physicsClientId=client)
        pb.performCollisionDetection(physicsClientId=client)
        pb.resetBasePositionAndOrientation(rod, position.tolist(), turn, physicsClientId=client)
        plain = contacts.cached_collides(client, rod)
        exact = contacts.boxes_overlap(contacts.box_of(client, rod, -1),
                                       contacts.box_of(client, 0, -1))
        gjk = any(pt[8] < 0 for pt in pb.getClosestPoints(rod, 0, 0.0, physicsClientId=client))
        same += plain == exact
        overlapping += exact
        gjk_apart += exact and not gjk
    assert same == 400
    assert 40 < overlapping < 360
    assert gjk_apart > 0


def test_self_collisions_are_confirmed():
    """Link pairs of one body are confirmed too: random arm configurations (far apart, so
    no cached point survives from one to the next) get the plain answer, many of them
    self-collisions."""
    client = connect()
    arm = Panda(client, [0.0, 0.0, 0.0])
    not_base = lambda pt: pt[3] == -1  # noqa: E731
    rng = np.random.default_rng(0)
    hits = 0
    for _ in range(300):
        arm.set(rng.uniform(LOWER, UPPER))
        fresh = contacts.collides(client, arm.body, not_base)
        assert fresh == contacts.cached_collides(client, arm.body, not_base)
        hits += fresh
    assert hits > 20
    pb.disconnect(client)
