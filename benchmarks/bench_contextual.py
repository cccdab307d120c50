"""CONTEXTUAL against BOX on a score store, leave-one-out, side by side in one run.

    python benchmarks/bench_contextual.py STORE.zarr [--features X.npy] [--k K]
                                          [--selectors box,contextual,contextual_capped]

Reads the store's matrices with plain zarr (``scores/score``, ``scores/feasible``,
``scores/time``, ``scores/checks`` and, where the store has them, ``instances/features``;
``--features`` gives an (n, q) .npy array instead; an entry with ``--budget`` checks
or more that is infeasible ran out of the planner's budget).  Prints, per selector: mean time to
the first feasible plan over the rows where one exists, its ratio to BOX with the paired
95 % interval (box_core.stats.paired_ratio; above 1: faster than BOX), the mean number of
tries to it (a resumed try counts again), the mean time spent on tries that ran out of the
planner's budget, the settings chosen by nested tuning, and the selector's own compute
seconds over the whole evaluation (tuning included), measured separately: the times and
ratios are planning time only, what ``measure_overhead=False`` gives (deterministic).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import box_core  # noqa: E402
from box_core.stats import paired_ratio  # noqa: E402

SELECTORS = ("box", "contextual", "contextual_capped")


def fail(message: str) -> None:
    print(f"bench_contextual: {message}", file=sys.stderr)
    raise SystemExit(2)


def load(path: str, features: str | None):
    import zarr

    try:
        g = zarr.open_group(path, mode="r")
        scores = np.asarray(g["scores/score"][:], dtype=np.float64)
        feasible = np.asarray(g["scores/feasible"][:], dtype=bool)
        times = np.asarray(g["scores/time"][:], dtype=np.float64)
        checks = np.asarray(g["scores/checks"][:])
    except Exception as exc:  # a missing store or array: one line
        fail(f"cannot read the score matrices of {path}: {exc}")
    X, names = None, None
    if features is not None:
        try:
            X = np.load(features, allow_pickle=False)
        except Exception as exc:
            fail(f"cannot read --features {features}: {exc}")
    elif "features" in g.get("instances", {}):
        X = np.asarray(g["instances/features"][:], dtype=np.float64)
        if "instance_feature" in g["instances"]:
            names = np.array([str(x) for x in g["instances/instance_feature"][:]])
    if X is not None and names is None:
        names = np.array([f"#{f}" for f in range(X.shape[1])])
    return scores, feasible, times, checks, X, names


def budget_time(result, name, times, checks, feasible, budget) -> float:
    """Mean seconds per eligible row spent on tries of entries that ran out of budget
    (infeasible, with ``budget`` checks or more), up to the first plan."""
    order, step = result.order[name], result.first_feasible_step[name]
    rows = np.flatnonzero(step >= 0)
    cost = result.try_time.get(name)
    total = 0.0
    for i in rows:
        cols = order[i, :step[i] + 1]
        spent = cost[i, :step[i] + 1] if cost is not None else times[i, cols]
        total += float(spent[(checks[i, cols] >= budget) & ~feasible[i, cols]].sum())
    return total / max(rows.size, 1)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store")
    parser.add_argument("--features", help="an (n, q) .npy array of instance features")
    parser.add_argument("--k", type=int, default=None, help="tries per row (default m)")
    parser.add_argument("--selectors", default=",".join(SELECTORS))
    parser.add_argument("--budget", type=int, default=20000,
                        help="an entry with at least this many checks ran out of budget")
    args = parser.parse_args(argv)
    S, F, T, C, X, names_of = load(args.store, args.features)
    names = tuple(args.selectors.split(","))
    if "box" not in names:
        names = ("box",) + names
    if X is None:
        print("no instance features: contextual is BOX")
    n, m = S.shape
    print(f"{args.store}: {n} x {m}, {int(F.any(axis=1).sum())} rows with a plan, "
          f"instance features {None if X is None else X.shape}")
    kwargs = dict(times=T, feasible=F, selectors=names, k=args.k, instance_features=X,
                  checks=C)
    try:
        start = time.perf_counter()
        res = box_core.loocv(S, measure_overhead=True, **kwargs)
        wall = time.perf_counter() - start
    except ValueError as exc:
        fail(str(exc))
    print(f"leave-one-out of {', '.join(names)}: {wall:.1f} s")
    # planning time only: what measure_overhead=False gives as first_feasible_time (the
    # orders do not depend on the clock), so the ratios are deterministic
    planning = res.first_feasible_planning_time
    box = planning["box"]
    print(f"{'selector':<18} {'mean ms':>8} {'BOX/this':>9} {'95 % interval':>16} "
          f"{'tries':>6} {'budget ms':>9} {'own s':>7}")
    for name in names:
        t = planning[name]
        ratio, low, high = paired_ratio(box, t)
        step = res.first_feasible_step[name]
        tries = float((step[step >= 0] + 1).mean())
        own = float(res.overhead[name].sum()) + res.tuning_seconds.get(name, 0.0)  # tuning too
        print(f"{name:<18} {1e3 * np.nanmean(t):8.2f} {ratio:9.3f} "
              f"[{low:6.3f}, {high:6.3f}] {tries:6.2f} "
              f"{1e3 * budget_time(res, name, T, C, F, args.budget):9.2f} {own:7.1f}")
    for name, chosen in res.settings.items():
        parts = []
        for key in ("k", "cap"):
            if key in chosen:
                values, counts = np.unique(chosen[key], return_counts=True)
                parts.append(f"{key} " + ", ".join(f"{v:g}: {c}" for v, c in
                                                   zip(values, counts, strict=True)))
        if "feature_mask" in chosen:
            used, counts = np.unique(chosen["feature_mask"].astype(bool), axis=0,
                                     return_counts=True)
            for mask, count in zip(used, counts, strict=True):
                picked = ", ".join(names_of[mask]) if mask.any() else "none (BOX)"
                parts.append(f"features {picked}: {count} rows")
        print(f"{name} settings (value: rows): {'; '.join(parts)}")


if __name__ == "__main__":
    main()
