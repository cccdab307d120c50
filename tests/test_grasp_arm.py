"""The grasp-and-arm domain: two Pandas, a table with a shelf, 162 grasps."""

import json
import subprocess
import sys

import numpy as np
import pytest

from pipeline.domains import InstanceError, load_domain
from pipeline.domains.grasps import grasp_set
from pipeline.planning import Status, path_is_free

TARGET = {"size": [0.04, 0.04, 0.12], "position": [0.42, 0.3, 0.061], "yaw": 0.0}
OPEN = {"domain": "grasp_arm", "seed": 0, "target": TARGET, "obstacles": []}


def _walls(cx, cy, half, height):
    """Four walls and a lid enclosing (cx, cy) on the table."""
    t = 0.01
    walls = [([2 * half, t, height], [cx, cy + half, height / 2]),
             ([2 * half, t, height], [cx, cy - half, height / 2]),
             ([t, 2 * half, height], [cx + half, cy, height / 2]),
             ([t, 2 * half, height], [cx - half, cy, height / 2]),
             ([2 * half + t, 2 * half + t, t], [cx, cy, height + t / 2])]
    return [{"size": s, "position": p, "yaw": 0.0} for s, p in walls]


ENCLOSED = {"domain": "grasp_arm", "seed": 0, "target": TARGET,
            "obstacles": _walls(0.42, 0.3, 0.15, 0.3)}


@pytest.fixture(scope="module")
def domain():
    return load_domain("grasp_arm")


def _index(arm, approach, rotation=0.0, depth=0.0):
    for k, g in enumerate(grasp_set()):
        if (g.arm == arm and np.allclose(g.approach, approach) and g.rotation == rotation
                and g.depth == depth):
            return k
    raise KeyError


def test_the_grasp_set_is_162_distinct_constraints(domain):
    cs = domain.constraints()
    assert cs.features.shape == (162, 6)
    assert len({tuple(r) for r in cs.features}) == 162
    assert (cs.source_instance == -1).all()
    for k in (0, 57, 161):  # a feature row names the same grasp as its index
        assert domain.constraint(cs.features[k]) is domain.constraint(k)


def test_pregrasp_is_ten_centimetres_back_along_the_approach(domain):
    inst = domain.check_instance(OPEN)
    g = domain.constraint(_index(0, [0, 0, -1]))
    pre, _ = domain.pregrasp_pose(inst, g)
    np.testing.assert_allclose(pre, np.array(TARGET["position"]) + [0, 0, 0.10], atol=1e-12)


def test_an_unobstructed_top_grasp_is_feasible(domain):
    res = domain.plan(OPEN, _index(0, [0, 0, -1]), seed=1)
    assert res.status is Status.OK and res.feasible and res.length > 0
    assert res.path.shape[1] == 7 and res.score == -res.length


def test_an_enclosed_object_is_infeasible_for_every_constraint(domain):
    statuses = {domain.plan(ENCLOSED, j, seed=j).status for j in range(162)}
    assert Status.OK not in statuses
    assert statuses <= {Status.NO_IK, Status.GOAL_IN_COLLISION, Status.BUDGET_EXHAUSTED}


def test_paths_are_collision_free_when_rechecked_at_0_01_rad(domain):
    checked = 0
    for seed in range(4):
        inst = domain.sample_instance(seed)
        raw = domain.raw_plan(inst, seed=seed)
        if not raw.plan.feasible:
            continue
        arm = int(raw.constraint[0])
        scene = domain.build_scene(inst)
        try:
            assert path_is_free(raw.plan.path, scene.arms[arm].check, resolution=0.01)
        finally:
            scene.close()
        checked += 1
    assert checked >= 2


def test_same_call_is_bitwise_identical_in_another_process_and_order(domain):
    inst = domain.sample_instance(3)
    j = next(j for j in range(162) if domain.plan(inst, j, seed=5).feasible)
    here = domain.plan(inst, j, seed=5)
    domain.plan(domain.sample_instance(4), 10, seed=1)  # something else in between
    assert domain.plan(inst, j, seed=5).path.tobytes() == here.path.tobytes()
    code = ("import json,sys; from pipeline.domains import load_domain; "
            "d = load_domain('grasp_arm'); r = d.plan(json.loads(sys.argv[1]), int(sys.argv[2]),"
            " seed=5); print(r.path.tobytes().hex(), r.checks)")
    out = subprocess.run([sys.executable, "-c", code, json.dumps(inst), str(j)],
                         capture_output=True, text=True, check=True).stdout.split()
    assert out == [here.path.tobytes().hex(), str(here.checks)]


def test_results_do_not_depend_on_the_order_of_calls(domain):
    """IK leaves an arm wherever its last attempt ended: the next call must not see that."""
    inst = domain.sample_instance(3)  # an instance where a displaced arm used to matter

    def run(order):
        out = {}
        for j in order:
            r = domain.plan(inst, j, seed=j)
            out[j] = (r.status, r.path.tobytes(), r.checks)
        return out

    forward = run(range(162))
    assert run(reversed(range(162))) == forward
    assert Status.START_IN_COLLISION not in {v[0] for v in forward.values()}


def test_instances_vary_enough_that_no_grasp_wins_everywhere(domain):
    F = np.array([[domain.plan(domain.sample_instance(i), j, seed=j).feasible
                   for j in range(162)] for i in range(24)])
    assert F.any(axis=0).sum() >= 60  # many columns feasible somewhere
    assert F.mean(axis=0).max() < 1.0  # none feasible everywhere
    assert F.any(axis=1).sum() >= 18


def test_sampled_instances_are_json_and_determined_by_the_seed(domain):
    a = domain.sample_instance(11)
    assert a == domain.sample_instance(11) and json.loads(json.dumps(a)) == a
    assert a != domain.sample_instance(12)
    assert a["target"]["surface"] in {"table_front", "under_shelf", "shelf_top"}
    assert 0 <= len(a["obstacles"]) <= 20


@pytest.mark.parametrize("spec, words", [
    ({"seed": 0, "obstacles": []}, "target"),
    ({"seed": 0, "target": {"size": [1, 1], "position": [0, 0, 0], "yaw": 0},
      "obstacles": []}, "target.size"),
    ({"seed": 0, "target": TARGET, "obstacles": [{"size": [1, 1, 1], "yaw": 0}]},
     "position"),
    ({"seed": 0, "target": dict(TARGET, size=[0.1, -0.1, 0.1]), "obstacles": []}, "positive"),
])
def test_malformed_specs_are_refused_naming_the_field(domain, spec, words):
    with pytest.raises(InstanceError, match=words):
        domain.plan(spec, 0)


def test_constraint_out_of_range_is_refused(domain):
    with pytest.raises(ValueError, match="out of range"):
        domain.plan(OPEN, 162)
    with pytest.raises(ValueError, match="neither an index"):
        domain.plan(OPEN, [9.0] * 6)


def test_a_simulator_failure_becomes_a_status(domain, monkeypatch):
    def boom(*a, **k):
        raise RuntimeError("simulated pybullet failure")

    monkeypatch.setattr(domain, "scene", boom)
    res = domain.plan(OPEN, 0)
    assert res.status is Status.ERROR and "simulated pybullet failure" in res.error


def test_render_is_a_non_empty_image(domain, tmp_path):
    import matplotlib.image as mpimg

    j = _index(0, [0, 0, -1])
    res = domain.plan(OPEN, j, seed=1)
    out = domain.render(OPEN, res, path=tmp_path / "scene.png", constraint=j)
    img = mpimg.imread(out)
    assert img.shape[:2] == (360, 480) and img[..., :3].std() > 0.05
    # the target is drawn in red
    red = (img[..., 0] > 0.6) & (img[..., 1] < 0.3) & (img[..., 2] < 0.3)
    assert red.sum() > 20
