"""The scan's segments (``collide.SEGMENT``): an arm motion's rows cleared several at a time
against row by row, on the motions pick_place really scans.

One process, one core.  The scans (``collide.edge_first``'s calls of the compiled
``_scan``) of ``--instances`` instances × ``--constraints`` constraints of a pick_place
block (paper step order, as ``bench_pick_place.py`` draws them) are recorded as planning
makes them, then replayed with each segment size of ``--sizes`` (0: row by row, the code
before 2026-11-28), every call from the memo it had when recorded, hot: the best of
``--rounds`` rounds per size, the sizes taking turns.  Printed: µs per call by kind of
motion and how it ended, the total per size and its ratio to row by row, and whether every
replayed answer (rows, first row in doubt, proof) is the recorded one.

Run: python benchmarks/bench_scan_segments.py [--raw 40] [--instances 3] [--constraints 40]
         [--rounds 5] [--sizes 0,4,8,16]
"""

from __future__ import annotations

import argparse
import collections
import time

import numpy as np
from bench_pick_place import entries

#: where _scan's arguments sit: the kind, the motion's ends, its limit, the segment size,
#: the memo (floats, ints) the call reads and updates
KIND, QA, QB, LIMIT, SEGMENT_ARG, MEMO_F, MEMO_I = 0, 3, 4, 6, 8, -2, -1


def record(data: dict) -> list[tuple[tuple, tuple]]:
    """(arguments, answer) of every motion scan of the block, the memo as it was before."""
    from pipeline import worker
    from pipeline.sim import collide

    spec = {"name": "pick_place", "config": {"step_order": "paper"},
            "planner": {"name": "rrt_connect", "wall_cap_s": 1e6}}
    theta = data["theta"]
    worker.score_block(spec, 1, [str(s) for s in data["warm_specs"]],
                       [int(s) for s in data["warm_seeds"]], theta[:12], 0)
    scan, calls = collide._scan, []

    def recorded(*args):
        before = args[:MEMO_F] + (args[MEMO_F].copy(), args[MEMO_I].copy())
        answer = scan(*args)
        if args[KIND] != 2:
            calls.append((before, tuple(answer)))
        return answer

    collide._scan = recorded
    try:
        worker.score_block(spec, 0, [str(s) for s in data["specs"]],
                           [int(s) for s in data["seeds"]], theta, 0)
    finally:
        collide._scan = scan
    return calls


def category(args, answer) -> str:
    kind = "arm" if args[KIND] == 0 else "base"
    what = "state" if np.array_equal(args[QA], args[QB]) else "motion"
    steps, k, proved = answer
    end = ("proof" if proved else "free" if k >= min(steps, args[LIMIT])
           else "unknown wrist cell" if k < 0 else "row in doubt")
    return f"{kind} {what}, {end}"


def replay(calls, size: int) -> tuple[list, list]:
    """The calls' arguments with segment size ``size`` and a fresh copy of their memo."""
    return [args[:SEGMENT_ARG] + (size,) + args[SEGMENT_ARG + 1:MEMO_F]
            + (args[MEMO_F].copy(), args[MEMO_I].copy()) for args, _ in calls]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--raw", type=int, default=40)
    ap.add_argument("--instances", type=int, default=3)
    ap.add_argument("--constraints", type=int, default=40)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--sizes", default=[0, 4, 8, 16], help="segment sizes, comma-separated",
                    type=lambda v: [int(s) for s in v.split(",")])
    ap.add_argument("--seed", type=int, default=2017)
    args = ap.parse_args()
    from pipeline.sim import collide

    sizes = args.sizes
    calls = record(entries(args.raw, args.instances, args.constraints, args.seed))
    groups = collections.defaultdict(list)
    for k, (a, answer) in enumerate(calls):
        groups[category(a, answer)].append(k)
    same = {}
    for size in sizes:  # compiled and checked once before timing
        replayed = replay(calls, size)
        same[size] = all(tuple(collide._scan(*a)) == answer
                         for a, (_, answer) in zip(replayed, calls, strict=True))
    best = {(size, g): np.inf for size in sizes for g in groups}
    for r in range(args.rounds):
        for size in sizes[r % len(sizes):] + sizes[:r % len(sizes)]:
            replayed = replay(calls, size)
            for g, members in groups.items():
                batch = [replayed[k] for k in members]
                t = time.perf_counter()
                for a in batch:
                    collide._scan(*a)
                best[size, g] = min(best[size, g], time.perf_counter() - t)
    print(f"pick_place scans replayed: {len(calls)} calls from {args.instances} instances × "
          f"{args.constraints} constraints, one core, best of {args.rounds} rounds "
          f"(µs per call; default segment size {collide.SEGMENT})")
    print(f"  {'motion, how it ended':<32}{'calls':>7}" + "".join(f"{f'size {s}':>11}"
                                                         for s in sizes))
    for g in sorted(groups):
        n = len(groups[g])
        print(f"  {g:<32}{n:>7}" + "".join(f"{best[s, g] / n * 1e6:>11.1f}" for s in sizes))
    total = {s: sum(best[s, g] for g in groups) for s in sizes}
    print(f"  {'all (s)':<39}" + "".join(f"{total[s]:>11.3f}" for s in sizes))
    if 0 in total:
        print(f"  {'row by row / size':<39}" + "".join(f"{total[0] / total[s]:>10.2f}x"
                                                      for s in sizes))
    print("  answers identical to the recorded ones: "
          + ", ".join(f"size {s} {'yes' if same[s] else 'NO'}" for s in sizes))


if __name__ == "__main__":
    main()
