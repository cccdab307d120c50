"""Running blocks of planning calls on Dask: submission, retries, progress, and a watchdog
that stops a run with no usable worker left.  The cluster itself: ``pipeline.cluster``;
progress counts entries, also inside running blocks (``pipeline.entry_progress``)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass

from rich.console import Console

from pipeline.cluster import ClusterFailed, TaskFailed, connect_first
from pipeline.cluster.watchdog import Watchdog
from pipeline.entry_progress import EntryCount, counting
from pipeline.progress import EntryProgress

__all__ = ["Task", "TaskFailed", "connect_first", "dask_client", "run_tasks"]

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


def dask_client(cfg, console: Console, preload=()):
    """:func:`pipeline.cluster.connect` (imported here, with ``distributed``, only when a
    run starts or reaches a cluster)."""
    from pipeline.cluster.session import connect

    return connect(cfg, console, preload)


def _cannot_import(exc: BaseException) -> bool:
    from pipeline.cluster import worker_side

    return isinstance(exc, ModuleNotFoundError) and \
        (exc.name or "").split(".")[0] in worker_side.PACKAGES


def run_tasks(client, tasks: list[Task], on_done: Callable[[Task, dict], None], *,
              retries: int, label: str, console: Console, progress: bool,
              every_s: float) -> None:
    """Submit every task, call ``on_done`` in the coordinator as each finishes.

    Results are released as soon as they are consumed.  A task that still fails after
    ``retries`` is reported after the others finished (their work is kept).  While waiting,
    the client's watchdog (``pipeline.cluster.connect`` attaches one) stops the run with
    ClusterFailed when no worker is left or a worker cannot run this package's code.
    ``progress``: show the entries done (``pipeline.progress``; lines every ``every_s``
    seconds off a terminal).
    """
    from pipeline.cluster import worker_side

    watchdog = getattr(client, "watchdog", None) or Watchdog(
        client, timeout=180.0, digest=worker_side.code_digest(),
        say=lambda text: console.print(text, highlight=False))
    by_key = {t.key: t for t in tasks}
    failures = []
    shown = EntryProgress(label, sum(t.entries for t in tasks), console, enabled=progress,
                          every_s=every_s)
    with counting(client, {t.key: t.entries for t in tasks}) as count, shown:
        pending = {client.submit(t.fn, *t.args, key=t.key, retries=retries, pure=False)
                   for t in tasks}
        try:
            _consume(pending, by_key, on_done, failures, watchdog, label, count, shown)
        except BaseException:
            with contextlib.suppress(Exception):  # the cluster may be gone already
                client.cancel(list(pending))  # a failed write or Ctrl-C: no work left running
            raise
    if failures:
        task, exc = failures[0]
        raise TaskFailed(f"{len(failures)} of {len(tasks)} {label} blocks failed after "
                         f"{retries} retries; first: block {task.block}: {exc!r}. "
                         "Finished blocks are saved; re-run to retry the rest.")


def result_watched(future, watchdog, longest_wait_s: float = 60.0):
    """``future.result()``, checking the cluster while it waits.  A block can finish, then
    lose its worker before its result is gathered: Dask computes it again, which needs a
    worker, so with none left an unwatched ``result()`` waits forever (seen when every
    worker was killed while a result was being fetched).  A fetch that outlasts a wait is
    started again, so each wait is twice the last (up to ``longest_wait_s``): a large
    result on a slow link still arrives."""
    wait_s = POLL_S
    while True:
        try:
            return future.result(timeout=wait_s)
        except TimeoutError:
            if future.status == "error":  # the task's own TimeoutError
                raise
            watchdog.check()
            wait_s = min(2 * wait_s, longest_wait_s)


def _consume(pending: set, by_key, on_done, failures: list, watchdog, label: str,
             count: EntryCount, shown: EntryProgress) -> None:
    """Hand each finished future's result to ``on_done``; ``pending`` shrinks in place.
    An entry is counted done once its block's result has been handed over."""
    from distributed import wait

    while pending:
        try:
            finished = wait(pending, timeout=POLL_S, return_when="FIRST_COMPLETED").done
        except TimeoutError:
            finished = set()
        pending -= finished
        for future in finished:
            task = by_key[future.key]
            try:
                result = result_watched(future, watchdog)
            except ClusterFailed:
                raise
            except Exception as exc:  # noqa: BLE001 (reported below, others go on)
                if _cannot_import(exc):
                    raise ClusterFailed(f"{label} block {task.block} failed on a worker "
                                        f"that cannot import this package: {exc}") from None
                failures.append((task, exc))
                count.drop(task.key)
            else:
                on_done(task, result)
                count.finish(task.key)
            future.release()
        shown.update(count.shown)
        if pending:
            watchdog.check()
