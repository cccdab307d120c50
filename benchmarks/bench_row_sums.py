"""Sparse-weighted row sums read in column tiles (box_core.row_sums) against scipy's
product with the whole table, on one core, at the contextual pair's pick_place shape.

The table is (n, w) = (1350, 5000) by default: CONTEXTUAL+CAPS's five blocks of m = 1000
columns over the 1350 training rows of a tuning group.  The weights are ones at ``--k``
distinct neighbours of each of ``--instances`` instances (a batch's first sums) or, with
``--changes`` per instance, random weight changes (a step's update).  Both products run
``--repeats`` times, alternating; printed: the median seconds of each, their ratio, and
whether the results are equal bit for bit.

Run: python benchmarks/bench_row_sums.py [--rows 1350] [--width 5000] [--instances 1000]
         [--k 80] [--changes 0] [--repeats 7]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np
from scipy import sparse

from box_core.row_sums import RowTable


def weights(instances: int, rows: int, per: int, rng) -> sparse.csr_matrix:
    cols = np.stack([np.sort(rng.choice(rows, per, replace=False)) for _ in range(instances)])
    data = np.ones(cols.size) if per else np.zeros(0)
    return sparse.csr_matrix((data, cols.ravel(), np.arange(instances + 1) * per),
                             shape=(instances, rows))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=1350)
    parser.add_argument("--width", type=int, default=5000)
    parser.add_argument("--instances", type=int, default=1000)
    parser.add_argument("--k", type=int, default=80)
    parser.add_argument("--changes", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    per = args.changes or args.k
    if min(args.rows, args.width, args.instances, args.repeats) < 1 or not 0 < per <= args.rows:
        print("bench_row_sums: sizes and repeats must be 1 or more, and the nonzeros per "
              "instance between 1 and --rows", file=sys.stderr)
        return 2
    rng = np.random.default_rng(0)
    rows = rng.random((args.rows, args.width))
    W = weights(args.instances, args.rows, per, rng)
    if args.changes:
        W.data = rng.uniform(-1.0, 0.0, W.nnz)
    table = RowTable(rows)
    table.weighted(W)  # the tiles are made at the first product, as in a run
    times = {"whole": [], "tiles": []}
    results = {}
    for _ in range(args.repeats):
        for name in times:
            start = time.perf_counter()
            results[name] = (np.asarray(W @ rows) if name == "whole" else table.weighted(W))
            times[name].append(time.perf_counter() - start)
    whole, tiles = (statistics.median(times[k]) for k in ("whole", "tiles"))
    print(f"({args.instances} x {args.rows} weights, {W.nnz} nonzero) @ ({args.rows} x "
          f"{args.width}) table, median of {args.repeats}:")
    print(f"  whole table   {whole:8.4f} s")
    print(f"  column tiles  {tiles:8.4f} s   {whole / tiles:.2f}x")
    print("  identical: " + ("yes" if np.array_equal(results["whole"], results["tiles"])
                             else "NO"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
