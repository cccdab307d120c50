"""What the per-variant benchmarks (bench_pick_place, bench_trajopt, bench_paper_scale)
share: each variant runs in its own process on one core, reports one JSON line, and saves
its result arrays so that variants can be compared entry by entry."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

#: one thread for every numeric library a child may load: CPU time per entry, one core
ONE_THREAD = {k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                               "NUMBA_NUM_THREADS")}


def run_child(script: str, job: dict, root: Path, label: str, profile: bool = False) -> dict:
    """``python script --child JSON`` with the code under ``root`` first on the path (this
    checkout, or another revision's copy); its last stdout line, parsed.  With ``profile``
    the child's cProfile table (printed to stderr) is shown."""
    env = dict(os.environ, **ONE_THREAD, PYTHONPATH=str(root))
    done = subprocess.run([sys.executable, script, "--child", json.dumps(job)], cwd=root,
                          env=env, capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"{label}: {done.stderr[-3000:]}")
    if profile:
        print(f"-- cProfile of {label} (top 25 by own time)\n" + done.stderr[-6000:])
    return json.loads(done.stdout.strip().splitlines()[-1])


def export_revision(rev: str, into: Path, parts=("pipeline", "conf")) -> Path | None:
    """The folders ``parts`` of git revision ``rev`` of this repository under ``into``
    (``git archive``), or None (said why) when git cannot give them."""
    root = Path(__file__).resolve().parents[1]
    try:
        archive = subprocess.run(["git", "-C", str(root), "archive", rev, *parts],
                                 capture_output=True, check=True).stdout
        into.mkdir(parents=True, exist_ok=True)
        subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    except (OSError, subprocess.CalledProcessError) as exc:
        print(f"(no baseline: git archive {rev} failed: {exc})")
        return None
    return into


def agreement(a: Path, b: Path, columns) -> np.ndarray:
    """(entries,) whether every one of ``columns`` of two saved variants agrees bit for bit
    (NaN where both are NaN, as failures' lengths are)."""
    return columns_agree(np.load(a), np.load(b), columns)


def columns_agree(x, y, columns, rtol: float = 0.0, atol: float = 0.0) -> np.ndarray:
    """Per entry, whether every one of ``columns`` of the result arrays ``x`` and ``y``
    (mappings of name to array) agrees: equal, floats within ``rtol``/``atol`` (both 0:
    bit for bit; NaN where both are NaN)."""
    agree = np.ones(np.shape(x["status"]), dtype=bool)
    for k in columns:
        u, v = np.asarray(x[k]), np.asarray(y[k])
        agree &= (np.isclose(u, v, rtol=rtol, atol=atol, equal_nan=True)
                  if u.dtype.kind == "f" else u == v)
    return agree
