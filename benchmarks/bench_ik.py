"""``domain.ik=damped`` (pybullet's damped IK, as Panda.ik runs it) against ``analytic``
(frankik's closed-form solutions, pipeline/sim/analytic_ik.py) in the grasp_arm domain, one
core, both measured in the same run.

1. Per pose, on the pre-grasp poses within reach: ms per pose and the share of poses with a
   solution within the domain's tolerances (5 mm, 0.05 rad) and the joint limits, checked
   with pybullet's own forward kinematics.  Collision checks are left out (the same for
   both).  frankik solves for the flange; its hand offset (0.1034 m) is not the URDF's TCP
   (0.105 m), so the target handed to it is T_tcp · inv(flange → TCP of the URDF)
   (``analytic_ik.candidates`` does this).
2. Per entry, on the same instances × all 162 constraints (π as a store computes it: IK,
   collision checks, the planner): ms per entry with each setting (median and mean, and
   their ratios damped / analytic), the number of feasible entries under each and the
   entries feasible under one only.  The two settings alternate per instance (which goes
   first too), so a noisy machine slows both alike.  The issue's rule: ``damped`` stays the
   default unless ``analytic`` gives at least as many feasible entries on the same
   instances.
3. The wrist-reach test (``pipeline.sim.panda.wrist_out_of_reach``, which answers NO_IK
   without running IK where no configuration can reach the pose): ``domain.ik=damped``
   with it and without it (the IK step as it was before, the test replaced by one that
   never refuses), the same instances × 162 constraints, alternating per instance: CPU ms
   per entry, the median of the per-instance ratios, the entries it answered and whether
   every entry is the same (status, feasible, failed step, checks, length, score).

4. grasp_arm as issue 27 found it: the code at ``--filed-rev`` (2ff2245, the parent of the
   issue's first commit; ``''`` skips this part) against this checkout, ``damped`` and
   ``analytic``, on the same instances × 162 constraints, each variant in its own process
   (benchmarks/entries_child.py, which runs on the old code too) after an untimed warm-up
   run, the variants in turn, median of ``--filed-repeats`` runs: CPU ms per entry, the
   ratios, and whether the old and the new ``damped`` give every entry the same status and
   feasibility.

Run: python benchmarks/bench_ik.py [--instances 5] [--entry-instances 20]
         [--wrist-instances 20] [--filed-rev 2ff2245] [--filed-instances 20]
         [--filed-repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
from child_runs import export_revision, run_child

from pipeline.domains import load_domain
from pipeline.planning import Status
from pipeline.sim import analytic_ik, fast_check
from pipeline.sim import panda as P

#: issue 27, item 2: grasp_arm's mean per entry with ``domain.ik=analytic`` (ms), and how
#: many times cheaper than ``damped`` it is to be
TARGET_MS, TARGET_RATIO = 1.0, 2.0
#: the code when issue 27 was filed: the parent of its first commit (17ef58b)
FILED_REV = "2ff2245"
ROOT = Path(__file__).resolve().parents[1]


def reached(arm, q, pos, orn) -> bool:
    """``q`` within the limits puts the TCP at the pose (pybullet's forward kinematics)."""
    if q is None or np.any(q < P.LOWER) or np.any(q > P.UPPER):
        return False
    p, o = arm.tcp_pose(q)
    return bool(np.linalg.norm(p - pos) <= P.IK_POS_TOL and P._angle(o, orn) <= P.IK_ANG_TOL)


def per_pose(n: int) -> None:
    domain = load_domain("grasp_arm")
    poses = []
    for seed in range(n):
        inst = domain.check_instance(domain.sample_instance(seed))
        scene = domain.scene(inst)
        for g in domain.grasps:
            arm = scene.arms[g.arm]
            pos, orn = domain.pregrasp_pose(inst, g)
            if np.linalg.norm(pos - arm.shoulder) <= P.REACH:
                poses.append((arm, pos, np.asarray(orn)))
    if not poses:
        print(f"IK per pose: none of {n} instances has a pre-grasp pose within reach")
        return
    analytic_ik.candidates(*poses[0])  # warm-up: frankik's import, the URDF's offsets
    rows = {}
    for name in ("damped (4 restarts)", "analytic (all solutions)"):
        ok, t = 0, 0.0
        for k, (arm, pos, orn) in enumerate(poses):
            t0 = time.perf_counter()
            if name.startswith("damped"):  # Panda.ik without the collision check
                q, _, _ = arm.ik(pos, orn, P.ik_starts(k, 4), collides=lambda q: False)
            else:
                sols = analytic_ik.candidates(arm, pos, orn)
                q = sols[0] if len(sols) else None
            t += time.perf_counter() - t0
            ok += reached(arm, q, pos, orn)
            arm.set(P.HOME)
        rows[name] = (t / len(poses) * 1e3, ok / len(poses))
    domain.close()
    print(f"IK on {len(poses)} grasp_arm pre-grasp poses within reach, one core")
    for name, (ms, share) in rows.items():
        print(f"  {name:<26} {ms:7.3f} ms per pose, solved {share:.1%}")


def per_entry(n: int) -> None:
    methods = ("damped", "analytic")
    domains = {m: load_domain("grasp_arm", ik=m) for m in methods}
    instances = [domains["damped"].check_instance(domains["damped"].sample_instance(i))
                 for i in range(n)]  # checked once per instance, as a worker does
    fast_check.compile_kernels()  # a cold numba cache compiles here, not in an entry
    for d in domains.values():  # warm-up: scene, memos
        d.plan(instances[0], 0, seed=0)
    times = {m: np.zeros((n, 162)) for m in methods}
    feasible = {m: np.zeros((n, 162), dtype=bool) for m in methods}
    status = {m: np.zeros((n, 162), dtype=int) for m in methods}
    for i, inst in enumerate(instances):
        for m in methods if i % 2 == 0 else methods[::-1]:
            for j in range(162):
                res = domains[m].plan(inst, j, seed=j)
                times[m][i, j], feasible[m][i, j] = res.time, res.feasible
                status[m][i, j] = int(res.status)
    for d in domains.values():
        d.close()
    entries = n * 162
    print(f"\ngrasp_arm, {n} instances x 162 constraints = {entries} entries per setting, "
          "one core, the two settings alternating per instance")
    for m in methods:
        mix = ", ".join(f"{Status(k).name.lower()} {v} ({times[m][status[m] == k].mean() * 1e3:.2f}"
                        " ms)" for k, v in Counter(status[m].ravel().tolist()).most_common())
        print(f"  domain.ik={m:<9} median {np.median(times[m]) * 1e3:6.3f} ms per entry, mean "
              f"{times[m].mean() * 1e3:6.3f} ms; feasible {feasible[m].sum()} of {entries}")
        print(f"    outcomes (mean ms each): {mix}")
    med = np.median(times["damped"]) / np.median(times["analytic"])
    mean = times["damped"].mean() / times["analytic"].mean()
    print(f"  damped / analytic: {med:.2f}x per entry (medians), {mean:.2f}x (means)")
    analytic_ms = times["analytic"].mean() * 1e3
    print(f"  target: grasp_arm <= {TARGET_MS:g} ms per entry with analytic: "
          f"{'met' if analytic_ms <= TARGET_MS else 'not met'} ({analytic_ms:.3f} ms, mean)")
    print(f"  target: analytic >= {TARGET_RATIO:g}x cheaper per entry than damped: "
          f"{'met' if mean >= TARGET_RATIO else 'not met'} ({mean:.2f}x, means)")
    at_ik = {m: np.isin(status[m], [int(Status.NO_IK), int(Status.GOAL_IN_COLLISION)])
             for m in methods}
    ik_ms = {m: times[m][at_ik[m]].mean() * 1e3 for m in methods}
    print(f"  entries that end at IK (no_ik, goal_in_collision): mean {ik_ms['damped']:.3f} ms "
          f"damped ({at_ik['damped'].sum()}), {ik_ms['analytic']:.3f} ms analytic "
          f"({at_ik['analytic'].sum()}): {ik_ms['damped'] / ik_ms['analytic']:.2f}x")
    same = status["damped"] == status["analytic"]
    print(f"  on the {same.sum()} entries with the same outcome under both: mean "
          f"{times['damped'][same].mean() * 1e3:.3f} ms damped, "
          f"{times['analytic'][same].mean() * 1e3:.3f} ms analytic "
          f"({times['damped'][same].mean() / times['analytic'][same].mean():.2f}x); the "
          "others plan paths under one setting only")
    only_d = int((feasible["damped"] & ~feasible["analytic"]).sum())
    only_a = int((feasible["analytic"] & ~feasible["damped"]).sum())
    print(f"  feasible under damped only: {only_d}; under analytic only: {only_a}")
    more = feasible["analytic"].sum() >= feasible["damped"].sum()
    print(f"  analytic gives {'at least as many' if more else 'fewer'} feasible entries on "
          "these instances (the rule for making it the default)")


def wrist_test(n: int) -> None:
    """Section 3 of the module docstring."""
    from pipeline.domains import ik as ik_step

    domain = load_domain("grasp_arm")
    instances = [domain.check_instance(domain.sample_instance(1000 + i)) for i in range(n)]
    fast_check.compile_kernels()
    domain.plan(instances[0], 0, seed=0)  # warm-up: scene, memos
    real = ik_step.wrist_out_of_reach
    answered = [0]

    def counted(*args):
        out = real(*args)
        answered[0] += out
        return out

    variants = {"with the wrist test": counted, "without it": lambda *args: False}
    cpu = {name: np.zeros(n) for name in variants}
    rows = {name: [] for name in variants}
    try:
        for i, inst in enumerate(instances):
            for name in variants if i % 2 == 0 else list(variants)[::-1]:
                ik_step.wrist_out_of_reach = variants[name]
                t0 = time.process_time()
                rows[name] += [domain.plan(inst, j, seed=j) for j in range(162)]
                cpu[name][i] = time.process_time() - t0
    finally:
        ik_step.wrist_out_of_reach = real
        domain.close()

    def key(r):  # NaN (a failure's length and score) compares equal to NaN here
        return (r.status, r.feasible, r.step, r.checks,
                *(None if np.isnan(x) else x for x in (r.score, r.length)))

    same = sum(key(a) == key(b) for a, b in zip(*rows.values(), strict=True))
    on, off = cpu["with the wrist test"], cpu["without it"]
    print(f"\nthe wrist-reach test, grasp_arm, domain.ik=damped, {n} instances x 162 "
          f"constraints = {n * 162} entries per variant, one core, alternating per instance")
    for name, t in cpu.items():
        print(f"  {name:<20} {t.sum() / (n * 162) * 1e3:6.3f} CPU ms per entry")
    print(f"  without / with: {off.sum() / on.sum():.2f}x in all, {np.median(off / on):.2f}x "
          f"(median over instances); {answered[0]} entries answered by the test; "
          f"{same} of {n * 162} entries identical")


def as_filed(rev: str, n: int, repeats: int) -> None:
    """Section 4 of the module docstring."""
    child = str(Path(__file__).with_name("entries_child.py"))
    with tempfile.TemporaryDirectory(prefix="bench_ik_") as tmp:
        old = export_revision(rev, Path(tmp) / "old")
        if old is None:
            return
        variants = {f"damped at {rev}": (old, None), "damped": (ROOT, "damped"),
                    "analytic": (ROOT, "analytic")}
        for label, (root, ik) in variants.items():  # untimed: numba caches, wrist table
            run_child(child, {"domain": "grasp_arm", "ik": ik, "instances": 1,
                              "constraints": 162}, root, label)
        runs = {label: [] for label in variants}
        names = list(variants)
        for r in range(repeats):
            for label in names[r % len(names):] + names[: r % len(names)]:
                root, ik = variants[label]
                runs[label].append(run_child(child, {"domain": "grasp_arm", "ik": ik,
                                                     "instances": n, "constraints": 162},
                                             root, label))
    entries = n * 162
    ms = {label: statistics.median(sum(o["cpu"]) for o in outs) / entries * 1e3
          for label, outs in runs.items()}
    then = f"damped at {rev}"
    print(f"\ngrasp_arm as issue 27 found it ({rev}) and now, {n} instances x 162 "
          f"constraints = {entries} entries per run, one core, median of {repeats} runs")
    for label in variants:
        gain = "" if label == then else f"; {ms[then] / ms[label]:.2f}x cheaper than at {rev}"
        print(f"  {label:<20} {ms[label]:6.3f} CPU ms per entry; feasible "
              f"{sum(runs[label][0]['feasible'])} of {entries}{gain}")
    print(f"  as filed: grasp_arm per entry {ms[then] / ms['damped']:.2f}x cheaper now with "
          f"damped, {ms[then] / ms['analytic']:.2f}x with analytic (item 2 asked >= "
          f"{TARGET_RATIO:g}x with analytic)")
    same = all(runs[then][0][k] == runs["damped"][0][k] for k in ("status", "feasible"))
    print(f"  damped at {rev} and now: every entry's status and feasibility "
          + ("the same" if same else "NOT the same"))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--instances", type=int, default=5,
                    help="instances of the per-pose part; 0 skips it")
    ap.add_argument("--entry-instances", type=int, default=20,
                    help="instances of the per-entry part (x 162 entries); 0 skips it")
    ap.add_argument("--wrist-instances", type=int, default=20,
                    help="instances of the wrist test's part (x 162 entries); 0 skips it")
    ap.add_argument("--filed-rev", default=FILED_REV,
                    help="the revision of the 'as filed' part; '' skips it")
    ap.add_argument("--filed-instances", type=int, default=20,
                    help="instances of the 'as filed' part (x 162 entries)")
    ap.add_argument("--filed-repeats", type=int, default=3,
                    help="timed runs per variant of the 'as filed' part")
    args = ap.parse_args()
    for name in ("instances", "entry_instances", "wrist_instances"):
        if getattr(args, name) < 0:
            ap.error(f"--{name.replace('_', '-')} must be >= 0")
    for name in ("filed_instances", "filed_repeats"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be >= 1")
    try:
        import frankik  # noqa: F401
    except ImportError:
        raise SystemExit("bench_ik.py needs the frankik package: pip install frankik") from None
    if args.instances:
        per_pose(args.instances)
    if args.entry_instances:
        per_entry(args.entry_instances)
    if args.wrist_instances:
        wrist_test(args.wrist_instances)
    if args.filed_rev:
        as_filed(args.filed_rev, args.filed_instances, args.filed_repeats)


if __name__ == "__main__":
    main()
