"""Every block of ``raw`` and ``scores`` records the environment that computed it
(``pipeline/environment.py``, docs/reproducibility.md): on the workers that computed it,
across a resume in another environment (said in one line, or refused with
``store.environment=refuse``), and in stores of layout 2 migrated in place.

"Another environment" is made real on this machine: NumPy started with its SIMD kernels
switched off (``NPY_DISABLE_CPU_FEATURES``) fingerprints, and computes, as an older CPU.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pytest
import zarr
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.environment import agree, fingerprint
from pipeline.store import LAYOUT_VERSION
from tests import pipeline_runs as pr
from tests.cluster.conftest import DaskProcesses, kill
from tests.replay import child_env, code_paths

LAYOUT_2 = Path(__file__).parent / "data" / "layout2_planar.tar.gz"
#: the command that made LAYOUT_2 with the code of layout 2 (main at 9e0ba8a), in /tmp/l2:
#: python -m pipeline stage=all domain=planar instances.n=12 constraints.m=8
#:   store.block_instances=4 store.block_constraints=4 cluster.n_workers=1
#:   planner.max_checks=4000 evaluate.k=4 store.path=/tmp/l2/layout2.zarr
LAYOUT_2_RUN = ("domain=planar", "instances.n=12", "constraints.m=8", "store.block_instances=4",
                "store.block_constraints=4", "cluster.n_workers=1", "planner.max_checks=4000",
                "progress=false")


def other_environment() -> dict[str, str]:
    forced = code_paths().get("numpy-baseline-simd")
    if forced is None:
        pytest.skip("NumPy dispatches no SIMD kernels on this machine: no other environment "
                    "can be forced")
    return forced


def status(store: Path) -> dict:
    res = CliRunner().invoke(app, ["status", str(store), "--json"])
    assert res.exit_code == 0, res.output
    return json.loads(res.output)


def environment(store: Path, group: str) -> np.ndarray:
    return zarr.open_array(store / group / "environment", mode="r")[...]


def run_in(env: dict[str, str], store: Path, *overrides: str):
    return subprocess.run(pr.command(store, *overrides), capture_output=True, text=True,
                          cwd=store.parent, env=child_env(env), timeout=600)


def run_layout_2(store: Path, *overrides: str):
    """A run with the config that made LAYOUT_2."""
    return subprocess.run([sys.executable, "-m", "pipeline", *LAYOUT_2_RUN,
                           f"store.path={store}", *overrides], capture_output=True, text=True,
                          cwd=store.parent, env=pr.env(), timeout=600)


def damage_block(store: Path) -> None:
    """Delete one chunk of scores/score: block (1, 1) is computed again by the next run."""
    (store / "scores" / "score" / "c" / "1" / "1").unlink()


def test_every_block_records_the_environment_that_computed_it(made):
    store, _ = made
    table = zarr.open_group(store, mode="r").attrs["environments"]
    assert table == [fingerprint()]
    assert (environment(store, "scores") == 0).all() and (environment(store, "raw") == 0).all()
    doc = status(store)
    assert doc["layout_version"] == LAYOUT_VERSION
    assert doc["environments"] == [{"index": 0, "entries": {"raw": 24, "scores": 360},
                                    "environment": fingerprint()}]


def test_a_resume_in_another_environment_says_so_and_status_shows_both(made, tmp_path):
    forced = other_environment()
    store = tmp_path / "a.zarr"
    shutil.copytree(made[0], store)
    before = pr.matrix(store)
    damage_block(store)
    res = run_in(forced, store, "stage=generate")
    assert res.returncode == 0, res.stderr + res.stdout
    lines = res.stdout.splitlines()
    said = [k for k, line in enumerate(lines) if "resuming in another environment" in line]
    assert len(said) == 1 and "simd" in lines[said[0]] and "not bitwise" in lines[said[0]]
    assert said[0] < next(k for k, line in enumerate(lines) if "scores: 24 x 15 complete" in line)
    mask = np.zeros((24, 15), bool)
    mask[6:12, 5:10] = True  # block (1, 1) of 6 x 5 entries
    env = environment(store, "scores")
    assert (env[mask] == 1).all() and (env[~mask] == 0).all()
    doc = status(store)
    assert [e["entries"] for e in doc["environments"]] == [{"raw": 24, "scores": 330},
                                                         {"scores": 30}]
    assert doc["environments"][1]["environment"]["simd"] == ""
    res = CliRunner().invoke(app, ["status", str(store)])
    assert "computed in 2 environments (simd" in res.output
    after = pr.matrix(store)  # the recomputed block keeps the contract
    for name in ("feasible", "status", "checks", "step"):
        np.testing.assert_array_equal(before[name], after[name])
    assert agree(before["score"], after["score"]) and agree(before["length"], after["length"])


def test_store_environment_refuse_stops_before_computing_in_another_one(made, tmp_path):
    forced = other_environment()
    store = tmp_path / "a.zarr"
    shutil.copytree(made[0], store)
    damage_block(store)
    res = run_in(forced, store, "stage=generate", "store.environment=refuse")
    assert res.returncode == 2, res.stderr + res.stdout
    err = res.stderr.strip().splitlines()
    assert len(err) == 1 and "store.environment=refuse" in err[0] and "simd" in err[0]
    assert zarr.open_group(store, mode="r").attrs["environments"] == [fingerprint()]
    assert (environment(store, "scores") == 0).all()
    res = pr.run(store, "stage=generate", "store.environment=refuse")  # the same environment
    assert res.returncode == 0, res.stderr + res.stdout
    assert "another environment" not in res.stdout
    assert status(store)["environments"][0]["entries"]["scores"] == 360


def test_blocks_record_the_workers_environment_not_the_coordinators(tmp_path):
    """Real ``dask worker`` processes compute every block: first one of this environment,
    then, after damage, one started in another.  The run says before computing that the
    workers differ from the finished blocks' environment, and the recomputed block records
    the worker's environment, not the coordinator's."""
    forced = other_environment()
    store = tmp_path / "w.zarr"
    procs = DaskProcesses(tmp_path)
    try:
        address = procs.scheduler()
        cluster = ("cluster=address", f"cluster.address={address}")
        first = procs.worker(env=child_env({}))
        procs.wait_for_workers(1)
        res = pr.run(store, "stage=generate", *cluster)
        assert res.returncode == 0, res.stderr + res.stdout
        kill(first)
        procs.worker(env=child_env(forced))
        procs.wait_for_workers(1)
        damage_block(store)
        res = pr.run(store, "stage=generate", *cluster)
    finally:
        procs.close()
    assert res.returncode == 0, res.stderr + res.stdout
    assert "scores: resuming in another environment" in res.stdout
    table = zarr.open_group(store, mode="r").attrs["environments"]
    assert table[0] == fingerprint() and table[1]["simd"] == "" != fingerprint()["simd"]
    mask = np.zeros((24, 15), bool)
    mask[6:12, 5:10] = True
    env = environment(store, "scores")
    assert (env[mask] == 1).all() and (env[~mask] == 0).all()


def _made_by_layout_2(tmp_path: Path) -> Path:
    with tarfile.open(LAYOUT_2) as tar:
        tar.extractall(tmp_path, filter="data")
    return tmp_path / "layout2.zarr"


def test_a_layout_2_store_opens_resumes_and_migrates_keeping_every_entry(tmp_path):
    store = _made_by_layout_2(tmp_path)
    doc = status(store)
    assert doc["layout_version"] == 2 and doc["environments"] == [] and not doc["damaged"]
    before = pr.matrix(store)
    res = run_layout_2(store, "stage=generate")  # layout 5's instance features: work
    assert res.returncode == 0, res.stderr + res.stdout
    assert "scores: already complete" in res.stdout
    assert all(f"migrated to layout {k}" in res.stdout for k in (3, 4, 5))
    damage_block(store)
    res = run_layout_2(store, "stage=generate")
    assert res.returncode == 0, res.stderr + res.stdout
    assert "migrated" not in res.stdout
    assert "computed before environments were recorded" in res.stdout
    doc = status(store)
    assert doc["layout_version"] == LAYOUT_VERSION and not doc["damaged"]
    assert [(e["index"], e["entries"]) for e in doc["environments"]] == [
        (-1, {"raw": 12, "scores": 80}), (0, {"scores": 16})]
    after = pr.matrix(store)
    for name in ("feasible", "status", "checks", "step"):
        np.testing.assert_array_equal(before[name], after[name])
    assert agree(before["score"], after["score"])
    untouched = np.ones(before["score"].shape, bool)
    untouched[4:8, 4:8] = False
    assert before["score"][untouched].tobytes() == after["score"][untouched].tobytes()
    res = run_layout_2(store, "stage=evaluate", "evaluate.k=4")
    assert res.returncode == 0, res.stderr + res.stdout
    assert not status(store)["damaged"]
