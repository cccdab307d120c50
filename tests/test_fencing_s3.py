"""Fencing of the S3 lease (issue 24, case 3), with a real S3 server (``moto_server``) and
real runs: a run paused past its lease's lifetime loses the lease to a second run, and when
it is resumed it stops before writing again, in one line, with a non-zero exit, never saying
"complete".  The lease itself is only ever written conditionally (If-None-Match to create,
If-Match on the ETag its writer last saw to renew or take over), so two runs can never both
hold it: the in-process tests race holders and takers on one lease object."""

import os
import signal
import threading
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipeline.store.errors import LockError
from pipeline.store.location import locate
from pipeline.store.locking import LEASE_ENV, LeaseLock, StoreLock
from tests import pipeline_runs as pr
from tests.s3_server import BUCKET, done, serve

#: The lease lifetime of the runs here (seconds; 60 by default): short, so that the paused
#: run's lease expires soon.  Nothing else competes for the lease while a run holds it, so
#: a heartbeat made late by a loaded machine costs nothing: the run renews it conditionally.
LEASE_S = 3.0
#: A small planar store: 12 blocks of 2 x 2 entries, so a run is still writing when paused.
SIZE = ("instances.n=8", "constraints.m=6", "store.block_instances=2",
        "store.block_constraints=2", "cluster.n_workers=1")
ENTRIES = 8 * 6
#: The longest wait for anything here; a wait that runs out fails, naming what it waited for.
PATIENCE_S = 400


@pytest.fixture(scope="module")
def s3():
    """The server's environment, with versioning on in its bucket: every write of an object
    leaves a version, so "nothing was written" can be checked exactly."""
    with serve() as env:
        _client().put_bucket_versioning(Bucket=BUCKET,
                                        VersioningConfiguration={"Status": "Enabled"})
        yield env


def _client():
    import boto3

    return boto3.client("s3", endpoint_url=os.environ["AWS_ENDPOINT_URL"])


def _versions(prefix: str) -> set[tuple[str, str]]:
    """Every (key, version) under ``prefix``, delete markers included."""
    found = set()
    for page in _client().get_paginator("list_object_versions").paginate(Bucket=BUCKET,
                                                                         Prefix=prefix):
        for v in page.get("Versions", []) + page.get("DeleteMarkers", []):
            found.add((v["Key"], v["VersionId"]))
    return found


def _group(pgid: int) -> list[int]:
    """The processes of process group ``pgid`` (a run and its Dask workers)."""
    pids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue  # gone meanwhile
        if int(fields[2]) == pgid:
            pids.append(int(stat.parent.name))
    return pids


def _wait(what: str, ready, proc=None) -> None:
    deadline = time.monotonic() + PATIENCE_S
    while not ready():
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"the run ended while waiting for {what}:\n"
                                 f"{proc.stdout.read()}")
        assert time.monotonic() < deadline, f"waited {PATIENCE_S} s for {what}"
        time.sleep(0.2)


def _pause_between_writes(run, prefix: str) -> None:
    """SIGSTOP ``run`` while it writes nothing: its workers first (no result comes in, so
    the coordinator, which writes every block, finishes the block it may be writing and
    waits), then, once nothing in the store has changed for a while, the coordinator."""
    for pid in _group(run.pid):
        if pid != run.pid:
            os.kill(pid, signal.SIGSTOP)
    seen = [_versions(prefix)]

    def quiet() -> bool:
        time.sleep(1.5)
        seen.append(_versions(prefix))
        return seen[-1] == seen[-2]

    _wait("the paused run's last write", quiet, run)
    os.killpg(run.pid, signal.SIGSTOP)


def test_a_run_whose_lease_was_taken_over_stops_before_its_next_write(s3, tmp_path,
                                                                         monkeypatch):
    monkeypatch.setenv(LEASE_ENV, str(LEASE_S))  # for both runs
    url = f"s3://{BUCKET}/runs/fenced.zarr"
    prefix = "runs/fenced.zarr"  # the store and its lease object
    a = pr.start(url, "stage=generate", *SIZE, cwd=tmp_path)
    try:
        _wait("run A's first block", lambda: done(url) > 0, a)
        _pause_between_writes(a, prefix + "/")
        assert done(url) < ENTRIES, "run A finished before it was paused: nothing to test"
        _wait("run A's lease to expire", lambda: StoreLock(url).held_by_other() is None)

        b = pr.run(url, "stage=generate", *SIZE, cwd=tmp_path)  # takes the lease over
        assert b.returncode == 0, b.stdout + b.stderr
        assert "entries already done" in b.stdout and "complete" in b.stdout, b.stdout
        assert "took over the lease of a run presumed dead (pid" in b.stdout, b.stdout
        after_b = _versions(prefix)

        os.killpg(a.pid, signal.SIGCONT)
        out, _ = a.communicate(timeout=PATIENCE_S)
    finally:
        if a.poll() is None:
            os.killpg(a.pid, signal.SIGKILL)
            os.killpg(a.pid, signal.SIGCONT)
            a.wait(timeout=60)
    assert a.returncode == 2, out
    said = [line for line in out.splitlines() if "no longer its only writer" in line]
    assert len(said) == 1 and "lease" in said[0], out
    assert "complete" not in out and "Traceback" not in out, out
    assert _versions(prefix) == after_b  # A wrote nothing after it was resumed

    from pipeline.cli import app

    status = CliRunner().invoke(app, ["status", url])
    assert status.exit_code == 0, status.output


def _stale_lease(url: str) -> None:
    """The lease object of a run that died elsewhere long ago."""
    fs, key = locate(url).sibling(".lock").filesystem()
    fs.pipe_file(key, b'{"owner": "dead", "host": "elsewhere", "pid": 1, "since": "?", '
                      b'"heartbeat": 0.0, "lease_seconds": 60.0}')


def _race(takers: list[LeaseLock]) -> list[LeaseLock]:
    """Those of ``takers`` that got the lease, all trying at once."""
    start, got = threading.Barrier(len(takers)), []

    def take(lock):
        start.wait()
        try:
            lock.acquire()
        except LockError:
            return
        got.append(lock)

    threads = [threading.Thread(target=take, args=(t,)) for t in takers]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    return got


def test_takers_of_one_expired_lease_never_both_get_it(s3):
    url = f"s3://{BUCKET}/locks/raced.zarr"
    for _ in range(10):
        _stale_lease(url)
        takers = [LeaseLock(locate(url)) for _ in range(3)]
        got = _race(takers)
        assert len(got) == 1, f"{len(got)} takers hold the lease"
        assert got[0].took_over.startswith("pid 1 on elsewhere"), got[0].took_over
        got[0].check()
        for lock in takers:
            if lock is not got[0]:
                with pytest.raises(LockError, match="no longer its only writer"):
                    lock.check()
        got[0].release()


def test_a_holder_presumed_dead_cannot_renew_over_its_successor(s3):
    url = f"s3://{BUCKET}/locks/renewed.zarr"
    a = LeaseLock(locate(url), lease_seconds=1.0)
    a.acquire()
    assert a.took_over is None  # a lease where there was none
    a._stop.set()  # A's heartbeat stops (as if A were paused) ...
    a._thread.join()
    time.sleep(1.5)  # ... until its lease expires
    b = LeaseLock(locate(url))
    b.acquire()  # takes A's expired lease over
    a.renew()  # A, resumed just before renewing, cannot replace B's lease ...
    with pytest.raises(LockError, match="lease was taken over"):
        a.check()  # ... and stops before its next write
    b.check()  # B still holds it
    a.release()  # leaves B's lease alone
    b.check()
    assert StoreLock(url).held_by_other() is not None
    b.release()
    assert StoreLock(url).held_by_other() is None
