"""Two runs with the same config on one shared Dask scheduler (a real ``dask scheduler`` and
two ``dask worker`` processes on 127.0.0.1), each into its own store: workers compute,
only each run's coordinator writes, and task keys name the run."""

import json
import shutil
import subprocess
import time

import pytest

from tests import pipeline_runs as pr


@pytest.fixture(scope="module")
def scheduler(tmp_path_factory):
    dask = shutil.which("dask")
    if dask is None:
        pytest.skip("the dask command line (distributed) is not installed")
    root = tmp_path_factory.mktemp("sched")
    info = root / "scheduler.json"
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0",
                               "--no-dashboard", "--scheduler-file", str(info)],
                              env=pr.env(), stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)]
    try:
        while not info.exists():
            assert procs[0].poll() is None, "dask scheduler exited"
            time.sleep(0.1)
        address = json.loads(info.read_text())["address"]
        for _ in range(2):
            procs.append(subprocess.Popen(
                [dask, "worker", address, "--nthreads", "1", "--no-dashboard",
                 "--host", "127.0.0.1"], env=pr.env(), stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL, cwd=root))
        from distributed import Client

        with Client(address, timeout="60s") as client:
            client.wait_for_workers(2, timeout=120)
        yield address
    finally:
        for proc in reversed(procs):
            proc.terminate()
        for proc in procs:
            proc.wait(timeout=60)


def test_two_concurrent_runs_on_one_scheduler_both_complete_identically(scheduler, tmp_path):
    stores = [tmp_path / "a" / "run.zarr", tmp_path / "b" / "run.zarr"]
    for store in stores:
        store.parent.mkdir()
    procs = [pr.start(store, "stage=generate", "cluster=address",
                      f"cluster.address={scheduler}") for store in stores]
    outputs = [proc.communicate(timeout=600)[0] for proc in procs]
    for proc, output in zip(procs, outputs, strict=True):
        assert proc.returncode == 0, output
        assert "scores: 24 x 15 complete" in output
    a, b = (pr.matrix(store) for store in stores)
    assert (a["status"] >= 0).all() and (b["status"] >= 0).all()  # every entry computed
    assert pr.same_matrix(a, b)
