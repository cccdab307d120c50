"""LocalCluster workers forked from one preloaded process instead of spawned afresh.

A spawned worker is a new interpreter that imports Dask, this package, the domain and the
planner before its first task (about 1.5 CPU-s each, most of a small run's cost). With
multiprocessing's ``forkserver`` method those imports happen once, in the fork server,
and every worker, a restarted one included, is a fork of it.

The fork server is started here, before the nannies start their workers, with the
environment the nannies would give a spawned worker (``distributed.nanny.pre-spawn-environ``,
which the nanny copies into this process's environment before each start anyway, and
Dask's fixed ``PYTHONHASHSEED``), so a forked worker sees what a spawned one would: one
BLAS thread, the same hash seed, the same settings.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Iterable
from multiprocessing import forkserver

#: What every worker imports before its first task, whatever the domain and planner
#: (``scipy.linalg`` and ``threadpoolctl``: the environment fingerprint of every block).
ALWAYS = ("distributed", "pipeline.worker", "scipy.linalg", "threadpoolctl")

#: Dask's default for its workers' hash seed (distributed.nanny.Nanny)
DASK_HASH_SEED = "6640"


def worker_environment() -> dict[str, str]:
    """The variables a nanny sets in its process before it starts a worker."""
    import dask

    env = {k: str(v) for k, v in
           (dask.config.get("distributed.nanny.pre-spawn-environ", {}) or {}).items()
           if v is not None}
    if env.get("PYTHONHASHSEED") in (None, "0"):
        env["PYTHONHASHSEED"] = DASK_HASH_SEED
    return env


def use_forked_workers(modules: Iterable[str] = ()) -> None:
    """Make this process's nannies fork their workers from a server that imported
    ALWAYS and ``modules`` (module names; one that cannot be imported is skipped there and
    imported by the worker as usual).  Call before the LocalCluster starts.  Where the
    platform has no fork server (Windows), workers are spawned as Dask does by default."""
    import dask

    if "forkserver" not in multiprocessing.get_all_start_methods():
        return

    dask.config.set({"distributed.worker.multiprocessing-method": "forkserver"})
    os.environ.update(worker_environment())
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(list(dict.fromkeys((*ALWAYS, *modules))))
    forkserver.ensure_running()
    # Dask would otherwise set its own preload list, importing pandas and others in this
    # process to do so; the server already runs with ours, so that list would be unused.
    import distributed.utils

    distributed.utils._forkserver_preload_set = True
