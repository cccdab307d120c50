"""The memory estimate behind ``python -m pipeline``'s config checks, against measurement.

    python benchmarks/bench_memory_estimate.py

For a few synthetic matrices shaped like the paper's (most entries infeasible), runs the
leave-one-out evaluation of the pipeline's selectors under tracemalloc (which sees NumPy's
allocations) and prints the measured peak beside
:func:`pipeline.validation.evaluation_bytes`.  The estimate should be at or above the
measurement (ratio >= 1) without being far above it: it refuses runs that cannot fit,
not runs that can.  Also prints the bootstrap intervals' cost on 1000 rows.
"""

from __future__ import annotations

import sys
import time
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

import box_core  # noqa: E402
from box_core.stats import mean_ci, paired_ratio  # noqa: E402
from box_core.synthetic import score_matrix  # noqa: E402
from pipeline.validation import evaluation_bytes  # noqa: E402

SELECTORS = ("box", "static", "rand", "doo", "pembo", "oracle")
SHAPES = ((200, 40), (500, 100), (1000, 162))


def measured_peak(n: int, m: int) -> int:
    data = score_matrix(n, m, useful=min(50, m), per_type=4, seed=0)
    tracemalloc.start()
    result = box_core.loocv(data.scores, times=data.times, feasible=data.feasible,
                            features=data.features, selectors=SELECTORS,
                            measure_overhead=False)
    result.summary()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak


def main() -> None:
    print(f"leave-one-out of {', '.join(SELECTORS)} (k = m): peak memory, MiB")
    print(f"{'n x m':>12} {'measured':>10} {'estimate':>10} {'estimate / measured':>20}")
    for n, m in SHAPES:
        peak = measured_peak(n, m)
        estimate = evaluation_bytes(n, m, len(SELECTORS))
        print(f"{n:>5} x {m:<5} {peak / 2**20:>10.1f} {estimate / 2**20:>10.1f} "
              f"{estimate / peak:>20.2f}")
    x = np.random.default_rng(0).lognormal(-3, 2, 1000)
    start = time.perf_counter()
    for _ in range(10):
        mean_ci(x)
        paired_ratio(x, x[::-1])
    print(f"bootstrap interval + paired ratio on 1000 rows: "
          f"{(time.perf_counter() - start) / 10 * 1e3:.1f} ms")


if __name__ == "__main__":
    main()
