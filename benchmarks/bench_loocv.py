"""Leave-one-out evaluation speed: box_core against a naive implementation, same run.

    python benchmarks/bench_loocv.py [--repeats 3] [--naive-folds 12]

1. Full LOOCV of box, eips, static, rand and doo with k = m on a synthetic 1800 x 162 matrix
   shaped like the paper's grasp-and-arm data, beside the naive implementation of
   tests/reference.py (refit mu and Sigma per fold, eq. 2 solved afresh with
   numpy.linalg.solve at every step), timed on a few folds and extrapolated to all n.
   The naive and fast orders are compared on those folds.
2. 1000 x 1000 with k = 50: wall time and peak memory.
3. The cost of one live step (propose + update) of a selector running alone on one new
   instance, which is what a user pays; LOOCV reports the cost per step amortised over a
   batch of held-out rows, which is smaller.

Prints medians over repeats; no thresholds are asserted (machines are noisy).
"""

from __future__ import annotations

import argparse
import resource
import statistics
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import box_core  # noqa: E402
from box_core.failure import fill_failures  # noqa: E402
from box_core.synthetic import score_matrix  # noqa: E402
from tests import reference  # noqa: E402

SELECTORS = ("box", "eips", "static", "rand", "doo")


def timed(fn, repeats):
    times, out = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), out


def naive_fold(D, features, name, i, k, seed, feasible=None, times=None):
    """One fold of the naive evaluator (the refit is inside reference.*_order)."""
    train, truth = np.delete(D, i, axis=0), D[i]
    if name == "box":
        return reference.box_order(train, truth, k)
    if name == "eips":
        return reference.eips_order(train, np.delete(feasible, i, axis=0),
                                    np.delete(times, i, axis=0), truth, k)
    if name == "static":
        return reference.static_order(train, k)
    if name == "rand":
        return reference.rand_order(D.shape[1], k, (seed, i))
    return reference.doo_order(truth, features, k, (seed, i), unit=np.abs(D).max())


def paper_scale(repeats: int, naive_folds: int) -> None:
    data = score_matrix(1800, 162, seed=0)
    n, m = data.scores.shape
    print(f"== LOOCV {n} x {m}, k = m = {m}, selectors {', '.join(SELECTORS)}")
    print(f"   matrix: {data.feasible.mean():.1%} feasible entries, "
          f"{int(data.feasible.any(axis=0).sum())} columns ever feasible")

    def fast():
        return box_core.loocv(data.scores, feasible=data.feasible, times=data.times,
                              features=data.features, selectors=SELECTORS, seed=0)

    fast_s, result = timed(fast, repeats)
    per = {}
    for name in SELECTORS:
        per[name], _ = timed(lambda name=name: box_core.loocv(
            data.scores, feasible=data.feasible, times=data.times, features=data.features,
            selectors=(name,), seed=0), repeats)
    print(f"   box_core:  {fast_s:8.2f} s  (median of {repeats}; alone: "
          + ", ".join(f"{k} {v:.2f} s" for k, v in per.items()) + ")")

    D = fill_failures(data.scores, data.feasible, result.failure_value)
    folds = np.linspace(0, n - 1, naive_folds).astype(int)
    naive_per, agree = {}, True
    for name in SELECTORS:
        start = time.perf_counter()
        orders = [naive_fold(D, data.features, name, int(i), m, 0, data.feasible, data.times)
                  for i in folds]
        naive_per[name] = (time.perf_counter() - start) / len(folds) * n
        agree &= bool(np.array_equal(np.array(orders), result.order[name][folds]))
    naive_s = sum(naive_per.values())
    print(f"   naive:     {naive_s:8.1f} s  (timed on {len(folds)} folds, extrapolated to {n}: "
          + ", ".join(f"{k} {v:.1f} s" for k, v in naive_per.items()) + ")")
    print(f"   speed-up:  {naive_s / fast_s:8.1f} x   (target >= 60 x)")
    print(f"   orders identical to the naive ones on the timed folds: {'yes' if agree else 'NO'}")
    print("   " + str(result.summary()).replace("\n", "\n   "))


def large(repeats: int) -> None:
    data = score_matrix(1000, 1000, seed=1, types=40, useful=200, per_type=5)
    print("== LOOCV 1000 x 1000, k = 50, selectors " + ", ".join(SELECTORS))

    def run():
        return box_core.loocv(data.scores, feasible=data.feasible, times=data.times,
                              features=data.features, selectors=SELECTORS, k=50, seed=0)

    wall, _ = timed(run, repeats)
    tracemalloc.start()
    run()
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"   wall:      {wall:8.2f} s  (median of {repeats}; target <= 10 s)")
    print(f"   memory:    {peak / 2**20:8.1f} MiB peak allocated by the evaluation (tracemalloc), "
          f"{rss:.0f} MiB max RSS of this whole process (target <= 2 GiB)")


def live_steps(repeats: int) -> None:
    data = score_matrix(1800, 162, seed=0)
    D = fill_failures(data.scores, data.feasible, -20.0)
    train, truth = D[:-1], D[-1]
    print("== live selector on one new instance, trained on 1799 x 162, all 162 steps")
    extra = {"features": data.features, "feasible": data.feasible[:-1], "times": data.times[:-1]}
    for name in ("box", "eips", "pembo", "static", "doo"):
        def run(name=name):
            sel = box_core.make_selector(name, train, **extra)
            start = time.perf_counter()
            for _ in range(truth.size):
                j = sel.propose()
                sel.update(j, truth[j])
            return time.perf_counter() - start

        steps = statistics.median(run() for _ in range(repeats)) / truth.size
        build, _ = timed(lambda name=name: box_core.make_selector(name, train, **extra),
                         repeats)
        print(f"   {name:7s} {steps * 1e6:7.1f} us per step, {build * 1e3:6.1f} ms to build "
              "(fit the prior)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--naive-folds", type=int, default=12)
    args = parser.parse_args()
    paper_scale(args.repeats, args.naive_folds)
    large(args.repeats)
    live_steps(args.repeats)


if __name__ == "__main__":
    main()
