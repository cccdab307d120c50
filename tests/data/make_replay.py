"""Write ``tests/data/replay.json`` from small stores made by an earlier version.

Each store contributes its domain and planner configuration, a few instance specs, its
constraints, and for some entries the planning seed and what was stored (status,
feasible, score, step, checks), plus some RAWPLANNER results.  ``tests/test_replay.py``
replays these from their seeds with the current code; a difference means stored figures
would not survive the change.

Run: python tests/data/make_replay.py STORE.zarr [STORE.zarr ...]
(stores made with e.g. ``python -m pipeline stage=generate domain=planar instances.n=8
constraints.m=8 store.path=/tmp/ref/planar.zarr``).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import zarr

OUT = Path(__file__).with_name("replay.json")
#: entries kept per store (pick_place calls cost ~0.1-0.4 s each, the others ~10 ms)
ENTRIES = {"pick_place": 10}
RAWS = {"pick_place": 1, "grasp_base": 3}
RAW_ENTRY = 2**40  # the constraint index standing for RAWPLANNER in entry seeds


def entry_seed(run_seed: int, instance_seed: int, constraint: int) -> int:
    return int(np.random.SeedSequence([run_seed, instance_seed, constraint]).generate_state(1)[0])


def number(x: float) -> float | None:
    return None if np.isnan(x) else float(x)


def from_store(path: str) -> dict:
    g = zarr.open_group(path, mode="r")
    ident = g.attrs["identity"]
    domain, run_seed = ident["domain"]["name"], int(ident["seed"])
    specs = [json.loads(str(s)) for s in g["instances/spec"][:]]
    seeds = [int(s) for s in g["instances/seed"][:]]
    theta = g["constraints/theta"][:]
    s = {k: g[f"scores/{k}"][:] for k in ("status", "feasible", "score", "step", "checks")}
    r = {k: g[f"raw/{k}"][:] for k in ("status", "score", "step", "checks", "constraint")}
    n, m = s["status"].shape
    cells = [(i, j) for i in range(n) for j in range(m)]
    keep = ENTRIES.get(domain, len(cells))
    picked = sorted(np.random.default_rng(0).choice(len(cells), keep, replace=False))
    entries = []
    for c in picked:
        i, j = cells[c]
        entries.append({"instance": i, "constraint": j,
                        "seed": entry_seed(run_seed, seeds[i], j),
                        "status": int(s["status"][i, j]), "feasible": bool(s["feasible"][i, j]),
                        "score": number(s["score"][i, j]), "step": int(s["step"][i, j]),
                        "checks": int(s["checks"][i, j])})
    raws = [{"instance": i, "seed": entry_seed(run_seed, seeds[i], RAW_ENTRY),
             "status": int(r["status"][i]), "score": number(r["score"][i]),
             "step": int(r["step"][i]), "checks": int(r["checks"][i]),
             "constraint": [number(v) for v in r["constraint"][i]]}
            for i in range(min(RAWS.get(domain, n), n))]
    return {"store": Path(path).name, "domain": ident["domain"], "planner": ident["planner"],
            "instances": specs, "theta": theta.tolist(), "entries": entries, "raw": raws}


if __name__ == "__main__":
    OUT.write_text(json.dumps([from_store(p) for p in sys.argv[1:]], indent=None) + "\n")
    print(f"wrote {OUT} ({OUT.stat().st_size / 1e3:.0f} kB)")
