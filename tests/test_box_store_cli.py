"""``box status``, ``box show``, ``box export`` and ``box evaluate`` on a pipeline store."""

import csv
import json
import shutil

import numpy as np
import pytest
import zarr
from typer.testing import CliRunner

from pipeline.cli import app

runner = CliRunner()


def test_status_reports_stages_and_exit_codes(made, tmp_path):
    store, _ = made
    res = runner.invoke(app, ["status", str(store), "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    assert all(doc["stages"][s]["finished"] for s in ("instances", "raw", "constraints",
                                                       "scores", "evaluate"))
    assert doc["stages"]["scores"]["done"] == doc["stages"]["scores"]["total"] == 24 * 15
    copy = tmp_path / "c.zarr"
    shutil.copytree(store, copy)
    chunk = copy / "scores" / "length" / "c" / "1" / "2"
    chunk.write_bytes(chunk.read_bytes()[:-3] + b"xyz")
    (copy / "scores" / "time" / "c" / "0" / "1").unlink()
    root = zarr.open_group(copy, mode="r", use_consolidated=False)
    res = runner.invoke(app, ["status", str(copy), "--json"])
    counted = {a["array"]: a["chunks_written"] for a in json.loads(res.output)["arrays"]}
    assert counted == {key: root[key].nchunks_initialized for key in counted}  # Zarr's count
    assert counted["scores/time"] == counted["scores/length"] - 1
    res = runner.invoke(app, ["status", str(copy)])
    assert res.exit_code == 1 and "corrupted" in res.output
    res = runner.invoke(app, ["status", str(tmp_path / "missing.zarr")])
    assert res.exit_code == 2 and "no store" in res.output


def test_show_replans_the_stored_entry_and_writes_a_png(made, tmp_path):
    store, _ = made
    feasible = zarr.open_array(store / "scores" / "feasible", mode="r")[...]
    i, j = map(int, np.argwhere(feasible)[0])
    out = tmp_path / "entry.png"
    res = runner.invoke(app, ["show", str(store), "-i", str(i), "-c", str(j), "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert "feasible, length" in res.output and "as in the score matrix" in res.output
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    res = runner.invoke(app, ["show", str(store), "-i", "3", "-o", str(tmp_path / "i.png")])
    assert res.exit_code == 0 and (tmp_path / "i.png").exists()
    for args, message in ((["-i", "24"], "out of range"), (["-i", "0", "-c", "15"],
                                                           "out of range")):
        res = runner.invoke(app, ["show", str(store), *args, "-o", str(tmp_path / "x.png")])
        assert res.exit_code == 2 and message in res.output


def test_export_npz_round_trips_through_box_evaluate(made, tmp_path):
    store, _ = made
    out = tmp_path / "d.npz"
    res = runner.invoke(app, ["export", str(store), "-o", str(out)])
    assert res.exit_code == 0, res.output
    with np.load(out) as data:
        length = zarr.open_array(store / "scores" / "length", mode="r")[...]
        feasible = data["feasible"]
        np.testing.assert_array_equal(data["scores"][feasible], -length[feasible])
        assert json.loads(str(data["metadata"]))["complete"] is True
        assert data["features"].shape == (15, 2)
    a = runner.invoke(app, ["evaluate", str(out), "--json", "--no-overhead"])
    b = runner.invoke(app, ["evaluate", str(store), "--json", "--no-overhead"])
    assert a.exit_code == b.exit_code == 0
    sa, sb = json.loads(a.output)["selectors"], json.loads(b.output)["selectors"]
    assert [s["mean_time"] for s in sa] == [s["mean_time"] for s in sb]


def test_export_csv_holds_one_row_per_entry(made, tmp_path):
    store, _ = made
    res = runner.invoke(app, ["export", str(store), "--format", "csv", "-o", str(tmp_path / "c")])
    assert res.exit_code == 0, res.output
    with open(tmp_path / "c" / "entries.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 24 * 15
    status = zarr.open_array(store / "scores" / "status", mode="r")[...]
    from pipeline.planning import Status

    assert [r["status"] for r in rows] == [Status(c).name.lower() for c in status.reshape(-1)]
    score = zarr.open_array(store / "scores" / "score", mode="r")[...].reshape(-1)
    assert [float(r["score"]) if r["score"] else None for r in rows] == [
        None if np.isnan(x) else float(x) for x in score]
    meta = json.loads((tmp_path / "c" / "metadata.json").read_text())
    assert meta["config"]["domain"]["name"] == "planar"
    assert meta["steps"] == ["via_leg", "goal_leg"]
    steps = {r["step"] for r in rows if r["feasible"] == "0"}
    assert steps and steps <= {"via_leg", "goal_leg"}
    assert {r["step"] for r in rows if r["feasible"] == "1"} == {""}


def test_export_refuses_bad_formats_and_foreign_paths(made, tmp_path):
    res = runner.invoke(app, ["export", str(made[0]), "--format", "xlsx"])
    assert res.exit_code == 2 and "unknown format" in res.output
    (tmp_path / "mine").mkdir()
    res = runner.invoke(app, ["export", str(tmp_path / "mine")])
    assert res.exit_code == 2


@pytest.mark.parametrize("fmt, suffix", [("npz", ".npz"), ("netcdf", ".nc"),
                                         ("parquet", ".parquet")])
def test_every_export_keeps_nan_scores_and_evaluates_like_its_store(made, tmp_path, fmt,
                                                                   suffix):
    """Infeasible entries are NaN (never 0, the best score), the failure value that box
    evaluate puts in their place is in the file, and box evaluate reads the export back
    to the store's own result."""
    store, _ = made
    out = tmp_path / f"d{suffix}"
    res = runner.invoke(app, ["export", str(store), "-f", fmt, "-o", str(out)])
    assert res.exit_code == 0, res.output
    a = runner.invoke(app, ["evaluate", str(out), "--json", "--no-overhead"])
    b = runner.invoke(app, ["evaluate", str(store), "--json", "--no-overhead"])
    assert a.exit_code == b.exit_code == 0, a.output
    da, db = json.loads(a.output), json.loads(b.output)
    assert da["failure_value"] == db["failure_value"] and da["feasibility"] == "given"
    assert [s["mean_time"] for s in da["selectors"]] == [s["mean_time"] for s in db["selectors"]]
    feasible = zarr.open_array(store / "scores" / "feasible", mode="r")[...]
    if fmt == "npz":
        with np.load(out) as data:
            scores, meta = data["scores"], json.loads(str(data["metadata"]))
    elif fmt == "netcdf":
        import xarray as xr

        with xr.open_dataset(out) as ds:
            scores, meta = ds["scores"].values, json.loads(ds.attrs["metadata"])
            assert ds["times"].attrs["units"] == "seconds" and ds["times"].dtype == float
            assert ds["scores"].attrs["units"] == "m"  # the planar domain's lengths
            assert list(ds["feature"].values) == ["via_x", "via_y"]
            assert ds.indexes["instance"].tolist() == list(range(feasible.shape[0]))
            from pipeline.dataset import with_names
            assert set(np.unique(with_names(ds)["status"].values)) <= {
                "ok", "no_ik", "goal_in_collision", "budget_exhausted", "start_in_collision"}
            assert ds.attrs["failure_value"] == db["failure_value"]
    else:
        import pandas as pd
        import pyarrow.parquet as pq

        frame = pd.read_parquet(out)
        scores = frame["score"].to_numpy().reshape(feasible.shape)
        meta = json.loads(pq.read_schema(out).metadata[b"box-planning"])
        assert set(frame["status"]) <= {"ok", "no_ik", "goal_in_collision",
                                        "budget_exhausted", "start_in_collision"}
    assert np.isnan(scores[~feasible]).all() and (scores[feasible] < 0).all()
    assert meta["failure_value"] == db["failure_value"]


def test_evaluate_takes_nan_scores_with_a_mask_and_says_how_it_derives_feasibility(tmp_path):
    rng = np.random.default_rng(0)
    feasible = rng.random((12, 6)) < 0.5
    feasible[:, 0] = True
    scores = np.where(feasible, -rng.random((12, 6)) - 1, np.nan)
    with_mask, without = tmp_path / "m.npz", tmp_path / "n.npz"
    np.savez(with_mask, scores=scores, feasible=feasible)
    np.savez(without, scores=scores)
    res = runner.invoke(app, ["evaluate", str(with_mask), "--json", "--no-overhead"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["feasibility"] == "given"
    res = runner.invoke(app, ["evaluate", str(without)])
    assert res.exit_code == 2 and "NaN may mark infeasible entries only" in res.output
    np.savez(without, scores=np.where(feasible, scores, -5.0))
    res = runner.invoke(app, ["evaluate", str(without), "--json", "--no-overhead"])
    assert res.exit_code == 0
    assert json.loads(res.stdout)["feasibility"].startswith("derived: entries scoring above")
