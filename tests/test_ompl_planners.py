"""``planner=ompl``: OMPL's geometric planners by name through one adapter
(pipeline/planning/ompl_adapter.py), each accepted one deterministic under a counted budget
(the same checks and path call after call and process after process), parameters passed
through, the others refused in one line (issue 25, item 2)."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys

import numpy as np
import pytest

from pipeline import configs
from pipeline.domains.planar import PlanarScene
from pipeline.planning import Status, path_is_free
from pipeline.planning.ompl_adapter import ALGORITHMS, REFUSED
from pipeline.planning.ompl_planner import OmplPlanner
from pipeline.planning.rrt_connect import RRTConnect
from pipeline.planning.settings import OmplSettings, RRTConnectSettings
from tests import pipeline_runs as pr
from tests.test_bad_inputs import bad_input

#: a wall from the floor to y = 6 between start and goal, and a block above it
BOXES = np.array([[5.0, 3.0, 1.0, 6.0], [2.0, 7.0, 1.5, 1.5]])
START, GOAL = np.array([1.0, 2.0]), np.array([9.0, 2.0])


def scene() -> PlanarScene:
    return PlanarScene(BOXES, 0.25, lower=np.array([0.25, 0.25]), upper=np.array([9.75, 9.75]))


def results(algorithm: str, seeds=range(3), **settings) -> list:
    planner = OmplPlanner(OmplSettings(algorithm=algorithm, collision="exact", **settings))
    return [planner.plan(scene(), START, GOAL, seed=seed) for seed in seeds]


def digest(res: list) -> str:
    h = hashlib.sha256()
    for r in res:
        h.update(f"{r.status} {r.checks}".encode())
        if r.path is not None:
            h.update(np.ascontiguousarray(r.path).tobytes())
    return h.hexdigest()


def digests() -> dict[str, str]:
    return {a: digest(results(a)) for a in ALGORITHMS}


def test_every_accepted_algorithm_is_deterministic_in_and_across_processes():
    here = digests()
    assert digests() == here
    code = ("import json; from tests.test_ompl_planners import digests; "
            "print(json.dumps(digests()))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=pr.env(), cwd=pr.env()["PYTHONPATH"], check=True).stdout
    assert json.loads(out.strip().splitlines()[-1]) == here
    assert len(set(here.values())) >= len(ALGORITHMS) - 2  # FMT and BFMT may both fail


@pytest.mark.parametrize("algorithm", ["RRT", "RRTstar", "BITstar", "KPIECE1", "LBKPIECE1"])
def test_paths_are_free_and_checks_within_the_budget(algorithm):
    res = results(algorithm, max_checks=20_000)
    assert any(r.feasible for r in res)
    for r in res:
        assert r.checks <= 20_000
        if r.feasible:
            assert path_is_free(r.path, scene(), resolution=0.002)
            np.testing.assert_array_equal(r.path[[0, -1]], [START, GOAL])


def test_optimising_planners_stop_at_their_first_solution():
    for algorithm in ("RRTstar", "BITstar"):
        assert all(r.feasible and r.checks < 20_000 for r in results(algorithm))


def test_ompl_rrtconnect_is_rrt_connect_bit_for_bit():
    ours = RRTConnect(RRTConnectSettings(collision="exact"))
    theirs = [ours.plan(scene(), START, GOAL, seed=s) for s in range(3)]
    assert digest(results("RRTConnect")) == digest(theirs)


def test_parameters_reach_the_planner():
    plain = results("RRT")
    assert digest(results("RRT", params={"goal_bias": 0.5})) != digest(plain)
    assert digest(results("RRT", range=0.5)) != digest(plain)
    assert digest(results("RRT", range=0.5)) == digest(results("RRT", params={"range": 0.5}))
    no_shortcuts = results("RRT", shortcut_attempts=0)
    assert [len(r.path) for r in no_shortcuts] >= [len(r.path) for r in plain]


@pytest.mark.parametrize("planner, words", [
    ({"algorithm": "PRM"}, "PRM is refused: " + REFUSED["PRM"].split(":")[0]),
    ({"algorithm": "Bogus"}, "planner.algorithm=Bogus"),
    ({"algorithm": "RRT", "params": {"rewire_factor": 1.0}}, "no parameter rewire_factor"),
])
def test_refused_algorithms_and_parameters_name_the_key(planner, words):
    with pytest.raises(ValueError, match=words):
        configs.planner_settings({"name": "ompl", **planner})


def test_a_refused_algorithm_is_one_line_and_exit_2(tmp_path):
    res = pr.run(tmp_path / "s.zarr", "stage=generate", "planner=ompl",
                 "planner.algorithm=PRMstar")
    bad_input(res, "PRMstar", "second thread")


def test_a_budget_spent_before_the_goal_is_reported():
    res = results("KPIECE1", seeds=[0], max_checks=300)[0]
    assert res.status is Status.BUDGET_EXHAUSTED and res.checks == 300


def test_an_unknown_parameter_on_the_command_line_is_one_line_and_exit_2(tmp_path):
    res = pr.run(tmp_path / "s.zarr", "stage=generate", "planner=ompl",
                 "planner.algorithm=RRT", "+planner.params.rewire_factor=1.0")
    bad_input(res, "RRT has no parameter rewire_factor")
