"""Fencing of the local run lock (issue 24, case 4): removing the lock file while a run
holds it no longer lets two writers in.  The holder finds out before its next write and
stops with one line, never saying "complete"; a run that ends removes its lock file."""

import signal
import time

from pipeline.store.locking import LOCK_SUFFIX, StoreLock
from tests import pipeline_runs as pr


def _wait_for_a_block(proc, store) -> None:
    deadline = time.monotonic() + 300
    while pr.done_count(store) == 0:
        assert proc.poll() is None, proc.stdout.read()
        assert time.monotonic() < deadline
        time.sleep(0.05)


def test_a_holder_whose_lock_file_was_removed_stops_before_its_next_write(made, tmp_path):
    store = tmp_path / "a.zarr"
    lock = store.with_name(store.name + LOCK_SUFFIX)
    run = pr.start(store, "stage=generate", "cluster.n_workers=1")
    _wait_for_a_block(run, store)
    run.send_signal(signal.SIGSTOP)  # the holder, paused between two writes
    try:
        written = pr.done_count(store)
        lock.unlink()  # what a user tidying up might do
        other = StoreLock(store)
        other.acquire()  # a second run takes the lock at the path
        run.send_signal(signal.SIGCONT)
        out, _ = run.communicate(timeout=300)
        assert run.returncode != 0, out
        said = [line for line in out.splitlines() if "no longer its only writer" in line]
        assert len(said) == 1 and "complete" not in out.split(said[0])[1], out
        assert "scores: 24 x 15 complete" not in out
        assert pr.done_count(store) <= written + 30  # at most the block it was writing
        other.release()
    finally:
        if run.poll() is None:
            run.send_signal(signal.SIGCONT)
            run.kill()
    assert not lock.exists()  # released: removed with its lock held
    res = pr.run(store, "stage=generate")
    assert res.returncode == 0, res.stderr + res.stdout
    assert pr.same_matrix(pr.matrix(store), pr.matrix(made[0]))
    assert not lock.exists()


def test_a_lock_file_removed_while_nobody_else_locked_it_is_taken_again(tmp_path):
    store = tmp_path / "b.zarr"
    mine = StoreLock(store)
    mine.acquire()
    mine.path.unlink()
    mine.check()  # nobody took it: this holder locks the file there again
    assert mine.path.exists()
    other = StoreLock(store)
    try:
        other.acquire()
    except Exception as exc:  # noqa: BLE001
        assert "in use" in str(exc)
    else:
        raise AssertionError("a second holder got the lock")
    mine.release()
    assert not mine.path.exists()
