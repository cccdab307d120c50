"""The two ways a cluster ends a run: bad settings (exit 2) or lost workers (exit 1)."""

from __future__ import annotations


class ClusterError(ValueError):
    """Bad cluster settings or an unreachable scheduler, found before anything is written."""


class TaskFailed(RuntimeError):
    """Blocks failed, or the cluster can no longer compute them; finished blocks are kept."""


RESUME_HINT = "Finished blocks are saved; re-run the same command to resume."


class ClusterFailed(TaskFailed):
    """The cluster cannot go on (no worker left, workers without this package or with
    another version of it).  The message names the cause and ends with the resume hint."""

    def __init__(self, cause: str, *, resumable: bool = True):
        self.cause = cause
        super().__init__(f"{cause}. {RESUME_HINT}" if resumable else cause)
