"""Import-time weight and side effects (docs/architecture.md): what a light command imports
must not load the simulator or the planners, and importing or using the planning and
domain modules changes no process-wide setting.  Each check runs in a fresh interpreter."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

HEAVY = ("ompl", "pybullet")


#: scipy's subpackages that take 0.1-0.3 s each to import: box_core and the entry points
#: import them in the functions that use them (issue 27: every coordinator, every `box`
#: command and every test that runs one pays what these modules import)
SLOW_SCIPY = ("scipy.special", "scipy.stats", "scipy.sparse", "scipy.io", "scipy.spatial")


WATCHED = ("ompl", "pybullet", "matplotlib.pyplot", "pipeline.domains.grasp_arm", "distributed",
           *SLOW_SCIPY)


def loaded_after(code: str) -> dict:
    probe = (f"import sys, json\n{code}\n"
             f"print(json.dumps({{m: m in sys.modules for m in {WATCHED}}}))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


@pytest.mark.parametrize("module", ["box_core", "pipeline.store", "pipeline.store.status",
                                    "pipeline.store.migrate", "pipeline.configs",
                                    "pipeline.planning", "pipeline.domains",
                                    "pipeline.domains.planar"])
def test_light_modules_load_neither_ompl_nor_pybullet(module):
    loaded = loaded_after(f"import {module}")
    assert not any(loaded[m] for m in HEAVY), loaded


@pytest.mark.parametrize("module", ["box_core", "pipeline.cli", "pipeline.stages"])
def test_box_core_and_the_entry_points_load_no_slow_scipy_subpackage(module):
    loaded = loaded_after(f"import {module}")
    assert not any(loaded[m] for m in SLOW_SCIPY), loaded


@pytest.mark.parametrize("module", ["pipeline.stages", "pipeline.execution", "pipeline.cluster",
                                    "pipeline.validation"])
def test_the_stages_load_distributed_only_to_start_a_cluster(module):
    """``distributed`` (about 0.35 s to import) is imported where a cluster is started or
    reached, not by the modules every command imports."""
    assert not loaded_after(f"import {module}")["distributed"]


def run_main(*args: str) -> str:
    """``python -m pipeline ARGS`` in this interpreter's probe, as ``loaded_after`` code."""
    return (f"import runpy\nsys.argv = ['pipeline', *{list(args)}]\ntry:\n"
            "    runpy.run_module('pipeline', run_name='__main__', alter_sys=True)\n"
            "except SystemExit:\n    pass")


def test_commands_that_start_no_cluster_do_not_import_distributed(made, tmp_path):
    """A refused command, ``stage=status`` and a re-run with nothing to do start no cluster,
    so they do not import ``distributed``; a run that plans does (the control)."""
    import shutil

    from tests import pipeline_runs as pr

    store = tmp_path / "copy.zarr"  # a re-run takes the store's lock: not on the shared one
    shutil.copytree(made[0], store)
    small = [*pr.SMALL, "hydra.run.dir=" + str(tmp_path / "out")]
    for args in (["stage=status", f"store.path={tmp_path / 'none.zarr'}"],
                 [*small, f"store.path={store}", "stage=status"],
                 [*small, f"store.path={store}", "stage=generate"]):
        assert not loaded_after(run_main(*args))["distributed"], args
    assert loaded_after(run_main(*small, f"store.path={tmp_path / 'new.zarr'}",
                                 "instances.n=6", "constraints.m=5",
                                 "stage=generate"))["distributed"]


def test_registering_the_pipeline_configs_loads_no_domain():
    loaded = loaded_after("from pipeline.configs import register_configs; register_configs()")
    assert not any(loaded[m] for m in (*HEAVY, "pipeline.domains.grasp_arm")), loaded


def test_planning_leaves_ompl_logging_and_matplotlib_as_it_found_them(tmp_path):
    code = """
import json, sys
from ompl import util as ou
ou.setLogLevel(ou.LogLevel.LOG_WARN)
from pipeline.domains import load_domain
d = load_domain("planar")
spec = d.sample_instance(1)
raw = d.raw_plan(spec, seed=1)
d.render(spec, raw.plan, sys.argv[1], constraint=raw.constraint)
print(json.dumps([str(ou.getLogLevel()), "matplotlib.pyplot" in sys.modules,
                  raw.plan.feasible]))
"""
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "p.png")],
                         capture_output=True, text=True, check=True)
    level, pyplot, feasible = json.loads(out.stdout.strip().splitlines()[-1])
    assert level.endswith("LOG_WARN") and not pyplot and feasible
    assert "Error" not in out.stderr and "Info" not in out.stderr, out.stderr


def test_no_planning_module_imports_the_simulator():
    """The validity checker belongs to the robot model (issue 25, item 3): planning modules
    ask the model for its checkers and never import ``pipeline.sim``, even in a function."""
    import ast
    from pathlib import Path

    import pipeline.planning

    found = []
    for path in Path(pipeline.planning.__file__).parent.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            found += [f"{path.name}: {n}" for n in names if n.startswith("pipeline.sim")]
    assert found == []
