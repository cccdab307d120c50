"""Bringing a store of an older layout to the current one (in place, keeping every entry).

Layout 1 → 2: integrity tables are recorded from the current contents (blocks whose chunks
no longer decode are marked not done, so the next run computes them again), chunks that
were never written because they held only fill values are written, and the coordinates that
xarray shows are added.
"""

from __future__ import annotations

import numpy as np

from pipeline.store import (
    LAYOUT_VERSION,
    RAW_CONSTRAINT,
    THETA,
    ScoreStore,
    block_region,
    feature_coord,
    feature_names,
    instance_coord,
    source_coord,
)


def migrate(store: ScoreStore, domain) -> list[str]:
    """Migrate ``store`` (opened for writing, lock held); return what was done."""
    notes = []
    stages = store.attrs.get("stages", {})
    seeds = store.instance_seeds() if "instances" in stages else None
    if "instances" in stages:
        store.create_table("instances", ["seed", "spec"])
        _adopt(store, "instances", whole=True)
    if "constraints" in stages:
        p = store.array(THETA).shape[1]
        store.write_coords("constraints", feature_coord(feature_names(domain, p)),
                           ["theta", "source_instance"])
        store.create_table("constraints", ["theta", "source_instance", "feature"])
        _adopt(store, "constraints", whole=True)
    if store.has_results("raw") and seeds is not None:
        p = store.array(RAW_CONSTRAINT).shape[1]
        names = _data_names(store, "raw")
        coords = {**instance_coord(seeds), **feature_coord(feature_names(domain, p))}
        store.write_coords("raw", coords, names)
        store.create_table("raw", [*names, *coords])
        notes.append(f"raw: {_adopt(store, 'raw')} blocks adopted")
    if store.has_results("scores") and seeds is not None and "constraints" in stages:
        names = _data_names(store, "scores")
        coords = {**instance_coord(seeds),
                  **source_coord(store.source_instances())}
        store.write_coords("scores", coords, names)
        store.create_table("scores", [*names, *coords])
        notes.append(f"scores: {_adopt(store, 'scores')} blocks adopted")
    store.forget_stage("evaluate")  # recomputed with its inputs recorded
    store.root.attrs["layout_version"] = LAYOUT_VERSION
    return notes


def _data_names(store: ScoreStore, group: str) -> list[str]:
    names = sorted(name for name, _ in store.root[group].arrays() if name != "done")
    return [*names, "done"]


def _adopt(store: ScoreStore, group: str, whole: bool = False) -> int:
    """Record the blocks that are done and decode; un-mark the others."""
    grid = store.grid(group)
    layout = store.layout(group)
    if whole:
        blocks = list(np.ndindex(*grid))
    else:
        mask = store.array(f"{group}/done")
        done = mask[...]
        blocks = [b for b in np.ndindex(*grid) if done[block_region(b, mask.chunks)].all()]
    adopted, lost = [], []
    for block in blocks:
        try:
            for name in layout.names:
                arr = store.array(f"{group}/{name}")
                chunk = layout.chunk_of(arr.metadata.dimension_names, block)
                region = block_region(chunk, arr.chunks)
                arr[region] = arr[region]  # decodes it, and writes it if it was never written
        except Exception:  # noqa: BLE001 (a chunk that does not decode: compute it again)
            lost.append(block)
        else:
            adopted.append(block)
    if adopted:
        store.record_blocks(group, adopted)
    if lost and not whole:
        store.forget_blocks(group, lost)
    return len(adopted)
