"""Cost of one score-matrix entry in the grasp_arm domain (paper §V-A), on one core.

On 20 instances × all 162 constraints prints: collision checks per second, median ms per
feasible call (IK + RRT-Connect + shortcutting), median ms per call rejected at IK, the
status mix, and the mean ms per entry over all entries.  The authors' 2016 pipeline
averaged 1.4 s per entry of this matrix.

Then the same entries with planner=trajopt: median ms per feasible call and success rate
of each planner, the mean per entry of each, and the share of entries feasible for one
planner but not the other (IK is shared, so both see the same goals).
benchmarks/bench_trajopt.py measures TrajOpt in grasp_arm and grasp_base side by side with
RRT-Connect and with its code before the speed-up (issue 27, item 3).

Then the mobile domains (grasp_base, pick_place; paper §V-B, §V-C): RAWPLANNER on
``--mobile-instances`` instances, its extracted constraints as Θ̂ (as stage=constraints
does), and π on every (instance, constraint).  Per domain: median ms per feasible π call,
mean ms per entry (targets: <= 50 ms grasp_base, <= 200 ms pick_place), median seconds per
RAWPLANNER solve, and the ratio of the two medians (RAWPLANNER / feasible π).

Last, the collision checkers side by side (benchmarks/bench_collision.py): the same entries
with planner.collision=spheres and =exact, their ratios and feasibility agreement.

Run: python benchmarks/bench_planner.py [--instances 20] [--no-trajopt]
         [--mobile-instances 20] [--only grasp_arm|grasp_base|pick_place] [--no-collision]
"""

from __future__ import annotations

import argparse
import time
from collections import Counter

import numpy as np

from pipeline.domains import load_domain
from pipeline.planning import Status
from pipeline.sim import panda as P


def checks_per_second(domain, instances, per_instance: int = 2000) -> list[float]:
    rates = []
    for inst in instances:
        scene = domain.scene(domain.check_instance(inst))
        arm = scene.arms[0]
        Q = np.random.default_rng(0).uniform(P.LOWER, P.UPPER, (per_instance, 7))
        t0 = time.perf_counter()
        for q in Q:
            arm.collides_at(q)
        rates.append(per_instance / (time.perf_counter() - t0))
        arm.set(P.HOME)
    return rates


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--instances", type=int, default=20)
    ap.add_argument("--no-trajopt", action="store_true", help="skip the TrajOpt comparison")
    ap.add_argument("--mobile-instances", type=int, default=20)
    ap.add_argument("--only", choices=("grasp_arm", *MOBILE_TARGETS_MS))
    ap.add_argument("--no-collision", action="store_true",
                    help="skip the spheres-against-exact checker comparison")
    args = ap.parse_args()
    if not args.no_collision:
        compare_checkers(args)
    if args.only != "grasp_arm":
        for name in MOBILE_TARGETS_MS if args.only is None else (args.only,):
            bench_mobile(name, args.mobile_instances)
    if args.only not in (None, "grasp_arm"):
        return
    domain = load_domain("grasp_arm")
    instances = [domain.sample_instance(i) for i in range(args.instances)]
    rates = checks_per_second(domain, instances[:5])

    times, checks, total, rrt_ok = run_entries(domain, instances)
    entries = args.instances * 162
    mix = Counter({s.name.lower(): len(v) for s, v in times.items()})

    print(f"grasp_arm, {args.instances} instances x 162 constraints = {entries} entries, "
          "one core")
    print(f"  collision checks/s (random configurations, arm + 2nd arm + furniture + "
          f"obstacles): median {np.median(rates):,.0f} (target >= 20,000)")
    for status, target, label in ((Status.OK, 20, "feasible call (IK + RRT + shortcut)"),
                                  (Status.NO_IK, 3, "call rejected at IK")):
        v = times.get(status, [])
        med = f"{np.median(v) * 1e3:.2f} ms" if v else "n/a"
        print(f"  median per {label:<36} {med} (target <= {target} ms; {len(v)} calls)")
    print("  status mix: " + ", ".join(f"{k} {v} ({v / entries:.1%})"
                                       for k, v in mix.most_common()))
    print(f"  mean per entry over all entries: {total / entries * 1e3:.2f} ms (target <= 25 ms; "
          f"the authors' 2016 pipeline: 1400 ms)")
    print(f"  collision checks per entry: mean {checks / entries:,.0f}")
    if not args.no_trajopt:
        compare_trajopt(instances, times, rrt_ok, total)


MOBILE_TARGETS_MS = {"grasp_base": 50, "pick_place": 200}


def bench_mobile(name: str, n: int) -> None:
    domain = load_domain(name)
    specs = [domain.sample_instance(s) for s in range(n)]
    domain.plan(specs[0], domain.raw_plan(specs[0], seed=0).constraint, seed=0)  # warm-up
    raws = [domain.raw_plan(spec, seed=1000 + i) for i, spec in enumerate(specs)]
    theta = [r.constraint for r in raws if r.plan.feasible]
    results = []
    t0 = time.perf_counter()
    for i, spec in enumerate(specs):
        for j, row in enumerate(theta):
            results.append(domain.plan(spec, row, seed=i * len(theta) + j))
    total = time.perf_counter() - t0
    ok = [r.time for r in results if r.feasible]
    raw_s = float(np.median([r.time for r in raws]))
    print(f"{name}, {n} instances x {len(theta)} extracted constraints = {len(results)} "
          "entries, one core")
    print(f"  RAWPLANNER: solved {len(theta)} of {n}; median {raw_s:.3f} s per solve, "
          f"mean {np.mean([r.time for r in raws]):.3f} s, mean tries "
          f"{np.mean([r.tries for r in raws]):.1f}")
    if ok:
        print(f"  median per feasible pi call: {np.median(ok) * 1e3:.1f} ms ({len(ok)} calls, "
              f"{len(ok) / len(results):.1%} of entries)")
        print(f"  ratio median RAWPLANNER solve / median feasible pi call: "
              f"{raw_s / np.median(ok):.1f}x")
    print(f"  mean per entry over all entries: {total / len(results) * 1e3:.1f} ms "
          f"(target <= {MOBILE_TARGETS_MS[name]} ms)")
    steps = Counter(f"{r.status.name.lower()}" + (f"@{r.step}" if r.step else "")
                    for r in results)
    print("  outcomes: " + ", ".join(f"{k} {v} ({v / len(results):.0%})"
                                     for k, v in steps.most_common()))
    print()


def compare_checkers(args) -> None:
    """planner.collision=spheres against =exact on the same entries, per domain."""
    import bench_collision

    for name in (args.only,) if args.only else tuple(bench_collision.TARGETS):
        bench_collision.run(name, args.instances if name == "grasp_arm"
                            else args.mobile_instances)


def run_entries(domain, instances):
    """Plan every (instance, constraint): per-status times, checks, wall time, feasibility."""
    times: dict[Status, list[float]] = {}
    feasible = np.zeros((len(instances), 162), dtype=bool)
    checks = 0
    t0 = time.perf_counter()
    for i, inst in enumerate(instances):
        for j in range(162):
            res = domain.plan(inst, j, seed=j)
            times.setdefault(res.status, []).append(res.time)
            feasible[i, j] = res.feasible
            checks += res.checks
    return times, checks, time.perf_counter() - t0, feasible


def compare_trajopt(instances, rrt_times, rrt_ok, rrt_total: float) -> None:
    domain = load_domain("grasp_arm", planner="trajopt")
    times, _, total, ok = run_entries(domain, instances)
    entries = ok.size
    print(f"\ntrajopt on the same {entries} entries (T = 20 waypoints, 2 cm margin)")
    for name, t, feasible in (("rrt_connect", rrt_times, rrt_ok), ("trajopt", times, ok)):
        v = t.get(Status.OK, [])
        med = f"{np.median(v) * 1e3:.2f} ms" if v else "n/a"
        print(f"  {name:<12} median per feasible call {med}; feasible {feasible.sum()} of "
              f"{entries} ({feasible.mean():.1%})")
    print(f"  trajopt mean per entry: {total / entries * 1e3:.2f} ms; rrt_connect's "
          f"{rrt_total / entries * 1e3:.2f} ms (measured first: its run loads the compiled "
          "checker; benchmarks/bench_trajopt.py compares the two warmed up, in both domains)")
    print(f"  feasible for rrt_connect only: {(rrt_ok & ~ok).sum()} "
          f"({(rrt_ok & ~ok).mean():.2%}); for trajopt only: {(ok & ~rrt_ok).sum()} "
          f"({(ok & ~rrt_ok).mean():.2%})")
    mix = Counter({s.name.lower(): len(v) for s, v in times.items()})
    print("  trajopt status mix: " + ", ".join(f"{k} {v} ({v / entries:.1%})"
                                               for k, v in mix.most_common()))


if __name__ == "__main__":
    main()
