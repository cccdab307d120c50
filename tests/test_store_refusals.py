"""Bad overrides, foreign or different stores, and the run lock."""

import json
import subprocess
import sys

import pytest
from hydra import compose, initialize_config_dir

from pipeline import configs
from pipeline.store import StoreError, StoreLock
from tests import pipeline_runs as pr


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("s") / "small.zarr"
    res = pr.run(path, "stage=instances")
    assert res.returncode == 0, res.stderr
    return path


def _tree(path):
    return {p.relative_to(path): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("override, words", [
    ("instances.nn=3", "instances.nn"),
    ("instances.n=many", "instances.n"),
    ("stage=generat", "stage"),
    ("domain=nowhere", "domain"),
    ("planner.max_checks=lots", "planner.max_checks"),
    ("cluster=nowhere", "cluster"),
])
def test_bad_overrides_are_refused_by_hydra(tmp_path, override, words):
    res = pr.run(tmp_path / "x.zarr", override)
    assert res.returncode != 0
    assert words in res.stderr
    assert not (tmp_path / "x.zarr").exists()


@pytest.mark.parametrize("override, words", [
    ("instances.n=2", "instances.n must be >= 3"),
    ("planner.max_checks=0", "max_checks must be positive"),
    ("domain.robot_radius=-1", "robot_radius"),
])
def test_bad_values_are_refused_with_exit_code_2(tmp_path, override, words):
    res = pr.run(tmp_path / "x.zarr", override)
    assert res.returncode == 2 and words in res.stderr
    assert not (tmp_path / "x.zarr").exists()


def test_a_different_config_is_refused_naming_the_keys(store):
    before = _tree(store)
    res = pr.run(store, "stage=instances", "instances.n=30", "seed=1")
    assert res.returncode == 2
    assert "differing keys: instances.n, seed" in res.stderr
    assert _tree(store) == before


def test_overwrite_replaces_a_store_of_ours(tmp_path, store):
    import shutil

    copy = tmp_path / "copy.zarr"
    shutil.copytree(store, copy)
    res = pr.run(copy, "stage=instances", "instances.n=30", "store.mode=overwrite")
    assert res.returncode == 0, res.stderr
    attrs = json.loads((copy / "zarr.json").read_text())["attributes"]
    assert attrs["identity"]["instances"]["n"] == 30


@pytest.mark.parametrize("make", ["file", "dir", "zarr"])
def test_a_path_that_is_not_ours_is_refused_and_untouched(tmp_path, make):
    target = tmp_path / "foreign.zarr"
    if make == "file":
        target.write_text("precious")
    elif make == "dir":
        target.mkdir()
        (target / "notes.txt").write_text("precious")
    else:
        import zarr

        zarr.open_group(target, mode="w").attrs["owner"] = "someone else"
    before = _tree(target) if target.is_dir() else target.read_bytes()
    res = pr.run(target, "stage=generate", "store.mode=overwrite")
    assert res.returncode == 2 and "not a score store made by this pipeline" in res.stderr
    assert (_tree(target) if target.is_dir() else target.read_bytes()) == before


def test_a_second_run_on_a_locked_store_is_refused(store):
    with StoreLock(store):
        res = pr.run(store, "stage=instances")
    assert res.returncode == 2 and "in use by a running pipeline" in res.stderr
    assert "pid" in res.stderr


def test_a_dead_run_does_not_hold_the_lock(store):
    code = ("import os, sys; from pipeline.store import StoreLock; "
            "StoreLock(sys.argv[1]).acquire(); os.kill(os.getpid(), 9)")
    subprocess.run([sys.executable, "-c", code, str(store)], check=False)
    assert StoreLock(store).held_by_other() is None
    with StoreLock(store):
        with pytest.raises(StoreError, match="in use"):
            StoreLock(store).acquire()


def test_status_of_a_missing_store_is_an_error(tmp_path):
    res = pr.run(tmp_path / "none.zarr", "stage=status")
    assert res.returncode == 2 and "no store at" in res.stderr


def test_compose_gives_validated_defaults():
    configs.register_configs()
    with initialize_config_dir(config_dir=str(configs.CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=["seed=3", "domain.obstacles_max=5"])
    ident = configs.identity(cfg)
    assert ident["seed"] == 3 and ident["domain"]["obstacles_max"] == 5
    assert "cluster" not in ident  # where it runs does not change the matrix
    other = dict(ident, seed=4)
    assert configs.differing_keys(ident, other) == ["seed"]
    assert configs.config_hash(ident) != configs.config_hash(other)


def test_a_sweep_gives_one_store_per_run_under_data(tmp_path):
    cmd = [sys.executable, "-m", "pipeline", "-m", "stage=instances", "seed=0,1", "domain=planar",
           "instances.n=5", "progress=false"]
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, env=pr.env(),
                         timeout=300)
    assert res.returncode == 0, res.stderr
    stores = sorted(p.name for p in (tmp_path / "data").glob("*.zarr"))
    assert stores == ["planar-rrt_connect-seed0.zarr", "planar-rrt_connect-seed1.zarr"]
    seeds = [json.loads((tmp_path / "data" / s / "zarr.json").read_text())
             ["attributes"]["identity"]["seed"] for s in stores]
    assert seeds == [0, 1]
