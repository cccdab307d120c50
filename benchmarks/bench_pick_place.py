"""pick_place: ms per score-matrix entry on one core, the default checker against
``planner.collision=exact`` and against the code of another revision, side by side.

The entries are those of a paper-scale pick_place store (paper step order, as
stage=generate computes them): Θ̂ is RAWPLANNER's solutions on ``--raw`` instances (as
stage=constraints extracts it), and one block of ``--instances`` × ``--constraints`` entries
(other instances) is planned the way a worker plans a block
(:func:`pipeline.worker.score_block`: the instance set up once, then its constraints).  The
issue's target (issue 27, item 1): <= 4 ms per entry at 300 × 300, one core, answers and
check counts equal to ``exact``'s.  An instance's constraints share what depends on the
instance and the grasp only (the carry configuration, the base planner's model, the pick
IK), so a block with 300 constraints per instance (``--raw 400 --instances 3
--constraints 300``) costs less per entry than the default 40.

Every variant runs in its own process (one thread: OMP/OpenBLAS/MKL limited to 1), warmed
up on other instances first (numba's compiled kernels load, caches fill), then the block is
timed: ``--repeats`` times, the variants' order rotating from repeat to repeat so that the
machine's drift hits all alike.  The planner's wall-clock safety net is set out of reach
(``exact`` takes seconds on a few entries; its "timeout" would be no disagreement).
Printed: median wall and CPU ms per entry of each variant, their ratios, and how many
entries agree between the variants: status, feasibility, failed step, collision checks,
path length and score, bit for bit.

Variants: ``new`` (this checkout, the default ``planner.collision=spheres``), ``exact``
(this checkout, ``planner.collision=exact``) and ``base`` (the default setting at git
revision ``--baseline-rev``, exported with ``git archive``; ``--baseline-rev ''`` skips it).
``new`` and ``exact`` run with ``domain.contacts=--contacts`` (``fresh``, the default since
2026-11-27: every cached penetration confirmed afresh, docs/contacts.md; ``cached``: the
points as pybullet keeps them, the default before); ``base`` keeps its revision's default.

Run: python benchmarks/bench_pick_place.py [--raw 40] [--instances 8] [--constraints 40]
         [--repeats 3] [--baseline-rev 641b270] [--contacts cached|fresh] [--profile]
         [--entries FILE.npz]  (Θ̂ and the instances kept for the next run)
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from child_runs import agreement, export_revision, run_child

ROOT = Path(__file__).resolve().parents[1]
TARGET_MS = 4.0
#: the revision before issue 27's item 1 (the sphere pre-check of issue 26, 18 ms/entry)
BASELINE_REV = "641b270"
COLUMNS = ("status", "feasible", "step", "checks", "length", "score")
#: the wall-clock safety net out of reach: ``exact`` spends seconds on some entries, and a
#: "timeout" there would be the machine's speed, not a disagreement
WALL_CAP_S = 1e6


# -- the child: one variant, one process -------------------------------------------------

def child(job: dict) -> None:
    """Plan the block of ``job['data']`` under one variant; print its timing as JSON and
    save its result arrays to ``job['out']``."""
    from pipeline import worker

    data = np.load(job["data"])
    config = {"step_order": "paper"}
    if job.get("contacts"):  # only when asked: a baseline revision may not know the key
        config["contacts"] = job["contacts"]
    spec = {"name": "pick_place", "config": config,
            "planner": {"name": "rrt_connect", "collision": job["collision"],
                        "wall_cap_s": WALL_CAP_S}}
    theta, specs, seeds = data["theta"], [str(s) for s in data["specs"]], data["seeds"]
    warm = [str(s) for s in data["warm_specs"]]
    worker.score_block(spec, 1, warm, [int(s) for s in data["warm_seeds"]],
                       theta[: min(len(theta), 12)], 0)
    prof = None
    if job.get("profile"):
        import cProfile

        prof = cProfile.Profile()
        prof.enable()
    w0, c0 = time.perf_counter(), time.process_time()
    arrays, report = worker.score_block(spec, 0, specs, [int(s) for s in seeds], theta, 0)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    if prof is not None:
        import pstats

        prof.disable()
        pstats.Stats(prof, stream=sys.stderr).sort_stats("tottime").print_stats(25)
    np.savez(job["out"], **{k: arrays[k] for k in COLUMNS})
    n = arrays["status"].size
    print(json.dumps({"wall_ms": wall / n * 1e3, "cpu_ms": cpu / n * 1e3, "n": n,
                      "status": report["status"]}))


# -- the parent ---------------------------------------------------------------------------

def entries(raw: int, instances: int, constraints: int, seed: int) -> dict:
    """Θ̂ from RAWPLANNER on ``raw`` instances, and the block's and the warm-up's instances."""
    from pipeline.domains import load_domain

    domain = load_domain("pick_place", planner={"name": "rrt_connect"}, step_order="paper")
    rows = []
    t0 = time.perf_counter()
    for k in range(raw):
        spec = domain.sample_instance(seed + k)
        found = domain.raw_plan(spec, seed=seed + 50_000 + k)
        if found.plan.feasible:
            rows.append(found.constraint)
        if len(rows) == constraints:
            break
    print(f"Θ̂: {len(rows)} constraints from RAWPLANNER on {k + 1} instances "
          f"({time.perf_counter() - t0:.0f} s)")
    first = seed + 100_000
    block = [domain.sample_instance(first + i) for i in range(instances)]
    warm = [domain.sample_instance(first - 1 - i) for i in range(2)]
    domain.close()
    return {"theta": np.array(rows), "specs": np.array([json.dumps(s) for s in block]),
            "seeds": np.arange(first, first + instances),
            "warm_specs": np.array([json.dumps(s) for s in warm]),
            "warm_seeds": np.arange(first - 2, first)}


#: what an --entries file holds (:func:`entries`)
ENTRY_KEYS = {"theta", "specs", "seeds", "warm_specs", "warm_seeds"}


def entries_problem(path: Path) -> str:
    """Why ``path`` cannot be read or written as an --entries file ("" when it can)."""
    if not path.exists():
        return "" if path.parent.is_dir() else f"no folder {path.parent} to write it in"
    try:
        with np.load(path) as saved:
            missing = ENTRY_KEYS - set(saved.files)
    except (OSError, ValueError) as exc:
        return f"not an .npz this benchmark wrote ({exc})"
    return f"not an .npz this benchmark wrote (no {', '.join(sorted(missing))})" if missing else ""


def run(variant: str, root: Path, collision: str, data: Path, out: Path,
        profile: bool, contacts: str | None = None) -> dict:
    job = {"data": str(data), "out": str(out), "collision": collision, "profile": profile,
           "contacts": contacts}
    return run_child(__file__, job, root, variant, profile)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--raw", type=int, default=60, help="RAWPLANNER instances for Θ̂ (most)")
    ap.add_argument("--instances", type=int, default=8)
    ap.add_argument("--constraints", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=2017)
    ap.add_argument("--baseline-rev", default=BASELINE_REV)
    ap.add_argument("--contacts", choices=("cached", "fresh"), default="fresh",
                    help="domain.contacts of the new and exact variants")
    ap.add_argument("--profile", action="store_true", help="cProfile the last repeat")
    ap.add_argument("--entries", type=Path, help="an .npz of Θ̂ and the instances: read "
                    "when it exists (--raw, --instances, --constraints, --seed ignored), "
                    "else written after computing them")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(json.loads(args.child))
        return
    if args.entries is not None:
        problem = entries_problem(args.entries)
        if problem:
            print(f"bench_pick_place: --entries {args.entries}: {problem}", file=sys.stderr)
            sys.exit(2)
    with tempfile.TemporaryDirectory(prefix="bench_pick_place_") as tmp:
        tmp = Path(tmp)
        data = tmp / "entries.npz"
        if args.entries is not None and args.entries.is_file():
            shutil.copyfile(args.entries, data)
            print(f"Θ̂ and the instances from {args.entries}")
        else:
            np.savez(data, **entries(args.raw, args.instances, args.constraints, args.seed))
            if args.entries is not None:
                shutil.copyfile(data, args.entries)
        variants = {"new": (ROOT, "spheres"), "exact": (ROOT, "exact")}
        if args.baseline_rev:
            (tmp / "base").mkdir()
            base = export_revision(args.baseline_rev, tmp / "base")
            if base is not None:
                variants["base"] = (base, "spheres")
        times = {v: [] for v in variants}
        names = list(variants)
        for r in range(args.repeats):
            for v in names[r % len(names):] + names[: r % len(names)]:
                root, collision = variants[v]
                last = args.profile and r == args.repeats - 1 and v == "new"
                contacts = None if v == "base" else args.contacts
                times[v].append(run(v, root, collision, data, tmp / f"{v}.npz", last,
                                    contacts))
        report(args, times, tmp, variants)
        shutil.rmtree(tmp / "base", ignore_errors=True)


def report(args, times: dict, tmp: Path, variants: dict) -> None:
    n = times["new"][0]["n"]
    instances = len(np.load(tmp / "entries.npz")["specs"])
    med = {v: {k: statistics.median(t[k] for t in ts) for k in ("wall_ms", "cpu_ms")}
           for v, ts in times.items()}
    print(f"pick_place, paper step order: {instances} instances × "
          f"{n // instances} constraints = {n} entries per run, one core, median of "
          f"{args.repeats} runs per variant")
    print(f"  {'variant':<50}{'wall ms/entry':>15}{'cpu ms/entry':>14}{'/ new':>9}")
    contacts = f", contacts={args.contacts}"
    label = {"new": f"new (planner.collision=spheres{contacts})",
             "exact": f"new, planner.collision=exact{contacts}",
             "base": f"baseline {args.baseline_rev} (spheres)"}
    for v in variants:
        ratio = med[v]["cpu_ms"] / med["new"]["cpu_ms"]
        print(f"  {label[v]:<50}{med[v]['wall_ms']:>15.2f}{med[v]['cpu_ms']:>14.2f}"
              f"{ratio:>8.2f}x")
    print(f"  target: pick_place <= {TARGET_MS:g} ms per entry: "
          + ("met" if med["new"]["cpu_ms"] <= TARGET_MS else "not met")
          + f" ({med['new']['cpu_ms']:.2f} ms cpu, {med['new']['wall_ms']:.2f} ms wall)")
    for other in [v for v in variants if v != "new"]:
        agree = agreement(tmp / "new.npz", tmp / f"{other}.npz", COLUMNS)
        print(f"  new vs {other}: {agree.mean():.2%} of entries identical ({agree.sum()} of "
              f"{agree.size}: {', '.join(COLUMNS)})")
    status = times["new"][-1]["status"]
    print("  outcomes: " + ", ".join(f"{k} {v / n:.0%}" for k, v in sorted(
        status.items(), key=lambda kv: -kv[1])))


if __name__ == "__main__":
    main()
