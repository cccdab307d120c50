"""What box_core's bootstrap intervals cost, on the sizes the pipeline meets.

    python benchmarks/bench_intervals.py [--repeats 5]

Times (median over repeats, milliseconds):

1. ``mean_ci`` of 1000 heavy-tailed times (the interval of one selector's mean time);
2. ``paired_ratio`` of two such columns (one selector's ratio to BOX, with its interval);
3. ``mean_ci_columns`` of a 1000 x 200 array (the band of a best-score-versus-time curve);
4. ``Summary`` of a leave-one-out result on a synthetic 1000 x 162 matrix with six
   selectors (what ``stage=evaluate`` and the tests compute), the LOOCV itself excluded.

No thresholds are asserted: machines are noisy, and the figures are for a person to compare.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import box_core  # noqa: E402
from box_core.stats import mean_ci, mean_ci_columns, paired_ratio  # noqa: E402
from box_core.synthetic import score_matrix  # noqa: E402


def median_ms(fn, repeats: int) -> float:
    fn()  # warm up (imports, caches)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    repeats = parser.parse_args().repeats
    rng = np.random.default_rng(0)
    x = rng.lognormal(-3, 2, 1000)
    y = x * rng.lognormal(0.3, 0.5, 1000)
    curve = rng.normal(size=(1000, 200)).cumsum(axis=1)
    data = score_matrix(1000, 162, useful=50, per_type=4, seed=0)
    result = box_core.loocv(data.scores, times=data.times, feasible=data.feasible,
                            features=data.features,
                            selectors=("box", "eips", "static", "rand", "doo", "oracle"),
                            measure_overhead=False)
    rows = [
        ("mean_ci, 1000 rows", lambda: mean_ci(x)),
        ("paired_ratio, 1000 rows", lambda: paired_ratio(y, x)),
        ("mean_ci_columns, 1000 x 200", lambda: mean_ci_columns(curve)),
        ("Summary of a 1000 x 162 LOOCV, 6 selectors", result.summary),
    ]
    print(f"median of {repeats} runs")
    for name, fn in rows:
        print(f"{name:<45} {median_ms(fn, repeats):>9.1f} ms")


if __name__ == "__main__":
    main()
