"""Domains and planners from other packages (:mod:`pipeline.plugins`): the example plug-in
package ``examples/box-example-plugin`` (domain ``slalom``, planner ``biased_rrt``),
installed next to this one, runs like the built-in ones: ``stage=all`` writes a store that
resumes, evaluates and reports; their keys are checked up front with the same refusals;
their modules are imported only when they are used.  (The domain × planner contract suite
checks them too: tests/test_domain_contract.py.)"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from pipeline.plugins import plugin_targets
from tests import pipeline_runs as pr
from tests.test_bad_inputs import bad_input, composed

if "slalom" not in plugin_targets("domain") or "biased_rrt" not in plugin_targets("planner"):
    pytest.skip("the example plug-in is not installed (pip install -e examples/box-example-plugin)",
                allow_module_level=True)

SMALL = ("domain=slalom", "instances.n=18", "constraints.m=6", "store.block_instances=6",
         "store.block_constraints=3", "progress=false", "cluster.n_workers=2",
         "planner.max_checks=4000")


def pipeline(cwd, *overrides: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pipeline", *SMALL, *overrides],
                          capture_output=True, text=True, cwd=cwd, env=pr.env(), timeout=600)


def test_stage_all_on_a_plug_in_domain_writes_resumes_evaluates_and_reports(tmp_path):
    store, report = tmp_path / "slalom.zarr", tmp_path / "report"
    first = pipeline(tmp_path, "stage=all", f"store.path={store}", f"report.dir={report}")
    assert first.returncode == 0, first.stderr + first.stdout
    made = pr.matrix(store)
    assert made["score"].shape == (18, 6) and made["feasible"].any()
    assert (report / "report.html").is_file() and list(report.glob("*.png"))

    again = pipeline(tmp_path, "stage=all", f"store.path={store}", f"report.dir={report}")
    assert again.returncode == 0, again.stderr + again.stdout
    for stage in ("scores", "evaluate"):
        assert f"{stage}: already complete" in again.stdout, again.stdout
    assert pr.same_matrix(pr.matrix(store), made)


@pytest.mark.parametrize("overrides, words", [
    (("domain.door_width=0.2",), ("door_width",)),
    (("domain.pillars_max=-1",), ("pillars_max",)),
    (("domain.pillars_max=many",), ("pillars_max",)),
    (("domain.no_such_key=1",), ("no_such_key",)),
])
def test_bad_plug_in_keys_are_one_line_exit_2_with_nothing_written(tmp_path, overrides, words):
    res = pipeline(tmp_path, "stage=generate", f"store.path={tmp_path / 's.zarr'}", *overrides)
    bad_input(res, *words)
    assert list(tmp_path.iterdir()) == []


def test_load_domain_gives_the_schema_defaults_and_checks_overrides():
    from box_example.schema import SlalomConfig

    from pipeline.domains import domain_schema, load_domain

    assert domain_schema("slalom") is SlalomConfig
    d = load_domain("slalom", pillars_max=2)
    assert d.config == SlalomConfig(pillars_max=2) and d.name == "slalom"
    with pytest.raises(ValueError, match="door_width"):
        load_domain("slalom", door_width=0.2)


LAZY = """
import sys
from pipeline.domains import domain_names
from pipeline.validation import validate
from tests.test_bad_inputs import composed
assert "slalom" in domain_names()
validate(composed("domain=slalom", "stage=instances", "instances.n=10"), available=None)
validate(composed("domain=planar", "stage=instances", "instances.n=10"), available=None)
print(sorted(m for m in sys.modules if m.startswith("box_example")), "ompl" in sys.modules)
from pipeline.domains import load_domain
load_domain("slalom")
print(sorted(m for m in sys.modules if m.startswith("box_example")))
load_domain("slalom", planner="biased_rrt").planner_for(object)
print(sorted(m for m in sys.modules if m.startswith("box_example")), "ompl" in sys.modules)
"""


def test_the_plug_in_modules_are_imported_only_when_used():
    """Listing, registering and validating read the schemas only (light modules): neither
    the domain's module nor the planner's (nor OMPL) until each is used."""
    out = subprocess.run([sys.executable, "-c", LAZY], capture_output=True, text=True,
                         env=pr.env(), check=True).stdout.splitlines()
    light = ["box_example", "box_example.planner_settings", "box_example.schema"]
    assert out == [f"{light} False", str(light + ["box_example.slalom"]),
                   f"{sorted(light + ['box_example.slalom', 'box_example.biased_rrt'])} True"]


def test_a_plug_in_domain_composes_with_its_schema_defaults():
    cfg = composed("domain=slalom", "domain.pillars_max=3")
    assert cfg.domain.name == "slalom" and cfg.domain.pillars_max == 3
    assert cfg.domain.door_width == 1.5 and np.isclose(cfg.domain.size, 10.0)


def test_a_plug_in_planner_plans_by_name_resumes_and_checks_its_keys(tmp_path):
    store = tmp_path / "biased.zarr"
    first = pipeline(tmp_path, "stage=generate", "planner=biased_rrt", "planner.goal_bias=0.3",
                     f"store.path={store}")
    assert first.returncode == 0, first.stderr + first.stdout
    import zarr

    root = zarr.open_group(store, mode="r", use_consolidated=False)
    identity = root.attrs["identity"]["planner"]
    assert identity["name"] == "biased_rrt" and identity["goal_bias"] == 0.3
    made = pr.matrix(store)
    assert made["feasible"].any()
    again = pipeline(tmp_path, "stage=generate", "planner=biased_rrt", "planner.goal_bias=0.3",
                     f"store.path={store}")
    assert "scores: already complete" in again.stdout, again.stdout + again.stderr
    assert pr.same_matrix(pr.matrix(store), made)
    bad = tmp_path / "bad"
    bad.mkdir()
    bad_input(pipeline(bad, "stage=generate", "planner=biased_rrt", "planner.goal_bias=2",
                       f"store.path={bad / 's.zarr'}"), "planner.goal_bias")
    assert list(bad.iterdir()) == []


@pytest.fixture
def broken_plugins(tmp_path):
    """A package installed the way pip installs one whose entry points name modules that
    cannot be imported (a domain and a planner)."""
    info = tmp_path / "site" / "broken_plugin-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(
        "[box_planning.domains]\nbroken_domain = no_such_module:Schema\n\n"
        "[box_planning.planners]\nbroken_planner = no_such_module:Settings\n")
    env = pr.env()
    env["PYTHONPATH"] = f"{env['PYTHONPATH']}:{tmp_path / 'site'}"
    return env


def test_a_broken_plug_in_stops_only_the_runs_that_ask_for_it(tmp_path, broken_plugins):
    def run(domain="planar", planner="rrt_connect"):
        return subprocess.run([sys.executable, "-m", "pipeline", f"domain={domain}",
                               f"planner={planner}", "progress=false", "stage=instances",
                               "instances.n=4", f"store.path={tmp_path / 's.zarr'}"],
                              capture_output=True, text=True, cwd=tmp_path,
                              env=broken_plugins, timeout=600)

    fine = run()  # other runs are not disturbed
    assert fine.returncode == 0, fine.stderr
    for res, group in ((run(domain="broken_domain"), "domain"),
                       (run(planner="broken_planner"), "planner")):
        bad_input(res, f"{group} plug-in 'broken_{group}'", "no_such_module:",
                  "ModuleNotFoundError")
