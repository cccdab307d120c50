"""Bringing a store of an older layout to the current one (in place, keeping every entry),
one layout at a time.

Layout 1 → 2: integrity tables are recorded from the current contents (blocks whose chunks
no longer decode are marked not done, so the next run computes them again), chunks that
were never written because they held only fill values are written, and the coordinates that
xarray shows are added.

Layout 2 → 3: ``raw`` and ``scores`` get their ``environment`` array, -1 ("not recorded")
for every entry, and their integrity tables a column for it; the recorded digests of every
other array are kept as they are (nothing is re-read, so nothing unverified is adopted).

Layout 3 → 4: every group gets the index coordinates it lacks (``instance``,
``constraint``) and ``feature_units``, and the integrity tables a column for each; the
``feature`` coordinate takes the domain's feature names (its column recomputed); CF
attributes are set on every array; an evaluation stored one group per selector becomes one
dataset along ``selector`` when its recorded digests still hold (else it is dropped and
computed again).  No entry of D is rewritten.

Layout 4 → 5: when the domain declares instance features and stage ``instances`` has run,
``instances/features`` is computed from the stored specs (the same values stage
``instances`` stores, which computes them from the same text), with its coordinates
``instance_feature`` and ``instance_feature_units``; the integrity table of ``instances``
gets their columns in one write.  Nothing of ``raw``, ``constraints``, ``scores`` or the
evaluation is touched.

Each step can be interrupted and run again.
"""

from __future__ import annotations

import numpy as np

from pipeline.store import evaluation as evaluation_store
from pipeline.store import integrity, layout
from pipeline.store.blocks import block_region
from pipeline.store.integrity import digest
from pipeline.store.layout import (
    ENVIRONMENT,
    FEATURES,
    INSTANCE_FEATURE,
    INSTANCE_FEATURE_UNITS,
    INSTANCE_FEATURES,
    INSTANCE_SEED,
    INSTANCE_SPEC,
    RAW_CONSTRAINT,
    THETA,
    create_instance_features,
    feature_coord,
    index_coord,
    instance_coord,
    instance_feature_coord,
    result_attrs,
    result_key,
    source_coord,
)
from pipeline.store.score_store import ScoreStore


def migrate(store: ScoreStore, domain) -> list[str]:
    """Migrate ``store`` (opened for writing, lock held) to the current layout; return what
    was done, a line per step."""
    notes = []
    if store.layout_version < 2:
        notes += [f"layout 2: {note}" for note in to_layout_2(store, domain)]
    if store.layout_version < 3:
        notes += [f"layout 3: {note}" for note in to_layout_3(store)]
    if store.layout_version < 4:
        notes += [f"layout 4: {note}" for note in to_layout_4(store, domain)]
    if store.layout_version < 5:
        notes += [f"layout 5: {note}" for note in to_layout_5(store, domain)]
    return notes


def to_layout_2(store: ScoreStore, domain) -> list[str]:
    notes = []
    stages = store.attrs.get("stages", {})
    seeds = store.instance_seeds() if "instances" in stages else None
    if "instances" in stages:
        store.create_table("instances", ["seed", "spec"])
        _adopt(store, "instances", whole=True)
    if "constraints" in stages:
        store.write_coords("constraints", feature_coord(domain), ["theta", "source_instance"])
        store.create_table("constraints", ["theta", "source_instance", "feature"])
        _adopt(store, "constraints", whole=True)
    if store.has_results("raw") and seeds is not None:
        names = _data_names(store, "raw")
        coords = {**instance_coord(seeds), **feature_coord(domain)}
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
    store.set_attrs(layout_version=2)
    return notes


def to_layout_3(store: ScoreStore) -> list[str]:
    notes = []
    for group in ("raw", "scores"):
        if store.has_results(group) and store.has_table(group):
            notes.append(f"{group}: {_add_environment(store, group)} blocks of unrecorded "
                         "environment")
    store.set_attrs(layout_version=3)
    return notes


def _add_environment(store: ScoreStore, group: str) -> int:
    """Add ``group``'s environment array (-1 everywhere) and its integrity column; return
    the number of recorded blocks it covers."""
    if ENVIRONMENT not in store.layout(group).names:  # else an interrupted run got this far
        done = store.array(f"{group}/done")
        store.create_environment(group, done.shape, done.chunks, done.metadata.dimension_names)
        _record_columns(store, group, [ENVIRONMENT])
    return len(store.finished_blocks(group))


def _record_columns(store: ScoreStore, group: str, names, order=None, skip=()) -> None:
    """Record in ``group``'s integrity table the digests of arrays ``names`` (new columns,
    or columns recomputed) for every recorded block but those in ``skip`` (left unrecorded:
    the stage computes them again); other columns are kept as they are.  ``order``: the
    table's columns afterwards (default: the old ones, then the new)."""
    layout = store.layout(group)
    columns = list(order or [*layout.names, *(n for n in names if n not in layout.names)])
    table = store.array(f"{integrity.GROUP}/{group}")
    old = table[...]
    rows = np.zeros((*old.shape[:-1], len(columns)), dtype="uint64")
    for block in np.ndindex(*old.shape[:-1]):
        if not np.all(old[block] != integrity.NOT_RECORDED):
            continue  # not finished: nothing recorded, nothing to add
        rows[block][[columns.index(name) for name in layout.names]] = old[block]
        if block in skip:
            continue
        for name in names:
            arr = store.array(f"{group}/{name}")
            chunk = layout.chunk_of(arr.metadata.dimension_names, block)
            rows[block][columns.index(name)] = digest(arr.blocks[chunk])
    store.create(f"{integrity.GROUP}/{group}", rows.shape, table.chunks[:-1] + (len(columns),),
                 "uint64", 0, table.metadata.dimension_names,
                 **{**dict(table.attrs), "arrays": columns})[...] = rows


def _order_columns(store: ScoreStore, group: str, columns: list[str]) -> None:
    """Put ``group``'s integrity table in the column order of the layout (that of a store
    made by this version, which :mod:`pipeline.store.metadata` checks it against): the recorded
    digests move with their names; a column the layout adds is recorded from the current
    values of recorded blocks."""
    names = list(store.layout(group).names)
    if names == columns:
        return
    added = [name for name in columns if name not in names]
    if added:
        _record_columns(store, group, added)
        names = list(store.layout(group).names)
    table = store.array(f"{integrity.GROUP}/{group}")
    rows = table[...][..., [names.index(name) for name in columns]]
    store.create(f"{integrity.GROUP}/{group}", rows.shape, table.chunks[:-1] + (len(columns),),
                 "uint64", 0, table.metadata.dimension_names,
                 **{**dict(table.attrs), "arrays": columns})[...] = rows


def to_layout_4(store: ScoreStore, domain) -> list[str]:
    notes = []
    for group in ("instances", "raw", "constraints", "scores"):
        if store.has_table(group):
            added = _add_coords(store, group, _coords(store, group, domain))
            if added:
                notes.append(f"{group}: coordinates {', '.join(added)}")
    _describe(store, domain)
    for group in ("instances", "raw", "constraints", "scores"):
        if store.has_table(group):
            _order_columns(store, group, [c for c in layout.table_columns(group, domain)
                                          if c not in LAYOUT_5_COLUMNS])
    if store.has_group(evaluation_store.GROUP) and not store.has(evaluation_store.key("selector")):
        notes.append(_regroup_evaluation(store))
    store.set_attrs(layout_version=4)
    return notes


#: The columns that layout 5 adds to the integrity table of ``instances``.
LAYOUT_5_COLUMNS = (FEATURES, INSTANCE_FEATURE, INSTANCE_FEATURE_UNITS)


def to_layout_5(store: ScoreStore, domain) -> list[str]:
    notes = []
    if domain.n_instance_features and store.has_table("instances") \
            and store.stage_info("instances") is not None:
        notes.append(_add_instance_features(store, domain))
    store.set_attrs(layout_version=5)
    return notes


def _add_instance_features(store: ScoreStore, domain) -> str:
    """``instances/features`` from the stored specs, its coordinates, and their columns in
    the integrity table (written once, in the layout's order: a run interrupted before that
    write finds a layout-4 store and does it all again).  Blocks whose seeds or specs are
    damaged get no features and no record of them: stage instances samples them again and
    repairs the block, features included."""
    size = layout.size_of(store.attrs)
    damaged = store.verify("instances", expect_all=True).blocks
    intact = np.ones(size.n, dtype=bool)
    for (block,) in damaged:
        intact[block * size.block_instances:(block + 1) * size.block_instances] = False
    features = np.full((size.n, domain.n_instance_features), np.nan)
    if intact.any():
        features[intact] = domain.instance_feature_rows(store.instance_specs()[intact])
    create_instance_features(store, size, features.shape[1])
    store.array(INSTANCE_FEATURES)[...] = features
    coords = instance_feature_coord(domain)
    store.write_coords("instances", coords, [FEATURES])
    _record_columns(store, "instances", [FEATURES, *coords],
                    order=layout.table_columns("instances", domain), skip=damaged)
    lost = f" ({len(damaged)} damaged blocks left to stage instances)" if damaged else ""
    return f"instances: {features.shape[1]} features of {int(intact.sum())} instances{lost}"


def _coords(store: ScoreStore, group: str, domain) -> dict:
    """The coordinates of ``group`` in layout 4 (as the stages write them)."""
    if group == "instances":
        return index_coord("instance", len(store.instance_seeds()), "instance index")
    if group == "raw":
        return {**instance_coord(store.instance_seeds()), **feature_coord(domain)}
    if group == "constraints":
        return {**index_coord("constraint", len(store.source_instances()), "constraint index"),
                **feature_coord(domain)}
    return {**instance_coord(store.instance_seeds()), **source_coord(store.source_instances())}


def _add_coords(store: ScoreStore, group: str, coords: dict) -> list[str]:
    """Write ``coords`` into ``group`` and record the digests of those that are new (and of
    ``feature``, which takes the domain's names); return the names recorded."""
    layout = store.layout(group)
    names = [name for name in coords if name not in layout.names or name == "feature"]
    if not names:
        return []
    store.write_coords(group, coords, [name for name in layout.names if name not in coords])
    _record_columns(store, group, names)
    return names


def _describe(store: ScoreStore, domain) -> None:
    """The CF attributes of layout 4 on arrays made before it (metadata only)."""
    described = result_attrs(domain)
    for group in ("raw", "scores"):
        if store.has_results(group):
            for name, attrs in described.items():
                store.array(result_key(group, name)).attrs.update(attrs)
    for key, long_name in ((INSTANCE_SEED, "seed the instance was sampled from"),
                           (INSTANCE_SPEC, "instance spec, JSON text"),
                           (THETA, "features of the constraint θ; units: feature_units"),
                           (RAW_CONSTRAINT, "constraint θ extracted from the raw solution "
                                            "(NaN: none); units: feature_units")):
        if store.has(key):
            store.array(key).attrs["long_name"] = long_name


def _regroup_evaluation(store: ScoreStore) -> str:
    """An evaluation of layout ≤ 3 (a group per selector) as one dataset along
    ``selector``, when its recorded digests hold; else dropped (computed again)."""
    info = store.stage_info("evaluate")
    recorded = (info or {}).get("outputs")
    try:
        intact = info is not None and not (recorded and store.verify_whole(recorded))
        old = evaluation_store.read(store) if intact else None
    except Exception:  # noqa: BLE001 (anything unreadable: compute it again)
        old = None
    store.forget_stage("evaluate")
    if old is None:
        store.remove(evaluation_store.GROUP)
        return "evaluation: damaged or incomplete; it is computed again by stage evaluate"
    units = store.array(result_key("scores", "score")).attrs.get("units", "1")
    evaluation_store.write(store, old, score_units=units)
    store.mark_finished("evaluate", **{**info, **evaluation_store.record(store)})
    return f"evaluation: {len(old.selectors)} selectors along the selector dimension"


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
