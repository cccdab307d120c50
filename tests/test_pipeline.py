"""End-to-end runs of ``python -m pipeline`` on the planar domain: completion, resume,
integrity and refusals.  The reference store is computed once per module."""

import json
import os
import shutil
import signal
import time

import numpy as np
import pytest
import xarray as xr

from tests import pipeline_runs as pr


@pytest.fixture(scope="module")
def reference(made_run, tmp_path_factory):
    """An uninterrupted ``stage=all`` run with two workers: the session's (``made_run``),
    its store copied, since tests here run the pipeline on it again."""
    made, _, res = made_run
    store = tmp_path_factory.mktemp("ref") / "ref.zarr"
    shutil.copytree(made, store)
    return store, res, pr.matrix(store)


def test_all_completes_and_reports(reference):
    store, res, D = reference
    assert "scores: 24 x 15 complete" in res.stdout
    assert "box" in res.stdout and "rawplanner" in res.stdout
    assert D["status"].min() >= 0  # every entry computed
    assert D["feasible"].any() and not D["feasible"].all()
    np.testing.assert_array_equal(np.isnan(D["score"]), ~D["feasible"])
    np.testing.assert_allclose(D["score"][D["feasible"]], -D["length"][D["feasible"]])


def test_store_opens_with_xarray_with_named_dimensions(reference):
    store, _, D = reference
    scores = xr.open_zarr(store, group="scores")
    assert scores["score"].dims == ("instance", "constraint")
    assert set(scores.data_vars) >= {"score", "length", "feasible", "time", "status", "checks",
                                     "done"}
    np.testing.assert_array_equal(scores["feasible"].values, D["feasible"])
    specs = xr.open_zarr(store, group="instances")["spec"].values
    assert json.loads(str(specs[0]))["domain"] == "planar"
    theta = xr.open_zarr(store, group="constraints")["theta"]
    assert theta.dims == ("constraint", "feature") and theta.shape == (15, 2)
    raw = xr.open_zarr(store, group="raw")
    assert raw["constraint"].dims == ("instance", "feature")
    box = xr.open_zarr(store, group="evaluation").sel(selector="box")
    assert box["order"].dims == ("instance", "step")


def test_root_attributes_describe_the_run(reference):
    store, _, _ = reference
    attrs = json.loads((store / "zarr.json").read_text())["attributes"]
    assert attrs["identity"]["instances"] == {"n": 24}
    assert attrs["config"]["domain"]["name"] == "planar"
    assert len(attrs["config_hash"]) == 16 and attrs["versions"]["zarr"]
    assert set(attrs["stages"]) == {"instances", "raw", "constraints", "scores", "evaluate"}


def test_rerunning_a_finished_run_does_nothing_and_says_so(reference):
    store, _, D = reference
    before = {p: p.stat().st_mtime_ns for p in (store / "scores").rglob("c/*/*")}
    res = pr.run(store, "stage=all")
    assert res.returncode == 0, res.stderr
    for stage in ("instances", "raw", "constraints", "scores", "evaluate"):
        assert f"{stage}: already complete" in res.stdout
    assert "dask:" not in res.stdout  # no cluster was even started
    after = {p: p.stat().st_mtime_ns for p in (store / "scores").rglob("c/*/*")}
    assert before == after
    assert pr.same_matrix(D, pr.matrix(store))


def test_one_worker_gives_the_same_matrix(reference, tmp_path):
    _, _, D = reference
    store = tmp_path / "one.zarr"
    res = pr.run(store, "stage=generate", "cluster.n_workers=1")
    assert res.returncode == 0, res.stderr
    assert pr.same_matrix(D, pr.matrix(store))


def _kill_when_some_blocks_done(proc, store, sig, group_kill=True):
    deadline = time.monotonic() + 300
    while pr.done_count(store) == 0:
        assert proc.poll() is None, proc.stdout.read()
        assert time.monotonic() < deadline
        time.sleep(0.05)
    if group_kill:
        os.killpg(proc.pid, sig)
    else:
        proc.send_signal(sig)
    proc.wait(timeout=120)


def test_kill_9_then_rerun_finishes_bitwise_identical_without_recomputing(reference, tmp_path):
    _, _, D = reference
    store = tmp_path / "killed.zarr"
    proc = pr.start(store, "stage=generate")
    _kill_when_some_blocks_done(proc, store, signal.SIGKILL)
    done_before = pr.done_count(store)
    assert 0 < done_before < D["score"].size, "the kill came too late to test resuming"
    chunk_times = _done_chunk_mtimes(store)
    res = pr.run(store, "stage=generate")
    assert res.returncode == 0, res.stderr
    assert f"{done_before} of {D['score'].size} entries already done" in res.stdout
    assert pr.same_matrix(D, pr.matrix(store))
    assert _done_chunk_mtimes(store, only=chunk_times) == chunk_times  # never recomputed


def _done_chunk_mtimes(store, only=None):
    import zarr

    done = zarr.open_array(store / "scores" / "done", mode="r")[...]
    out = {}
    for i, j in np.ndindex(4, 3):
        if done[i * 6:(i + 1) * 6, j * 5:(j + 1) * 5].all():
            p = store / "scores" / "score" / "c" / str(i) / str(j)
            if p.exists() and (only is None or p in only):
                out[p] = p.stat().st_mtime_ns
    return out


def test_ctrl_c_stops_cleanly_and_resumes(reference, tmp_path):
    _, _, D = reference
    store = tmp_path / "interrupted.zarr"
    # small blocks (60 of them): Ctrl-C lands while most are still to do, however fast the
    # machine (with 12 blocks an idle machine finished them all before the signal came)
    proc = pr.start(store, "stage=generate", "store.block_instances=2",
                    "store.block_constraints=3")
    _kill_when_some_blocks_done(proc, store, signal.SIGINT, group_kill=False)
    output = proc.stdout.read()
    assert proc.returncode == 130, output
    assert "re-run the same command to resume" in output
    res = pr.run(store, "stage=generate", "store.block_instances=2", "store.block_constraints=3")
    assert res.returncode == 0, res.stderr
    assert "already done" in res.stdout
    assert pr.same_matrix(D, pr.matrix(store))


def test_a_killed_worker_is_replaced_and_its_block_retried(reference, tmp_path):
    """The workers are forks of one server that imported the run's domain and planner,
    with the environment a spawned worker gets; killing one mid-run loses nothing."""
    _, _, D = reference
    store = tmp_path / "worker.zarr"
    proc = pr.start(store, "stage=generate")
    deadline = time.monotonic() + 300
    while pr.done_count(store) == 0:
        assert proc.poll() is None and time.monotonic() < deadline
        time.sleep(0.05)
    workers = pr.worker_processes(proc.pid)
    assert len(workers) == 2, f"expected the 2 workers, found {workers}"
    server = workers[0].parent()
    assert {w.parent().pid for w in workers} == {server.pid}
    assert server.parent().pid == proc.pid
    preloaded = " ".join(server.cmdline())
    assert "pipeline.domains.planar" in preloaded and "pipeline.planning.rrt_connect" in preloaded
    for worker in workers:
        env = worker.environ()
        assert env["OPENBLAS_NUM_THREADS"] == env["OMP_NUM_THREADS"] == "1"
        assert env["PYTHONHASHSEED"] == "6640" and "MALLOC_TRIM_THRESHOLD_" not in env
    workers[-1].kill()
    output, _ = proc.communicate(timeout=300)
    assert proc.returncode == 0, output
    assert pr.same_matrix(D, pr.matrix(store))


def test_corrupted_chunk_is_reported_and_recomputed(reference, tmp_path):
    store, _, D = reference
    copy = tmp_path / "copy.zarr"
    shutil.copytree(store, copy)
    chunk = copy / "scores" / "feasible" / "c" / "1" / "2"
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0xFF
    chunk.write_bytes(bytes(data))
    status = pr.run(copy, "stage=status")
    assert status.returncode == 1, status.stderr  # damage: non-zero, like box status
    assert "corrupted chunks found" in status.stdout and "scores/feasible" in status.stderr
    res = pr.run(copy, "stage=scores", "store.mode=resume")
    # the stage was finished: a resume must still notice damage
    assert res.returncode == 0, res.stderr
    assert pr.same_matrix(D, pr.matrix(copy))
    assert "corrupted chunks found" not in pr.run(copy, "stage=status").stdout


def test_stored_evaluation_is_the_full_runs_where_it_stops_early(reference):
    """Stage evaluate stops each held-out row once it has its first plan (or none to
    find) and its optimal score: the stored first feasible steps are a full run's through
    every try, each stored order is the start of the full run's order, and it holds the
    row's best plan of the full run (so the curves are the same)."""
    from pipeline.evaluation import store_loocv
    from pipeline.store import ScoreStore
    from pipeline.store import evaluation as evaluation_store

    path, _, D = reference
    store = ScoreStore.open(path)
    stored = evaluation_store.read(store)
    seed = int(store.attrs.get("config", {}).get("seed", 0))
    full = store_loocv(store, store.stage_info("evaluate")["settings"], seed,
                       until_best=False, measure_overhead=False, workers=1)
    plans = np.where(D["feasible"], D["score"], -np.inf)
    stopped = 0
    for name in full.selectors:
        np.testing.assert_array_equal(stored.first_feasible_step[name],
                                      full.first_feasible_step[name], err_msg=name)
        for i, whole in enumerate(full.order[name]):
            tried = stored.order[name][i][stored.order[name][i] >= 0]
            assert tried.tolist() == whole[:tried.size].tolist(), (name, i)
            assert plans[i, tried].max(initial=-np.inf) == plans[i, whole].max(initial=-np.inf)
            stopped += tried.size < whole.size
    assert stopped  # some row stopped before its last try
