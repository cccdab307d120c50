"""Stage ``status`` (and ``box status``): what a store holds, per stage and per array, and
every damage found (read-only: works on stores that cannot be written)."""

from __future__ import annotations

import numpy as np
from rich.console import Console

from pipeline.environment import describe, difference
from pipeline.provenance import WHY
from pipeline.store import integrity, metadata
from pipeline.store.errors import StoreError
from pipeline.store.integrity import Damage
from pipeline.store.layout import BLOCK_DIMS, STAGE_GROUPS
from pipeline.store.locking import StoreLock
from pipeline.store.score_store import ScoreStore
from pipeline.tables import Column, FittedTable


def _damage(store: ScoreStore, stage: str, group: str) -> Damage:
    if group in BLOCK_DIMS:
        if not store.has_table(group) and store.layout_version >= 2 \
                and (store.stage_info(stage) is not None or store.has(f"{group}/done")):
            damage = Damage()
            damage.add("missing", f"{integrity.GROUP}/{group}", ())
            return damage
        if store.has_table(group) or store.has_group(group):
            whole = not store.has(f"{group}/done")  # instances, constraints
            return store.verify(group, expect_all=whole and store.stage_info(stage) is not None)
        return Damage()
    outputs = (store.stage_info(stage) or {}).get("outputs")
    if outputs is not None:
        return store.verify_whole(outputs)
    return store._verify_decoding(group)  # noqa: SLF001 (an evaluation of layout 1)


def refuse_damaged(store: ScoreStore, stages=("instances", "constraints", "scores")) -> None:
    """Raise StoreError naming the damaged arrays of ``stages`` (for readers such as
    ``box export`` that must not hand damaged values on)."""
    found = [_damage(store, stage, STAGE_GROUPS[stage]) for stage in stages]
    named = "; ".join(d.describe() for d in found if d)
    if named:
        raise StoreError(f"store {store.path} is damaged: {named}; re-run the pipeline "
                         "command that made it to repair it (box status shows the damage)")


def collect(path) -> dict:
    """Plain-data status of the store at ``path`` (raises StoreError if it is not ours).
    Each object it needs is read once (:meth:`ScoreStore.reading_once`)."""
    store = ScoreStore.open(path, checked=False)
    with store.reading_once():
        return _collect(store)


def _collect(store: ScoreStore) -> dict:
    attrs = store.attrs
    found = metadata.check(store, metadata.store_domain(store))
    unreadable = metadata.structural(found)  # never read as their documents now say
    report = {"path": str(store.path), "config_hash": attrs.get("config_hash"),
              "created": attrs.get("created"), "layout_version": store.layout_version,
              "running": StoreLock(store.location).held_by_other(), "stages": {},
              "arrays": [], "damaged": {}, "metadata": [d.describe() for d in found]}
    damage = Damage()
    for stage, group in STAGE_GROUPS.items():
        info = attrs.get("stages", {}).get(stage)
        entry = {"finished": info.get("finished") if info else None}
        report["stages"][stage] = entry
        if group in unreadable:
            continue
        if store.has(f"{group}/done"):
            try:
                done = store.done(group)
            except Exception:  # noqa: BLE001 (a damaged mask: reported below)
                done = np.zeros(store.array(f"{group}/done").shape, dtype=bool)
            entry["done"], entry["total"] = int(done.sum()), int(done.size)
        found = _damage(store, stage, group)
        for kind in ("corrupted", "missing"):
            for array, blocks in getattr(found, kind).items():
                getattr(damage, kind).setdefault(array, set()).update(blocks)
    for group in (*STAGE_GROUPS.values(), integrity.GROUP):
        for key in store.arrays_under(group):
            if key.split("/")[0] in unreadable or key.split("/")[-1] in unreadable \
                    and group == integrity.GROUP:
                continue
            arr = store.array(key)
            report["arrays"].append({
                "array": key, "shape": list(arr.shape),
                "dims": list(arr.metadata.dimension_names or ()),
                "chunks_written": store.chunks_written(key), "chunks": int(arr.nchunks),
                "corrupted": len(damage.corrupted.get(key, ())),
                "missing": len(damage.missing.get(key, ()))})
    for key in damage.arrays:
        report["damaged"][key] = {"corrupted": len(damage.corrupted.get(key, ())),
                                  "missing": len(damage.missing.get(key, ()))}
    report["environments"] = _environments(store)
    return report


def _environments(store: ScoreStore) -> list[dict]:
    """Each environment that computed finished entries: its index (-1: not recorded), its
    entries per group, and the environment itself (None when not recorded)."""
    table = store.environments()
    used: dict[int, dict[str, int]] = {}
    for group in ("raw", "scores"):
        try:
            counts = store.environments_used(group)
        except Exception:  # noqa: BLE001 (a damaged array: reported as damage above)
            continue
        for index, entries in counts.items():
            used.setdefault(index, {})[group] = entries
    return [{"index": index, "entries": entries,
             "environment": table[index] if 0 <= index < len(table) else None}
            for index, entries in sorted(used.items())]


def damaged(report: dict) -> str:
    """The damage of a status report in words ("" when there is none)."""
    blocks = (f"{key} ({', '.join(f'{n} {kind}' for kind, n in counts.items() if n)} blocks)"
              for key, counts in report["damaged"].items())
    return "; ".join([*(f"metadata {m}" for m in report["metadata"]), *blocks])


def _print_environments(found: list[dict], layout: int, console: Console) -> None:
    if not found:
        if layout < 3:
            console.print(f"environments: not recorded (layout {layout}; recorded from layout 3 "
                          "on, by the next run that writes to the store)", highlight=False)
        return
    rows = [[str(e["index"]), str(e["entries"].get("raw", 0)),
             str(e["entries"].get("scores", 0)),
             describe(e["environment"]) if e["environment"] else
             "not recorded (computed before layout 3)"] for e in found]
    console.print(FittedTable([Column("#"), Column("raw"), Column("scores"),
                               Column("environment", "left", wrap=True)], rows,
                              title="environments that computed the entries"))
    known = [e["environment"] for e in found if e["environment"]]
    if len(found) > 1:
        change = f" ({difference(known[0], known[1])})" if len(known) > 1 else ""
        console.print(f"[yellow]computed in {len(found)} environments{change}: {WHY}",
                      highlight=False, soft_wrap=True)


def print_status(path, console: Console) -> dict:
    report = collect(path)
    console.print(f"store {report['path']}  config {report['config_hash']}  created "
                  f"{report['created']}  layout {report['layout_version']}", highlight=False)
    console.print(f"running: {report['running'] or 'no'}", highlight=False)
    stages = []
    for stage, entry in report["stages"].items():
        progress = f"{entry['done']}/{entry['total']}" if "total" in entry else "-"
        if entry["finished"]:
            state = "[green]complete"
        elif "total" in entry or any(a["array"].startswith(STAGE_GROUPS[stage] + "/")
                                     for a in report["arrays"]):
            state = "[yellow]partial"
        else:
            state = "not started"
        stages.append([stage, state, progress, entry["finished"] or "-"])
    console.print(FittedTable([Column("stage", "left"), Column("state", "left"),
                               Column("entries done"), Column("finished at", "left", drop=1)],
                              stages, title="stages"))
    arrays = []
    for a in report["arrays"]:
        bad = f"[red]{a['corrupted']}" if a["corrupted"] else "0"
        gone = f"[red]{a['missing']}" if a["missing"] else "0"
        arrays.append([a["array"], ", ".join(a["dims"]), " x ".join(map(str, a["shape"])),
                       f"{a['chunks_written']}/{a['chunks']}", bad, gone])
    # integrity is what status is for: the chunk counts stay, the layout goes first
    console.print(FittedTable([Column("array", "left"),
                               Column("dims", "left", drop=2, wrap=True),
                               Column("shape", drop=1), Column("chunks written"),
                               Column("corrupted"), Column("missing")], arrays,
                              title="arrays"))
    _print_environments(report["environments"], report["layout_version"], console)
    for line in report["metadata"]:
        console.print(f"[red]metadata differs: {line}", highlight=False, soft_wrap=True)
    if report["damaged"]:
        console.print(f"[red]corrupted chunks found: {damaged(report)}; re-run the same "
                      "command to recompute them", highlight=False)
    elif report["metadata"]:
        console.print("[red]re-run the same command to repair the metadata (or to be told "
                      "why it cannot be)", highlight=False)
    return report
