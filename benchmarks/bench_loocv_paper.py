"""Leave-one-out at paper scale: 1500 x 1000 (pick_place's shape), k = m, default selectors.

    python benchmarks/bench_loocv_paper.py [--repeats 1] [--baseline-rows 12]
                                           [--baseline-rev 6c488f3] [--no-baseline]

The selectors are stage evaluate's defaults (``evaluate.selectors`` without rawplanner,
which stage raw measures).  Two synthetic matrices from ``box_core.synthetic``:

  A  ``score_matrix(1500, 1000, seed=0)``: 50 columns ever feasible (95 % never are);
  B  the 1000 x 1000 parameters of bench_loocv.py at 1500 rows (types=40, useful=200,
     per_type=5): 200 columns ever feasible.

For each: the wall time of box_core.loocv (the fast path) with all selectors in one call
and with each alone, and the peak memory of the process that ran it (a fresh interpreter
per measurement: its max RSS, and its RSS before the evaluation started).  Then the call
as stage evaluate makes it on two cores (``workers=2``, ``until_best=True``: a held-out row
stops once nothing the summary and curves read can change), its peak memory (both
processes) and whether its first feasible steps and planning times are the one-process
full run's (``--repeats`` of it too; issue 27's 60 s is for 2 cores).  Beside it, the
code before the fast path (``--baseline-rev``, taken from git into a temporary folder and
run in the same way): in full for the selectors it can afford (static, rand, oracle,
fastest, doo), and for box, eips and pembo on ``--baseline-rows`` evenly spaced rows, each
with its exact leave-one-out prior, their time scaled to all rows (each of those rows runs
alone in a batch of one there, so its cost does not depend on the others).  The orders,
first feasible steps and planning times of those rows are compared with the fast path's.

Then both on a 300 x 200 matrix in full, every output compared (overhead left out, so the
times and curves are deterministic): the ratio there is measured, not extrapolated.

Timed runs measure the selectors' overhead, as stage evaluate does.  Prints medians over
``--repeats``; asserts nothing (machines are noisy).
"""

from __future__ import annotations

import argparse
import json
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from box_core.synthetic import score_matrix  # noqa: E402
from pipeline.configs import RAWPLANNER, EvaluateConfig  # noqa: E402

SELECTORS = tuple(s for s in EvaluateConfig().selectors if s != RAWPLANNER)
AFFORDABLE = ("static", "rand", "oracle", "fastest", "doo")  # by the baseline, in full
MATRICES = {
    "A": dict(n=1500, m=1000, seed=0),
    "B": dict(n=1500, m=1000, seed=1, types=40, useful=200, per_type=5),
    "A small": dict(n=300, m=200, seed=0),
    "B small": dict(n=300, m=200, seed=1, types=8, useful=40, per_type=5),
}


def matrix(name):
    spec = dict(MATRICES[name])
    return score_matrix(spec.pop("n"), spec.pop("m"), **spec)


def rss_mib() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")  # pragma: no cover


# -- what a child interpreter runs ------------------------------------------------------


def child(job: dict) -> dict:
    """One measurement in this (fresh) interpreter; ``job`` says which."""
    if job["code"] == "baseline":
        sys.path.insert(0, job["path"])
    module = __import__(job["package"])
    data = matrix(job["matrix"])
    kw = dict(times=data.times, feasible=data.feasible, features=data.features, seed=0,
              measure_overhead=job.get("measure", True), **job.get("options", {}))
    before = rss_mib()
    out = {"rss_before": before, "runs": {}}
    for names in job["runs"]:
        start = time.perf_counter()
        if job.get("rows") is None:
            result = module.loocv(data.scores, selectors=tuple(names), **kw)
        else:
            result = rows_only(module, data, tuple(names), np.asarray(job["rows"]), kw)
        out["runs"][",".join(names)] = time.perf_counter() - start
        # the evaluation's peak, before the comparison's copies of its results
        out["max_rss"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        out["max_rss_children"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        if job.get("keep"):
            out.setdefault("results", {}).update(summarise(result))
    return out


def rows_only(module, data, names, rows, kw):
    """Leave-one-out of ``rows`` only (each with the prior of all other rows), through
    the internals both versions share."""
    loocv = sys.modules[f"{module.__name__}.loocv"]
    setup = loocv._Setup.check(data.scores, data.times, data.feasible, names, None,
                               data.features, None, "magnitude", min_rows=3)
    prior = module.Prior.fit(setup.Dn)
    outcomes = lambda held: loocv.TrainingOutcomes.of(  # noqa: E731
        setup.Dn, setup.feas, setup.T, held)
    return setup.evaluate(prior.folds, outcomes, rows, kw["seed"], None, kw["measure_overhead"])


def summarise(result) -> dict:
    out = {}
    for name in result.selectors:
        out[name] = {
            "order": result.order[name].tolist(),
            "step": result.first_feasible_step[name].tolist(),
            "planning": np.nan_to_num(result.first_feasible_planning_time[name],
                                      nan=-1.0).tolist(),
            "time": np.nan_to_num(result.first_feasible_time[name], nan=-1.0).tolist(),
            "curve": result.best_score[name].tolist(),
            "grid": result.time_grid.tolist(),
        }
    return out


# -- the parent -------------------------------------------------------------------------


def run_child(job: dict) -> dict:
    out = subprocess.run([sys.executable, __file__, "--child", json.dumps(job)],
                         capture_output=True, text=True)
    if out.returncode:
        raise RuntimeError(out.stderr[-3000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def baseline_package(rev: str, into: Path) -> str | None:
    """box_core at git revision ``rev`` as the package ``box_core_baseline`` in ``into``."""
    try:
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "box_core"],
                                 capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError) as exc:
        print(f"   (no baseline: git archive {rev} failed: {exc})")
        return None
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    pkg = into / "box_core_baseline"
    shutil.move(str(into / "box_core"), pkg)
    for path in pkg.glob("*.py"):
        path.write_text(re.sub(r"\bbox_core\b", "box_core_baseline", path.read_text()))
    return str(into)


def timed(job: dict, repeats: int) -> tuple[dict, dict]:
    """Median seconds per run over ``repeats`` children, and the last child's output."""
    outs = [run_child(job) for _ in range(repeats)]
    med = {key: statistics.median(o["runs"][key] for o in outs) for key in outs[0]["runs"]}
    return med, outs[-1]


def paper_scale(name: str, args, base_path: str | None) -> None:
    data = matrix(name)
    n, m = data.scores.shape
    print(f"== {name}: LOOCV {n} x {m}, k = m, {', '.join(SELECTORS)}")
    print(f"   matrix: {MATRICES[name]}: {data.feasible.mean():.1%} feasible entries, "
          f"{int(data.feasible.any(axis=0).sum())} columns ever feasible")
    job = dict(code="fast", package="box_core", matrix=name, runs=[list(SELECTORS)])
    med, out = timed(dict(job, keep=True), args.repeats)
    full = out["results"]
    total = med[",".join(SELECTORS)]
    print(f"   fast path:  {total:7.1f} s  all selectors in one call (median of "
          f"{args.repeats}); peak RSS {out['max_rss']:.0f} MiB "
          f"({out['rss_before'] :.0f} MiB before the evaluation)")
    alone, out = timed(dict(job, runs=[[s] for s in SELECTORS]), 1)
    print("               alone: " + ", ".join(f"{s} {alone[s]:.1f} s" for s in SELECTORS)
          + f" (sum {sum(alone.values()):.1f} s)")
    as_run(job, args.repeats, full)
    if base_path is None:
        return
    rows = np.linspace(0, n - 1, args.baseline_rows).astype(int)
    costly = [s for s in SELECTORS if s not in AFFORDABLE]
    cheap = [s for s in SELECTORS if s in AFFORDABLE]
    part = run_child(dict(code="baseline", package="box_core_baseline", path=base_path,
                          matrix=name, runs=[[s] for s in costly], rows=rows.tolist(),
                          keep=True))
    full = run_child(dict(code="baseline", package="box_core_baseline", path=base_path,
                          matrix=name, runs=[[s] for s in cheap]))
    est = {s: part["runs"][s] * n / rows.size for s in costly}
    est.update({s: full["runs"][s] for s in cheap})
    base_total = sum(est.values())
    print(f"   baseline ({args.baseline_rev}): {base_total:7.0f} s  ("
          + ", ".join(f"{s} {est[s]:.0f} s" for s in SELECTORS) + ")")
    print(f"               {', '.join(costly)}: {rows.size} of {n} rows timed, scaled to "
          f"{n}; {', '.join(cheap)}: all rows; peak RSS of the partial run "
          f"{part['max_rss']:.0f} MiB")
    print(f"   speed-up:   {base_total / total:7.1f} x  (baseline sum of selectors alone / "
          f"fast path with all in one call; target <= 60 s)")
    fast = run_child(dict(code="fast", package="box_core", matrix=name,
                          runs=[list(costly)], rows=rows.tolist(), keep=True))
    same = all(fast["results"][s][key] == part["results"][s][key]
               for s in costly for key in ("order", "step", "planning"))
    print(f"   orders, first feasible steps and planning times of {', '.join(costly)} on "
          f"those rows identical to the baseline's: {'yes' if same else 'NO'}")


def as_run(job: dict, repeats: int, full: dict) -> None:
    """The call as stage evaluate makes it on two cores, against the one-process full run's
    (``full``) first feasible steps and planning times (the values ``until_best`` keeps)."""
    med, out = timed(dict(job, options={"workers": 2, "until_best": True}, keep=True),
                     repeats)
    same = all(out["results"][s][key] == full[s][key] for s in SELECTORS
               for key in ("step", "planning"))
    print(f"   as stage evaluate runs it (workers=2, until_best): "
          f"{med[','.join(SELECTORS)]:7.1f} s (median of {repeats}); peak RSS "
          f"{out['max_rss']:.0f} + {out['max_rss_children']:.0f} MiB (second process); "
          f"first feasible steps and planning times as the full run's: "
          f"{'yes' if same else 'NO'}; target <= 60 s: "
          + ("met" if med[",".join(SELECTORS)] <= 60 else "not met"))


def small_scale(name: str, args, base_path: str) -> None:
    data = matrix(name)
    n, m = data.scores.shape
    print(f"== {name}: LOOCV {n} x {m}, k = m, both in full, overhead left out")
    jobs = {
        "fast": dict(code="fast", package="box_core", matrix=name, runs=[list(SELECTORS)],
                     measure=False, keep=True),
        "baseline": dict(code="baseline", package="box_core_baseline", path=base_path,
                         matrix=name, runs=[list(SELECTORS)], measure=False, keep=True),
    }
    med, outs = {}, {}
    for label, job in jobs.items():
        times, outs[label] = timed(job, args.repeats)
        med[label] = times[",".join(SELECTORS)]
    same = outs["fast"]["results"] == outs["baseline"]["results"]
    print(f"   fast path {med['fast']:.2f} s, baseline {med['baseline']:.2f} s (medians of "
          f"{args.repeats}): {med['baseline'] / med['fast']:.1f} x")
    print("   orders, first feasible steps and times, best-score curves and time grid of "
          f"every selector identical: {'yes' if same else 'NO'}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--baseline-rows", type=int, default=12)
    parser.add_argument("--baseline-rev", default="6c488f3",
                        help="git revision of the code before the fast path")
    parser.add_argument("--no-baseline", action="store_true")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(json.loads(args.child))))
        return
    with tempfile.TemporaryDirectory() as tmp:
        base = None if args.no_baseline else baseline_package(args.baseline_rev, Path(tmp))
        for name in ("A", "B"):
            paper_scale(name, args, base)
        if base is not None:
            for name in ("A small", "B small"):
                small_scale(name, args, base)


if __name__ == "__main__":
    main()
