"""The report's two long computations (a store's learning curve and BOX's C tuning), as
jobs that can start before the report does.

Both are seeded functions of the score matrix and a few settings alone, not of the stored
evaluation, so ``stage=all`` starts them beside ``evaluate`` (which leaves part of the
second core idle) and the report takes their results when it gets there.  A job is known
by a digest of its function and every input: the report uses a result computed earlier
only for the very job it would run itself, so the numbers are the same either way.
"""

from __future__ import annotations

import hashlib
import multiprocessing
import os
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

import box_core

#: The selectors a learning curve shows, those of them that were evaluated.
CURVE_SELECTORS = ("box", "eips", "static")


@dataclass(frozen=True)
class LoocvJob:
    """``fn(scores, **kwargs)``: one of the report's leave-one-out computations."""

    fn: Callable
    scores: np.ndarray
    kwargs: dict
    key: str = field(init=False)

    def __post_init__(self) -> None:
        h = hashlib.sha256(f"{self.fn.__module__}.{self.fn.__qualname__}".encode())
        for name, value in [("scores", self.scores), *sorted(self.kwargs.items())]:
            h.update(name.encode())
            if isinstance(value, np.ndarray):
                h.update(f"{value.dtype.str}{value.shape}".encode())
                h.update(np.ascontiguousarray(value).tobytes())
            else:
                h.update(repr(value).encode())
        object.__setattr__(self, "key", h.hexdigest())

    def run(self):
        return self.fn(self.scores, **self.kwargs)


def store_jobs(scores, *, times, feasible, forbidden, seed: int, failure_rule: str,
               evaluated, settings: dict) -> tuple[LoocvJob, LoocvJob]:
    """(learning curve, C tuning) of one store: its matrix, the ``evaluate.*`` failure rule
    and selectors it was evaluated with, the run's seed and the ``report.*`` ``settings``."""
    matrix = {"times": times, "feasible": feasible, "failure_rule": failure_rule,
              "forbidden": forbidden}
    curve = LoocvJob(box_core.learning_curve, scores, {
        "selectors": [s for s in CURVE_SELECTORS if s in evaluated],
        "fractions": list(settings["fractions"]), "repeats": settings["repeats"],
        "seed": seed, **matrix})
    tuning = LoocvJob(box_core.tune_c, scores, {
        "grid": list(settings["c_grid"]), "folds": settings["c_folds"], "seed": seed,
        **matrix})
    return curve, tuning


class JobsBeside:
    """Jobs running in ``processes`` spawned processes, their results by job key.

    ``niceness``: added to the processes' nice value.  Jobs started beside ``evaluate``
    run at the lowest priority, so that they take only the CPU time it leaves idle: it
    times the selectors' own computation by the clock, and competing processes would
    lengthen those times and with them its results.

    :meth:`close` stops whatever still runs (a failed or interrupted run does not wait
    for a C tuning nobody will read)."""

    def __init__(self, processes: int, niceness: int = 0) -> None:
        self._pool = multiprocessing.get_context("spawn").Pool(
            processes, initializer=os.nice if niceness else None,
            initargs=(niceness,) if niceness else ())
        self._started: dict = {}  # job key -> AsyncResult

    def start(self, job: LoocvJob) -> None:
        if job.key not in self._started:
            # the function itself, not the job: a child unpickling a job would import this
            # package (matplotlib, zarr: 1.5 s), the function only box_core (0.2 s)
            self._started[job.key] = self._pool.apply_async(job.fn, (job.scores,), job.kwargs)

    def has(self, job: LoocvJob) -> bool:
        return job.key in self._started

    def result(self, job: LoocvJob):
        """The job's result (waiting for it); raises what the job raised."""
        return self._started[job.key].get()

    def close(self) -> None:
        self._pool.terminate()
        self._pool.join()
