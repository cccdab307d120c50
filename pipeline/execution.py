"""Running blocks of planning calls on Dask: the cluster, submission, retries, progress."""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")  # before distributed loads

from rich.console import Console  # noqa: E402
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,  # noqa: E402
    TimeRemainingColumn,
)

from pipeline.configs import ClusterConfig, ClusterKind  # noqa: E402


@dataclass(frozen=True)
class Task:
    """One block: ``fn(*args)`` computes ``entries`` planning calls; ``key`` names it."""

    key: str
    fn: Callable
    args: tuple
    entries: int
    block: tuple


def tune_workers() -> None:
    """Dask settings that cost planning throughput, measured (benchmarks/bench_pipeline.py):

    * the nanny exports ``MALLOC_TRIM_THRESHOLD_=65536`` to its workers, which makes glibc
      return memory to the OS constantly: the planar planner ran 25-40 % slower with it;
    * the statistical profiler (every 10 ms) and the 20 ms event-loop tick take the GIL
      from the planning thread: together about 5-10 % more.

    Applies to workers this process starts (local, SLURM); workers of an existing
    scheduler keep their own settings.
    """
    import dask
    import distributed  # noqa: F401 (loads distributed's defaults first)

    environ = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}))
    environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    dask.config.set({"distributed.nanny.pre-spawn-environ": environ,
                     "distributed.worker.profile.enabled": False,
                     "distributed.admin.tick.interval": "1s"})


@contextlib.contextmanager
def dask_client(cfg: ClusterConfig, console: Console) -> Iterator:
    """A distributed Client for ``cluster.kind``: a LocalCluster, an existing scheduler,
    or SLURM through dask-jobqueue.  Closed (and a local cluster stopped) on exit."""
    from distributed import Client, LocalCluster

    tune_workers()
    if cfg.kind is ClusterKind.local:
        n = cfg.n_workers or os.cpu_count() or 1
        if n < 1:
            raise ValueError(f"cluster.n_workers must be >= 1, got {n}")
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=":0")
        client = Client(cluster)
    elif cfg.kind is ClusterKind.address:
        if not cfg.address:
            raise ValueError("cluster=address needs cluster.address=tcp://host:port")
        cluster = None
        client = Client(cfg.address, timeout="30s")
    else:
        try:
            from dask_jobqueue import SLURMCluster
        except ImportError:
            raise ValueError('cluster=slurm needs dask-jobqueue: pip install -e ".[slurm]"') \
                from None
        s = cfg.slurm
        cluster = SLURMCluster(queue=s.queue, account=s.account, cores=s.cores, processes=s.cores,
                               memory=s.memory, walltime=s.walltime)
        cluster.scale(n=cfg.n_workers or 1)
        client = Client(cluster)
    try:
        console.print(f"dask: {_describe(client)}; dashboard {client.dashboard_link}",
                      highlight=False)
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _describe(client) -> str:
    workers = client.scheduler_info().get("workers", {})
    return f"{len(workers)} workers at {client.scheduler.address}"


class TaskFailed(RuntimeError):
    pass


def run_tasks(client, tasks: list[Task], on_done: Callable[[Task, dict], None], *,
              retries: int, label: str, console: Console, progress: bool) -> None:
    """Submit every task, call ``on_done`` in the coordinator as each finishes.

    Results are released as soon as they are consumed.  A task that still fails after
    ``retries`` is reported after the others finished (their work is kept).
    """
    from distributed import as_completed

    by_key = {t.key: t for t in tasks}
    total = sum(t.entries for t in tasks)
    futures = [client.submit(t.fn, *t.args, key=t.key, retries=retries, pure=False)
               for t in tasks]
    failures = []
    columns = (TextColumn(f"[bold]{label}"), BarColumn(), MofNCompleteColumn(),
               TextColumn("entries"), TextColumn("{task.fields[rate]} /s"), TimeElapsedColumn(),
               TextColumn("ETA"), TimeRemainingColumn())
    start = time.perf_counter()
    with Progress(*columns, console=console, disable=not progress, transient=False) as bar:
        job = bar.add_task(label, total=total, rate="-")
        done = 0
        for future in as_completed(futures):
            task = by_key[future.key]
            try:
                result = future.result()
            except Exception as exc:  # noqa: BLE001 (reported below, others go on)
                failures.append((task, exc))
            else:
                on_done(task, result)
                done += task.entries
                rate = done / max(time.perf_counter() - start, 1e-9)
                bar.update(job, completed=done, rate=f"{rate:,.0f}")
            future.release()
    if failures:
        task, exc = failures[0]
        raise TaskFailed(f"{len(failures)} of {len(tasks)} {label} blocks failed after "
                         f"{retries} retries; first: block {task.block}: {exc!r}. "
                         "Finished blocks are saved; re-run to retry the rest.")
