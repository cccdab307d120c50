"""Closes a worker while its heartbeat to the scheduler is in flight, then waits until the
worker has left; run as ``python -m tests.cluster.heartbeat_race bare|connect`` and read its
stderr.  ``bare``: a plain LocalCluster, where distributed logs the aborted heartbeat with
its tracebacks; ``connect``: the cluster a run gets (pipeline.cluster.connect)."""

from __future__ import annotations

import asyncio
import contextlib
import io
import sys
import time

from distributed import Client, LocalCluster
from rich.console import Console


async def _race(dask_worker) -> None:
    asyncio.ensure_future(dask_worker.heartbeat())
    await asyncio.sleep(0)  # the heartbeat's request is on its way
    asyncio.ensure_future(dask_worker.close(nanny=False))


@contextlib.contextmanager
def _bare():
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        yield client


def _run(client) -> None:
    (address,) = client.run(_race)
    deadline = time.monotonic() + 60
    while address in client.scheduler_info()["workers"]:
        assert time.monotonic() < deadline, "the worker did not close"
        time.sleep(0.1)
    time.sleep(0.5)  # whatever it logs while closing has reached stderr


def main(kind: str) -> None:
    if kind == "bare":
        with _bare() as client:
            _run(client)
        return
    from pipeline.cluster import connect
    from pipeline.configs import ClusterConfig

    with connect(ClusterConfig(n_workers=1, dashboard_address=None),
                 Console(file=io.StringIO())) as client:
        _run(client)


if __name__ == "__main__":
    main(sys.argv[1])
