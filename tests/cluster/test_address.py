"""cluster=address against real ``dask scheduler`` / ``dask worker`` processes on 127.0.0.1."""

from __future__ import annotations

import operator
import re
import shutil
import threading
import time
from pathlib import Path

from distributed import Client, wait

from pipeline.cluster import ClusterFailed, worker_side
from pipeline.cluster.watchdog import Watchdog
from pipeline.execution import result_watched
from tests import pipeline_runs as pr
from tests.cluster.conftest import kill

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]


def address_run(store: Path, address: str, *overrides: str):
    return pr.run(store, "cluster=address", f"cluster.address={address}", *overrides)


def error_lines(stderr: str) -> list[str]:
    """stderr's lines, less the banner pybullet's C library prints when it loads."""
    return [line for line in stderr.splitlines()
            if line.strip() and not line.startswith("pybullet build time")]


def probe_all(address: str) -> dict:
    with Client(address, timeout="30s") as client:
        return client.run(worker_side.probe)


def test_no_scheduler_one_line_exit_2_nothing_written(tmp_path):
    store = tmp_path / "s.zarr"
    res = address_run(store, "tcp://127.0.0.1:9", "cluster.connect_timeout=2")
    assert res.returncode == 2
    lines = error_lines(res.stderr)
    assert len(lines) == 1 and "cluster.address=tcp://127.0.0.1:9" in lines[0], res.stderr
    assert not store.exists() and not Path(f"{store}.lock").exists()


def test_zero_workers_refused(tmp_path):
    store = tmp_path / "s.zarr"
    res = pr.run(store, "cluster.n_workers=0")
    assert res.returncode == 2
    assert error_lines(res.stderr) == ["error: cluster.n_workers must be >= 1 (or null), got 0"]
    assert not store.exists()


def test_scheduler_without_workers_stops_before_the_store(tmp_path, dask_procs):
    address = dask_procs.scheduler()
    store = tmp_path / "s.zarr"
    res = address_run(store, address, "cluster.worker_timeout=2")
    assert res.returncode == 1
    assert error_lines(res.stderr) == [
        f"failed: no Dask worker connected within 2 s (cluster.worker_timeout); check that "
        f"workers run for {address}"], res.stderr
    assert not store.exists() and not Path(f"{store}.lock").exists()


def test_same_matrix_as_local_and_workers_tuned(tmp_path, dask_procs, local_reference):
    address = dask_procs.scheduler()
    dask_procs.worker()
    dask_procs.worker()
    dask_procs.wait_for_workers(2)
    before = probe_all(address)
    assert all(p["env"].get("MALLOC_TRIM_THRESHOLD_") == "65536" for p in before.values())
    store = tmp_path / "a.zarr"
    res = address_run(store, address)
    assert res.returncode == 0, res.stderr
    assert "dask: 2 workers at " + address in res.stdout
    assert pr.same_matrix(pr.matrix(store), local_reference)
    after = probe_all(address)
    assert len(after) == 2
    for info in after.values():  # restarted by the run's nanny plugin, and still so
        assert info["env"] == {}
        assert info["config"] == worker_side.TUNED_CONFIG


def _wait_for_blocks(store: Path, proc, at_least: int = 1) -> int:
    while (done := pr.done_count(store)) < at_least:
        assert proc.poll() is None, proc.stdout.read()
        time.sleep(0.05)
    return done


def test_one_worker_killed_run_completes(tmp_path, dask_procs, local_reference):
    address = dask_procs.scheduler()
    doomed = dask_procs.worker()
    dask_procs.worker()
    dask_procs.wait_for_workers(2)
    store = tmp_path / "a.zarr"
    proc = pr.start(store, "cluster=address", f"cluster.address={address}", "progress=true",
                    "progress_every=0.01")
    assert _wait_for_blocks(store, proc) < 24 * 15  # killed mid-run
    kill(doomed)
    out = pr.finish(proc)
    assert proc.returncode == 0, out
    assert pr.same_matrix(pr.matrix(store), local_reference)
    # the lost worker's entries in progress are shown until its blocks run again; the
    # entries counted done are those written, each once
    counts = [int(k) for k in re.findall(r"scores: (\d+)/360 entries", out)]
    assert max(counts) == 360 and "scores: 360/360 entries (100%)" in out


def test_all_workers_killed_watchdog_stops_the_run(tmp_path, dask_procs):
    address = dask_procs.scheduler()
    workers = [dask_procs.worker(), dask_procs.worker()]
    dask_procs.wait_for_workers(2)
    store = tmp_path / "a.zarr"
    proc = pr.start(store, "cluster=address", f"cluster.address={address}",
                    "cluster.worker_timeout=3")
    _wait_for_blocks(store, proc)
    for w in workers:
        kill(w)
    out = pr.finish(proc)
    assert proc.returncode == 1, out
    assert "no Dask worker connected for 3 s (cluster.worker_timeout)" in out
    assert "re-run the same command to resume" in out
    assert pr.done_count(store) > 0  # finished blocks kept


def test_a_result_lost_with_its_last_worker_stops_the_wait(dask_procs):
    """The race behind a run that hung once in CI: a block finished, then every worker was
    killed before its result was fetched.  Dask computes it again, which needs a worker;
    the wait for it must end with the watchdog's ClusterFailed, not go on forever."""
    address = dask_procs.scheduler()
    worker = dask_procs.worker()
    dask_procs.wait_for_workers(1)
    with Client(address, timeout="30s") as client:
        future = client.submit(operator.add, 1, 2, key="lost-block")
        wait([future])  # finished: its result lives on the worker only
        kill(worker)
        watchdog = Watchdog(client, timeout=2.0, digest=worker_side.code_digest(),
                            say=lambda text: None)
        outcome = []

        def fetch():
            try:
                outcome.append(result_watched(future, watchdog))
            except BaseException as exc:  # noqa: BLE001 (what ended the wait)
                outcome.append(exc)

        waiting = threading.Thread(target=fetch, daemon=True)
        waiting.start()
        waiting.join(300)  # a guard against a hang (the watchdog needs a few seconds)
        assert not waiting.is_alive(), "the wait for a lost result never ended"
        assert isinstance(outcome[0], ClusterFailed), outcome
        assert "no Dask worker connected for 2 s" in str(outcome[0])


def test_worker_without_the_package_is_named(tmp_path, dask_procs):
    address = dask_procs.scheduler()
    dask_procs.worker("--preload", str(HERE / "hide_package.py"))
    dask_procs.wait_for_workers(1)
    store = tmp_path / "a.zarr"
    res = address_run(store, address, "cluster.worker_timeout=20")
    assert res.returncode == 1
    lines = error_lines(res.stderr)
    assert len(lines) == 1 and "cannot import this package" in lines[0], res.stderr
    assert not store.exists()  # checked on connect, before the store


def test_worker_with_another_version_is_named(tmp_path, dask_procs):
    other = tmp_path / "other"
    for package in worker_side.PACKAGES:
        shutil.copytree(ROOT / package, other / package,
                        ignore=shutil.ignore_patterns("__pycache__"))
    with open(other / "pipeline" / "stages" / "__init__.py", "a") as f:
        f.write("\n# another version\n")
    address = dask_procs.scheduler()
    dask_procs.worker(env={**pr.env(), "PYTHONPATH": str(other)})
    dask_procs.wait_for_workers(1)
    res = address_run(tmp_path / "a.zarr", address)
    assert res.returncode == 1
    lines = error_lines(res.stderr)
    assert len(lines) == 1 and "runs another version of this package" in lines[0], res.stderr
