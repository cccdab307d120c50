"""Write ``tests/data/replay.json`` from small stores, and measure the reproducibility
contract's tolerance on this machine.

Each store contributes its domain and planner configuration, a few instance specs, its
constraints, and for some entries the planning seed and what was stored (status,
feasible, score, step, checks), plus some RAWPLANNER results.  ``tests/test_replay.py``
replays these from their seeds with the current code, on any machine: discrete outcomes
must be equal, floats within ``pipeline.environment.RTOL``/``ATOL`` (docs/reproducibility.md).

Beside the entries the file records the contract's tolerance, the environment the stores
were replayed in here (``made_in``), and ``measured``: for each code path that
``tests.replay.code_paths`` forces on this machine (NumPy without its SIMD kernels,
OpenBLAS with an older core's kernels, one or two BLAS threads), the largest relative
difference from this machine's own replay and the number of contract breaches.  The script
refuses to write a file whose tolerance its own measurement breaks.

Run: python tests/data/make_replay.py STORE.zarr [STORE.zarr ...]
(stores made with e.g. ``python -m pipeline stage=generate domain=planar instances.n=8
constraints.m=8 store.path=/tmp/ref/planar.zarr``; the file in the repository was made
from planar, grasp_arm and grasp_base with rrt_connect and trajopt, and pick_place).
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import zarr

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from pipeline.environment import ATOL, RTOL, fingerprint  # noqa: E402
from pipeline.worker import RAW_ENTRY, entry_seed  # noqa: E402
from tests import replay  # noqa: E402

OUT = Path(__file__).with_name("replay.json")
#: entries kept per store (pick_place calls cost ~0.1-0.4 s each, the others ~10 ms)
ENTRIES = {"pick_place": 10}
RAWS = {"pick_place": 1, "grasp_base": 3}


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


def measure(stores: list[dict]) -> dict:
    """Replay ``stores`` here and under every forced code path; the largest relative
    difference and the contract breaches of each path against this machine's replay."""
    here = [replay.replay_store(s) for s in stores]
    measured = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, env in replay.code_paths().items():
            got = replay.replay_in_child(env, Path(tmp) / f"{name}.json")["stores"]
            measured[name] = {
                "env": env,
                "largest_relative_difference": max(
                    replay.largest_difference(a, b) for a, b in zip(here, got, strict=True)),
                "breaches": sum(len(replay.compare(a, b)) for a, b in
                                zip(here, got, strict=True))}
            print(f"{name:22s} {measured[name]['largest_relative_difference']:.2e} "
                  f"relative, {measured[name]['breaches']} breaches")
    return measured


if __name__ == "__main__":
    stores = [from_store(p) for p in sys.argv[1:]]
    OUT.write_text(json.dumps({"stores": stores}) + "\n")  # replay.code_paths reads them
    measured = measure(stores)
    doc = {"contract": {"rtol": RTOL, "atol": ATOL}, "made_in": fingerprint(),
           "measured": measured, "stores": stores}
    OUT.write_text(json.dumps(doc) + "\n")
    print(f"wrote {OUT} ({OUT.stat().st_size / 1e3:.0f} kB)")
    if any(m["breaches"] for m in measured.values()):
        sys.exit("the contract's tolerance is too tight for what this machine measured")
