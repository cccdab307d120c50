"""The store as analysts see it: xarray datasets and data trees with coordinates and CF flag
attributes, and stores of the first layout (layout_version 1) still read and migrated."""

import json
import shutil

import numpy as np
import xarray as xr
import zarr
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.store import LAYOUT_VERSION
from tests import pipeline_runs as pr


def test_open_zarr_gives_coordinates_and_flag_attributes(made):
    store, _ = made
    scores = xr.open_zarr(store, group="scores")
    assert scores["score"].dims == ("instance", "constraint")
    assert {"instance_seed", "constraint_source"} <= set(scores.coords)
    seeds = zarr.open_array(store / "instances" / "seed", mode="r")[...]
    np.testing.assert_array_equal(scores["instance_seed"].values, seeds)
    status = scores["status"]
    codes = dict(zip(status.attrs["flag_values"], status.attrs["flag_meanings"].split(),
                     strict=True))
    assert codes[0] == "ok"
    assert set(np.unique(status.values)) <= set(codes)
    step = scores["step"]
    assert step.attrs["flag_meanings"].split() == ["via_leg", "goal_leg"]
    theta = xr.open_zarr(store, group="constraints")["theta"]
    assert list(theta["feature"].values) == ["via_x", "via_y"]
    assert list(theta["feature_units"].values) == ["m", "m"]
    raw = xr.open_zarr(store, group="raw")
    assert raw["constraint"].dims == ("instance", "feature") and "instance_seed" in raw.coords


def test_open_datatree_reads_the_whole_store(made):
    store, _ = made
    tree = xr.open_datatree(store, engine="zarr")
    assert {"instances", "raw", "constraints", "scores", "evaluation"} <= set(tree.children)
    assert tree["scores"]["score"].dims == ("instance", "constraint")
    assert tree["evaluation"]["order"].dims == ("selector", "instance", "step")
    np.testing.assert_array_equal(tree["scores"]["feasible"].values, pr.matrix(store)["feasible"])


def _as_layout_1(store):
    """Rewrite ``store`` as the first layout wrote it: no integrity records, no
    coordinates, no recorded inputs."""
    g = zarr.open_group(store, mode="r+", use_consolidated=False)
    del g["integrity"]
    for key in ("scores/instance_seed", "scores/constraint_source", "raw/instance_seed",
                "raw/feature", "constraints/feature", "scores/environment", "raw/environment",
                "instances/instance", "raw/instance", "scores/instance", "scores/constraint",
                "constraints/constraint", "raw/feature_units", "constraints/feature_units",
                "evaluation"):
        del g[key]
    for group in ("raw", "scores", "constraints"):
        for _, arr in g[group].arrays():
            if "coordinates" in arr.attrs:
                del arr.attrs["coordinates"]
    stages = {k: {f: v for f, v in info.items() if f not in ("inputs", "outputs")}
              for k, info in g.attrs["stages"].items()}
    g.attrs.update({"layout_version": 1, "stages": stages})
    del g.attrs["environments"]
    zarr.consolidate_metadata(store)


def test_a_layout_1_store_is_read_then_migrated_without_recomputing(made, tmp_path):
    """Reading it writes nothing; re-running it finished migrates it (to layout 2, then 3,
    4 and 5: the instance features of layout 5 are work for stage instances) and computes
    nothing again."""
    copy = tmp_path / "old.zarr"
    shutil.copytree(made[0], copy)
    _as_layout_1(copy)
    res = CliRunner().invoke(app, ["status", str(copy), "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["layout_version"] == 1
    assert xr.open_zarr(copy, group="scores")["score"].shape == (24, 15)
    res = pr.run(copy, "stage=generate")
    assert res.returncode == 0, res.stderr + res.stdout
    assert all(f"migrated to layout {k}" in res.stdout for k in (2, 3, 4, 5))
    assert "scores: already complete" in res.stdout and "dask:" not in res.stdout
    res = pr.run(copy, "stage=evaluate", "evaluate.k=5")
    assert res.returncode == 0, res.stderr + res.stdout
    assert "migrated" not in res.stdout
    res = CliRunner().invoke(app, ["status", str(copy), "--json"])
    doc = json.loads(res.output)
    assert res.exit_code == 0 and doc["layout_version"] == LAYOUT_VERSION and not doc["damaged"]
    assert pr.same_matrix(pr.matrix(made[0]), pr.matrix(copy))
    assert "instance_seed" in xr.open_zarr(copy, group="scores").coords
