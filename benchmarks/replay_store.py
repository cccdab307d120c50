"""Replay a sample of a store's score entries with this checkout: are they still the stored
ones, and what do they cost now against what they cost when the store was made?

A store made by an earlier version (or on another machine) is the fairest yardstick for a
change to the planners' speed: the same entries, planned by the code that made them and by
this checkout.  ``--blocks`` blocks of the store's layout are drawn at random (``--seed``)
and the first ``--rows`` instances of each are planned against all the block's
constraints, as a worker plans a block (:func:`pipeline.worker.score_block`, one core), with
the store's own domain and planner config, after one entry planned untimed (the scene,
numba's kernels and the caches load); the planner's wall-clock safety net is set out of
reach, so that a busy machine cannot turn an entry into "timeout".

Printed per block and in all: entries whose status, feasibility, failed step, check count,
path length and score equal the stored ones (floats bit for bit, and within the
reproducibility contract of :mod:`pipeline.environment` when the store was made elsewhere),
and the planning time per entry now and as stored (median and mean, the same entries).
The stored times were measured when the store was made, on that day's machine: the ratio
includes the machine's drift as well as the code's change.  Exit status 1 when an entry
breaks the contract (bit for bit is only promised within one environment), 2 on bad input.

Run: python benchmarks/replay_store.py STORE [--blocks 8] [--rows 5] [--seed 0]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from child_runs import columns_agree

COLUMNS = ("status", "feasible", "step", "checks", "length", "score")
#: the planner's wall-clock safety net, out of reach
WALL_CAP_S = 1e6


def sample_blocks(n: int, m: int, bi: int, bj: int, count: int, seed: int):
    """``count`` distinct blocks (row slice, column slice) of an n × m layout of bi × bj
    blocks, drawn at random."""
    rows, cols = -(-n // bi), -(-m // bj)
    picks = np.random.default_rng(seed).choice(rows * cols, min(count, rows * cols),
                                               replace=False)
    for p in picks:
        i, j = divmod(int(p), cols)
        yield slice(i * bi, min((i + 1) * bi, n)), slice(j * bj, min((j + 1) * bj, m))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("store")
    ap.add_argument("--blocks", type=int, default=8)
    ap.add_argument("--rows", type=int, default=5, help="instances replayed per block")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if args.blocks < 1 or args.rows < 1:
        print("replay_store: --blocks and --rows must be at least 1", file=sys.stderr)
        return 2

    from pipeline import worker
    from pipeline.environment import ATOL, RTOL
    from pipeline.store import ScoreStore, StoreError
    from pipeline.store.layout import SCORES

    try:
        store = ScoreStore.open(args.store)
        spec = store.domain_spec()
        config = store.attrs["config"]
        if not (store.stage_info("scores") or {}).get("finished"):
            raise StoreError(f"{args.store}: its scores stage is not complete")
    except (StoreError, KeyError, FileNotFoundError) as e:
        print(f"replay_store: {e}", file=sys.stderr)
        return 2
    spec = {**spec, "planner": {**spec["planner"], "wall_cap_s": WALL_CAP_S}}
    specs, seeds, theta = store.instance_specs(), store.instance_seeds(), store.theta()
    stored = {c: store.result(SCORES, c) for c in (*COLUMNS, "time")}
    n, m = stored["status"].shape
    bi, bj = config["store"]["block_instances"], config["store"]["block_constraints"]
    print(f"{args.store}: {spec['name']}, {spec['planner']['name']}, {n} × {m}; replaying "
          f"{args.rows} instances of each of {args.blocks} blocks of {bi} × {bj}")

    blocks = list(sample_blocks(n, m, bi, bj, args.blocks, args.seed))
    # warm up (the scene, numba's kernels, caches) on one entry, not timed
    rows, cols = blocks[0]
    worker.score_block(spec, config["seed"], [str(specs[rows.start])], [int(seeds[rows.start])],
                       theta[cols.start:cols.start + 1], cols.start)
    exact_all, close_all, now, then = [], [], [], []
    for rows, cols in blocks:
        rows = slice(rows.start, min(rows.stop, rows.start + args.rows))
        got, _ = worker.score_block(spec, config["seed"], [str(s) for s in specs[rows]],
                                    [int(s) for s in seeds[rows]], theta[cols], cols.start)
        held = {c: stored[c][rows, cols] for c in COLUMNS}
        exact = columns_agree(got, held, COLUMNS)
        close = columns_agree(got, held, COLUMNS, rtol=RTOL, atol=ATOL)
        exact_all.append(exact.ravel())
        close_all.append(close.ravel())
        now.append(got["time"].ravel())
        then.append(stored["time"][rows, cols].ravel())
        print(f"  instances {rows.start}-{rows.stop - 1} × constraints {cols.start}-"
              f"{cols.stop - 1}: {int(exact.sum())} of {exact.size} identical", flush=True)
    exact, close = np.concatenate(exact_all), np.concatenate(close_all)
    now, then = np.concatenate(now) * 1e3, np.concatenate(then) * 1e3
    print(f"entries identical to the stored ones: {int(exact.sum())} of {exact.size} bit for "
          f"bit, {int(close.sum())} within the contract")
    print(f"planning time per entry: now median {np.median(now):.2f} ms, mean "
          f"{now.mean():.2f} ms; stored median {np.median(then):.2f} ms, mean "
          f"{then.mean():.2f} ms (now / stored: {now.mean() / then.mean():.2f}× on the mean)")
    return 0 if close.all() else 1


if __name__ == "__main__":
    sys.exit(main())
