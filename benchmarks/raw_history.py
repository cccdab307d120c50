"""Whether a store's RAWPLANNER solutions depend on what the process planned before them,
under each ``domain.contacts`` setting.

    python benchmarks/raw_history.py STORE INSTANCE [INSTANCE ...] [--blocks 8] [--before 1300]

For each setting (``fresh``, then ``cached``), in a fresh process: RAWPLANNER on the given
instances with nothing planned before, then again after each of ``--blocks`` blocks of the
store's other instances (the store's ``store.block_instances`` each, from ``--before``),
as a worker that was given those blocks first would plan them.  Printed: the collision
checks of each instance's solution after each history, and how many distinct answers each
instance got.  A setting whose answers are a function of the seeds gives one per instance.

On the paper-size pick_place store of 2026-11-27 (docs/contacts.md), instances 1423 and
1467 are the two whose solutions differed between two runs of one command.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

SETTINGS = ("fresh", "cached")


def child(job: dict) -> None:
    """One setting in this fresh process: a JSON line per history."""
    from pipeline import worker
    from pipeline.store import ScoreStore

    store = ScoreStore.open(job["store"])
    spec = store.domain_spec()
    spec = {**spec, "config": {**spec["config"], "contacts": job["contacts"]},
            "planner": {**spec["planner"], "wall_cap_s": 1e6}}  # no timeouts on a busy machine
    seed = store.attrs["config"]["seed"]
    specs, seeds = store.instance_specs(), store.instance_seeds()
    targets = job["instances"]

    def raw(rows):
        arrays, _ = worker.raw_block(spec, seed, [str(specs[i]) for i in rows],
                                     [int(seeds[i]) for i in rows])
        return [int(c) for c in arrays["checks"]]

    print(json.dumps(["nothing", raw(targets)]), flush=True)
    size = job["block"]
    for b in range(job["blocks"]):
        start = job["before"] + b * size
        others = [i for i in range(start, min(start + size, len(specs))) if i not in targets]
        if not others:
            break
        raw(others)
        print(json.dumps([f"instances {start}-{start + size - 1}", raw(targets)]), flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("store", nargs="?")
    ap.add_argument("instances", nargs="*", type=int)
    ap.add_argument("--blocks", type=int, default=8)
    ap.add_argument("--before", type=int, default=0, help="first instance of the histories")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(json.loads(args.child))
        return 0
    if not args.store or not args.instances:
        ap.error("a store and at least one instance are needed")
    from pipeline.store import ScoreStore, StoreError

    try:
        store = ScoreStore.open(args.store)
        n = store.instance_seeds().size
        block = int(store.attrs["config"]["store"]["block_instances"])
    except (StoreError, KeyError, FileNotFoundError) as e:
        print(f"raw_history: {e}", file=sys.stderr)
        return 2
    if not all(0 <= i < n for i in args.instances):
        print(f"raw_history: instances must lie in [0, {n})", file=sys.stderr)
        return 2
    print(f"{args.store}: RAWPLANNER's collision checks on instances "
          f"{', '.join(map(str, args.instances))}, after each history")
    for contacts in SETTINGS:
        job = dict(store=args.store, contacts=contacts, instances=args.instances,
                   blocks=args.blocks, before=args.before, block=block)
        out = subprocess.run([sys.executable, __file__, "--child", json.dumps(job)],
                             capture_output=True, text=True, check=False)
        if out.returncode:
            print(out.stderr[-3000:], file=sys.stderr)
            return 1
        rows = [json.loads(line) for line in out.stdout.splitlines() if line.startswith("[")]
        print(f"  domain.contacts={contacts}")
        for history, checks in rows:
            print(f"    after {history:<24}" + "".join(f"{c:>9}" for c in checks))
        distinct = [len({checks[k] for _, checks in rows}) for k in range(len(args.instances))]
        print("    distinct answers per instance: " + ", ".join(map(str, distinct)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
