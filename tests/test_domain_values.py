"""Every domain's and planner's values are checked by the up-front validation (declared
with their schemas), so a bad value is refused in one line before Hydra or a stage writes
anything (issue 24, case 8)."""

import os

import pytest

from pipeline.domains.pick_place import world
from pipeline.domains.pick_place.steps import ORDERS
from pipeline.domains.schemas import PICK_PLACE_DOOR_MAX, PICK_PLACE_ORDERS
from pipeline.validation import ConfigError, validate
from tests import pipeline_runs as pr
from tests.test_bad_inputs import bad_input, composed


@pytest.mark.parametrize("overrides, words", [
    (("domain=planar", "domain.obstacles_min=9", "domain.obstacles_max=2"), "obstacles_min"),
    (("domain=planar", "domain.start=[0,5]"), "domain.start"),
    (("domain=planar", "domain.obstacle_size_min=0"), "obstacle_size_min"),
    (("domain=grasp_arm", "domain.obstacles_min=9", "domain.obstacles_max=2"),
     "obstacles_min"),
    (("domain=grasp_arm", "domain.obstacle_height=[0.2,0.1]"), "domain.obstacle_height"),
    (("domain=grasp_arm", "domain.ik_restarts=0"), "ik_restarts"),
    (("domain=grasp_base", "domain.reach_radius=0"), "reach_radius"),
    (("domain=grasp_base", "domain.obstacles=-1"), "obstacles"),
    (("domain=pick_place", "domain.door_width=5"), "door_width"),
    (("domain=pick_place", "domain.step_order=fastest"), "step_order"),
    (("domain=pick_place", "domain.rod_lengths=[]"), "rod_lengths"),
    (("domain=pick_place", "domain.raw_grasps=0"), "raw_"),
    (("domain=grasp_arm", "domain.ik=fast"), "domain.ik must be one of damped, analytic"),
    (("domain=pick_place", "domain.ik=numeric"), "domain.ik"),
    (("domain=grasp_base", "domain.contacts=stale"),
     "domain.contacts must be one of cached, fresh"),
    (("planner=trajopt", "planner.trajopt_waypoints=2"), "trajopt_waypoints"),
    (("planner=trajopt", "planner.trajopt_trust_radius=0"), "trajopt_"),
])
def test_domain_and_planner_values_are_checked_up_front(overrides, words):
    with pytest.raises(ConfigError, match=words):
        validate(composed("stage=instances", "instances.n=10", *overrides))


def test_a_bad_domain_value_writes_nothing(tmp_path):
    store = tmp_path / "s.zarr"
    res = pr.run(store, "stage=generate", "domain.obstacles_min=9", "domain.obstacles_max=2")
    bad_input(res, "obstacles_min")
    assert os.listdir(tmp_path) == []  # no store, no outputs/ of Hydra


def test_the_schemas_constants_match_the_domain():
    assert PICK_PLACE_ORDERS == tuple(ORDERS)
    rooms = world.ROOMS
    assert PICK_PLACE_DOOR_MAX == pytest.approx(rooms[3] - rooms[2] - 0.2)
