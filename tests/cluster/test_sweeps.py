"""``python -m pipeline -m``: sweeps that share one cluster."""

from __future__ import annotations

import importlib.util
import subprocess
import sys

import pytest
import zarr

from tests import pipeline_runs as pr

#: Two tiny runs (seeds 0 and 1): what matters here is where they run.
SWEEP = ("domain=planar", "instances.n=6", "constraints.m=4", "progress=false",
         "planner.max_checks=2000", "seed=0,1")


def sweep(tmp_path, *overrides: str) -> subprocess.CompletedProcess:
    store = f"store.path={tmp_path}/s${{seed}}.zarr"
    return subprocess.run([sys.executable, "-m", "pipeline", "-m", *SWEEP, store, *overrides],
                          capture_output=True, text=True, cwd=tmp_path, env=pr.env())


def complete(tmp_path) -> bool:
    return all(zarr.open_array(tmp_path / f"s{seed}.zarr" / "scores" / "done", mode="r")[...].all()
               for seed in (0, 1))


def test_sequential_sweep_reuses_one_cluster(tmp_path):
    res = sweep(tmp_path, "cluster.n_workers=1", "cluster.reuse=true")
    assert res.returncode == 0, res.stderr
    banners = [line for line in res.stdout.splitlines() if line.startswith("dask:")]
    assert len(banners) == 2 and banners[1].startswith("dask: reusing 1 worker at "), banners
    assert banners[0].split(" at ")[1].split(";")[0] in banners[1]  # the same scheduler
    assert complete(tmp_path)


def test_joblib_sweep_on_one_scheduler(tmp_path, dask_procs):
    if importlib.util.find_spec("hydra_plugins.hydra_joblib_launcher") is None:
        pytest.skip('needs hydra-joblib-launcher: pip install -e ".[sweeps]"')
    address = dask_procs.scheduler()
    dask_procs.worker()
    dask_procs.worker()
    dask_procs.wait_for_workers(2)
    res = sweep(tmp_path, "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", "cluster=address",
                f"cluster.address={address}")
    assert res.returncode == 0, res.stderr
    assert res.stdout.count(f"workers at {address}") + res.stdout.count(
        f"worker at {address}") == 2
    assert complete(tmp_path)
