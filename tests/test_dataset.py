"""The store as a dataset (layout 4): index coordinates on every dimension, units and long
names, the evaluation along ``selector``, codes as names in one call, the README's analysis,
and a layout-3 store migrated in place keeping every entry and its evaluation."""

import json
import re
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr
import zarr
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.dataset import code_names, with_names
from pipeline.planning import Status
from pipeline.store import LAYOUT_VERSION
from tests import pipeline_runs as pr

ROOT = Path(__file__).resolve().parents[1]
LAYOUT_3 = Path(__file__).parent / "data" / "layout3_planar.tar.gz"
#: the command that made LAYOUT_3 with the code of layout 3 (main at 715bc48), in /tmp/l3
#: (its report step failed on the folds; the store's evaluation had finished):
#: python -m pipeline stage=all domain=planar instances.n=12 constraints.m=8
#:   store.block_instances=4 store.block_constraints=4 cluster.n_workers=1
#:   planner.max_checks=4000 evaluate.k=4 progress=false store.path=/tmp/l3/layout3.zarr
LAYOUT_3_RUN = ("domain=planar", "instances.n=12", "constraints.m=8", "store.block_instances=4",
                "store.block_constraints=4", "cluster.n_workers=1", "planner.max_checks=4000",
                "progress=false")


def test_every_dimension_has_an_index_coordinate(made):
    store, _ = made
    tree = xr.open_datatree(store, engine="zarr")
    for group in ("instances", "raw", "constraints", "scores", "evaluation"):
        ds = tree[group].to_dataset()
        assert set(ds.dims) <= set(ds.indexes), (group, set(ds.dims) - set(ds.indexes))
    scores = tree["scores"].to_dataset()
    np.testing.assert_array_equal(scores.instance.values, np.arange(24))
    np.testing.assert_array_equal(scores.constraint.values, np.arange(15))
    evaluation = tree["evaluation"].to_dataset()
    grid = evaluation.time.values
    assert grid[0] == 0 and np.all(np.diff(grid) > 0)
    assert list(evaluation.step.values) == list(range(evaluation.sizes["step"]))
    # selecting by label is selecting by position: instance 5 is row 5 of the matrix
    row = pr.matrix(store)["checks"][5]
    np.testing.assert_array_equal(scores.checks.sel(instance=5).values, row)


def test_physical_quantities_carry_units_and_long_names(made):
    store, _ = made
    scores = xr.open_zarr(store, group="scores")
    assert scores.time.attrs["units"] == "seconds" and scores.time.dtype == np.float64
    assert scores.score.attrs["units"] == scores.length.attrs["units"] == "m"
    for name in ("score", "length", "time", "status", "checks", "step", "feasible"):
        assert scores[name].attrs["long_name"], name
    evaluation = xr.open_zarr(store, group="evaluation")
    assert evaluation.first_feasible_time.attrs["units"] == "seconds"
    assert evaluation.time.attrs["units"] == "seconds"
    assert evaluation.best_score.attrs["units"] == "m"
    # the documented choice: float seconds by default; timedelta64 when asked for, which
    # truncates to whole nanoseconds
    decoded = xr.open_zarr(store, group="scores", decode_timedelta=True)
    assert decoded.time.dtype.kind == "m"
    np.testing.assert_allclose(decoded.time.values / np.timedelta64(1, "s"),
                               scores.time.values, rtol=0, atol=1e-9)


def test_evaluation_is_one_dataset_along_selector(made):
    store, _ = made
    evaluation = xr.open_zarr(store, group="evaluation")
    info = zarr.open_group(store, mode="r").attrs["stages"]["evaluate"]
    names = [line["name"] for line in info["summary"]["selectors"]]
    assert list(evaluation.selector.values) == names
    box = evaluation.sel(selector="box")
    assert box.order.dims == ("instance", "step")
    line = next(line for line in info["summary"]["selectors"] if line["name"] == "box")
    eligible = evaluation.eligible.values
    assert np.isclose(float(box.first_feasible_time.values[eligible].mean()), line["mean_time"],
                      rtol=1e-12)
    raw = evaluation.sel(selector="rawplanner")
    assert (raw.order.values == -1).all()
    ok = xr.open_zarr(store, group="raw")
    found = ok.feasible.values
    np.testing.assert_array_equal(np.isfinite(raw.first_feasible_time.values), found)
    # its curve: the failure value before its plan, minus the plan's length from its time
    last = raw.best_score.isel(time=-1).values
    within = found & (ok.time.values <= float(evaluation.time[-1]))
    assert within.sum() >= 5
    np.testing.assert_array_equal(last[within], -ok.length.values[within])
    assert (last[~within] == info["failure_value"]).all()
    frame = evaluation.first_feasible_time.to_dataframe()
    assert frame.index.names == ["selector", "instance"]


def test_statuses_and_steps_become_names_in_one_call(made):
    store, _ = made
    scores = xr.open_zarr(store, group="scores")
    named = with_names(scores)
    codes = scores.status.values
    expect = np.vectorize(lambda c: Status(c).name.lower())(codes)
    np.testing.assert_array_equal(named.status.values, expect)
    steps = named.step.values
    assert set(np.unique(steps)) <= {"none", "via_leg", "goal_leg"}
    assert ((steps == "none") == (scores.step.values == -1)).all()
    frame = named.isel(instance=slice(0, 3), constraint=slice(0, 2)).to_dataframe()
    assert list(frame.index.names) == ["instance", "constraint"] and len(frame) == 6
    assert frame["status"].map(type).eq(str).all()
    assert named.time.equals(scores.time)  # other variables untouched
    assert code_names(scores.status.attrs)[-1] == "not_computed"


def test_feature_names_say_what_they_are_in_every_domain():
    from pipeline.domains import load_domain
    for name in ("planar", "grasp_arm", "grasp_base", "pick_place"):
        domain = load_domain(name)
        names = [f.name for f in domain.theta_features]
        assert len(set(names)) == len(names) == domain.n_features
        assert not any(re.fullmatch(r"theta\d+", n) for n in names)
        assert {f.units for f in domain.theta_features} <= {"m", "rad", "1"}


def readme_analysis() -> str:
    """The README's analysis example (the python block that opens the main job's store)."""
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    found = [b for b in blocks if "with_names" in b and "open_zarr" in b]
    assert len(found) == 1, "README.md: expected one python analysis example"
    return found[0]


def test_the_readmes_analysis_runs_on_a_real_store(made, tmp_path):
    store, _ = made
    code = readme_analysis()
    path = re.search(r'store = "([^"]+)"', code).group(1)
    script = tmp_path / "analysis.py"
    script.write_text(code.replace(path, str(store)))
    res = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         cwd=tmp_path, env=pr.env(), timeout=300)
    assert res.returncode == 0, res.stderr
    assert "goal_in_collision" in res.stdout or "budget_exhausted" in res.stdout
    assert "box" in res.stdout


def _layout_3_copy(tmp_path: Path) -> Path:
    with tarfile.open(LAYOUT_3) as tar:
        tar.extractall(tmp_path, filter="data")
    return tmp_path / "layout3.zarr"


def _status(store: Path) -> dict:
    res = CliRunner().invoke(app, ["status", str(store), "--json"])
    assert res.exit_code == 0, res.output
    return json.loads(res.output)


def run_layout_3(store: Path, *overrides: str):
    return subprocess.run([sys.executable, "-m", "pipeline", *LAYOUT_3_RUN,
                           f"store.path={store}", *overrides], capture_output=True, text=True,
                          cwd=store.parent, env=pr.env(), timeout=600)


def test_a_layout_3_store_migrates_keeping_every_entry_and_its_evaluation(tmp_path):
    store = _layout_3_copy(tmp_path)
    assert _status(store)["layout_version"] == 3
    g = zarr.open_group(store, mode="r")
    before = {key: g[key][...] for key in ("scores/score", "scores/time", "scores/status",
                                            "raw/constraint", "constraints/theta")}
    info = g.attrs["stages"]["evaluate"]
    names = [line["name"] for line in info["summary"]["selectors"]]
    old = {(name, what): g[f"evaluation/{name}/{what}"][...] for name in names
           for what in ("order", "first_feasible_time", "best_score")
           if f"{name}/{what}" in g["evaluation"]}
    # read as it is: a report of the old layout needs no migration (and writes nothing)
    res = run_layout_3(store, "stage=report", "evaluate.k=4", "report.c_folds=2",
                       f"report.dir={tmp_path / 'report'}")
    assert res.returncode == 0, res.stderr + res.stdout
    assert "migrated" not in res.stdout and _status(store)["layout_version"] == 3
    # the first run with work migrates it: here instance specs to sample again, which
    # changes none of the evaluation's inputs
    (store / "instances" / "spec" / "c" / "1").unlink()
    res = run_layout_3(store, "stage=generate")
    assert res.returncode == 0, res.stderr + res.stdout
    assert "migrated to layout 4" in res.stdout and "repaired" in res.stdout
    doc = _status(store)
    assert doc["layout_version"] == LAYOUT_VERSION and not doc["damaged"]
    g = zarr.open_group(store, mode="r")
    for key, values in before.items():
        assert g[key][...].tobytes() == values.tobytes(), key
    evaluation = xr.open_zarr(store, group="evaluation")
    assert list(evaluation.selector.values) == names  # regrouped, not computed again
    for (name, what), values in old.items():
        new = evaluation[what].sel(selector=name).values
        assert new.tobytes() == values.tobytes(), (name, what)
    # its intervals were percentile ones: the next evaluate with the same settings (the
    # selectors it was run with, not today's defaults) computes them as this version does
    same = (f"evaluate.selectors=[{','.join(info['settings']['selectors'])}]", "evaluate.k=4")
    res = run_layout_3(store, "stage=evaluate", *same)
    assert res.returncode == 0, res.stderr + res.stdout
    assert "its intervals are percentile bootstrap" in res.stdout
    res = run_layout_3(store, "stage=evaluate", *same)
    assert "evaluate: already complete" in res.stdout
    assert list(xr.open_zarr(store, group="constraints").feature.values) == ["via_x", "via_y"]
    assert isinstance(with_names(xr.open_zarr(store, group="scores")).status.to_series(),
                      pd.Series)


def test_a_migrated_store_with_a_damaged_evaluation_computes_it_again(tmp_path):
    store = _layout_3_copy(tmp_path)
    shutil.rmtree(store / "evaluation" / "box" / "order" / "c")
    res = run_layout_3(store, "stage=evaluate", "evaluate.k=4")
    assert res.returncode == 0, res.stderr + res.stdout
    assert "evaluation: damaged or incomplete" in res.stdout
    assert "evaluate: already complete" not in res.stdout
    assert not _status(store)["damaged"]
    assert "box" in xr.open_zarr(store, group="evaluation").selector.values
