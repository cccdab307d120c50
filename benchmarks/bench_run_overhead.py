"""What a small ``python -m pipeline`` run costs beyond its planning: this checkout against
another revision, side by side.

The test suite starts a few hundred such runs (each with a LocalCluster of two workers),
and a user's quick run is one: start-up (imports, Hydra, the cluster, the workers' imports)
weighs more there than the planning. Each variant runs the same command into a new store,
alternating, ``--repeats`` times: a 3-instance planar run (3 × 1 entries: nearly all
start-up) and the tests' small planar run (24 × 15 entries in 4 × 3 blocks, as
tests/pipeline_runs.py runs it). Measured: wall time, and the CPU time of the whole machine
while the run lasted (from /proc/stat: the coordinator, its workers and any server they
start, which a child's rusage would miss), so run it on an otherwise idle machine.

Run: python benchmarks/bench_run_overhead.py [--repeats 5] [--baseline-rev f4e195f]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from child_runs import export_revision  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

#: the code before forked local workers and box_core's lazy scipy imports (2026-11-24)
BASELINE_REV = "f4e195f"

SMALL = ("domain=planar", "progress=false", "cluster.n_workers=2", "planner.max_checks=4000",
         "cluster.dashboard_address=null", "stage=generate")
RUNS = {
    "3 x 1 entries": ("instances.n=3", "constraints.m=1", "store.block_instances=3",
                      "store.block_constraints=1"),
    "24 x 15 entries": ("instances.n=24", "constraints.m=15", "store.block_instances=6",
                        "store.block_constraints=5"),
}


def busy_seconds() -> float:
    """CPU-seconds the whole machine has spent outside idle and I/O wait since boot."""
    fields = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return (sum(fields) - fields[3] - fields[4]) / os.sysconf("SC_CLK_TCK")


def measure(root: Path, overrides: tuple[str, ...], store: Path) -> tuple[float, float]:
    """(wall s, machine CPU-s) of one run of the code under ``root``."""
    env = dict(os.environ, PYTHONPATH=str(root))
    cpu, start = busy_seconds(), time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "pipeline", *SMALL, *overrides,
                           f"store.path={store}"], cwd=store.parent, env=env,
                          capture_output=True, text=True)
    wall, cpu = time.perf_counter() - start, busy_seconds() - cpu
    if done.returncode:
        raise RuntimeError(f"{root}: {done.stderr[-3000:]}")
    return wall, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--baseline-rev", default=BASELINE_REV)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="run-overhead-") as tmp:
        variants = {"this checkout": ROOT}
        base = export_revision(args.baseline_rev, Path(tmp) / "base",
                               parts=("pipeline", "conf", "box_core"))
        if base is not None:
            variants[args.baseline_rev] = base
        for label, root in variants.items():  # warm-up: numba's cache, the OS's file cache
            measure(root, RUNS["3 x 1 entries"], Path(tmp) / f"warm-{len(label)}.zarr")
        print(f"{'run':18s} {'variant':14s} {'wall s':>8s} {'CPU-s':>8s}   (medians of "
              f"{args.repeats})")
        for r, (name, overrides) in enumerate(RUNS.items()):
            found = {label: [] for label in variants}
            for k in range(args.repeats):
                for i, (label, root) in enumerate(variants.items()):
                    found[label].append(measure(root, overrides, Path(tmp) / f"s{r}-{k}-{i}.zarr"))
            medians = {label: (statistics.median(w for w, _ in v),
                               statistics.median(c for _, c in v)) for label, v in found.items()}
            for label, (wall, cpu) in medians.items():
                print(f"{name:18s} {label:14s} {wall:8.2f} {cpu:8.2f}")
            if len(medians) == 2:
                (w1, c1), (w0, c0) = medians.values()
                print(f"{name:18s} {'ratio':14s} {w0 / w1:7.2f}x {c0 / c1:7.2f}x  "
                      f"(baseline / this checkout)")


if __name__ == "__main__":
    main()
