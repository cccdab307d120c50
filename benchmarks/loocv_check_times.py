"""Leave-one-out on a store with planning times rebuilt from counted collision checks.

    python benchmarks/loocv_check_times.py STORE [--fit-rows 100]

Wall-clock times in a store reflect the machine's load while it was computed (on a shared
machine the same entry can take 15x longer later in the run).  Collision checks are counted
and do not depend on load, so this fits time = a + b * checks + c * feasible on the first
``--fit-rows`` rows (computed first) and replays the leave-one-out with those times for
every entry.  Prints the fit, its R^2 on the fitted rows, and the summary table.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import zarr

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import box_core  # noqa: E402

SELECTORS = ("box", "eips", "static", "rand", "pembo", "oracle", "fastest")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store")
    parser.add_argument("--fit-rows", type=int, default=100)
    args = parser.parse_args()

    def read(key):
        return zarr.open_array(Path(args.store) / key, mode="r")[...]

    T, F = read("scores/time"), read("scores/feasible")
    checks, length = read("scores/checks").astype(np.float64), read("scores/length")
    rows = slice(0, args.fit_rows)
    A = np.column_stack([np.ones(checks[rows].size), checks[rows].ravel(), F[rows].ravel()])
    coef, *_ = np.linalg.lstsq(A, T[rows].ravel(), rcond=None)
    model = coef[0] + coef[1] * checks + coef[2] * F
    fitted = T[rows]
    r2 = 1 - ((model[rows] - fitted) ** 2).sum() / ((fitted - fitted.mean()) ** 2).sum()
    print(f"time = {coef[0] * 1e3:.3g} ms + {coef[1] * 1e6:.3g} us/check "
          f"{coef[2] * 1e3:+.3g} ms if feasible; R^2 = {r2:.3f} on rows 0-{args.fit_rows - 1}")
    scores = np.where(F, -np.nan_to_num(length), 0.0)
    res = box_core.loocv(scores, times=np.maximum(model, 1e-5), feasible=F,
                         selectors=SELECTORS, measure_overhead=False)
    print(res.summary())


if __name__ == "__main__":
    main()
