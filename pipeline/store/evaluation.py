"""The store's ``evaluation/`` group: stage ``evaluate`` writes it, the report reads it.

One dataset along ``selector`` (layout 4), so that ``xarray.open_zarr(store,
group="evaluation").sel(selector="box")`` compares selectors without any concatenation::

    order                (selector, instance, step)  columns tried, in order, up to the
                                                     try after which nothing above can
                                                     change (a plan found, or none to
                                                     find, and the optimal score: loocv's
                                                     until_best); -1 after it and for
                                                     RAWPLANNER
    first_feasible_step  (selector, instance)        0-based step of the first feasible
                                                     try; -1: none (RAWPLANNER: -1)
    first_feasible_time  (selector, instance)        seconds to the first feasible plan
    best_score           (selector, instance, time)  best score found by each time
    eligible             (instance)                  rows with a feasible constraint
    optimal_score        (instance)                  each row's best score

RAWPLANNER is measured in stage ``raw``, not by leave-one-out: it has a time and a best
score curve (its one plan from the time it is found), no order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.configs import RAWPLANNER
from pipeline.store.integrity import digest
from pipeline.store.layout import (
    BEST_SCORE,
    ELIGIBLE,
    EVALUATION,
    EVALUATION_ARRAYS,
    EVALUATION_COORDS,
    EVALUATION_TIME,
    FIRST_FEASIBLE_STEP,
    FIRST_FEASIBLE_TIME,
    OPTIMAL_SCORE,
    ORDER,
    RAW,
    SELECTOR,
    TIME_GRID,
    evaluation_key,
    result_key,
)
from pipeline.store.score_store import ScoreStore

GROUP = EVALUATION
#: Rows per chunk along ``instance``.
BLOCK_ROWS = 1000


@dataclass(eq=False)
class StoredEvaluation:
    """The arrays of ``evaluation/`` as plain numpy, per selector name (``order`` and
    ``first_feasible_step`` for the selectors evaluated by leave-one-out only)."""

    selectors: list[str]
    time_grid: np.ndarray
    eligible: np.ndarray
    optimal_score: np.ndarray
    first_feasible_time: dict[str, np.ndarray]
    best_score: dict[str, np.ndarray]
    first_feasible_step: dict[str, np.ndarray]
    order: dict[str, np.ndarray]


key = evaluation_key


def remove(store: ScoreStore) -> None:
    """Delete ``evaluation/`` (derived data, replaced as a whole)."""
    store.remove(GROUP)


def write(store: ScoreStore, evaluation: StoredEvaluation, score_units: str) -> None:
    """Replace ``evaluation/`` with ``evaluation`` (the caller forgets the stage first): the
    arrays :data:`pipeline.store.layout.EVALUATION_ARRAYS` declares."""
    remove(store)
    names = evaluation.selectors
    n, g = len(evaluation.eligible), len(evaluation.time_grid)
    k = max((o.shape[1] for o in evaluation.order.values()), default=0)
    rows = max(1, min(n, BLOCK_ROWS))
    coords = dict(zip(EVALUATION_COORDS, (np.asarray(names, dtype=str), np.arange(n),
                                          np.arange(k), evaluation.time_grid), strict=True))
    for name, values in coords.items():
        dtype, fill = (str, "") if values.dtype.kind == "U" else (values.dtype, 0)
        store.create(key(name), values.shape, (max(len(values), 1),), dtype, fill, (name,),
                     **EVALUATION_COORDS[name])[...] = values
    lengths = dict(zip(list(EVALUATION_COORDS)[1:], (n, k, g), strict=True))
    for name, spec in EVALUATION_ARRAYS.items():
        attrs = {**spec.attrs, **({"units": score_units} if spec.scored else {})}
        values = getattr(evaluation, name)
        if spec.dims[0] == SELECTOR:
            shape = tuple(lengths[d] for d in spec.dims[1:])
            data = np.full((len(names), *shape), spec.fill, dtype=spec.dtype)
            for s, selector in enumerate(names):
                if selector in values:  # traces shorter than the longest: padded with fill
                    found = np.asarray(values[selector])
                    data[(s, *(slice(0, w) for w in found.shape))] = found
            chunks = (1, rows, *shape[1:])
        else:
            data, chunks = values, (rows,)
        store.create(key(name), data.shape, chunks, spec.dtype, spec.fill, spec.dims,
                     **attrs)[...] = data


def read(store: ScoreStore) -> StoredEvaluation:
    """The stored evaluation of a store whose stage ``evaluate`` finished (any layout)."""
    if not store.has(key(SELECTOR)):
        return _read_groups(store)
    names = [str(s) for s in store.array(key(SELECTOR))[...]]
    arrays = {name: store.array(key(name))[...] for name in
              (ORDER, FIRST_FEASIBLE_STEP, FIRST_FEASIBLE_TIME, BEST_SCORE)}

    def per_selector(name, selectors):
        return {s: arrays[name][names.index(s)] for s in selectors}
    learnt = [s for s in names if s != RAWPLANNER]
    return StoredEvaluation(
        selectors=names,
        time_grid=store.array(key(EVALUATION_TIME))[...],
        eligible=store.array(key(ELIGIBLE))[...],
        optimal_score=store.array(key(OPTIMAL_SCORE))[...],
        first_feasible_time=per_selector(FIRST_FEASIBLE_TIME, names),
        best_score=per_selector(BEST_SCORE, names),
        first_feasible_step=per_selector(FIRST_FEASIBLE_STEP, learnt),
        order=per_selector(ORDER, learnt))


def _read_groups(store: ScoreStore) -> StoredEvaluation:
    """An evaluation of layout 3 or before: a group per selector, no RAWPLANNER curve."""
    info = store.stage_info("evaluate")
    names = [line["name"] for line in info["summary"]["selectors"]]
    learnt = [name for name in names if name != RAWPLANNER]

    def read_each(what, selectors):
        return {name: store.array(key(f"{name}/{what}"))[...] for name in selectors}
    time_grid = store.array(key(TIME_GRID))[...]
    best = read_each(BEST_SCORE, learnt)
    if RAWPLANNER in names:
        raw = (store.array(result_key(RAW, name))[...] for name in ("feasible", "time",
                                                                       "length"))
        best[RAWPLANNER] = raw_curve(*raw, time_grid, float(info["failure_value"]))
    return StoredEvaluation(
        selectors=names, time_grid=time_grid, eligible=store.array(key(ELIGIBLE))[...],
        optimal_score=store.array(key(OPTIMAL_SCORE))[...],
        first_feasible_time=read_each(FIRST_FEASIBLE_TIME, names), best_score=best,
        first_feasible_step=read_each(FIRST_FEASIBLE_STEP, learnt),
        order=read_each(ORDER, learnt))


def record(store: ScoreStore) -> dict:
    """What the evaluate stage records of what it wrote: the digest of each array's values
    (``outputs``) and each node's metadata document (``metadata``, checked by
    :mod:`pipeline.store.metadata`)."""
    keys = store.arrays_under(GROUP)
    return {"outputs": {k: f"{digest(store.array(k)[...]):016x}" for k in keys},
            "metadata": {k: store.document(k) for k in (GROUP, *keys)}}


def raw_curve(feasible, time, length, time_grid, failure_value) -> np.ndarray:
    """RAWPLANNER's best score by each time of ``time_grid``, per row: its one plan's score
    from the time it is found, the failure value before (and when it finds none)."""
    reached = feasible[:, None] & (time[:, None] <= time_grid[None])
    return np.where(reached, -length[:, None], failure_value)
