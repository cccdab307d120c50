"""The checks every stage makes before writing anything: why it must run, or None.  They
only read, so a run checks every stage it was asked for on a read-only view of the store
first."""

from __future__ import annotations

from typing import TYPE_CHECKING

from box_core import SELECTOR_REVISION
from box_core.stats import INTERVAL_METHOD
from pipeline.evaluation import interval_method, stored_revision
from pipeline.store.layout import CONSTRAINTS, FEATURES_LAYOUT, INSTANCES, RAW, SCORES

if TYPE_CHECKING:
    from pipeline.stages.run import Run


def todo_whole(run: Run, stage: str, group: str) -> str | None:
    """Why a stage written whole (instances, constraints) must run, or None."""
    store = run.store
    if store is None or store.stage_info(stage) is None:
        return "not run yet"
    if lost_table(store, group):
        return "its integrity table is missing"
    changed = run.changed_inputs(stage)
    if changed:
        return f"its inputs changed ({', '.join(changed)})"
    damage = store.verify(group, expect_all=True)
    return f"damaged: {damage.describe()}" if damage else None


def todo_instances(run: Run) -> str | None:
    """Why stage ``instances`` must run, or None: as :func:`todo_whole`, and on a store of
    layout 4 or older whose domain declares instance features, to add them (opening the
    store for writing migrates it: pipeline/store/migrate.py; D is not touched)."""
    store = run.store
    if store is not None and store.stage_info("instances") is not None \
            and store.layout_version < FEATURES_LAYOUT and run.domain.n_instance_features:
        return f"its instance features are not stored yet (a store of layout " \
               f"{store.layout_version})"
    return todo_whole(run, "instances", INSTANCES)


def lost_table(store, group: str) -> bool:
    """Whether ``group``'s integrity table is gone from a store that had one: its data can
    no longer be verified, so it is computed again (and compared, where it is an input)."""
    return store.layout_version >= 2 and store.has_group(group) and not store.has_table(group)


def todo_blocks(run: Run, stage: str) -> str | None:
    """Why a result stage (raw, scores) must run, or None."""
    store = run.store
    if store is None or not store.has_results(stage):
        return "not run yet"
    if lost_table(store, stage):
        return "its integrity table is missing: every block is computed again"
    changed = run.changed_inputs(stage)
    if changed:
        return f"its inputs changed ({', '.join(changed)})"
    pending, damage = run.block_state(stage)
    if damage:
        return f"damaged: {damage.describe()}"
    if pending or store.stage_info(stage) is None:
        return f"{len(pending)} blocks to compute"
    return None


def todo_evaluate(run: Run) -> str | None:
    store = run.store
    info = store.stage_info("evaluate") if store is not None else None
    if info is None:
        return "not run yet"
    if info.get("settings") != run.plain["evaluate"]:
        return "its settings changed"
    if stored_revision(info) != SELECTOR_REVISION:
        return (f"box_core's selectors changed (revision {stored_revision(info)} -> "
                f"{SELECTOR_REVISION})")
    if interval_method(info) != INTERVAL_METHOD:
        return f"its intervals are {interval_method(info)}, this version's are {INTERVAL_METHOD}"
    changed = run.changed_inputs("evaluate")
    if changed:
        return f"its inputs changed ({', '.join(changed)})"
    outputs = info.get("outputs")
    if outputs is None:
        return None  # run before outputs were recorded
    damage = store.verify_whole(outputs)
    return f"its results are damaged: {damage.describe()}" if damage else None


TODO = {"instances": todo_instances,
        "raw": lambda run: todo_blocks(run, RAW),
        "constraints": lambda run: todo_whole(run, "constraints", CONSTRAINTS),
        "scores": lambda run: todo_blocks(run, SCORES),
        "evaluate": todo_evaluate}

