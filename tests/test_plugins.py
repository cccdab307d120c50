"""Domains from other packages (:mod:`pipeline.plugins`): the example plug-in package
``examples/box-example-plugin`` (domain ``slalom``), installed next to this one, runs like a
built-in domain: ``stage=all`` writes a store that resumes, evaluates and reports; its keys
are checked up front with the same refusals; its domain module is imported only when it is
used.  (The domain × planner contract suite checks it too: tests/test_domain_contract.py.)"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from pipeline.plugins import plugin_targets
from tests import pipeline_runs as pr
from tests.test_bad_inputs import bad_input, composed

if "slalom" not in plugin_targets("domain"):
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
print(sorted(m for m in sys.modules if m.startswith("box_example")))
from pipeline.domains import load_domain
load_domain("slalom")
print(sorted(m for m in sys.modules if m.startswith("box_example")))
"""


def test_the_plug_in_domain_module_is_imported_only_when_the_domain_is_used():
    """Listing, registering and validating read its schema only (a light module)."""
    out = subprocess.run([sys.executable, "-c", LAZY], capture_output=True, text=True,
                         env=pr.env(), check=True).stdout.splitlines()
    assert out == ["['box_example', 'box_example.schema']",
                   "['box_example', 'box_example.schema', 'box_example.slalom']"]


def test_a_plug_in_domain_composes_with_its_schema_defaults():
    cfg = composed("domain=slalom", "domain.pillars_max=3")
    assert cfg.domain.name == "slalom" and cfg.domain.pillars_max == 3
    assert cfg.domain.door_width == 1.5 and np.isclose(cfg.domain.size, 10.0)
