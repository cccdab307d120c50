"""``domain.ik=analytic`` (frankik's closed-form Panda IK, pipeline/sim/analytic_ik.py):
its solutions reach the pose within the domain's tolerances and the joint limits (checked
with pybullet's own forward kinematics), its outcomes mean what the damped path's mean,
its stores are the same in every process, and the store identity records it while stores
made before the key existed (``damped``) still resume and replay."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.configs import LATER_KEYS, differing_keys, identity
from pipeline.domains import load_domain
from pipeline.domains.ik import solve_ik
from pipeline.planning import Status
from pipeline.sim import analytic_ik
from pipeline.sim import panda as P
from pipeline.store import THETA, ScoreStore
from pipeline.worker import entry_seed
from tests import pipeline_runs as pr
from tests import replay
from tests.test_bad_inputs import bad_input, composed

pytest.importorskip("frankik")

#: a tiny grasp_arm store: 3 instances x 4 constraints, one block
TINY = ("domain=grasp_arm", "instances.n=3", "constraints.m=4", "store.block_instances=3",
        "store.block_constraints=4", "cluster.n_workers=1")


@pytest.fixture(scope="module")
def poses():
    """Every pre-grasp pose within reach of its arm in four grasp_arm instances."""
    domain = load_domain("grasp_arm")
    out = []
    for seed in range(4):
        inst = domain.check_instance(domain.sample_instance(seed))
        scene = domain.scene(inst)
        for g in domain.grasps:
            pos, orn = domain.pregrasp_pose(inst, g)
            if np.linalg.norm(pos - scene.arms[g.arm].shoulder) <= P.REACH:
                out.append((scene.arms[g.arm], pos, np.asarray(orn)))
    yield out
    domain.close()


def on_pose(arm, q, pos, orn) -> bool:
    p, o = arm.tcp_pose(q)
    return bool(np.linalg.norm(p - pos) <= P.IK_POS_TOL and P._angle(o, orn) <= P.IK_ANG_TOL)


def test_every_analytic_solution_reaches_the_pose_within_the_limits(poses):
    solved = 0
    for arm, pos, orn in poses:
        sols = analytic_ik.candidates(arm, pos, orn)
        solved += len(sols) > 0
        for q in sols[:: max(1, len(sols) // 8)]:  # spread over the candidates
            assert (q >= P.LOWER).all() and (q <= P.UPPER).all()
            assert on_pose(arm, q, pos, orn), (pos, orn, q)
        arm.set(P.HOME)
    # most poses within reach have solutions (the damped path solves fewer, bench_ik.py)
    assert len(poses) > 200 and solved > 0.5 * len(poses)


def test_the_analytic_outcome_is_collision_free_on_the_pose_and_keeps_the_statuses(poses):
    seen = set()
    for k, (arm, pos, orn) in enumerate(poses[::3]):
        out = solve_ik(arm, pos, orn, [k, 7], 4, "analytic")
        seen.add(out.status)
        if out.status is Status.OK:
            assert on_pose(arm, out.q, pos, orn) and not arm.collides_at(out.q)
            assert 1 <= out.checks <= 4
        elif out.status is Status.GOAL_IN_COLLISION:
            assert 1 <= out.checks <= 4
        else:
            assert out.status is Status.NO_IK and out.checks == 0
            assert len(analytic_ik.candidates(arm, pos, orn)) == 0
        # every candidate colliding: GOAL_IN_COLLISION after at most `tries` checks
        if len(analytic_ik.candidates(arm, pos, orn)):
            q, checks, reached = arm.analytic_ik(pos, orn, 3, collides=lambda q: True)
            assert q is None and reached and 1 <= checks <= 3
        arm.set(P.HOME)
    assert {Status.OK, Status.NO_IK} <= seen


def test_the_choice_depends_on_the_pose_alone(poses):
    arm, pos, orn = next(p for p in poses if len(analytic_ik.candidates(*p)))
    a = solve_ik(arm, pos, orn, [1, 7], 4, "analytic")
    b = solve_ik(arm, pos, orn, [99, 7], 4, "analytic")
    assert a.status == b.status and np.array_equal(a.q, b.q) and a.checks == b.checks


def test_identity_records_ik_only_when_it_is_not_the_older_behaviour():
    assert LATER_KEYS["domain.ik"] == "damped"
    plain = identity(composed("domain=grasp_arm"))
    damped = identity(composed("domain=grasp_arm", "domain.ik=damped"))
    analytic = identity(composed("domain=grasp_arm", "domain.ik=analytic"))
    assert plain == damped and "ik" not in damped["domain"]
    assert analytic["domain"]["ik"] == "analytic"
    assert differing_keys(damped, analytic) == ["domain.ik"]
    assert "ik" not in identity(composed("domain=planar"))["domain"]


def test_planar_has_no_ik_and_refuses_the_key_in_one_line(tmp_path):
    res = pr.run(tmp_path / "s.zarr", "stage=instances", "domain.ik=analytic")
    bad_input(res, "domain.ik")
    assert not (tmp_path / "s.zarr").exists()


def test_analytic_stores_are_the_same_in_every_process_and_old_stores_resume(tmp_path):
    """Two analytic stores and a damped one made at once (separate processes, each with its
    own worker); the damped one is then made to look like a store of the code before
    ``domain.ik`` existed (no ``ik`` in its config), and resumes "already complete"."""
    stores = {name: tmp_path / f"{name}.zarr" for name in ("a1", "a2", "old")}
    runs = {name: pr.start(path, *TINY, *(() if name == "old" else ("domain.ik=analytic",)))
            for name, path in stores.items()}
    for name, proc in runs.items():
        out, _ = proc.communicate(timeout=600)
        assert proc.returncode == 0, (name, out)
    a1, a2 = pr.matrix(stores["a1"]), pr.matrix(stores["a2"])
    assert pr.same_matrix(a1, a2)
    attrs = ScoreStore(stores["a1"]).attrs
    assert attrs["identity"]["domain"]["ik"] == "analytic"

    old = ScoreStore(stores["old"])
    assert "ik" not in old.attrs["identity"]["domain"]
    config = json.loads(json.dumps(old.attrs["config"]))
    assert config["domain"].pop("ik") == "damped"
    old.set_attrs(config=config)  # as the code before domain.ik wrote it
    before = pr.matrix(stores["old"])
    res = pr.run(stores["old"], *TINY)
    assert res.returncode == 0, res.stderr
    assert "scores: already complete" in res.stdout and "migrated" not in res.stdout
    assert pr.same_matrix(before, pr.matrix(stores["old"]))

    # its entries replay from the stored config (no ik, so damped) in this process
    store = ScoreStore(stores["old"])
    domain = replay.domain_of(store.attrs["config"])
    assert domain.config.ik == "damped"
    seeds, theta = store.instance_seeds(), store.array(THETA)[...]
    for i, spec in enumerate(store.instance_specs()):
        for j, row in enumerate(theta):
            got = domain.plan(json.loads(spec), row, seed=entry_seed(0, int(seeds[i]), j))
            assert (int(got.status), got.checks, got.feasible) == (
                before["status"][i, j], before["checks"][i, j], before["feasible"][i, j])
            if got.feasible:
                assert got.score == pytest.approx(before["score"][i, j], rel=1e-9, abs=1e-12)
    domain.close()

    # an analytic run refuses the damped store, naming the key
    res = pr.run(stores["old"], *TINY, "domain.ik=analytic")
    bad_input(res, "domain.ik")
