"""TrajOpt at scale (issue 27, item 3): ms per score-matrix entry of ``planner=trajopt`` in
grasp_arm and grasp_base on one core, against RRT-Connect's on the same entries and against
TrajOpt's code of another revision, side by side.

Entries.  grasp_arm: ``--arm-instances`` instances × the 162 grasps; grasp_base: Θ̂ is
RAWPLANNER's constraints on ``--raw`` instances (at most ``--base-constraints`` of them, as
stage=constraints extracts them), planned on ``--base-instances`` other instances.  Each
variant plans them as a worker plans a block (the instance set up once, then its
constraints; the planning seeds of ``pipeline.worker.entry_seed``).

Variants, each in its own process with one thread (OMP/OpenBLAS/MKL/numba limited to 1),
warmed up on other instances first, the planner's wall-clock safety net out of reach (a
"timeout" would be the machine's speed, not a disagreement); ``--repeats`` runs each, their
order rotating so that the machine's drift hits all alike:

* ``rrt``: this checkout, ``planner=rrt_connect`` (its default ``collision=spheres``);
* ``new``: this checkout, ``planner=trajopt`` (default ``collision=spheres``: bodies out
  of reach left out of the distance queries, the dense re-check through the sphere
  pre-check);
* ``exact``: this checkout, ``planner=trajopt planner.collision=exact`` (pybullet asked
  about every body and every re-checked configuration);
* ``base``: this checkout with TrajOpt's module (``pipeline/planning/trajopt.py``) as it
  was at git revision ``--baseline-rev`` (the change measured alone, whatever else the
  checkout holds); ``--baseline-rev ''`` skips it.

Printed per domain: mean wall and CPU ms per entry over all entries (median of the
repeats), median ms per feasible call (IK + planner, each variant's own feasible calls),
TrajOpt's ratio to RRT-Connect (target <= 3), and how many entries of ``new`` agree with
``exact`` and ``base`` bit for bit: status, feasibility, failed step, checks, path length,
score and the path's bytes; and, entry by entry, which outcome under RRT-Connect met which
under TrajOpt, with each pair's mean cost and share of TrajOpt's time.

Run: python benchmarks/bench_trajopt.py [--arm-instances 6] [--raw 40] [--base-instances 20]
         [--base-constraints 30] [--repeats 3] [--baseline-rev 4e14f96] [--only grasp_arm]
         [--profile]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
from child_runs import agreement, run_child

ROOT = Path(__file__).resolve().parents[1]
#: issue 27, item 3: TrajOpt within 3x of RRT-Connect per entry
TARGET_RATIO = 3.0
#: the revision before TrajOpt's speed-up
BASELINE_REV = "4e14f96"
MODULE = "pipeline/planning/trajopt.py"
COLUMNS = ("status", "feasible", "step", "checks", "length", "score", "path")
WALL_CAP_S = 1e6
RUN_SEED = 1
DOMAINS = ("grasp_arm", "grasp_base")
#: variant -> (planner, collision)
VARIANTS = {"rrt": ("rrt_connect", "spheres"), "new": ("trajopt", "spheres"),
            "exact": ("trajopt", "exact"), "base": ("trajopt", "spheres")}


# -- the child: one variant, one process -------------------------------------------------

def child(job: dict) -> None:
    """Plan the entries of ``job['data']`` under one variant; print the timing as JSON and
    save the per-entry results to ``job['out']``."""
    from pipeline.domains.cache import domain_for
    from pipeline.worker import entry_seed

    data = np.load(job["data"])
    domain = domain_for({"name": job["domain"], "config": {},
                         "planner": {"name": job["planner"], "collision": job["collision"],
                                     "wall_cap_s": WALL_CAP_S}})
    theta = data["theta"]

    def plan_all(specs, seeds, rows):
        out = []
        for spec, s in zip(specs, seeds, strict=True):
            inst = domain.check_instance(json.loads(str(spec)))
            for j, row in enumerate(rows):
                out.append(domain.plan(inst, row, seed=entry_seed(RUN_SEED, int(s), j)))
        return out

    plan_all(data["warm_specs"], data["warm_seeds"], theta[::4])
    prof = None
    if job.get("profile"):
        import cProfile

        prof = cProfile.Profile()
        prof.enable()
    w0, c0 = time.perf_counter(), time.process_time()
    results = plan_all(data["specs"], data["seeds"], theta)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    if prof is not None:
        import pstats

        prof.disable()
        pstats.Stats(prof, stream=sys.stderr).sort_stats("tottime").print_stats(25)
    path = [hashlib.sha256(r.path.tobytes()).hexdigest() if r.path is not None else ""
            for r in results]
    np.savez(job["out"], status=np.array([int(r.status) for r in results]),
             feasible=np.array([r.feasible for r in results]),
             step=np.array([r.step or "" for r in results]),
             checks=np.array([r.checks for r in results]),
             length=np.array([r.length if r.feasible else np.nan for r in results]),
             score=np.array([r.score for r in results], dtype=float),
             path=np.array(path), time=np.array([r.time for r in results]))
    ok = [r.time for r in results if r.feasible]
    n = len(results)
    print(json.dumps({"wall_ms": wall / n * 1e3, "cpu_ms": cpu / n * 1e3, "n": n,
                      "feasible_ms": float(np.median(ok)) * 1e3 if ok else float("nan"),
                      "feasible": len(ok),
                      "status": Counter(r.status.name.lower() for r in results)}))


# -- the parent ---------------------------------------------------------------------------

def entries(name: str, args) -> dict:
    """The entries of ``name`` (module docstring) and the warm-up's instances."""
    from pipeline.domains import load_domain

    domain = load_domain(name)
    first = args.seed + 100_000
    if name == "grasp_arm":
        theta = domain.constraints().features
        count = args.arm_instances
    else:
        rows, t0 = [], time.perf_counter()
        for k in range(args.raw):
            found = domain.raw_plan(domain.sample_instance(args.seed + k),
                                    seed=args.seed + 50_000 + k)
            if found.plan.feasible:
                rows.append(found.constraint)
            if len(rows) == args.base_constraints:
                break
        print(f"grasp_base Θ̂: {len(rows)} constraints from RAWPLANNER on {k + 1} instances "
              f"({time.perf_counter() - t0:.0f} s)")
        theta, count = np.array(rows), args.base_instances
    block = [domain.sample_instance(first + i) for i in range(count)]
    warm = [domain.sample_instance(first - 1 - i) for i in range(2)]
    domain.close()
    return {"theta": np.asarray(theta, float),
            "specs": np.array([json.dumps(s) for s in block]),
            "seeds": np.arange(first, first + count),
            "warm_specs": np.array([json.dumps(s) for s in warm]),
            "warm_seeds": np.arange(first - 2, first)}


def baseline(rev: str, into: Path) -> Path | None:
    """This checkout's ``pipeline`` and ``conf`` under ``into``, TrajOpt's module as it was
    at git revision ``rev``."""
    try:
        old = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:{MODULE}"],
                             capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError) as exc:
        print(f"(no baseline: git show {rev}:{MODULE} failed: {exc})")
        return None
    for part in ("pipeline", "conf"):
        shutil.copytree(ROOT / part, into / part,
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    (into / MODULE).write_bytes(old)
    return into


def run(variant: str, name: str, root: Path, data: Path, out: Path, profile: bool) -> dict:
    planner, collision = VARIANTS[variant]
    job = {"domain": name, "planner": planner, "collision": collision, "data": str(data),
           "out": str(out), "profile": profile}
    return run_child(__file__, job, root, f"{name} {variant}", profile)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--arm-instances", type=int, default=6)
    ap.add_argument("--raw", type=int, default=40, help="RAWPLANNER instances for Θ̂ (most)")
    ap.add_argument("--base-instances", type=int, default=20)
    ap.add_argument("--base-constraints", type=int, default=30)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=2017)
    ap.add_argument("--baseline-rev", default=BASELINE_REV)
    ap.add_argument("--only", choices=DOMAINS)
    ap.add_argument("--profile", action="store_true", help="cProfile new's last repeat")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(json.loads(args.child))
        return
    with tempfile.TemporaryDirectory(prefix="bench_trajopt_") as tmp:
        tmp = Path(tmp)
        roots = {"rrt": ROOT, "new": ROOT, "exact": ROOT}
        if args.baseline_rev:
            (tmp / "base").mkdir()
            base = baseline(args.baseline_rev, tmp / "base")
            if base is not None:
                roots["base"] = base
        for name in (args.only,) if args.only else DOMAINS:
            data = tmp / f"{name}.npz"
            np.savez(data, **entries(name, args))
            times = {v: [] for v in roots}
            names = list(roots)
            for r in range(args.repeats):
                for v in names[r % len(names):] + names[: r % len(names)]:
                    last = args.profile and r == args.repeats - 1 and v == "new"
                    times[v].append(run(v, name, roots[v], data, tmp / f"{name}.{v}.npz",
                                        last))
            report(name, args, times, tmp)


def report(name: str, args, times: dict, tmp: Path) -> None:
    n = times["new"][0]["n"]
    med = {v: {k: statistics.median(t[k] for t in ts)
               for k in ("wall_ms", "cpu_ms", "feasible_ms")} for v, ts in times.items()}
    print(f"\n{name}: {n} entries per run, one core, median of {args.repeats} runs per "
          "variant")
    print(f"  {'variant':<44}{'wall ms/entry':>14}{'cpu ms/entry':>13}"
          f"{'ms/feasible':>12}{'feasible':>10}{'cpu / rrt':>11}")
    label = {"rrt": "rrt_connect (collision=spheres)",
             "new": "trajopt (collision=spheres, default)",
             "exact": "trajopt, collision=exact",
             "base": f"trajopt at {args.baseline_rev}"}
    for v in times:
        ratio = med[v]["cpu_ms"] / med["rrt"]["cpu_ms"]
        print(f"  {label[v]:<44}{med[v]['wall_ms']:>14.2f}{med[v]['cpu_ms']:>13.2f}"
              f"{med[v]['feasible_ms']:>12.2f}{times[v][-1]['feasible']:>10}{ratio:>10.2f}x")
    ratio = med["new"]["cpu_ms"] / med["rrt"]["cpu_ms"]
    print(f"  target: {name}, trajopt <= {TARGET_RATIO:g}x rrt_connect per entry: "
          + ("met" if ratio <= TARGET_RATIO else "not met") + f" ({ratio:.2f}x cpu, "
          f"{med['new']['wall_ms'] / med['rrt']['wall_ms']:.2f}x wall)")
    if "base" in times:
        print(f"  trajopt speed-up over {args.baseline_rev}: "
              f"{med['base']['cpu_ms'] / med['new']['cpu_ms']:.2f}x cpu")
    for other in [v for v in times if v not in ("new", "rrt")]:
        agree = agreement(tmp / f"{name}.new.npz", tmp / f"{name}.{other}.npz", COLUMNS)
        print(f"  trajopt new vs {other}: {agree.mean():.2%} of entries identical "
              f"({agree.sum()} of {agree.size}: {', '.join(COLUMNS)})")
    for v in ("rrt", "new"):
        status = times[v][-1]["status"]
        print(f"  outcomes {v}: " + ", ".join(f"{k} {c / n:.1%}" for k, c in sorted(
            status.items(), key=lambda kv: -kv[1])))
    outcome_pairs(tmp / f"{name}.rrt.npz", tmp / f"{name}.new.npz")


def outcome_pairs(rrt: Path, new: Path) -> None:
    """Where TrajOpt's time goes against RRT-Connect's, entry by entry (each planning call's
    own measured time, the last run of each): per pair of outcomes, the entries, the mean ms
    of each planner and TrajOpt's share of its total."""
    from pipeline.planning import Status

    a, b = np.load(rrt), np.load(new)
    total = b["time"].sum()
    rows = []
    for (x, y), count in Counter(zip(a["status"].tolist(), b["status"].tolist(),
                                     strict=True)).items():
        here = (a["status"] == x) & (b["status"] == y)
        rows.append((b["time"][here].sum(), x, y, count, here))
    print("  outcome pairs (rrt -> trajopt): entries, mean ms rrt / trajopt, trajopt's share")
    for spent, x, y, count, here in sorted(rows, key=lambda row: -row[0]):
        print(f"    {Status(x).name.lower():>18} -> {Status(y).name.lower():<18}{count:6d}"
              f"{a['time'][here].mean() * 1e3:9.2f} /{b['time'][here].mean() * 1e3:8.2f}"
              f"{spent / total:8.1%}")

if __name__ == "__main__":
    main()
