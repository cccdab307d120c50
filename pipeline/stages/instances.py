"""Stage ``instances``: the instances sampled from their seeds, and their features (when the
domain declares some), written whole."""

from __future__ import annotations

import json

import numpy as np

from pipeline.stages.run import Run
from pipeline.store import layout
from pipeline.store.layout import INSTANCES


def instance_seeds(seed: int, n: int) -> np.ndarray:
    """Seeds of instances 0..n-1 of run ``seed`` (instance i's seed does not depend on n)."""
    return np.array([np.random.SeedSequence([seed, i]).generate_state(1)[0] for i in range(n)],
                    dtype=np.int64)


def stage_instances(run: Run) -> None:
    store, n = run.store, run.cfg.instances.n
    reason = run.todo("instances")
    if reason is None:
        run.say(f"instances: already complete ({n} instances); nothing to do")
        return
    seeds = instance_seeds(run.cfg.seed, n)
    specs = np.array([json.dumps(run.domain.sample_instance(int(s)), sort_keys=True)
                      for s in seeds], dtype=str)
    size = layout.size_of(store.attrs)
    coords = layout.coords(INSTANCES, run.domain, size)

    def make():
        layout.create(store, INSTANCES, run.domain, size, coords)

    repairing = store.stage_info("instances") is not None
    features = run.domain.instance_feature_rows(specs)  # from the text the store holds
    store.write_whole(INSTANCES, {**layout.instance_arrays(seeds, specs, features),
                                  **{k: v for k, (_, v, _) in coords.items()}}, make,
                      changed=lambda: run.changed_inputs("instances"))
    run.finish("instances", n=n)
    if repairing:
        run.say(f"instances: {reason}; sampled again from their seeds and repaired")
    else:
        run.say(f"instances: sampled {n} {run.domain.name} instances")

