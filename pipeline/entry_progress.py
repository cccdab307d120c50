"""Entries finished inside running blocks: workers report them, the coordinator counts them.

A block takes a minute or more, so counting only finished blocks leaves a run at "0/2400"
for its first minute.  A task reports how many of its entries it has finished as a Dask
event (``Worker.log_event`` on :data:`TOPIC`, at most every :data:`REPORT_EVERY_S` seconds,
naming its task key); the scheduler forwards it to the subscribed coordinator
(``Client.subscribe_topic``).  Events travel on the connections workers and clients already
keep with the scheduler: nothing to create or clean up, and they work alike on a local
cluster, a shared scheduler and SLURM workers.

Reports only ever show work *in progress*: an entry counts as done when the coordinator has
its block's result (:meth:`EntryCount.finish`).  A task's latest report replaces its
earlier ones, so a retried task (its worker lost, or it raised) starts again from its new
reports instead of adding to them, and reports that arrive after a block's result, or that
name another run's task (runs can share a scheduler), are ignored.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator

#: The Dask event topic of entry reports (their messages name the task, so one topic
#: serves every run on a scheduler).
TOPIC = "box-planning-entries"

#: Seconds between a running task's reports: enough for a bar that moves, and a few
#: hundred SLURM workers send the scheduler a few hundred small messages a second.
REPORT_EVERY_S = 1.0


class EntryReporter:
    """Counts the entries a block task has finished and reports the count (see the module
    docstring).  Outside a Dask worker (the function called directly) it only counts."""

    def __init__(self) -> None:
        self.done = 0
        self._worker, self._key = _current_task()
        self._last = time.monotonic()

    def add(self, n: int = 1) -> None:
        self.done += n
        now = time.monotonic()
        if self._worker is None or now - self._last < REPORT_EVERY_S:
            return
        self._last = now
        with contextlib.suppress(Exception):  # a lost report must never fail the block
            self._worker.log_event(TOPIC, {"key": self._key, "done": self.done})


def _current_task():
    """(worker, key of the task running in this thread), or (None, None) outside one."""
    try:
        from distributed import get_worker

        worker = get_worker()
        return worker, worker.get_current_task()
    except (ImportError, ValueError, KeyError):
        return None, None


class EntryCount:
    """Entries of a set of tasks (``entries``: key -> entries): those of finished tasks and
    those reported by running ones.  ``report`` runs on the client's event-loop thread, the
    rest on the coordinator's: a lock keeps the counts consistent."""

    def __init__(self, entries: dict[str, int]) -> None:
        self._pending = dict(entries)
        self._running: dict[str, int] = {}
        self._lock = threading.Lock()
        self.finished = 0

    def report(self, event) -> None:
        """A ``subscribe_topic`` handler: ``event`` is (scheduler time, message)."""
        try:
            _, msg = event
            key, done = msg["key"], int(msg["done"])
        except (TypeError, ValueError, KeyError):
            return
        with self._lock:
            if key in self._pending:
                self._running[key] = max(0, min(done, self._pending[key]))

    def finish(self, key: str) -> None:
        """The task's result was consumed: its entries are done."""
        with self._lock:
            self.finished += self._pending.pop(key)
            self._running.pop(key, None)

    def drop(self, key: str) -> None:
        """The task failed for good: its reported entries were not written."""
        with self._lock:
            self._pending.pop(key, None)
            self._running.pop(key, None)

    @property
    def shown(self) -> int:
        """Finished entries plus those reported by running tasks."""
        with self._lock:
            return self.finished + sum(self._running.values())


@contextlib.contextmanager
def counting(client, entries: dict[str, int]) -> Iterator[EntryCount]:
    """An :class:`EntryCount` fed by the scheduler's entry reports while the block runs
    (subscribe before submitting, so that no report is missed)."""
    count = EntryCount(entries)
    client.subscribe_topic(TOPIC, count.report)
    try:
        yield count
    finally:
        with contextlib.suppress(Exception):  # the cluster may be gone already
            client.unsubscribe_topic(TOPIC)
