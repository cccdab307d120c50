"""Pipeline overhead, scaling and raw write throughput on the planar domain.

Prints:
  * the scores stage with 1 worker versus a plain serial loop over the same planning calls
    (same entries, same seeds, one process): the pipeline's overhead, with and without
    starting the LocalCluster;
  * 2 workers versus 1 (this machine has 2 cores);
  * entries per second written with the no-op planner (the pipeline's own cost).

Run: python benchmarks/bench_pipeline.py [--n 96 --m 40 --noop-n 2000 --noop-m 200]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from hydra import compose, initialize_config_dir
from rich.console import Console

from pipeline import configs, stages, worker
from pipeline.store import ScoreStore
from pipeline.store.layout import SCORES, table_key


def compose_cfg(store: Path, overrides: list[str]):
    with initialize_config_dir(config_dir=str(configs.CONF_DIR), version_base="1.3"):
        return compose(config_name="config", overrides=[f"store.path={store}", "progress=false",
                                                        "domain=planar", *overrides])


def prepared(store: Path, overrides: list[str], console: Console) -> None:
    """Instances, raw and constraints (not timed)."""
    cfg = compose_cfg(store, ["stage=constraints", *overrides])
    for stage in ("instances", "raw", "constraints"):
        cfg.stage = stage
        stages.run_pipeline(cfg, console)


def planar_setup(n: int, m: int, prefix: str):
    """A temporary folder with a planar store of ``n`` instances and up to ``m``
    constraints prepared (:func:`prepared`): (folder, its overrides, store, entries of D,
    a quiet console)."""
    configs.register_configs()
    console = Console(file=sys.stderr, quiet=True)
    tmp = Path(tempfile.mkdtemp(prefix=prefix))
    real = [f"instances.n={n}", f"constraints.m={m}", "store.block_instances=12",
            "store.block_constraints=20"]
    store = tmp / "planar.zarr"
    prepared(store, real, console)
    entries = n * ScoreStore.open(store).stage_info("constraints")["m"]
    return tmp, real, store, entries, console


def timed_scores(store: Path, overrides: list[str], console: Console) -> tuple[float, float]:
    """(cluster start-up seconds, scores-stage seconds) for a fresh scores stage."""
    cfg = compose_cfg(store, ["stage=scores", *overrides])
    run = stages.Run(cfg, console)
    try:
        run.open_for_writing()
        if run.store.has_results(SCORES):  # start from an empty scores group each time
            run.store.remove(SCORES)
            run.store.remove(table_key(SCORES))
            run.store.forget_stage("scores")
        t0 = time.perf_counter()
        _ = run.client
        t1 = time.perf_counter()
        stages.stage_scores(run)
        t2 = time.perf_counter()
    finally:
        run.close()
    return t1 - t0, t2 - t1


def serial_loop(store: Path, overrides: list[str], console: Console) -> tuple[float, list[float]]:
    """The same planning calls in a plain loop in this process."""
    cfg = compose_cfg(store, ["stage=scores", *overrides])
    run = stages.Run(cfg, console)
    st = ScoreStore.open(store)
    specs = [json.loads(str(s)) for s in st.array("instances/spec")[...]]
    seeds = st.array("instances/seed")[...]
    theta = st.array("constraints/theta")[...]
    domain = run.domain
    per_call = []
    t0 = time.perf_counter()
    for spec, s in zip(specs, seeds, strict=True):
        inst = domain.check_instance(spec)
        for j, row in enumerate(theta):
            c0 = time.perf_counter()
            domain.plan(inst, row, seed=worker.entry_seed(cfg.seed, int(s), j))
            per_call.append(time.perf_counter() - c0)
    return time.perf_counter() - t0, per_call


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=48)
    ap.add_argument("--m", type=int, default=40)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--noop-n", type=int, default=2000)
    ap.add_argument("--noop-m", type=int, default=200)
    args = ap.parse_args()
    tmp, real, store, entries, console = planar_setup(args.n, args.m, "bench-pipeline-")
    # this machine's speed drifts by 20-30 % over minutes: interleave, take medians, and
    # compare within a round
    rows = []
    for _ in range(args.rounds):
        serial, per_call = serial_loop(store, real, console)
        start1, one = timed_scores(store, [*real, "cluster.n_workers=1"], console)
        start2, two = timed_scores(store, [*real, "cluster.n_workers=2"], console)
        rows.append((serial, one, start1, two, start2))
    serial, one, start1, two, start2 = (np.median(col) for col in zip(*rows, strict=True))
    over = np.median([r[1] / r[0] - 1 for r in rows]) * 100
    over_start = np.median([(r[1] + r[2]) / r[0] - 1 for r in rows]) * 100
    speed = np.median([r[1] / r[3] for r in rows])
    print(f"planar scores stage, {entries} planning calls (median call "
          f"{np.median(per_call) * 1e3:.2f} ms), medians of {args.rounds} interleaved rounds")
    print(f"  serial loop, one process   {serial:7.2f} s")
    print(f"  pipeline, 1 worker         {one:7.2f} s  overhead {over:+.1f} % "
          f"(with the {start1:.2f} s cluster start: {over_start:+.1f} %)")
    print(f"  pipeline, 2 workers        {two:7.2f} s  speed-up over 1 worker {speed:.2f}x")
    print("  per round (serial, 1 worker, 2 workers): " + "; ".join(
        f"{r[0]:.1f} {r[1]:.1f} {r[3]:.1f}" for r in rows))

    # the raw stage (which gives the constraints) still plans: keep it cheap here
    noop = [f"instances.n={args.noop_n}", f"constraints.m={args.noop_m}",
            "store.block_instances=250", "store.block_constraints=100",
            "planner.max_checks=3000", "domain.raw_max_tries=2", "planner=noop"]
    noop_store = tmp / "noop.zarr"
    prepared(noop_store, noop, console)
    n_noop = args.noop_n * ScoreStore.open(noop_store).stage_info("constraints")["m"]
    rates = [n_noop / timed_scores(noop_store, [*noop, "cluster.n_workers=2"], console)[1]
             for _ in range(args.rounds)]
    print(f"no-op planner, {n_noop} entries, 2 workers: {np.median(rates):,.0f} entries/s "
          f"(median of {args.rounds})")


if __name__ == "__main__":
    main()
