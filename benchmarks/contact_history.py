"""How often pybullet's cached contacts change an exact collision answer, and whether an
entry's result depends on what its worker process checked before (docs/contacts.md).

Every exact check of the project is ``performCollisionDetection`` and then "any contact
point with distance < 0 that is not ignored".  Here the four places that do it
(``Panda.collides_at``, ``MobilePanda._in_collision``, ``PickPlaceScene.rod_collides``,
``fast_check._touches_world``) are replaced, in the child process only, by one that asks
the same question of the cached contacts and of :func:`pipeline.sim.contacts.penetrating`
(each penetrating pair confirmed afresh), counts where the two differ and answers with one
of them.  Modes: ``plain`` (the code as it is, nothing replaced), ``count`` (both asked,
the cached answer used: must give ``plain``'s results) and ``fresh`` (the fresh answer
used: what would change in D).

Per domain, one block (instances × Θ̂, planned as a worker plans a block,
:func:`pipeline.worker.score_block`) is planned in its own process on one core under each
checker (``planner.collision`` spheres and exact) and mode, ``after`` a warm-up block of
other instances in the same process (the domain cache keeps the scene, as in a worker) and,
for ``plain`` and ``fresh``, also ``alone`` (a fresh process).  Printed: the checks and
their disagreements per site, and how many entries agree (status, feasibility, failed
step, checks, length, score) between runs.

Run: python benchmarks/contact_history.py [--only grasp_arm|grasp_base|pick_place]
         [--arm-instances 3] [--mobile-instances 10] [--pick-place-data entries.npz]
     python benchmarks/contact_history.py --cost 400   (µs per check, plain and fresh)
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np
from child_runs import agreement, run_child

ROOT = Path(__file__).resolve().parents[1]
COLUMNS = ("status", "feasible", "step", "checks", "length", "score")
CHECKERS = ("spheres", "exact")
WALL_CAP_S = 1e6  # the planner's wall-clock safety net out of reach (as bench_pick_place)


# -- the child ---------------------------------------------------------------------------

def install(mode: str, tally: dict) -> None:
    """Replace the four exact checks by :func:`judge` (see the module's docstring)."""
    from pipeline.domains.pick_place.scene import PickPlaceScene
    from pipeline.sim import fast_check
    from pipeline.sim.mobile import HAND_LINKS, MobilePanda
    from pipeline.sim.panda import Panda

    def collides_at(self, q) -> bool:
        self.set(q)
        return judge(mode, tally, "panda", self.client,
                     [(self.body, lambda pt: pt[3] == -1)])

    def in_collision(self) -> bool:
        robot, held, arm = (self.platform, self.body), self.held, self.body
        queries = [(self.platform, lambda pt: pt[2] in robot),
                   (self.body, lambda pt: pt[3] == -1 or (pt[2] == held
                                                         and pt[3] in HAND_LINKS))]
        if held is not None:
            queries.append((held, lambda pt: pt[2] == arm and pt[4] in HAND_LINKS))
        return judge(mode, tally, "mobile", self.client, queries)

    def rod_collides(self) -> bool:
        return judge(mode, tally, "rod", self.client_id, [(self.rod, None)])

    def touches_world(client, body, robot_bodies) -> bool:
        return judge(mode, tally, "fixed_robot", client,
                     [(body, lambda pt: pt[2] in robot_bodies)])

    Panda.collides_at = collides_at
    MobilePanda._in_collision = in_collision
    PickPlaceScene.rod_collides = rod_collides
    fast_check._touches_world = touches_world


def judge(mode: str, tally: dict, site: str, client: int, queries) -> bool:
    """The cached and the fresh answer for ``queries`` ((body, ignore) pairs) after one
    ``performCollisionDetection``; counted under ``site``; ``mode`` says which is used."""
    import pybullet as pb

    from pipeline.sim import contacts

    pb.performCollisionDetection(physicsClientId=client)
    cached, fresh, deepest = False, False, 0.0
    for body, ignore in queries:
        hits = [pt[8] for pt in pb.getContactPoints(bodyA=body, physicsClientId=client)
                if pt[8] < 0 and not (ignore is not None and ignore(pt))]
        if hits:
            cached, deepest = True, min(deepest, *hits)
        fresh = fresh or contacts.penetrating(client, body, ignore)
    count = tally.setdefault(site, Counter())
    count["checks"] += 1
    count["cached"] += cached
    count["fresh"] += fresh
    if cached and not fresh:
        count["stale"] += 1
        count["stale_deepest_um"] = max(count["stale_deepest_um"], round(-deepest * 1e6))
    count["missed"] += fresh and not cached
    return fresh if mode == "fresh" else cached


def child(job: dict) -> None:
    from pipeline import worker

    tally: dict = {}
    if job["mode"] != "plain":
        install(job["mode"], tally)
    data = np.load(job["data"])
    spec = {"name": job["domain"], "config": job["config"],
            "planner": {"name": "rrt_connect", "collision": job["collision"],
                        "wall_cap_s": WALL_CAP_S}}
    theta = data["theta"]
    if job["after"]:
        worker.score_block(spec, 1, [str(s) for s in data["warm_specs"]],
                           [int(s) for s in data["warm_seeds"]], theta[:12], 0)
    before = {k: dict(v) for k, v in tally.items()}
    arrays, _ = worker.score_block(spec, 0, [str(s) for s in data["specs"]],
                                   [int(s) for s in data["seeds"]], theta, 0)
    np.savez(job["out"], **{k: arrays[k] for k in COLUMNS})
    block = {site: {k: v - before.get(site, {}).get(k, 0) if k != "stale_deepest_um" else v
                    for k, v in count.items()} for site, count in tally.items()}
    print(json.dumps({"n": int(arrays["status"].size), "tally": block}))


# -- the parent --------------------------------------------------------------------------

def block_data(name: str, args) -> dict:
    """Θ̂, the block's instances and the warm-up block's, as score_block takes them."""
    from pipeline.domains import load_domain

    config = {"step_order": "paper"} if name == "pick_place" else {}
    domain = load_domain(name, planner={"name": "rrt_connect"}, **config)
    if name == "grasp_arm":
        theta, first, n = domain.constraints().features, 100, args.arm_instances
    else:
        rows = []
        for k in range(args.mobile_instances):
            found = domain.raw_plan(domain.check_instance(domain.sample_instance(k)),
                                    seed=50_000 + k)
            if found.plan.feasible:
                rows.append(found.constraint)
        theta, first, n = np.array(rows), 1000, args.mobile_instances
    block = [domain.sample_instance(first + i) for i in range(n)]
    warm = [domain.sample_instance(first - 1 - i) for i in range(2)]
    domain.close()
    return {"theta": theta, "specs": np.array([json.dumps(s) for s in block]),
            "seeds": np.arange(first, first + n),
            "warm_specs": np.array([json.dumps(s) for s in warm]),
            "warm_seeds": np.arange(first - 2, first)}


def run_domain(name: str, args, tmp: Path) -> None:
    data = Path(args.pick_place_data) if name == "pick_place" and args.pick_place_data \
        else tmp / f"{name}.npz"
    if not data.exists():
        np.savez(data, **block_data(name, args))
    config = {"step_order": "paper"} if name == "pick_place" else {}
    runs = [(c, m, True) for c in CHECKERS for m in ("plain", "count", "fresh")]
    runs += [(c, m, False) for c in CHECKERS for m in ("plain", "fresh")]
    out, tallies = {}, {}
    for collision, mode, after in runs:
        key = f"{collision}-{mode}-{'after' if after else 'alone'}"
        job = {"domain": name, "config": config, "collision": collision, "mode": mode,
               "after": after, "data": str(data), "out": str(tmp / f"{name}-{key}.npz")}
        res = run_child(__file__, job, ROOT, key)
        out[key], tallies[key] = Path(job["out"]), res["tally"]
    n = res["n"]
    print(f"{name}: {n} entries per run")
    for key in ("spheres-count-after", "exact-count-after"):
        for site, count in sorted(tallies[key].items()):
            print(f"  {key:<20} {site:<12} " + ", ".join(f"{k} {v}" for k, v in
                                                       sorted(count.items())))
    pairs = [("spheres-plain-after", "spheres-count-after"),
             ("exact-plain-after", "exact-count-after"),
             ("spheres-plain-after", "exact-plain-after"),
             ("spheres-fresh-after", "exact-fresh-after"),
             ("spheres-plain-after", "spheres-fresh-after"),
             ("exact-plain-after", "exact-fresh-after"),
             ("spheres-plain-alone", "spheres-plain-after"),
             ("exact-plain-alone", "exact-plain-after"),
             ("spheres-fresh-alone", "spheres-fresh-after"),
             ("exact-fresh-alone", "exact-fresh-after")]
    for a, b in pairs:
        agree = agreement(out[a], out[b], COLUMNS)
        where = [tuple(int(i) for i in ix) for ix in np.argwhere(~agree)][:8]
        print(f"  {a} vs {b}: {agree.sum()} of {agree.size} identical"
              + (f"; differ at (instance, constraint) {where}" if where else ""))
    sys.stdout.flush()


def cost(configurations: int, repeats: int = 5) -> None:
    """µs per check of a Panda among boxes (self-collision on, base link ignored), the
    plain check against :func:`pipeline.sim.contacts.collides`: each configuration
    checked ``repeats`` times by each, alternating; medians over repeats, then over the
    configurations, free and colliding apart."""
    import time

    from pipeline.sim import contacts
    from pipeline.sim.panda import LOWER, UPPER, Panda
    from pipeline.sim.world import add_box, connect

    client = connect()
    arm = Panda(client, [0.0, 0.0, 0.0])
    for size, centre in [((0.3, 0.8, 0.4), (0.55, 0.0, 0.2)), ((0.8, 0.3, 0.6), (0.0, 0.6, 0.3)),
                         ((2.0, 2.0, 0.02), (0.0, 0.0, -0.011))]:
        add_box(client, size, centre)
    not_base = lambda pt: pt[3] == -1  # noqa: E731
    rng = np.random.default_rng(0)
    times = {(method, hit): [] for method in ("plain", "fresh") for hit in (False, True)}
    for _ in range(configurations):
        q = rng.uniform(LOWER, UPPER)
        arm.set(q)
        hit = contacts.cached_collides(client, arm.body, not_base)
        for method, check in (("plain", contacts.cached_collides), ("fresh", contacts.collides)):
            spent = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                arm.set(q)
                check(client, arm.body, not_base)
                spent.append(time.perf_counter() - t0)
            times[method, hit].append(np.median(spent) * 1e6)
    for hit in (False, True):
        plain, fresh = np.median(times["plain", hit]), np.median(times["fresh", hit])
        print(f"  {'colliding' if hit else 'free':<9} ({len(times['plain', hit])} "
              f"configurations): plain {plain:.1f} µs, fresh {fresh:.1f} µs per check "
              f"({fresh / plain:.2f}x)")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", choices=("grasp_arm", "grasp_base", "pick_place"))
    ap.add_argument("--arm-instances", type=int, default=3)
    ap.add_argument("--mobile-instances", type=int, default=10)
    ap.add_argument("--pick-place-data", help="a bench_pick_place block (entries.npz)")
    ap.add_argument("--cost", type=int, metavar="N",
                    help="only time both checks on N random Panda configurations")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(json.loads(args.child))
        return
    if args.cost:
        cost(args.cost)
        return
    names = [args.only] if args.only else ["grasp_arm", "grasp_base", "pick_place"]
    with tempfile.TemporaryDirectory(prefix="contact_history_") as tmp:
        for name in names:
            run_domain(name, args, Path(tmp))


if __name__ == "__main__":
    main()
