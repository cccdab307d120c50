"""What a Dask task runs: one block of planning calls, returned as arrays.

Tasks are pure functions of plain inputs (the domain spec, the block's instance specs and
seeds, its θ rows): they never open the store, so workers need no access to it, and a
retried or duplicated task returns exactly the same values.  Only the coordinating process
writes what they return (docs/architecture.md, "The store"); while they run, tasks only
report how many entries they have done (``pipeline.entry_progress``).  The domain (and
with it any simulator client) is built once per worker process and cached.
"""

from __future__ import annotations

import json
import time
from collections import Counter

import numpy as np

from pipeline.domains.cache import domain_for
from pipeline.entry_progress import EntryReporter
from pipeline.environment import fingerprint
from pipeline.planning import PlanResult, Status
from pipeline.planning.registry import planner_class
from pipeline.store.layout import (
    CHECKS,
    FEASIBLE,
    LENGTH,
    RESULT_COLUMNS,
    SCORE,
    STATUS,
    STEP,
    TIME,
    raw_extras,
)

#: Stands in for the constraint index in the seed of RAWPLANNER's call on an instance.
RAW_ENTRY = 2**40


def entry_seed(run_seed: int, instance_seed: int, constraint: int) -> int:
    """The planning seed of entry (instance, constraint): independent of worker and order."""
    return int(np.random.SeedSequence([run_seed, instance_seed, constraint]).generate_state(1)[0])


def _results_block(results: list[PlanResult], shape, steps=()) -> dict[str, np.ndarray]:
    out = {name: np.full(shape, col.fill, dtype=col.dtype) for name, col in RESULT_COLUMNS.items()}
    flat = {name: arr.reshape(-1) for name, arr in out.items()}
    for k, r in enumerate(results):
        flat[SCORE][k] = r.score
        flat[LENGTH][k] = r.length if r.feasible else np.nan
        flat[FEASIBLE][k] = r.feasible
        flat[TIME][k] = r.time
        flat[STATUS][k] = int(r.status)
        flat[CHECKS][k] = r.checks
        flat[STEP][k] = steps.index(r.step) if r.step else -1
    return out


def score_block(domain_spec: dict, run_seed: int, specs: list[str], seeds: list[int],
                theta: np.ndarray, first_constraint: int) -> tuple[dict, dict]:
    """Plan every entry of the block (instances ``specs``/``seeds`` x θ rows ``theta``,
    whose first row is constraint ``first_constraint``); return (arrays, report)."""
    t0 = time.perf_counter()
    skip = planner_class(domain_spec["planner"]["name"]).plans_nothing  # measures the pipeline
    domain = None if skip else domain_for(domain_spec)
    shape = (len(specs), len(theta))
    if skip:
        arrays = _results_block([], shape)
        arrays[STATUS][...] = int(Status.SKIPPED)
        arrays[TIME][...] = 0.0
        return arrays, _report(Counter({Status.SKIPPED.name.lower(): arrays[STATUS].size}),
                               [], t0)
    results, reporter = [], EntryReporter()
    for spec, inst_seed in zip(specs, seeds, strict=True):
        instance = domain.check_instance(json.loads(spec))
        for j, row in enumerate(theta, start=first_constraint):
            results.append(domain.plan(instance, row,
                                       seed=entry_seed(run_seed, int(inst_seed), j)))
            reporter.add()
    return _results_block(results, shape, domain.steps), _summary(results, t0)


def raw_block(domain_spec: dict, run_seed: int, specs: list[str],
              seeds: list[int]) -> tuple[dict, dict]:
    """RAWPLANNER on the given instances; return (raw result arrays, report)."""
    t0 = time.perf_counter()
    domain = domain_for(domain_spec)
    raws, reporter = [], EntryReporter()
    for spec, s in zip(specs, seeds, strict=True):
        raws.append(domain.raw_plan(domain.check_instance(json.loads(spec)),
                                    seed=entry_seed(run_seed, int(s), RAW_ENTRY)))
        reporter.add()
    arrays = _results_block([r.plan for r in raws], (len(raws),), domain.steps)
    arrays.update(raw_extras(np.array([r.tries for r in raws], dtype="int32"),
                             np.stack([r.constraint for r in raws]).astype("float64")))
    return arrays, _summary([r.plan for r in raws], t0)


def _summary(results: list[PlanResult], t0: float) -> dict:
    return _report(Counter(r.status.name.lower() for r in results),
                   sorted({r.error for r in results if r.error})[:3], t0)


def _report(status: Counter, errors: list[str], t0: float) -> dict:
    """What the coordinator logs and records with the block: status counts, errors, time,
    and the environment that computed it (``pipeline/environment.py``)."""
    return {"n": sum(status.values()), "status": dict(status), "errors": errors,
            "seconds": time.perf_counter() - t0, "environment": fingerprint()}
