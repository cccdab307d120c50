"""What a Dask task runs: one block of planning calls, written as whole chunks.

Tasks are pure functions of their arguments (plain data) and the store's read-only
inputs, so a task retried after a worker died writes exactly the same values.  The domain
(and with it any simulator client) is built once per worker process and cached.
"""

from __future__ import annotations

import json
import time
from collections import Counter

import numpy as np

from pipeline.domains.cache import domain_for
from pipeline.planning import PlanResult, Status
from pipeline.store import RESULT_COLUMNS, ScoreStore

#: Stands in for the constraint index in the seed of RAWPLANNER's call on an instance.
RAW_ENTRY = 2**40


def entry_seed(run_seed: int, instance_seed: int, constraint: int) -> int:
    """The planning seed of entry (instance, constraint): independent of worker and order."""
    return int(np.random.SeedSequence([run_seed, instance_seed, constraint]).generate_state(1)[0])


def _results_block(results: list[PlanResult], shape, steps=()) -> dict[str, np.ndarray]:
    out = {name: np.full(shape, col.fill, dtype=col.dtype) for name, col in RESULT_COLUMNS.items()}
    flat = {name: arr.reshape(-1) for name, arr in out.items()}
    for k, r in enumerate(results):
        flat["score"][k] = r.score
        flat["length"][k] = r.length if r.feasible else np.nan
        flat["feasible"][k] = r.feasible
        flat["time"][k] = r.time
        flat["status"][k] = int(r.status)
        flat["checks"][k] = r.checks
        flat["step"][k] = steps.index(r.step) if r.step else -1
    return out


def _write(store: ScoreStore, group: str, region, arrays: dict[str, np.ndarray]) -> None:
    for name, values in arrays.items():
        store.array(f"{group}/{name}", mode="r+")[region] = values


def score_block(store_path: str, domain_spec: dict, run_seed: int, rows: tuple[int, int],
                cols: tuple[int, int]) -> dict:
    """Plan every entry of D[rows, cols] and write the block's chunks."""
    t0 = time.perf_counter()
    store = ScoreStore(store_path)
    specs = store.array("instances/spec")[rows[0]:rows[1]]
    seeds = store.array("instances/seed")[rows[0]:rows[1]]
    theta = store.array("constraints/theta")[cols[0]:cols[1]]
    skip = domain_spec["planner"]["name"] == "noop"
    domain = None if skip else domain_for(domain_spec)
    results = []
    for spec, inst_seed in zip(specs, seeds, strict=True):
        instance = None if skip else domain.check_instance(json.loads(str(spec)))
        for j, row in enumerate(theta, start=cols[0]):
            if skip:
                results.append(PlanResult(Status.SKIPPED))
            else:
                results.append(domain.plan(instance, row, seed=entry_seed(run_seed,
                                                                         int(inst_seed), j)))
    shape = (rows[1] - rows[0], cols[1] - cols[0])
    steps = domain.steps if domain else ()
    _write(store, "scores", (slice(*rows), slice(*cols)), _results_block(results, shape, steps))
    return _report(results, t0)


def raw_block(store_path: str, domain_spec: dict, run_seed: int, rows: tuple[int, int]) -> dict:
    """RAWPLANNER on instances[rows]; writes the raw results and extracted constraints."""
    t0 = time.perf_counter()
    store = ScoreStore(store_path)
    specs = store.array("instances/spec")[rows[0]:rows[1]]
    seeds = store.array("instances/seed")[rows[0]:rows[1]]
    domain = domain_for(domain_spec)
    raws = [domain.raw_plan(domain.check_instance(json.loads(str(spec))),
                            seed=entry_seed(run_seed, int(s), RAW_ENTRY))
            for spec, s in zip(specs, seeds, strict=True)]
    region = slice(*rows)
    arrays = _results_block([r.plan for r in raws], (len(raws),), domain.steps)
    arrays["tries"] = np.array([r.tries for r in raws], dtype="int32")
    _write(store, "raw", region, arrays)
    store.array("raw/constraint", mode="r+")[region] = np.stack([r.constraint for r in raws])
    return _report([r.plan for r in raws], t0)


def _report(results: list[PlanResult], t0: float) -> dict:
    return {"n": len(results), "status": dict(Counter(r.status.name.lower() for r in results)),
            "errors": sorted({r.error for r in results if r.error})[:3],
            "seconds": time.perf_counter() - t0}
