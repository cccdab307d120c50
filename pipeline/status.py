"""Stage ``status`` (and ``box status``): what a store holds, per stage and per array."""

from __future__ import annotations

from pathlib import Path

import zarr
from rich.console import Console
from rich.table import Table

from pipeline.store import ScoreStore, StoreLock

STAGE_GROUPS = {"instances": "instances", "raw": "raw", "constraints": "constraints",
                "scores": "scores", "evaluate": "evaluation"}


def _arrays(store: ScoreStore, group: str):
    if not (store.path / group / "zarr.json").exists():
        return []
    g = zarr.open_group(store.path / group, mode="r", use_consolidated=False)
    return sorted(g.arrays(), key=lambda kv: kv[0])


def collect(path) -> dict:
    """Plain-data status of the store at ``path`` (raises StoreError if it is not ours)."""
    store = ScoreStore.open(path)
    attrs = store.attrs
    report = {"path": str(store.path), "config_hash": attrs.get("config_hash"),
              "created": attrs.get("created"), "running": StoreLock(store.path).held_by_other(),
              "stages": {}, "arrays": []}
    for stage, group in STAGE_GROUPS.items():
        info = attrs.get("stages", {}).get(stage)
        entry = {"finished": info.get("finished") if info else None}
        has_done = store.has(f"{group}/done")
        if has_done:
            done = store.done(group)
            entry["done"], entry["total"] = int(done.sum()), int(done.size)
        report["stages"][stage] = entry
        corrupted: dict[str, int] = {}
        if has_done:
            blocks, _ = store.blocks(group)
            for name, _ in _arrays(store, group):
                corrupted[name] = len(store.corrupted_blocks(group, [name], blocks))
        for name, arr in _arrays(store, group):
            report["arrays"].append({
                "array": f"{group}/{name}", "shape": list(arr.shape),
                "dims": list(arr.metadata.dimension_names or ()),
                "chunks_written": int(arr.nchunks_initialized), "chunks": int(arr.nchunks),
                "corrupted": corrupted.get(name, 0)})
    return report


def print_status(path, console: Console) -> dict:
    report = collect(Path(path))
    console.print(f"store {report['path']}  config {report['config_hash']}  created "
                  f"{report['created']}", highlight=False)
    console.print(f"running: {report['running'] or 'no'}", highlight=False)
    stages = Table(title="stages")
    for col in ("stage", "state", "entries done", "finished at"):
        stages.add_column(col)
    for stage, entry in report["stages"].items():
        progress = f"{entry['done']}/{entry['total']}" if "total" in entry else "-"
        if entry["finished"]:
            state = "[green]complete"
        elif "total" in entry or any(a["array"].startswith(STAGE_GROUPS[stage] + "/")
                                     for a in report["arrays"]):
            state = "[yellow]partial"
        else:
            state = "not started"
        stages.add_row(stage, state, progress, entry["finished"] or "-")
    console.print(stages)
    arrays = Table(title="arrays")
    for col in ("array", "dims", "shape", "chunks written", "corrupted"):
        arrays.add_column(col)
    for a in report["arrays"]:
        bad = f"[red]{a['corrupted']}" if a["corrupted"] else "0"
        arrays.add_row(a["array"], ", ".join(a["dims"]), " x ".join(map(str, a["shape"])),
                       f"{a['chunks_written']}/{a['chunks']}", bad)
    console.print(arrays)
    if any(a["corrupted"] for a in report["arrays"]):
        console.print("[red]corrupted chunks found: re-run the same command to recompute them")
    return report
