"""What a first run pays before it plans: numba compiling the collision kernels into an
empty cache, and importing the packages, for this checkout and another revision side by
side.

A run in a fresh checkout (the README's main job, CI) compiles the sphere pre-check's
kernels once; every process of later runs loads them from numba's cache in about 0.1 s.
Every process that imports ``box_core`` (the pipeline's coordinator, the ``box`` command)
pays its import time on every run.

Each measurement is a fresh interpreter with one thread (OMP/OpenBLAS/MKL/numba limited to
1): ``compile`` calls :func:`pipeline.sim.fast_check.compile_kernels` with
``NUMBA_CACHE_DIR`` pointing at a new, empty folder and counts the specializations numba
wrote; ``import box_core`` and ``import pipeline.stages`` are timed inside the child. The
variants alternate in every repeat. Printed: medians, and this checkout's ratio to the
baseline.

Run: python benchmarks/bench_cold_start.py [--repeats 3] [--baseline-rev 605e735]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from child_runs import ONE_THREAD, export_revision  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

#: the code before the compile-time work (issue 27, 2026-11-24)
BASELINE_REV = "605e735"

CHILD = {
    "compile": """
import os, time
from pipeline.sim import fast_check
t = time.perf_counter(); fast_check.compile_kernels(); s = time.perf_counter() - t
n = sum(f.endswith(".nbc") for _, _, fs in os.walk(os.environ["NUMBA_CACHE_DIR"]) for f in fs)
print(s, n)
""",
    "import box_core": "import time\nt = time.perf_counter(); import box_core\n"
                       "print(time.perf_counter() - t, 0)",
    "import pipeline.stages": "import time\nt = time.perf_counter(); import pipeline.stages\n"
                              "print(time.perf_counter() - t, 0)",
}


def measure(what: str, root: Path) -> tuple[float, int]:
    """(seconds, compiled specializations) of one fresh child running ``CHILD[what]``."""
    with tempfile.TemporaryDirectory(prefix="numba-cold-") as cache:
        env = dict(os.environ, **ONE_THREAD, PYTHONPATH=str(root), NUMBA_CACHE_DIR=cache)
        done = subprocess.run([sys.executable, "-c", CHILD[what]], cwd=root, env=env,
                              capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"{what} in {root}: {done.stderr[-2000:]}")
    seconds, count = done.stdout.split()[-2:]
    return float(seconds), int(count)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--baseline-rev", default=BASELINE_REV)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        roots = {"this checkout": ROOT}
        if args.baseline_rev:
            base = export_revision(args.baseline_rev, Path(tmp) / "base",
                                   ("pipeline", "conf", "box_core"))
            if base is not None:
                roots[f"baseline {args.baseline_rev}"] = base
        got = {(w, v): [] for w in CHILD for v in roots}
        counts = {}
        start = time.perf_counter()
        for r in range(args.repeats):
            for what in CHILD:
                for variant in (list(roots) if r % 2 == 0 else list(roots)[::-1]):
                    seconds, count = measure(what, roots[variant])
                    got[what, variant].append(seconds)
                    counts[what, variant] = count
    print(f"cold start, {args.repeats} repeats (median s), one thread, "
          f"{time.perf_counter() - start:.0f} s in all")
    names = list(roots)
    print(f"| | {' | '.join(names)} | ratio |")
    print(f"|---|{'---|' * len(names)}---|")
    for what in CHILD:
        med = [statistics.median(got[what, v]) for v in names]
        extra = (f" ({', '.join(str(counts[what, v]) for v in names)} specializations)"
                 if what == "compile" else "")
        ratio = f"{med[1] / med[0]:.2f}x faster" if len(med) > 1 else ""
        print(f"| {what}{extra} | {' | '.join(f'{m:.2f}' for m in med)} | {ratio} |")
    print(json.dumps({f"{w} / {v}": statistics.median(x) for (w, v), x in got.items()}))


if __name__ == "__main__":
    main()
