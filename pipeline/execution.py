"""Running blocks of planning calls on Dask: submission, retries, progress, and a watchdog
that stops a run with no usable worker left.  The cluster itself: ``pipeline.cluster``."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from pipeline.cluster import ClusterFailed, TaskFailed, connect_first, tune_workers, worker_side
from pipeline.cluster import connect as dask_client
from pipeline.cluster.watchdog import Watchdog

__all__ = ["Task", "TaskFailed", "connect_first", "dask_client", "run_tasks", "tune_workers"]

#: Seconds between checks of the cluster while waiting for results.
POLL_S = 1.0


@dataclass(frozen=True)
class Task:
    """One block: ``fn(*args)`` computes ``entries`` planning calls; ``key`` names it."""

    key: str
    fn: Callable
    args: tuple
    entries: int
    block: tuple


def _cannot_import(exc: BaseException) -> bool:
    return isinstance(exc, ModuleNotFoundError) and \
        (exc.name or "").split(".")[0] in worker_side.PACKAGES


def run_tasks(client, tasks: list[Task], on_done: Callable[[Task, dict], None], *,
              retries: int, label: str, console: Console, progress: bool) -> None:
    """Submit every task, call ``on_done`` in the coordinator as each finishes.

    Results are released as soon as they are consumed.  A task that still fails after
    ``retries`` is reported after the others finished (their work is kept).  While waiting,
    the client's watchdog (``pipeline.cluster.connect`` attaches one) stops the run with
    ClusterFailed when no worker is left or a worker cannot run this package's code.
    """
    watchdog = getattr(client, "watchdog", None) or Watchdog(
        client, timeout=180.0, digest=worker_side.code_digest(),
        say=lambda text: console.print(text, highlight=False))
    by_key = {t.key: t for t in tasks}
    total = sum(t.entries for t in tasks)
    pending = {client.submit(t.fn, *t.args, key=t.key, retries=retries, pure=False)
               for t in tasks}
    failures = []
    columns = (TextColumn(f"[bold]{label}"), BarColumn(), MofNCompleteColumn(),
               TextColumn("entries"), TextColumn("{task.fields[rate]} /s"), TimeElapsedColumn(),
               TextColumn("ETA"), TimeRemainingColumn())
    try:
        _consume(client, pending, by_key, on_done, failures, watchdog, label, total, columns,
                 console, progress)
    except BaseException:
        with contextlib.suppress(Exception):  # the cluster may be gone already
            client.cancel(list(pending))  # a failed write or Ctrl-C: no work left running
        raise
    if failures:
        task, exc = failures[0]
        raise TaskFailed(f"{len(failures)} of {len(tasks)} {label} blocks failed after "
                         f"{retries} retries; first: block {task.block}: {exc!r}. "
                         "Finished blocks are saved; re-run to retry the rest.")


def _consume(client, pending: set, by_key, on_done, failures: list, watchdog, label: str,
             total: int, columns, console, progress: bool) -> None:
    """Hand each finished future's result to ``on_done``; ``pending`` shrinks in place."""
    from distributed import wait

    start = time.perf_counter()
    with Progress(*columns, console=console, disable=not progress, transient=False) as bar:
        job = bar.add_task(label, total=total, rate="-")
        done = 0
        while pending:
            try:
                finished = wait(pending, timeout=POLL_S, return_when="FIRST_COMPLETED").done
            except TimeoutError:
                finished = set()
            pending -= finished
            for future in finished:
                task = by_key[future.key]
                try:
                    result = future.result()
                except Exception as exc:  # noqa: BLE001 (reported below, others go on)
                    if _cannot_import(exc):
                        raise ClusterFailed(f"{label} block {task.block} failed on a worker "
                                            f"that cannot import this package: {exc}") from None
                    failures.append((task, exc))
                else:
                    on_done(task, result)
                    done += task.entries
                    rate = done / max(time.perf_counter() - start, 1e-9)
                    bar.update(job, completed=done, rate=f"{rate:,.0f}")
                future.release()
            if pending:
                watchdog.check()
