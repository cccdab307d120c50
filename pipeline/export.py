"""``box export``: a store's score matrix and metadata in formats other tools read."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from pipeline.evaluation import path_scores
from pipeline.store import ScoreStore, StoreError

FORMATS = ("npz", "csv")


def _arrays(store: ScoreStore) -> dict[str, np.ndarray]:
    if not store.has("scores/done"):
        raise StoreError(f"{store.path} has no score matrix yet; run stage=generate first")
    done = store.done("scores")
    feasible = store.array("scores/feasible")[...] & done
    length = store.array("scores/length")[...]
    return {
        "scores": path_scores(feasible, length),  # what ``box evaluate`` reads
        "feasible": feasible,
        "times": store.array("scores/time")[...],
        "features": store.array("constraints/theta")[...],
        "length": length,
        "status": store.array("scores/status")[...],
        "checks": store.array("scores/checks")[...],
        "step": (store.array("scores/step")[...] if store.has("scores/step")  # older stores
                 else np.full(feasible.shape, -1, dtype="int8")),
        "done": done,
        "instance_seed": store.array("instances/seed")[...],
    }


def metadata(store: ScoreStore, arrays: dict) -> dict:
    attrs = store.attrs
    from pipeline.planning import Status

    return {"store": str(store.path), "config_hash": attrs.get("config_hash"),
            "config": attrs.get("config"), "versions": attrs.get("versions"),
            "git_revision": attrs.get("git_revision"), "created": attrs.get("created"),
            "stages": attrs.get("stages"), "complete": bool(arrays["done"].all()),
            "status_codes": {s.name: int(s) for s in Status},
            "steps": (store.array("scores/step").attrs.get("flag_meanings", "").split()
                      if store.has("scores/step") else []),
            "score": "-(path length) where feasible; 0 where infeasible or not computed",
            "times": "seconds per planning call; NaN where not computed"}


def export(path, fmt: str, out: Path | None = None) -> tuple[Path, bool]:
    """Write the store at ``path`` as ``fmt``; return (what was written, complete?)."""
    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}; choose {' or '.join(FORMATS)}")
    from pipeline.status import refuse_damaged

    store = ScoreStore.open(path)
    refuse_damaged(store)
    arrays = _arrays(store)
    meta = metadata(store, arrays)
    stem = store.path.name.removesuffix(".zarr")
    if fmt == "npz":
        out = Path(out) if out else Path.cwd() / f"{stem}.npz"
        if out.suffix != ".npz":
            raise ValueError(f"{out}: an npz export needs a path ending in .npz")
        out.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(out, **arrays, metadata=np.array(json.dumps(meta)))
        return out, meta["complete"]
    out = Path(out) if out else Path.cwd() / f"{stem}-csv"
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out} exists and is not a directory (a csv export is a folder)")
    out.mkdir(parents=True, exist_ok=True)
    n, m = arrays["scores"].shape
    with open(out / "entries.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["instance", "constraint", "done", "feasible", "length", "time", "status",
                    "checks", "step"])
        steps = meta["steps"]
        for i in range(n):
            for j in range(m):
                k = int(arrays["step"][i, j])
                w.writerow([i, j, int(arrays["done"][i, j]), int(arrays["feasible"][i, j]),
                            _cell(arrays["length"][i, j]), _cell(arrays["times"][i, j]),
                            int(arrays["status"][i, j]), int(arrays["checks"][i, j]),
                            steps[k] if 0 <= k < len(steps) else ""])
    with open(out / "constraints.csv", "w", newline="") as f:
        w = csv.writer(f)
        theta = arrays["features"]
        w.writerow(["constraint", *[f"theta{k}" for k in range(theta.shape[1])]])
        for j, row in enumerate(theta):
            w.writerow([j, *(repr(float(x)) for x in row)])
    with open(out / "instances.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["instance", "seed", "spec"])
        specs = store.array("instances/spec")[...]
        for i, (seed, spec) in enumerate(zip(arrays["instance_seed"], specs, strict=True)):
            w.writerow([i, int(seed), str(spec)])
    (out / "metadata.json").write_text(json.dumps(meta, indent=1))
    return out, meta["complete"]


def _cell(x) -> str:
    return "" if np.isnan(x) else repr(float(x))
