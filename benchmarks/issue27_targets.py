"""Issue 27's targets side by side, in one run: the benchmarks that measure them, one after
another on this machine (each measures on one core, as the issue asks), then every line in
which one of them says whether its target is met or whether the fast path's answers are
identical to ``exact``'s, together, with each benchmark's wall time.

The benchmarks and the settings the issue names:

* ``bench_paper_scale.py``: CPU time per entry of each domain × planner, projected to the
  paper's sizes on 2 cores (the three RRT-Connect stores within an hour).
* ``bench_pick_place.py --raw 400 --instances 3 --constraints 300``: pick_place at 300
  constraints per instance (≤ 4 ms per entry; every entry identical to ``exact``'s).
* ``bench_ik.py``: grasp_arm with ``domain.ik=analytic`` against ``damped`` (≤ 1 ms per
  entry, ≥ 2× cheaper), and both against the code when the issue was filed (its "as filed"
  line).
* ``bench_trajopt.py``: TrajOpt against RRT-Connect on the same entries (≤ 3×).
* ``bench_loocv_paper.py``: leave-one-out at 1500 × 1000, k = m, the default selectors
  (≤ 60 s and ≤ 4 GiB on 2 cores).

The two remaining targets are whole commands, timed as a user runs them: the README's main
job (``/usr/bin/time python -m pipeline stage=all``, ≤ 4 minutes) and the test suite
(``bash .ci/run``, under 10 minutes).  About 10 minutes on the 2-core machine; nothing
else should run meanwhile.

Run: python benchmarks/issue27_targets.py
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

#: (script, its arguments): no baseline revisions, which the targets do not need
RUNS = (
    ("bench_paper_scale.py", ()),
    ("bench_pick_place.py", ("--raw", "400", "--instances", "3", "--constraints", "300",
                             "--baseline-rev", "")),
    ("bench_ik.py", ("--wrist-instances", "0")),
    ("bench_trajopt.py", ("--baseline-rev", "")),
    ("bench_loocv_paper.py", ("--no-baseline",)),
)


def run(script: str, args) -> tuple[list[str], float, int]:
    """Run one benchmark, its output shown as it comes; (its lines that name a target, an
    agreement or the state as filed, wall seconds, exit code)."""
    print(f"\n== {script} {' '.join(a or repr(a) for a in args)}", flush=True)
    t0 = time.perf_counter()
    found = []
    with subprocess.Popen([sys.executable, str(HERE / script), *args], cwd=HERE.parent,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) as child:
        for line in child.stdout:
            print(line, end="", flush=True)
            if any(word in line for word in ("target", "identical", "as filed")):
                found.append(line.strip())
    return found, time.perf_counter() - t0, child.returncode


def main() -> None:
    argparse.ArgumentParser(description="Issue 27's targets side by side (no options: the "
                            "settings are the issue's, RUNS)").parse_args()
    summary = [(script, *run(script, args)) for script, args in RUNS]
    print("\nissue 27's targets, this run:")
    for script, lines, seconds, code in summary:
        state = "" if code == 0 else f", exit code {code}"
        print(f"  {script} ({seconds / 60:.1f} min{state})")
        for line in lines or ["(no target line printed)"]:
            print(f"    {line}")
    if any(code for *_, code in summary):
        sys.exit(1)


if __name__ == "__main__":
    main()
