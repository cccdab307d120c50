"""Throughput of 2 workers of an existing scheduler (cluster=address: a ``dask scheduler``
and 2 ``dask worker`` processes on 127.0.0.1, tuned by the run's plugin) against a
LocalCluster of 2 workers, on the same planar scores stage.

Prints entries/s of each (medians of interleaved rounds; cluster start-up not timed) and
their ratio.  The address workers are warmed up once first (the tuning plugin restarts
them the first time a run registers it).

Run: python benchmarks/bench_cluster.py [--n 48 --m 40 --rounds 3]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_pipeline import planar_setup, timed_scores  # noqa: E402

DASK = Path(sys.executable).parent / "dask"


def start_address_cluster(folder: Path, workers: int) -> tuple[str, list[subprocess.Popen]]:
    file = folder / "scheduler.json"
    procs = [subprocess.Popen([str(DASK), "scheduler", "--host", "127.0.0.1", "--port", "0",
                               "--dashboard-address", "127.0.0.1:0", "--scheduler-file",
                               str(file)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    while not file.exists() or not file.read_text().strip():
        time.sleep(0.1)
    address = json.loads(file.read_text())["address"]
    procs += [subprocess.Popen([str(DASK), "worker", address, "--host", "127.0.0.1",
                                "--nthreads", "1", "--no-dashboard"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
              for _ in range(workers)]
    return address, procs


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=48)
    ap.add_argument("--m", type=int, default=40)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    tmp, real, store, entries, console = planar_setup(args.n, args.m, "bench-cluster-")
    address, procs = start_address_cluster(tmp, 2)
    try:
        local = [*real, "cluster.n_workers=2"]
        remote = [*real, "cluster=address", f"cluster.address={address}"]
        timed_scores(store, remote, console)  # warm-up: registers the tuning, restarts workers
        rows = []
        for _ in range(args.rounds):
            rows.append((entries / timed_scores(store, local, console)[1],
                         entries / timed_scores(store, remote, console)[1]))
    finally:
        for proc in reversed(procs):
            proc.terminate()
            proc.wait()
    local_rate, remote_rate = (np.median(col) for col in zip(*rows, strict=True))
    ratio = np.median([r[1] / r[0] for r in rows])
    print(f"planar scores stage, {entries} planning calls, medians of {args.rounds} "
          f"interleaved rounds")
    print(f"  LocalCluster, 2 workers        {local_rate:8.1f} entries/s")
    print(f"  address, 2 dask worker procs   {remote_rate:8.1f} entries/s  "
          f"ratio {ratio:.2f} (address / local)")
    print("  per round (local, address): " + "; ".join(f"{a:.1f} {b:.1f}" for a, b in rows))


if __name__ == "__main__":
    main()
