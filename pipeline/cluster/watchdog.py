"""Watching the workers while a run waits for results: a run never hangs silently."""

from __future__ import annotations

import time

from pipeline.cluster.checks import check_workers
from pipeline.cluster.errors import ClusterFailed


class Watchdog:
    """Called repeatedly by the coordinator while it waits (``check``), at most once per
    ``poll`` seconds it:

    * probes workers that joined since the last check (``check_workers``: package missing
      or another version stops the run);
    * stops the run when no worker has been connected for ``timeout`` seconds;
    * lets ``keeper`` (SLURM) replace jobs that ended early.
    """

    def __init__(self, client, *, timeout: float, digest: str, say, keeper=None,
                 hint: str = "", poll: float = 1.0):
        self.client, self.timeout, self.digest, self.say = client, timeout, digest, say
        self.keeper, self.hint, self.poll = keeper, hint, poll
        self.known: set[str] = set()
        self.empty_since: float | None = None
        self.last = -float("inf")

    def check(self, force: bool = False) -> int:
        """Run the checks if due (or ``force``); returns the number of workers connected."""
        now = time.monotonic()
        if not force and now - self.last < self.poll:
            return len(self.known)
        self.last = now
        workers = set(self.client.nthreads())
        if workers - self.known:
            check_workers(self.client, workers - self.known, self.digest, self.say)
        left = bool(self.known - workers)
        self.known = workers
        if workers:
            self.empty_since = None
        elif self.empty_since is None:
            self.empty_since = now
        elif now - self.empty_since >= self.timeout:
            raise ClusterFailed(f"no Dask worker connected for {self.timeout:g} s "
                                f"(cluster.worker_timeout){self.hint}")
        if self.keeper is not None:
            self.keeper.replace_lost(force=left)  # a worker left: was its job lost?
        return len(workers)

    def wait_for_first(self) -> int:
        """Block until a worker is connected (before any work: nothing to resume), or
        raise after ``timeout`` seconds."""
        start = time.monotonic()
        while True:
            self.empty_since = None
            n = self.check(force=True)
            if n:
                return n
            if time.monotonic() - start >= self.timeout:
                raise ClusterFailed(f"no Dask worker connected within {self.timeout:g} s "
                                    f"(cluster.worker_timeout){self.hint}")
            time.sleep(0.2)
