"""A worker that closes while its heartbeat is in flight: distributed logs the aborted
heartbeat as an error with tracebacks (tests/cluster/heartbeat_race.py shows it on a plain
LocalCluster); the workers of a run drop that record, and only once they are closing."""

from __future__ import annotations

import logging
import subprocess
import sys

import pytest
from distributed.core import Status

from pipeline.cluster.worker_side import HEARTBEAT_FAILED, _ClosingHeartbeat
from tests import pipeline_runs as pr


def _race(kind: str) -> str:
    done = subprocess.run([sys.executable, "-m", "tests.cluster.heartbeat_race", kind],
                          capture_output=True, text=True, env=pr.env(), timeout=300,
                          cwd=pr.env()["PYTHONPATH"])
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stderr


def test_a_run_s_worker_closing_mid_heartbeat_logs_no_traceback():
    bare = _race("bare")
    if HEARTBEAT_FAILED not in bare:
        pytest.skip("the plain LocalCluster logged no aborted heartbeat (the heartbeat "
                    "finished before the close, or this distributed no longer logs it): no "
                    "race to compare with")
    assert "Traceback" in bare
    ours = _race("connect")
    assert HEARTBEAT_FAILED not in ours and "Traceback" not in ours, ours


class _Worker:
    """What the filter reads of a worker: its status (weakly referenced, as a worker)."""

    def __init__(self, status: Status):
        self.status = status


def _record(msg: str) -> logging.LogRecord:
    return logging.LogRecord("distributed.worker", logging.ERROR, __file__, 1, msg, (), None)


@pytest.mark.parametrize(("status", "kept"), [
    (Status.running, True), (Status.paused, True),
    (Status.closing, False), (Status.closing_gracefully, False), (Status.closed, False)])
def test_only_a_closing_worker_s_failed_heartbeat_is_dropped(status, kept):
    worker = _Worker(status)
    quiet = _ClosingHeartbeat(worker)
    assert quiet.filter(_record(HEARTBEAT_FAILED)) is kept
    assert quiet.filter(_record("Heartbeat to scheduler failed")) is True  # anything else
    del worker  # a worker that is gone has closed
    assert quiet.filter(_record(HEARTBEAT_FAILED)) is False
