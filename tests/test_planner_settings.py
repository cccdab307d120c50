"""Each planner declares its own settings (pipeline/planning/settings.py); a store's identity
holds the chosen planner's keys only, so stores made before that (whose identity holds every
planner's keys) still resume, and a key added to another planner changes no store (issue 25,
item 1).  Planner plug-ins (entry-point group box_planning.planners) work with
``planner=<name>`` and their keys are checked up front (item 4)."""

from __future__ import annotations

import copy
import dataclasses
import subprocess
import sys
import tarfile
import textwrap
from pathlib import Path

import numpy as np
import pytest
import zarr
from hydra import compose, initialize_config_dir

from pipeline import configs
from pipeline.planning import settings as S
from pipeline.planning.registry import make_planner, settings_class
from pipeline.planning.rrt_connect import RRTConnect
from pipeline.planning.trajopt import TrajOpt, TrajOptOptions
from tests import pipeline_runs as pr
from tests.test_bad_inputs import bad_input, composed

#: the planner part of identities made by the code before per-planner settings (7ee6b00)
OLD_PLANNER = {"max_checks": 20000, "wall_cap_s": 10.0, "resolution": 0.01, "range": 0.0,
               "shortcut_attempts": 40, "trajopt_waypoints": 20, "trajopt_margin": 0.02,
               "trajopt_penalty": 10.0, "trajopt_penalty_rounds": 4, "trajopt_iterations": 30,
               "trajopt_trust_radius": 0.3}

#: the identity of a small planar rrt_connect store made by that code (its root attribute)
OLD_PLANAR = {
    "domain": {"name": "planar", "size": 10.0, "robot_radius": 0.25, "start": [1.0, 5.0],
               "goal": [9.0, 5.0], "obstacles_min": 4, "obstacles_max": 12,
               "obstacle_size_min": 0.5, "obstacle_size_max": 3.0, "raw_max_tries": 50},
    "planner": {"name": "rrt_connect", **OLD_PLANNER, "max_checks": 4000},
    "seed": 0, "instances": {"n": 6}, "constraints": {"m": 5},
    "store.block_instances": 6, "store.block_constraints": 5}

#: a store of that identity made by that code (7ee6b00), in /tmp/fx:
#: python -m pipeline stage=generate <SMALL> store.path=/tmp/fx/flat_settings.zarr
FLAT_STORE = Path(__file__).parent / "data" / "flat_planner_settings_planar.tar.gz"

SMALL = ("domain=planar", "instances.n=6", "constraints.m=5", "store.block_instances=6",
         "store.block_constraints=5", "progress=false", "cluster.n_workers=1",
         "planner.max_checks=4000")


def composed_identity(*overrides: str) -> dict:
    configs.register_configs()
    with initialize_config_dir(config_dir=str(configs.CONF_DIR), version_base=None):
        return configs.identity(compose(config_name="config", overrides=list(overrides)))


def run(store, *overrides):
    return subprocess.run([sys.executable, "-m", "pipeline", *SMALL,
                              f"store.path={store}", *overrides], capture_output=True,
                             text=True, cwd=store.parent, env=pr.env(), timeout=600)


def test_a_store_made_before_per_planner_settings_resumes_as_it_is(tmp_path):
    with tarfile.open(FLAT_STORE) as tar:
        tar.extractall(tmp_path, filter="data")
    store = tmp_path / "flat_settings.zarr"
    assert zarr.open_group(store, mode="r", use_consolidated=False).attrs["identity"] \
        == OLD_PLANAR
    assert composed_identity(*SMALL) != OLD_PLANAR  # today's identity lacks trajopt_*
    before = pr.matrix(store)
    again = run(store, "stage=generate")
    assert again.returncode == 0, again.stderr
    assert "scores: already complete" in again.stdout + again.stderr
    root = zarr.open_group(store, mode="r", use_consolidated=False)
    assert root.attrs["identity"] == OLD_PLANAR  # not rewritten
    assert pr.same_matrix(before, pr.matrix(store))
    fresh = tmp_path / "fresh.zarr"  # today's code computes the same D
    assert run(fresh, "stage=generate").returncode == 0
    assert pr.same_matrix(before, pr.matrix(fresh))
    other = run(store, "stage=generate", "planner.shortcut_attempts=5")
    assert other.returncode != 0 and "planner.shortcut_attempts" in other.stderr


def test_old_identities_of_every_planner_match_todays():
    for name, domain in (("rrt_connect", "planar"), ("trajopt", "grasp_arm"),
                         ("noop", "grasp_arm")):
        today = composed_identity(f"domain={domain}", f"planner={name}")
        old = copy.deepcopy(today)
        old["planner"] = {"name": name, **OLD_PLANNER}
        assert configs.differing_keys(old, today) == [], name
        assert configs.matching_identity(old, today) is old
        changed = copy.deepcopy(old)
        changed["planner"]["max_checks"] = 5
        assert configs.differing_keys(changed, today) == ["planner.max_checks"]
        assert configs.matching_identity(changed, today) is today


def test_a_key_added_to_another_planner_changes_no_store(monkeypatch):
    @dataclasses.dataclass
    class WiderTrajOpt(S.TrajOptSettings):
        trajopt_new_key: float = 1.5

    before = composed_identity("domain=planar")
    monkeypatch.setitem(S.SETTINGS, "trajopt", WiderTrajOpt)
    stored = copy.deepcopy(OLD_PLANAR)
    stored["planner"]["trajopt_new_key"] = 1.5  # even a store that had it
    assert configs.differing_keys(stored, {**OLD_PLANAR, "planner": {
        k: v for k, v in OLD_PLANAR["planner"].items() if not k.startswith("trajopt")}}) == []
    assert composed_identity("domain=planar") == before
    assert "trajopt_new_key" not in composed_identity("domain=planar")["planner"]


def test_each_planner_declares_its_own_keys_and_defaults_once():
    assert S.keys_of(settings_class("noop")) == ["name", "max_checks", "wall_cap_s",
                                                 "resolution", "collision"]
    assert set(S.keys_of(settings_class("rrt_connect"))) - set(S.keys_of(S.PlannerSettings)) \
        == {"range", "shortcut_attempts"}
    assert {k for k in S.keys_of(settings_class("trajopt"))
            if k not in S.keys_of(S.PlannerSettings)} == {
        "trajopt_waypoints", "trajopt_margin", "trajopt_penalty", "trajopt_penalty_rounds",
        "trajopt_iterations", "trajopt_trust_radius"}
    opts, mine = TrajOptOptions(), S.TrajOptSettings()
    assert (opts.waypoints, opts.margin, opts.penalty, opts.penalty_rounds, opts.iterations,
            opts.trust_radius) == (mine.trajopt_waypoints, mine.trajopt_margin,
                                   mine.trajopt_penalty, mine.trajopt_penalty_rounds,
                                   mine.trajopt_iterations, mine.trajopt_trust_radius)
    assert composed_identity("domain=grasp_arm", "planner=trajopt")["planner"] == {
        k: v for k, v in dataclasses.asdict(mine).items() if k != "collision"}


@pytest.mark.parametrize("cls, key, value", [
    (S.NoopSettings, "max_checks", 0), (S.RRTConnectSettings, "range", -1.0),
    (S.RRTConnectSettings, "resolution", 0.0), (S.TrajOptSettings, "trajopt_waypoints", 2),
    (S.OmplSettings, "shortcut_attempts", -1), (S.OmplSettings, "algorithm", "Nope"),
])
def test_bounds_are_checked_when_settings_are_made_naming_the_key(cls, key, value):
    with pytest.raises(ValueError, match=key):
        cls(**{key: value})


def test_a_stand_in_and_a_planner_given_common_settings_get_their_own_defaults():
    planner = make_planner(S.NoopSettings(max_checks=7), RRTConnect)
    assert isinstance(planner, RRTConnect)
    assert planner.settings == S.RRTConnectSettings(max_checks=7)
    assert TrajOpt(S.PlannerSettings(name="trajopt")).settings == S.TrajOptSettings()


PLUGIN = '''
from dataclasses import dataclass
from typing import ClassVar

from pipeline.planning.rrt_connect import RRTConnect
from pipeline.planning.settings import RRTConnectSettings


@dataclass
class HalfSettings(RRTConnectSettings):
    planner_class: ClassVar[str] = "half_rrt_plugin:HalfRRT"

    name: str = "half_rrt"
    fraction: float = 0.5

    def __post_init__(self):
        super().__post_init__()
        if not 0 < self.fraction <= 1:
            raise ValueError("planner.fraction must be in (0, 1]")


class HalfRRT(RRTConnect):
    """RRT-Connect on a budget of fraction x max_checks."""

    name = "half_rrt"
    settings_class = HalfSettings

    def budget(self, robot):
        budget = super().budget(robot)
        budget.limit = max(1, int(budget.limit * self.settings.fraction))
        return budget
'''


@pytest.fixture
def plugin(tmp_path):
    """A planner plug-in installed the way pip installs one: its module and a dist-info
    folder whose entry_points.txt names it in group box_planning.planners."""
    site = tmp_path / "site"
    info = site / "half_rrt-0.1.dist-info"
    info.mkdir(parents=True)
    (site / "half_rrt_plugin.py").write_text(PLUGIN)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: half-rrt\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(textwrap.dedent("""\
        [box_planning.planners]
        half_rrt = half_rrt_plugin:HalfSettings
        rrt_connect = half_rrt_plugin:HalfSettings
        """))
    env = pr.env()
    env["PYTHONPATH"] = f"{env['PYTHONPATH']}:{site}"
    return env


def plugin_run(env, store, *overrides):
    return subprocess.run([sys.executable, "-m", "pipeline", *SMALL,
                              f"store.path={store}", *overrides], capture_output=True,
                             text=True, cwd=store.parent, env=env, timeout=600)


def test_a_plugin_planner_runs_by_name_and_its_keys_are_checked_up_front(plugin, tmp_path):
    store = tmp_path / "half.zarr"
    res = plugin_run(plugin, store, "stage=generate", "planner=half_rrt",
                     "planner.max_checks=8000")
    assert res.returncode == 0, res.stderr
    root = zarr.open_group(store, mode="r", use_consolidated=False)
    assert root.attrs["identity"]["planner"] == {
        "name": "half_rrt", "max_checks": 8000, "wall_cap_s": 10.0, "resolution": 0.01,
        "range": 0.0, "shortcut_attempts": 40, "fraction": 0.5}
    checks = pr.matrix(store)["checks"]
    assert checks.max() <= 4000 < 8000 and (checks == 4000).any()  # its own budget
    again = plugin_run(plugin, store, "stage=generate", "planner=half_rrt",
                       "planner.max_checks=8000")
    assert "scores: already complete" in again.stdout + again.stderr
    bad_input(plugin_run(plugin, tmp_path / "bad.zarr", "stage=generate", "planner=half_rrt",
                         "planner.fraction=2"), "planner.fraction")
    bad_input(plugin_run(plugin, tmp_path / "bad.zarr", "stage=generate", "planner=half_rrt",
                         "planner.trajopt_margin=1"), "trajopt_margin")


def test_a_plugin_never_replaces_a_builtin_planner(plugin):
    code = ("from pipeline.planning.registry import planner_class; "
            "print(planner_class('rrt_connect').__module__, planner_class('half_rrt').name)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            env=plugin, check=True).stdout.split()
    assert out == ["pipeline.planning.rrt_connect", "half_rrt"]


def test_a_robot_model_brings_its_own_checker():
    """``planner.collision=spheres`` asks the robot model for its faster checker (its
    ``certified`` capability); a model without one is checked as it is."""
    from pipeline.domains.planar import PlanarScene
    from pipeline.planning.base import capabilities

    class Faster(PlanarScene):
        def certified(self):
            return Counting(self)

    class Counting(PlanarScene):
        def __init__(self, model):
            super().__init__(np.zeros((0, 4)), model.radius, model.lower, model.upper)
            self.calls = 0

        def check(self, states):
            self.calls += 1
            return super().check(states)

    box = np.zeros((0, 4))
    fast = Faster(box, 0.25, np.zeros(2), np.full(2, 10.0))
    assert "certified" in capabilities(fast) and "certified" not in capabilities(PlanarScene)
    spheres = RRTConnect(S.RRTConnectSettings(collision="spheres"))
    budget = spheres.budget(fast)
    assert isinstance(budget.robot, Counting)
    assert spheres.plan(fast, np.ones(2), np.full(2, 9.0), seed=0, budget=budget).feasible
    assert budget.robot.calls > 0
    exact = RRTConnect(S.RRTConnectSettings(collision="exact"))
    assert exact.budget(fast).robot is fast
    plain = PlanarScene(box, 0.25, np.zeros(2), np.full(2, 10.0))
    assert spheres.budget(plain).robot is plain


def test_flat_settings_as_old_stores_record_them_still_make_a_domain():
    from pipeline.domains import load_domain

    domain = load_domain("planar", planner={"name": "rrt_connect", **OLD_PLANNER})
    assert domain.planner == S.RRTConnectSettings()
    with pytest.raises(ValueError, match="trajopt_waypoint"):  # a typo is still refused
        load_domain("planar", planner={"name": "rrt_connect", "trajopt_waypoint": 3})


def test_two_ompl_algorithms_get_their_own_default_store_paths():
    from pipeline.planning.settings import planner_label
    from pipeline.validation import run_store

    assert planner_label(S.OmplSettings(algorithm="RRTstar")) == "ompl-RRTstar"
    assert planner_label({"name": "rrt_connect", "range": 0.0}) == "rrt_connect"
    paths = {run_store(composed("planner=ompl", f"planner.algorithm={a}")).name
             for a in ("RRT", "BITstar")}
    assert paths == {"grasp_arm-ompl-RRT-seed0.zarr", "grasp_arm-ompl-BITstar-seed0.zarr"}
