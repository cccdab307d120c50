"""The store's ``evaluation/`` group: stage ``evaluate`` writes it, the report reads it.

One dataset along ``selector`` (layout 4), so that ``xarray.open_zarr(store,
group="evaluation").sel(selector="box")`` compares selectors without any concatenation::

    order                (selector, instance, step)  columns tried, in order; -1 after the
                                                     last try and for RAWPLANNER
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
from pipeline.integrity import digest
from pipeline.store import TIME_UNITS, ScoreStore, result_key

GROUP = "evaluation"
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


def key(name: str) -> str:
    return f"{GROUP}/{name}"


def write(store: ScoreStore, evaluation: StoredEvaluation, score_units: str) -> None:
    """Replace ``evaluation/`` with ``evaluation`` (the caller forgets the stage first)."""
    store.remove(GROUP)
    names = evaluation.selectors
    n, g = len(evaluation.eligible), len(evaluation.time_grid)
    k = max((o.shape[1] for o in evaluation.order.values()), default=0)
    rows = max(1, min(n, BLOCK_ROWS))
    coords = {"selector": (np.asarray(names, dtype=str), {"long_name": "constraint selector"}),
              "instance": (np.arange(n), {"long_name": "held-out instance index"}),
              "step": (np.arange(k), {"long_name": "0-based try of the selector"}),
              "time": (evaluation.time_grid, {"long_name": "time since the instance was given",
                                              "units": TIME_UNITS})}
    for name, (values, attrs) in coords.items():
        dtype, fill = (str, "") if values.dtype.kind == "U" else (values.dtype, 0)
        store.create(key(name), values.shape, (max(len(values), 1),), dtype, fill, (name,),
                     **attrs)[...] = values

    def per_selector(name, values, dims, shape, dtype, fill, **attrs):
        data = np.full((len(names), *shape), fill, dtype=dtype)
        for s, selector in enumerate(names):
            if selector in values:
                data[s] = values[selector]
        store.create(key(name), data.shape, (1, rows, *shape[1:]), dtype, fill,
                     ("selector", *dims), **attrs)[...] = data

    per_selector("order", evaluation.order, ("instance", "step"), (n, k), "int32", -1,
                 long_name="columns tried, in order (-1: no try)")
    per_selector("first_feasible_step", evaluation.first_feasible_step, ("instance",), (n,),
                 "int32", -1, long_name="0-based step of the first feasible try (-1: none)")
    per_selector("first_feasible_time", evaluation.first_feasible_time, ("instance",), (n,),
                 "float64", np.nan, long_name="time to the first feasible plan (NaN: none)",
                 units=TIME_UNITS)
    per_selector("best_score", evaluation.best_score, ("instance", "time"), (n, g), "float64",
                 np.nan, long_name="best score found by each time", units=score_units)
    store.create(key("eligible"), (n,), (rows,), "bool", False, ("instance",),
                 long_name="the instance has a feasible constraint")[...] = evaluation.eligible
    store.create(key("optimal_score"), (n,), (rows,), "float64", np.nan, ("instance",),
                 long_name="the instance's best score", units=score_units)[...] = \
        evaluation.optimal_score


def read(store: ScoreStore) -> StoredEvaluation:
    """The stored evaluation of a store whose stage ``evaluate`` finished (any layout)."""
    if not store.has(key("selector")):
        return _read_groups(store)
    names = [str(s) for s in store.array(key("selector"))[...]]
    arrays = {name: store.array(key(name))[...] for name in
              ("order", "first_feasible_step", "first_feasible_time", "best_score")}

    def per_selector(name, selectors):
        return {s: arrays[name][names.index(s)] for s in selectors}
    learnt = [s for s in names if s != RAWPLANNER]
    return StoredEvaluation(
        selectors=names,
        time_grid=store.array(key("time"))[...],
        eligible=store.array(key("eligible"))[...],
        optimal_score=store.array(key("optimal_score"))[...],
        first_feasible_time=per_selector("first_feasible_time", names),
        best_score=per_selector("best_score", names),
        first_feasible_step=per_selector("first_feasible_step", learnt),
        order=per_selector("order", learnt))


def _read_groups(store: ScoreStore) -> StoredEvaluation:
    """An evaluation of layout 3 or before: a group per selector, no RAWPLANNER curve."""
    info = store.stage_info("evaluate")
    names = [line["name"] for line in info["summary"]["selectors"]]
    learnt = [name for name in names if name != RAWPLANNER]

    def read_each(what, selectors):
        return {name: store.array(key(f"{name}/{what}"))[...] for name in selectors}
    time_grid = store.array(key("time_grid"))[...]
    best = read_each("best_score", learnt)
    if RAWPLANNER in names:
        raw = (store.array(result_key("raw", name))[...] for name in ("feasible", "time",
                                                                       "length"))
        best[RAWPLANNER] = raw_curve(*raw, time_grid, float(info["failure_value"]))
    return StoredEvaluation(
        selectors=names, time_grid=time_grid, eligible=store.array(key("eligible"))[...],
        optimal_score=store.array(key("optimal_score"))[...],
        first_feasible_time=read_each("first_feasible_time", names), best_score=best,
        first_feasible_step=read_each("first_feasible_step", learnt),
        order=read_each("order", learnt))


def record(store: ScoreStore) -> dict:
    """What the evaluate stage records of what it wrote: the digest of each array's values
    (``outputs``) and each node's metadata document (``metadata``, checked by
    :mod:`pipeline.metadata`)."""
    keys = store.arrays_under(GROUP)
    return {"outputs": {k: f"{digest(store.array(k)[...]):016x}" for k in keys},
            "metadata": {k: store.document(k) for k in (GROUP, *keys)}}


def raw_curve(feasible, time, length, time_grid, failure_value) -> np.ndarray:
    """RAWPLANNER's best score by each time of ``time_grid``, per row: its one plan's score
    from the time it is found, the failure value before (and when it finds none)."""
    reached = feasible[:, None] & (time[:, None] <= time_grid[None])
    return np.where(reached, -length[:, None], failure_value)
