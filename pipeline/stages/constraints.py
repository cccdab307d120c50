"""Stage ``constraints``: the candidate constraints (extracted from the raw solutions, or
the domain's fixed set), at most ``constraints.m`` of them kept, written whole."""

from __future__ import annotations

import numpy as np

from pipeline.domains import ConstraintSet
from pipeline.stages.run import Run
from pipeline.store import StoreError, layout
from pipeline.store.layout import CONSTRAINTS, RAW_CONSTRAINT


def stage_constraints(run: Run) -> None:
    store = run.store
    reason = run.todo("constraints")
    if reason is None:
        run.say(f"constraints: already complete "
                f"({store.stage_info('constraints')['m']} constraints); nothing to do")
        return
    domain = run.domain
    if domain.fixed_constraints:
        candidates = domain.constraints()
    else:
        run.require("raw", "constraints")
        features = store.array(RAW_CONSTRAINT)[...]
        extracted = ConstraintSet(features, np.arange(len(features)))
        candidates = domain.constraints(extracted)
    if candidates.m == 0:
        raise StoreError("constraints: no candidate constraints (RAWPLANNER solved no "
                         "instance); raise the raw planner's budget or instances.n")
    m = run.cfg.constraints.m
    keep = np.arange(candidates.m)
    if candidates.m > m:
        rng = np.random.default_rng([run.cfg.seed, 3])
        keep = np.sort(rng.choice(candidates.m, size=m, replace=False))
    theta = candidates.features[keep]
    size = layout.size_of(store.attrs)._replace(m=len(keep))
    coords = layout.coords(CONSTRAINTS, domain, size)

    def make():
        layout.create(store, CONSTRAINTS, domain, size, coords)

    repairing = store.stage_info("constraints") is not None and "damaged" in reason
    store.write_whole(CONSTRAINTS, {**layout.constraint_arrays(
                          theta, candidates.source_instance[keep]),
                      **{k: v for k, (_, v, _) in coords.items()}}, make,
                      changed=lambda: run.changed_inputs("constraints"))
    run.finish("constraints", m=len(keep), candidates=candidates.m, m_requested=m)
    if repairing:
        run.say(f"constraints: {reason}; computed again and repaired")
        return
    note = "" if len(keep) == m else f" (fewer than constraints.m = {m}: all candidates)"
    run.say(f"constraints: {len(keep)} of {candidates.m} candidates{note}")

