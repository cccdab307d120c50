"""Bringing a store of an older layout to the current one (in place, keeping every entry),
one layout at a time.

Layout 1 → 2: integrity tables are recorded from the current contents (blocks whose chunks
no longer decode are marked not done, so the next run computes them again), chunks that
were never written because they held only fill values are written, and the coordinates that
xarray shows are added.

Layout 2 → 3: ``raw`` and ``scores`` get their ``environment`` array, -1 ("not recorded")
for every entry, and their integrity tables a column for it; the recorded digests of every
other array are kept as they are (nothing is re-read, so nothing unverified is adopted).
Each step can be interrupted and run again.
"""

from __future__ import annotations

import numpy as np

from pipeline import integrity
from pipeline.integrity import digest
from pipeline.store import (
    ENVIRONMENT,
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
    """Migrate ``store`` (opened for writing, lock held) to the current layout; return what
    was done, a line per step."""
    notes = []
    if store.layout_version < 2:
        notes += [f"layout 2: {note}" for note in to_layout_2(store, domain)]
    if store.layout_version < 3:
        notes += [f"layout 3: {note}" for note in to_layout_3(store)]
    return notes


def to_layout_2(store: ScoreStore, domain) -> list[str]:
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
    store.root.attrs["layout_version"] = 2
    return notes


def to_layout_3(store: ScoreStore) -> list[str]:
    notes = []
    for group in ("raw", "scores"):
        if store.has_results(group) and store.has_table(group):
            notes.append(f"{group}: {_add_environment(store, group)} blocks of unrecorded "
                         "environment")
    store.root.attrs["layout_version"] = 3
    return notes


def _add_environment(store: ScoreStore, group: str) -> int:
    """Add ``group``'s environment array (-1 everywhere) and its integrity column; return
    the number of recorded blocks it covers."""
    layout = store.layout(group)
    if ENVIRONMENT in layout.names:  # an interrupted migration got this far
        return len(store.finished_blocks(group))
    done = store.array(f"{group}/done")
    env = store.create_environment(group, done.shape, done.chunks,
                                   done.metadata.dimension_names)
    old = store.array(f"{integrity.GROUP}/{group}")[...]
    rows = np.zeros((*old.shape[:-1], old.shape[-1] + 1), dtype="uint64")
    recorded = 0
    for block in np.ndindex(*old.shape[:-1]):
        if np.all(old[block] != integrity.NOT_RECORDED):
            rows[block] = [*old[block], digest(env.blocks[block])]
            recorded += 1
    table = store.array(f"{integrity.GROUP}/{group}")
    attrs = dict(table.attrs)
    store.create(f"{integrity.GROUP}/{group}", rows.shape, table.chunks[:-1] + (rows.shape[-1],),
                 "uint64", 0, table.metadata.dimension_names,
                 **{**attrs, "arrays": [*layout.names, ENVIRONMENT]})[...] = rows
    return recorded


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
