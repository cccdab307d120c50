"""``domain.contacts=fresh``: every exact check of the Panda domains (a fixed arm, the
mobile robot, the rod on its own, the platform against the world when an arm checker is
made) confirms pybullet's cached penetrations afresh, so its answer is a function of the
poses alone (pipeline/sim/contacts.py, docs/contacts.md); ``cached``, the default, keeps
the answers of every store made before; the store identity records the setting only when
it is ``fresh``."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest

from pipeline.configs import (
    LATER_KEYS,
    differing_keys,
    earlier_values,
    identity,
    with_earlier_values,
)
from pipeline.domains.geometry import Box
from pipeline.domains.pick_place.scene import PickPlaceScene
from pipeline.sim import contacts
from pipeline.sim import fast_check as FC
from pipeline.sim.mobile import PLATFORM, PLATFORM_LIFT, MobilePanda
from pipeline.sim.world import add_box, connect
from pipeline.store import ScoreStore
from tests import pipeline_runs as pr
from tests.test_bad_inputs import bad_input, composed
from tests.test_contacts import BESIDE, FAR, ROD, SUNK, TABLE, arm_scene, walk_near_a_box

#: a table for the mobile robot, far from where it stands: TABLE's pose moved by OFFSET
OFFSET = np.array([4.0, 4.0, 0.0])


def _put(client, body, position):
    pb.resetBasePositionAndOrientation(body, list(position), [0, 0, 0, 1],
                                       physicsClientId=client)


def test_identity_records_contacts_only_when_fresh():
    assert LATER_KEYS["domain.contacts"] == "cached"
    for name in ("grasp_arm", "grasp_base", "pick_place"):
        plain = identity(composed(f"domain={name}"))
        cached = identity(composed(f"domain={name}", "domain.contacts=cached"))
        fresh = identity(composed(f"domain={name}", "domain.contacts=fresh"))
        assert plain == fresh and fresh["domain"]["contacts"] == "fresh"  # the default
        assert "contacts" not in cached["domain"]  # as in every store made before the key
        assert differing_keys(cached, fresh) == ["domain.contacts"]
    assert "contacts" not in identity(composed("domain=planar"))["domain"]


def test_a_config_recorded_before_the_key_is_read_as_cached():
    """A store's config (or a replay file's) from before the key existed was computed with
    pybullet's cached contacts: that is how workers and replays read it, not as today's
    default; a domain without the key (planar) gets none."""
    old = {"seed": 1, "domain": {"name": "pick_place", "psi_scale": 1.0}}
    assert with_earlier_values(old)["domain"]["contacts"] == "cached"
    assert with_earlier_values(old)["seed"] == 1 and "contacts" not in old["domain"]
    assert with_earlier_values({"domain": {"name": "grasp_arm", "contacts": "fresh"}})[
        "domain"]["contacts"] == "fresh"
    assert "contacts" not in with_earlier_values({"domain": {"name": "planar"}})["domain"]


def test_only_an_unset_key_takes_the_stores_earlier_value():
    before = identity(composed("domain=pick_place", "domain.contacts=cached"))
    now = identity(composed("domain=pick_place"))
    assert earlier_values(before, now) == {"domain.contacts": "cached"}
    assert earlier_values(before, now, explicit={"domain.contacts"}) == {}
    assert earlier_values(now, now) == {} and earlier_values(None, now) == {}


def test_planar_has_no_contacts_key_and_refuses_it_in_one_line(tmp_path):
    res = pr.run(tmp_path / "s.zarr", "stage=instances", "domain.contacts=fresh")
    bad_input(res, "domain.contacts")
    assert not (tmp_path / "s.zarr").exists()


def test_a_fixed_arm_answers_as_a_client_without_history():
    """Panda.collides_at with fresh contacts on a random walk near a box: every answer is
    the plain answer of a client whose pairs are flushed before each check."""
    client, arm = arm_scene(contacts="fresh")
    walk_near_a_box(arm.collides_at)
    pb.disconnect(client)


def _platform_scene(setting):
    """A mobile robot and a cube beside it: the platform's front face 1.5 mm deep in the
    cube's side, 2 mm of its width over the cube's edge (SINK), or slid 2.5 mm further
    (SLID: 0.5 mm clear of the edge)."""
    client = connect()
    robot = MobilePanda(client, contacts=setting)
    size = 0.6
    cube = (2.0, 1.0, size / 2)
    add_box(client, (size, size, size), cube)
    x = cube[0] - size / 2 - PLATFORM[0] / 2 + 0.0015
    y = cube[1] - size / 2 - PLATFORM[1] / 2 + 0.002
    assert PLATFORM_LIFT + PLATFORM[2] < size  # the platform's side lies inside the cube's
    return client, robot, np.array([x, y, 0.0]), np.array([x, y - 0.0025, 0.0])


@pytest.mark.parametrize("setting, stale", [("cached", True), ("fresh", False)])
def test_the_mobile_robot_forgets_a_penetration_that_is_gone(setting, stale):
    client, robot, sink, slid = _platform_scene(setting)
    assert robot.base_collides(sink)
    assert robot.base_collides(slid) is stale  # cached: the point of the sunk pose
    other, robot2, _, slid2 = _platform_scene(setting)  # no history: free
    assert not robot2.base_collides(slid2)
    pb.disconnect(client)
    pb.disconnect(other)


@pytest.mark.parametrize("setting, stale", [("cached", True), ("fresh", False)])
def test_the_rod_on_its_own_forgets_a_penetration_that_is_gone(setting, stale):
    scene = PickPlaceScene([Box(TABLE, tuple(OFFSET), 0.0)], 0.5, setting)
    client = scene.client_id
    scene.rod = add_box(client, ROD, tuple(np.add(FAR, OFFSET)), movable=True)
    _put(client, scene.rod, np.add(SUNK, OFFSET))
    assert scene.rod_collides()
    _put(client, scene.rod, np.add(BESIDE, OFFSET))
    assert scene.rod_collides() is stale
    pb.disconnect(client)


@pytest.mark.parametrize("fresh", [False, True])
def test_the_platforms_touch_test_follows_the_setting(fresh):
    """``_touches_world`` (whether a part of the robot that stands still touches the world
    when an arm checker is made) asks the fresh question under the setting."""
    client = connect()
    add_box(client, TABLE, (0.0, 0.0, 0.0))
    rod = add_box(client, ROD, FAR, movable=True)
    _put(client, rod, SUNK)
    assert FC._touches_world(client, rod, set(), fresh)
    _put(client, rod, BESIDE)
    assert FC._touches_world(client, rod, set(), fresh) is not fresh
    assert not contacts.collides(client, rod)
    pb.disconnect(client)


#: a grasp_arm store of 3 x 4 entries, planned by one worker
TINY = ("domain=grasp_arm", "instances.n=3", "constraints.m=4", "store.block_instances=3",
        "store.block_constraints=4", "cluster.n_workers=1")


def test_a_default_store_records_fresh_and_refuses_to_go_on_cached(tmp_path):
    """The default reaches the store (identity and config, which workers and replays plan
    with), and a run that asks for ``cached`` refuses the store in one line naming the key,
    leaving it as it was."""
    store = tmp_path / "s.zarr"
    res = pr.run(store, *TINY)
    assert res.returncode == 0, res.stderr
    attrs = ScoreStore(store).attrs
    assert attrs["identity"]["domain"]["contacts"] == "fresh"
    assert attrs["config"]["domain"]["contacts"] == "fresh"
    before = pr.matrix(store)
    res = pr.run(store, *TINY, "domain.contacts=cached")
    bad_input(res, "domain.contacts")
    assert pr.same_matrix(before, pr.matrix(store))


def test_a_store_made_before_the_default_changed_resumes_cached(tmp_path):
    """A store made under ``cached`` without recording it (every store before 2026-11-27),
    stopped after its first stage: the same command, now under the ``fresh`` default,
    finishes it with ``cached`` and says so; asking for ``fresh`` on it is refused."""
    store = tmp_path / "s.zarr"
    res = pr.run(store, *TINY, "domain.contacts=cached", "stage=instances")
    assert res.returncode == 0, res.stderr
    made = ScoreStore(store).attrs["identity"]
    assert "contacts" not in made["domain"]
    res = pr.run(store, *TINY, "domain.contacts=fresh")
    bad_input(res, "domain.contacts")
    res = pr.run(store, *TINY)
    assert res.returncode == 0, res.stderr
    assert "made with domain.contacts=cached" in " ".join(res.stdout.split())
    attrs = ScoreStore(store).attrs
    assert attrs["identity"] == made and attrs["config"]["domain"]["contacts"] == "cached"
    assert attrs["stages"]["scores"]["finished"]
    assert pr.run(store, *TINY).returncode == 0  # complete: nothing to do, still cached
