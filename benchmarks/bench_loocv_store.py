"""Leave-one-out on a real store's score matrix, as ``box evaluate STORE`` runs it: this
checkout with two processes and with one, against the code of another revision.

    python benchmarks/bench_loocv_store.py STORE [--selectors box,static,rand,doo]
                                          [--repeats 1] [--baseline-rev 8115288]
                                          [--every 1]

The matrix is read once the way ``box evaluate`` reads a store (scores, feasibility,
times, Θ̂, instance features, checks, and each row's own constraints hidden), saved, and
each measurement runs in a fresh interpreter: ``box_core.loocv`` with k = all allowed
columns and the selectors' overhead measured, as ``box evaluate`` does.  ``--every N``
holds out only every N-th row (each still against all the others, so each row's trace is
the one the whole run gives it; ``box_core.loocv._loocv``'s ``rows``), for selectors whose
baseline would take an hour on every row.  Variants:

  two      this checkout, ``workers=2`` (what ``box evaluate`` and stage evaluate pass on
           a matrix this size where 2 cores are free: the second process takes half the
           rows, or the tuned selectors) and ``until_best=True`` (each row stops once
           its first plan and its best score are in, as both commands run it);
  one      this checkout, ``workers=1``, ``until_best=True``;
  base     box_core at ``--baseline-rev`` (``''``: none), ``workers=1``, every row to the
           end (code from before ``until_best``); its default is the code before BOX's
           posterior dropped its tried columns and before the rows were split (the
           workers of that code only move tuned selectors).  ``--baseline-until-best``
           and ``--baseline-workers 2`` run a revision that has ``until_best`` the way
           ``two`` runs this checkout: the same work, the code's own difference.

Every child has one thread per numeric library (``child_runs.ONE_THREAD``).  Printed:
median wall seconds (over ``--repeats``) and their range, the median CPU seconds of both
processes together (user and system), the peak memory of the measuring
process and of its second process, the ratio to ``base``, and whether every variant's
first feasible steps and planning times are those of ``base`` (or of ``one`` without a
baseline) bit for bit, and its orders too as far as both go, the shorter one holding its
row's best score of the longer (so every best-score curve over planning time is the same).
Issue 27's target: <= 60 s and <= 4 GiB on 2 cores for
the default selectors at 1500 x 1000.  Asserts nothing (machines are noisy).
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from child_runs import export_revision, run_child

ROOT = Path(__file__).resolve().parents[1]

#: what box evaluate runs on a store with constraint features
SELECTORS = "box,static,rand,doo"
#: the arrays of a matrix file, as pipeline.cli.store_matrix gives them
FIELDS = ("scores", "times", "feasible", "features", "instance_features", "checks")
#: what the variants must agree on (the times with overhead are the machine's)
COMPARED = ("order", "first_feasible_step", "first_feasible_planning_time")


def agree(a: Path, b: Path, plans: np.ndarray, rows: np.ndarray) -> bool:
    """Whether the results saved at ``a`` and ``b`` have the same first-feasible steps and
    planning times bit for bit, and orders that agree as far as both go, where the shorter
    one (a row stopped at its best, -1 after) holds its row's best plan of the longer
    (``plans``: the scores of feasible entries, -inf elsewhere): then every best-score
    curve over planning time is the same too."""
    x, y = np.load(a), np.load(b)
    if sorted(x.files) != sorted(y.files):
        return False
    for key in x.files:
        if not key.startswith("order|"):
            if not np.array_equal(x[key], y[key], equal_nan=True):
                return False
            continue
        p, q = x[key], y[key]
        both = (p >= 0) & (q >= 0)
        if not np.array_equal(p[both], q[both]):
            return False
        D = plans[rows]
        for i in range(p.shape[0]):
            short, full = sorted((p[i][p[i] >= 0], q[i][q[i] >= 0]), key=len)
            if D[i, full].max(initial=-np.inf) > D[i, short].max(initial=-np.inf):
                return False
    return True


def child(job: dict) -> dict:
    """One measurement in this fresh interpreter (box_core from the variant's root)."""
    import box_core as module

    data = np.load(job["data"])
    given = {f: data[f] for f in FIELDS[1:] if f in data.files}
    forbidden = data["forbidden"] if "forbidden" in data.files else None
    # box evaluate stops each row once its first plan and its best score are in (what the
    # summary and the figures read); code from before that option runs every row to the end
    extra = {"until_best": True} if job["until_best"] else {}
    start, cpu = time.perf_counter(), _cpu_seconds()
    if job["every"] > 1:
        from box_core.loocv import _loocv

        rows = np.arange(0, data["scores"].shape[0], job["every"])
        given = {"times": None, "feasible": None, "instance_features": None,
                 "checks": None, "features": None, **given}
        result = _loocv(data["scores"], selectors=tuple(job["selectors"]),
                        forbidden=forbidden, workers=job["workers"], seed=0,
                        measure_overhead=True, rows=rows, k=None, params=None,
                        failure_rule="magnitude", time_grid=None, **given, **extra)
    else:
        result = module.loocv(data["scores"], selectors=tuple(job["selectors"]),
                              forbidden=forbidden, workers=job["workers"], seed=0,
                              measure_overhead=True, **given, **extra)
    wall, cpu = time.perf_counter() - start, _cpu_seconds() - cpu
    np.savez(job["out"], **{f"{field}|{name}": getattr(result, field)[name]
                            for name in result.selectors for field in COMPARED})
    return {"wall": wall, "cpu": cpu,
            "rss": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "rss_second": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024}


def _cpu_seconds() -> float:
    """User and system CPU seconds of this process and of its ended children (the second
    process): less noisy than wall time on a shared machine, whose other load slows
    every variant's wall time alike only on average."""
    return sum(u.ru_utime + u.ru_stime for u in (resource.getrusage(resource.RUSAGE_SELF),
                                                 resource.getrusage(resource.RUSAGE_CHILDREN)))


def saved_matrix(store: str, into: Path) -> tuple[Path, tuple[int, int]]:
    """The store's matrix as ``box evaluate`` reads it, in an .npz file."""
    from pipeline.cli import store_matrix

    data, forbidden = store_matrix(Path(store))
    arrays = {f: getattr(data, f) for f in FIELDS if getattr(data, f) is not None}
    if forbidden is not None:
        arrays["forbidden"] = forbidden
    path = into / "matrix.npz"
    np.savez(path, **arrays)
    return path, np.shape(data.scores)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store", nargs="?")
    parser.add_argument("--selectors", default=SELECTORS)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--baseline-rev", default="8115288")
    parser.add_argument("--every", type=int, default=1)
    parser.add_argument("--baseline-until-best", action="store_true",
                        help="run the baseline as this checkout runs (until_best=True, "
                             "--baseline-workers): for a revision that has until_best")
    parser.add_argument("--baseline-workers", type=int, default=1)
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(json.loads(args.child))))
        return 0
    if not args.store:
        parser.error("a store is needed (a folder made by python -m pipeline)")
    from pipeline.store import StoreError

    selectors = [s.strip() for s in args.selectors.split(",") if s.strip()]
    if args.every < 1 or args.baseline_workers < 1:
        name, value = (("--every", args.every) if args.every < 1
                       else ("--baseline-workers", args.baseline_workers))
        print(f"bench_loocv_store: {name} must be 1 or more, got {value}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        try:
            data, (n, m) = saved_matrix(args.store, Path(tmp))
        except (StoreError, FileNotFoundError) as e:
            print(f"bench_loocv_store: {e}", file=sys.stderr)
            return 2
        common = dict(data=str(data), selectors=selectors, every=args.every)
        variants = {"two": (ROOT, dict(common, workers=2, until_best=True)),
                    "one": (ROOT, dict(common, workers=1, until_best=True))}
        base = (export_revision(args.baseline_rev, Path(tmp) / "base", ("box_core",))
                if args.baseline_rev else None)
        if base is not None:
            variants["base"] = (base, dict(common, workers=args.baseline_workers,
                                           until_best=args.baseline_until_best))
        runs = {v: [] for v in variants}
        names = list(variants)
        for r in range(args.repeats):  # the variants' order rotates: drift hits all alike
            for v in names[r % len(names):] + names[:r % len(names)]:
                root, job = variants[v]
                out = Path(tmp) / f"{v}-{r}.npz"
                runs[v].append({**run_child(__file__, dict(job, out=str(out)), root, v),
                                "out": out})
        saved = np.load(data)
        scores = saved["scores"]
        feasible = (saved["feasible"] if "feasible" in saved.files
                    else scores > np.nanmin(scores))  # box_core's rule without a mask
        plans = np.where(feasible, scores, -np.inf)
        rows = np.arange(0, n, args.every)
        held = ("" if args.every == 1 else
                f", every {args.every}th row held out ({-(-n // args.every)})")
        print(f"{args.store}: leave-one-out {n} x {m}{held}, {', '.join(selectors)}, k = all "
              f"allowed columns, overhead measured; median of {args.repeats}")
        reference = "base" if "base" in runs else "one"
        ref_wall = statistics.median(r["wall"] for r in runs[reference])
        label = {"two": "this checkout, workers=2", "one": "this checkout, workers=1",
                 "base": f"baseline {args.baseline_rev}, workers={args.baseline_workers}"}
        print(f"  {'variant':<36}{'wall s':>9}{'range':>14}{'cpu s':>8}{'peak MiB':>10}"
              f"{'2nd MiB':>9}{'/ ' + reference:>9}  identical")
        for v, rs in runs.items():
            wall = statistics.median(r["wall"] for r in rs)
            spread = f"{min(r['wall'] for r in rs):.1f}-{max(r['wall'] for r in rs):.1f}"
            cpu = statistics.median(r["cpu"] for r in rs)
            same = all(agree(r["out"], runs[reference][0]["out"], plans, rows) for r in rs)
            print(f"  {label[v]:<36}{wall:>9.1f}{spread:>14}{cpu:>8.1f}"
                  f"{max(r['rss'] for r in rs):>10.0f}{max(r['rss_second'] for r in rs):>9.0f}"
                  f"{ref_wall / wall:>8.2f}x  {'yes' if same else 'NO'}")
    if n * m >= 1500 * 1000 and args.every == 1:  # the target: the paper's largest matrices
        print("  target: <= 60 s on 2 cores at 1500 x 1000: " + (
            "met" if statistics.median(r["wall"] for r in runs["two"]) <= 60 else "not met"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
