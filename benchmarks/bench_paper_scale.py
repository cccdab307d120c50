"""The paper's whole experiment, projected: CPU-seconds per score-matrix entry of every
domain × planner measured on a sample, and the wall time of ``stage=generate`` at the
paper's sizes on N cores (issue 27, item 4).

Per domain × planner, in its own process on one core (OMP/OpenBLAS/MKL/numba limited to
one thread), with the configuration a run composes (``domain=… planner=…``, defaults
otherwise):

* after a warm-up solve, RAWPLANNER on ``--raw`` instances, as ``stage=raw`` runs it
  (CPU-s per instance); its feasible solutions give Θ̂ as ``stage=constraints`` extracts
  it (grasp_arm: the 162 fixed grasps);
* after a warm-up on other instances (numba's kernels load, caches fill), one block of
  ``--instances`` × ``--constraints`` entries planned as a worker plans a block
  (:func:`pipeline.worker.score_block`), CPU-s per entry.

Each is run ``--repeats`` times (fresh processes, the same entries): the table shows the
medians and the range of the CPU time per entry (one run's figure drifted by 7 % to 60 %
from the next on the 2-core machine, 2026-11-27).

The projection: ``n·m`` entries × CPU-s per entry + ``n`` RAWPLANNER solves, divided by the
cores.  It leaves out what does not scale with the entries (sampling instances, the
evaluation; seconds) and the pipeline's own overhead (``benchmarks/bench_pipeline.py``
measures it), and the sample's mean has its own error; ``--real`` runs one store for real
at a given size and prints its wall time next to the projection of that same size.

The paper's sizes (§V): grasp_arm 1800 × 162, grasp_base 1000 × 1000, pick_place 1500 × 1000.
TrajOpt runs on grasp_arm and grasp_base only (the paper's TrajOpt stores).

Run: python benchmarks/bench_paper_scale.py [--raw 30] [--instances 24] [--constraints 60]
         [--cores 2] [--repeats 3] [--only grasp_arm|grasp_base|pick_place]
         [--planners rrt_connect,trajopt]
         [--real grasp_base:1000x1000 | grasp_arm:1800x162:trajopt] [--ompl-too]
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
from pathlib import Path

import numpy as np
from child_runs import run_child

ROOT = Path(__file__).resolve().parents[1]
PAPER = {"grasp_arm": (1800, 162), "grasp_base": (1000, 1000), "pick_place": (1500, 1000)}
PLANNERS = {"grasp_arm": ("rrt_connect", "trajopt"), "grasp_base": ("rrt_connect", "trajopt"),
            "pick_place": ("rrt_connect",)}
TARGET_S = 3600.0  # issue 27: all three RRT-Connect stores within an hour on 2 cores


def run_config(domain: str, planner: str, overrides=()) -> dict:
    """The plain config ``python -m pipeline domain=… planner=…`` composes."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from pipeline import configs

    configs.register_configs()
    with initialize_config_dir(config_dir=str(configs.CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config",
                      overrides=[f"domain={domain}", f"planner={planner}", *overrides])
    return OmegaConf.to_container(cfg, resolve=True, enum_to_str=True)


# -- the child: one domain × planner, one process -----------------------------------------

def child(job: dict) -> None:
    from pipeline import worker
    from pipeline.domains import ConstraintSet
    from pipeline.domains.cache import domain_for
    from pipeline.store import domain_spec_of

    if job.get("ompl"):  # RRT-Connect through OMPL's own objects, as before the compiled one
        from pipeline.planning.rrt_connect import RRTConnect

        RRTConnect.compiled = False
    spec = domain_spec_of(run_config(job["domain"], job["planner"]))
    domain = domain_for(spec)
    seed = job["seed"]
    raw_specs = [json.dumps(domain.sample_instance(seed + k)) for k in range(job["raw"])]
    # one solve on another instance first: a cold numba cache compiles the kernels there,
    # which is not planning (it more than doubled pick_place's s/RAW on a fresh checkout)
    worker.raw_block(spec, 0, [json.dumps(domain.sample_instance(seed - 1))], [seed - 1])
    c0 = time.process_time()
    raw, _ = worker.raw_block(spec, 0, raw_specs, list(range(seed, seed + job["raw"])))
    raw_cpu = (time.process_time() - c0) / job["raw"]
    if domain.fixed_constraints:
        theta = domain.constraints().features
    else:
        extracted = ConstraintSet(raw["constraint"], np.arange(len(raw["constraint"])))
        theta = domain.constraints(extracted).features
    pick = np.random.default_rng(seed).permutation(len(theta))[: job["constraints"]]
    theta = theta[np.sort(pick)]
    first = seed + 100_000
    warm = [json.dumps(domain.sample_instance(first - 1))]
    worker.score_block(spec, 0, warm, [first - 1], theta[:12], 0)
    block = [json.dumps(domain.sample_instance(first + i)) for i in range(job["instances"])]
    w0, c0 = time.perf_counter(), time.process_time()
    arrays, _ = worker.score_block(spec, 0, block, list(range(first, first + len(block))),
                                   theta, 0)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    n = arrays["feasible"].size
    digest = hashlib.sha256(b"".join(np.ascontiguousarray(arrays[k]).tobytes() for k in (
        "status", "feasible", "step", "checks", "length", "score"))).hexdigest()
    print(json.dumps({"entry_cpu_s": cpu / n, "entry_wall_s": wall / n, "entries": n,
                      "digest": digest,
                      "feasible": float(arrays["feasible"].mean()), "raw_cpu_s": raw_cpu,
                      "raw_feasible": float(raw["feasible"].mean()),
                      "constraints": len(theta)}))


def measure(domain: str, planner: str, args, ompl: bool = False) -> dict:
    """The sample's figures, each the median of ``--repeats`` fresh processes (the same
    entries every time), with the range of the CPU time per entry ("entry_cpu_range") and
    the digest of the block's results (None where runs disagreed).  ``ompl``: RRT-Connect
    through OMPL's objects rather than compiled with the sphere checker's scan."""
    job = {"domain": domain, "planner": planner, "seed": args.seed, "raw": args.raw,
           "instances": args.instances, "constraints": args.constraints, "ompl": ompl}
    runs = [run_child(__file__, job, ROOT, f"{domain} × {planner}{' (OMPL)' if ompl else ''}")
            for _ in range(args.repeats)]
    digests = {run.pop("digest") for run in runs}
    row = {key: statistics.median(run[key] for run in runs) for key in runs[0]}
    row["digest"] = digests.pop() if len(digests) == 1 else None
    cpu = [run["entry_cpu_s"] for run in runs]
    row["entry_cpu_range"] = (min(cpu), max(cpu))
    return row


# -- the parent -------------------------------------------------------------------------

def projected_s(row: dict, n: int, m: int, cores: int) -> float:
    return (n * m * row["entry_cpu_s"] + n * row["raw_cpu_s"]) / cores


def clock(seconds: float) -> str:
    h, rest = divmod(round(seconds), 3600)
    return f"{h} h {rest // 60:02d} min" if h else f"{rest // 60} min {rest % 60:02d} s"


def real_run(domain: str, n: int, m: int, planner: str = "rrt_connect") -> dict:
    """``stage=generate`` of one store at n × m with ``planner`` on this machine's
    LocalCluster: wall time and the planning time its workers recorded in D."""
    from pipeline.store import ScoreStore

    tmp = Path(tempfile.mkdtemp(prefix="bench_paper_scale_"))
    try:
        store = tmp / f"{domain}.zarr"
        cmd = [sys.executable, "-m", "pipeline", "stage=generate", f"domain={domain}",
               f"planner={planner}", f"instances.n={n}", f"constraints.m={m}",
               f"store.path={store}", "progress=false", f"hydra.run.dir={tmp / 'outputs'}"]
        t0 = time.perf_counter()
        subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        matrix = ScoreStore.open(store).score_matrix()
        return {"wall_s": wall, "entries": matrix.feasible.size,
                "planning_cpu_s": float(matrix.times.sum()),
                "feasible": float(matrix.feasible.mean())}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def real_size(text: str) -> tuple[str, int, int, str]:
    """``--real``'s DOMAIN:NxM[:PLANNER] (the planner rrt_connect when not given)."""
    try:
        domain, size, *rest = text.split(":")
        n, m = (int(x) for x in size.split("x"))
        (planner,) = rest or ["rrt_connect"]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected DOMAIN:NxM[:PLANNER], e.g. "
                                         "grasp_base:1000x1000 or grasp_arm:1800x162:trajopt"
                                         ) from None
    if domain not in PAPER or n < 1 or m < 1 or planner not in PLANNERS.get(domain, ()):
        raise argparse.ArgumentTypeError(
            f"{text!r}: DOMAIN one of {', '.join(PAPER)}, N and M at least 1, PLANNER one "
            f"of the domain's ({', '.join(PLANNERS.get(domain, PLANNERS['grasp_arm']))})")
    return domain, n, m, planner


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--raw", type=int, default=30, help="RAWPLANNER instances (Θ̂ and its cost)")
    ap.add_argument("--instances", type=int, default=24, help="instances of the timed block")
    ap.add_argument("--constraints", type=int, default=60,
                    help="constraints of the timed block (the default store block's width)")
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=3,
                    help="sample runs per domain × planner (fresh processes; medians)")
    ap.add_argument("--seed", type=int, default=2017)
    ap.add_argument("--only", choices=sorted(PAPER))
    ap.add_argument("--planners", default="rrt_connect,trajopt")
    ap.add_argument("--real", type=real_size, help="DOMAIN:NxM[:PLANNER], one real "
                    "stage=generate run (RRT-Connect unless PLANNER), e.g. "
                    "grasp_base:1000x1000 or grasp_arm:1800x162:trajopt")
    ap.add_argument("--ompl-too", action="store_true",
                    help="also each RRT-Connect sample through OMPL's objects (the search "
                    "before it was compiled with the scan): ms/entry side by side, and "
                    "whether the results are identical")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(json.loads(args.child))
        return
    wanted = args.planners.split(",")
    unknown = sorted(set(wanted) - {"rrt_connect", "trajopt"})
    if unknown or args.cores < 1 or args.repeats < 1:
        ap.error(f"--planners: unknown {', '.join(unknown)}" if unknown
                 else "--cores and --repeats must be at least 1")
    rows = {}
    for domain in [args.only] if args.only else PAPER:
        for planner in PLANNERS[domain]:
            if planner in wanted:
                rows[domain, planner] = measure(domain, planner, args)
    report(rows, args)
    if args.ompl_too:
        compare_ompl(rows, args)
    if args.real:
        domain, n, m, planner = args.real
        row = rows.get((domain, planner)) or measure(domain, planner, args)
        got = real_run(domain, n, m, planner)
        print(f"\nreal run, {domain} {n} × {m}, {planner}, LocalCluster on this machine: "
              f"{clock(got['wall_s'])} wall ({got['entries']:,} entries, planning time in "
              f"D {got['planning_cpu_s']:.0f} s, {got['feasible']:.1%} feasible); "
              f"projected {clock(projected_s(row, n, m, args.cores))} on {args.cores} cores")


def report(rows: dict, args) -> None:
    c = args.cores
    print(f"Paper-scale stage=generate, projected from one-core samples ({args.instances} "
          f"instances × up to {args.constraints} constraints per domain × planner, "
          f"RAWPLANNER on {args.raw} instances; medians of {args.repeats} runs, the range of "
          f"ms/entry beside); wall = CPU / {c} cores, the pipeline's overhead left out")
    head = (f"  {'domain':<11}{'planner':<13}{'paper n × m':>14}{'ms/entry':>10}"
            f"{'range':>13}{'s/RAW':>7}{'feasible':>10}{'CPU-h':>7}{f'wall, {c} cores':>17}")
    print(head)
    totals = {}
    for (domain, planner), row in rows.items():
        n, m = PAPER[domain]
        wall = projected_s(row, n, m, c)
        totals[planner] = totals.get(planner, 0.0) + wall
        lo, hi = row["entry_cpu_range"]
        print(f"  {domain:<11}{planner:<13}{f'{n} × {m}':>14}{row['entry_cpu_s'] * 1e3:>10.2f}"
              f"{f'{lo * 1e3:.2f}–{hi * 1e3:.2f}':>13}"
              f"{row['raw_cpu_s']:>7.2f}{row['feasible']:>10.1%}"
              f"{wall * c / 3600:>7.2f}{clock(wall):>17}")
    for planner, total in totals.items():
        domains = [d for d, p in rows if p == planner]
        print(f"  all of {planner} ({', '.join(domains)}): {clock(total)} on {c} cores")
    if "rrt_connect" in totals and len([1 for d, p in rows if p == "rrt_connect"]) == 3:
        met = "met" if totals["rrt_connect"] <= TARGET_S * 2 / c else "not met"
        print(f"  target: the three RRT-Connect stores <= 1 h on 2 cores: {met}")


def compare_ompl(rows: dict, args) -> None:
    """Each RRT-Connect sample again through OMPL's objects: ms/entry of both, the ratio,
    and whether the two blocks' results are identical (status, feasibility, failed step,
    checks, length, score: the digests)."""
    print("\nRRT-Connect compiled with the scan against OMPL's objects (the same entries, "
          f"medians of {args.repeats} runs each)")
    print(f"  {'domain':<11}{'compiled ms':>12}{'OMPL ms':>9}{'OMPL / compiled':>17}"
          f"{'results':>11}")
    for (domain, planner), row in rows.items():
        if planner != "rrt_connect":
            continue
        ompl = measure(domain, planner, args, ompl=True)
        same = row["digest"] is not None and row["digest"] == ompl["digest"]
        print(f"  {domain:<11}{row['entry_cpu_s'] * 1e3:>12.2f}{ompl['entry_cpu_s'] * 1e3:>9.2f}"
              f"{ompl['entry_cpu_s'] / row['entry_cpu_s']:>16.2f}x"
              f"{'identical' if same else 'DIFFER':>11}")


if __name__ == "__main__":
    main()
