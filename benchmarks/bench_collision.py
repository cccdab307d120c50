"""Sphere-certified against exact-only collision checking, side by side, on one core.

For each robot domain the same entries (instance, constraint, seed) are planned twice,
with ``planner.collision=spheres`` and ``planner.collision=exact``, alternating entry by
entry so that the machine's drift hits both alike.  Printed per domain: mean ms per entry
and per feasible call under each checker and their ratios (exact / spheres), the share of
rows the pre-check cleared, the feasibility agreement (target >= 99 %, disagreements by
status) and how many entries came out identical (status, checks and path).  Instance
specs are parsed once per instance, as a worker parses each row's spec once per block.

grasp_arm: ``--instances`` instances × 162 constraints.  grasp_base and pick_place (the
paper's step order): RAWPLANNER on ``--mobile-instances`` instances, its extracted
constraints as Θ̂ (as bench_planner.py does), then every (instance, constraint).  One
warm-up instance per domain and checker is planned first, untimed (numba's compiled
kernels load, the wrist table's first cells).

Targets (ratios, one core): pick_place >= 5x, grasp_arm >= 3x per entry and per feasible
call, grasp_base >= 3x.

Run: python benchmarks/bench_collision.py [--instances 20] [--mobile-instances 12]
         [--only grasp_arm|grasp_base|pick_place] [--profile]
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time
from collections import Counter

import numpy as np

from pipeline.domains import load_domain

TARGETS = {"grasp_arm": 3.0, "grasp_base": 3.0, "pick_place": 5.0}
MODES = ("spheres", "exact")


def grasp_arm_entries(domain, n: int, warmup: int):
    instances = [domain.check_instance(domain.sample_instance(i))
                 for i in range(warmup, warmup + n)]
    return [(inst, j, j) for inst in instances for j in range(162)]


def mobile_entries(domain, n: int, warmup: int):
    """RAWPLANNER on n instances; its extracted constraints × the instances."""
    specs = [domain.check_instance(domain.sample_instance(s)) for s in range(warmup, warmup + n)]
    raws = [domain.raw_plan(spec, seed=1000 + i) for i, spec in enumerate(specs)]
    theta = [r.constraint for r in raws if r.plan.feasible]
    return [(spec, row, i * len(theta) + j) for i, spec in enumerate(specs)
            for j, row in enumerate(theta)]


def domains(name: str) -> dict:
    config = {"step_order": "paper"} if name == "pick_place" else {}
    return {mode: load_domain(name, planner={"name": "rrt_connect", "collision": mode}, **config)
            for mode in MODES}


def run(name: str, n: int, profile: bool = False) -> dict:
    doms = domains(name)
    make = grasp_arm_entries if name == "grasp_arm" else mobile_entries
    warm = make(doms["spheres"], 1, 0)
    for d in doms.values():  # untimed warm-up on instance 0
        for spec, row, seed in warm[:: max(1, len(warm) // 40)]:
            d.plan(spec, row, seed=seed)
    entries = make(doms["spheres"], n, 1)
    times = {m: np.zeros(len(entries)) for m in MODES}
    results = {m: [] for m in MODES}
    prof = cProfile.Profile() if profile else None
    for k, (spec, row, seed) in enumerate(entries):
        order = MODES if k % 2 == 0 else MODES[::-1]
        for mode in order:
            if prof is not None and mode == "spheres":
                prof.enable()
            t0 = time.perf_counter()
            res = doms[mode].plan(spec, row, seed=seed)
            times[mode][k] = time.perf_counter() - t0
            if prof is not None and mode == "spheres":
                prof.disable()
            results[mode].append(res)
    report(name, entries, times, results)
    if prof is not None:
        print(f"  cProfile of the {name} entries under planner.collision=spheres "
              "(top 15 by own time):")
        pstats.Stats(prof).sort_stats("tottime").print_stats(15)
    return {"times": times, "results": results}


def report(name, entries, times, results) -> None:
    fast, exact = results["spheres"], results["exact"]
    ok = {m: np.array([r.feasible for r in results[m]]) for m in MODES}
    n = len(entries)
    print(f"{name}: {n} entries, planned under both checkers, one core")
    print(f"  {'':<26}{'spheres':>12}{'exact':>12}{'ratio':>9}")
    mean = {m: times[m].mean() * 1e3 for m in MODES}
    print(f"  {'mean per entry':<26}{mean['spheres']:>9.2f} ms{mean['exact']:>9.2f} ms"
          f"{mean['exact'] / mean['spheres']:>8.2f}x (target >= {TARGETS[name]:g}x)")
    both = ok["spheres"] & ok["exact"]
    if both.any():
        feas = {m: times[m][both].mean() * 1e3 for m in MODES}
        med = {m: np.median(times[m][both]) * 1e3 for m in MODES}
        print(f"  {'mean per feasible call':<26}{feas['spheres']:>9.2f} ms{feas['exact']:>9.2f} ms"
              f"{feas['exact'] / feas['spheres']:>8.2f}x ({both.sum()} calls)")
        print(f"  {'median per feasible call':<26}{med['spheres']:>9.2f} ms{med['exact']:>9.2f} ms"
              f"{med['exact'] / med['spheres']:>8.2f}x")
    agree = ok["spheres"] == ok["exact"]
    print(f"  feasibility agreement: {agree.mean():.2%} ({(~agree).sum()} disagreements"
          + ("" if agree.all() else ": " + ", ".join(
              f"{k} {v}" for k, v in Counter(
                  f"spheres {a.status.name.lower()} / exact {b.status.name.lower()}"
                  for a, b, g in zip(fast, exact, agree, strict=True) if not g).items()))
          + ")")
    same = sum(a.status == b.status and a.checks == b.checks and a.step == b.step
               and (a.path is None) == (b.path is None)
               and (a.path is None or np.array_equal(a.path, b.path))
               for a, b in zip(fast, exact, strict=True))
    print(f"  identical entries (status, step, checks, path): {same} of {n}")
    mix = Counter(r.status.name.lower() + (f"@{r.step}" if r.step else "") for r in exact)
    print("  outcomes: " + ", ".join(f"{k} {v / n:.0%}" for k, v in mix.most_common()))
    print()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--instances", type=int, default=20)
    ap.add_argument("--mobile-instances", type=int, default=12)
    ap.add_argument("--only", choices=tuple(TARGETS))
    ap.add_argument("--profile", action="store_true",
                    help="cProfile the sphere-checked entries (pick_place only by default)")
    args = ap.parse_args()
    for name in (args.only,) if args.only else tuple(TARGETS):
        n = args.instances if name == "grasp_arm" else args.mobile_instances
        run(name, n, profile=args.profile and (args.only is not None or name == "pick_place"))


if __name__ == "__main__":
    main()
