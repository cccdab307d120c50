"""EIPS's leave-one-out time on the main job's store, this checkout against another revision.

    python benchmarks/bench_eips.py [--store PATH] [--repeats 3] [--baseline-rev 605e735]

The matrix is the store's (by default the main job's grasp_arm store,
/tmp/mj5/data/grasp_arm-rrt_connect-seed0.zarr, read as stage evaluate reads it: its scores,
feasibility, times and own-constraint mask), or, where that store is absent, the synthetic
``box_core.synthetic.score_matrix(1000, 162, seed=0)``.  Each measurement is one call of
``loocv(..., selectors="eips")`` with stage evaluate's defaults (k = m, overhead measured) in
a fresh interpreter on one thread; this checkout's box_core and the box_core of git revision
``--baseline-rev`` (exported with ``git archive``, as bench_loocv_paper.py does) alternate,
``--repeats`` times each.  Printed: the median seconds of each, their ratio, and whether
the two give the same orders, first feasible steps and planning times, bit for bit.
Asserts nothing (machines are noisy).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
from bench_loocv_paper import baseline_package  # noqa: E402
from child_runs import run_child  # noqa: E402

STORE = Path("/tmp/mj5/data/grasp_arm-rrt_connect-seed0.zarr")
#: the last revision before EIPS's faster leave-one-out
BASELINE_REV = "605e735"
COMPARED = ("order", "first_feasible_step", "first_feasible_planning_time")


def matrix(store: Path, into: Path) -> str:
    """The evaluated matrix saved to ``into`` (an .npz the children read); its label."""
    if store.exists():
        from pipeline.evaluation import own_constraints
        from pipeline.store import ScoreStore

        found = ScoreStore(store, read_only=True)
        scores, feasible, times, _ = found.score_matrix()
        hide = own_constraints(found)
        label = f"{store.name}"
    else:
        from box_core.synthetic import score_matrix

        data = score_matrix(1000, 162, seed=0)
        scores, feasible, times, hide = data.scores, data.feasible, data.times, None
        label = f"synthetic score_matrix(1000, 162, seed=0) ({store} is absent)"
    hide = np.zeros(scores.shape, dtype=bool) if hide is None else hide
    np.savez(into, scores=scores, feasible=feasible, times=times, hide=hide)
    n, m = scores.shape
    return f"{label}: {n} x {m}, {feasible.mean():.1%} feasible, {int(hide.sum())} hidden"


def child(job: dict) -> None:
    """One timed leave-one-out of EIPS in this interpreter; its traces to ``job['out']``."""
    if job.get("path"):
        sys.path.insert(0, job["path"])
    module = __import__(job["package"])
    data = np.load(job["data"])
    hide = data["hide"] if data["hide"].any() else None
    start = time.perf_counter()
    result = module.loocv(data["scores"], times=data["times"], feasible=data["feasible"],
                          selectors="eips", forbidden=hide, seed=0)
    seconds = time.perf_counter() - start
    np.savez(job["out"], **{key: getattr(result, key)["eips"] for key in COMPARED})
    print(json.dumps({"seconds": seconds}))


def same(a: Path, b: Path) -> bool:
    x, y = np.load(a), np.load(b)
    return all(np.array_equal(x[k], y[k], equal_nan=k.endswith("time")) for k in COMPARED)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--store", type=Path, default=STORE)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--baseline-rev", default=BASELINE_REV)
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(json.loads(args.child))
        return
    if args.repeats < 1:
        parser.exit(2, f"--repeats must be at least 1, got {args.repeats}\n")
    with tempfile.TemporaryDirectory(prefix="bench_eips_") as tmp:
        tmp = Path(tmp)
        print(f"EIPS leave-one-out (k = m, overhead measured), one thread: "
              f"{matrix(args.store, tmp / 'data.npz')}")
        variants = {"new": {"package": "box_core"}}
        base = baseline_package(args.baseline_rev, tmp)
        if base is not None:
            variants["base"] = {"package": "box_core_baseline", "path": base}
        seconds = {v: [] for v in variants}
        for _ in range(args.repeats):
            for v, job in reversed(variants.items()):
                out = run_child(__file__, dict(job, data=str(tmp / "data.npz"),
                                               out=str(tmp / f"{v}.npz")), ROOT, v)
                seconds[v].append(out["seconds"])
        med = {v: statistics.median(s) for v, s in seconds.items()}
        print(f"  this checkout:         {med['new']:6.2f} s  (median of {args.repeats}: "
              + ", ".join(f"{s:.2f}" for s in seconds["new"]) + ")")
        if base is None:
            return
        print(f"  baseline {args.baseline_rev:<12}  {med['base']:6.2f} s  (median of "
              f"{args.repeats}: " + ", ".join(f"{s:.2f}" for s in seconds["base"]) + ")")
        print(f"  ratio:                 {med['base'] / med['new']:6.2f} x")
        print("  orders, first feasible steps and planning times identical: "
              + ("yes" if same(tmp / "new.npz", tmp / "base.npz") else "NO"))


if __name__ == "__main__":
    main()
