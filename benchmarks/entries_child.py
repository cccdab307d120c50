"""One domain's entries in one process, on whatever code is first on the path: the child of
benchmarks that set this checkout against an older revision (bench_ik.py's section 4).  It
uses only what every revision has had (``load_domain``, ``sample_instance``,
``check_instance``, ``plan``, and ``fast_check.compile_kernels`` where there is one); ``ik`` is
passed only when set, since older code has no such key.

Run: python benchmarks/entries_child.py --child '{"domain": "grasp_arm", "ik": null,
         "instances": 20, "constraints": 162}'
     (prints one JSON line: CPU seconds per instance, each entry's status and feasibility)
"""

from __future__ import annotations

import json
import sys
import time


def child(job: dict) -> dict:
    from pipeline.domains import load_domain

    domain = load_domain(job["domain"], **({"ik": job["ik"]} if job.get("ik") else {}))
    instances = [domain.check_instance(domain.sample_instance(i))
                 for i in range(job["instances"])]
    try:  # every compiled kernel loaded from numba's cache now, not inside a timed entry
        from pipeline.sim.fast_check import compile_kernels
    except ImportError:  # code from before the compiled checker
        pass
    else:
        compile_kernels()
    domain.plan(instances[0], 0, seed=0)  # warm-up: scene, memos
    cpu, status, feasible = [], [], []
    for inst in instances:
        t0 = time.process_time()
        results = [domain.plan(inst, j, seed=j) for j in range(job["constraints"])]
        cpu.append(time.process_time() - t0)
        status += [int(r.status) for r in results]
        feasible += [bool(r.feasible) for r in results]
    domain.close()
    return {"cpu": cpu, "status": status, "feasible": feasible}


if __name__ == "__main__":
    if len(sys.argv) != 3 or sys.argv[1] != "--child":
        print("usage: entries_child.py --child JSON", file=sys.stderr)
        sys.exit(2)
    print(json.dumps(child(json.loads(sys.argv[2]))))
