"""Replaying stored entries (``tests/data/replay.json``) from their seeds, in this process or
in a child process with other CPU code paths forced, and comparing under the
reproducibility contract (``pipeline/environment.py``, docs/reproducibility.md).

``python -m tests.replay OUT.json`` replays every stored entry and raw solution and writes
what it got; ``code_paths()`` names the environments that make NumPy and OpenBLAS take
other kernels on this machine, as another CPU would.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from pipeline.environment import agree

DATA = Path(__file__).parent / "data" / "replay.json"
ROOT = Path(__file__).resolve().parents[1]
#: Environment variables a child must not inherit: thread counts and code paths set by
#: whatever ran before in this process (a Dask nanny copies OPENBLAS_NUM_THREADS=1 into
#: its parent's environment), so that each child runs exactly as asked.
INHERITED_SETTINGS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                      "OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES", "NPY_ENABLE_CPU_FEATURES")


def stored() -> dict:
    return json.loads(DATA.read_text())


def domain_of(store: dict):
    """The store's domain and planner, with the values of keys added since it was recorded
    that it was computed with (``domain.contacts=cached``); the wall-clock safety net out of
    reach, so that a loaded machine cannot turn a stored entry into "timeout"."""
    from pipeline.configs import with_earlier_values
    from pipeline.domains import load_domain

    recorded = with_earlier_values({"domain": store["domain"]})["domain"]
    config = {k: v for k, v in recorded.items() if k != "name"}
    planner = {**store["planner"], "wall_cap_s": 1e6}
    return load_domain(store["domain"]["name"], planner=planner, **config)


def _number(x: float) -> float | None:
    return None if math.isnan(x) else float(x)


def _step(domain, result) -> int:
    return domain.steps.index(result.step) if result.step else -1


def replay_store(store: dict) -> dict:
    """What the current code gives for the store's stored entries and raw solutions."""
    domain = domain_of(store)
    theta = np.asarray(store["theta"], float)
    entries = []
    for e in store["entries"]:
        got = domain.plan(store["instances"][e["instance"]], theta[e["constraint"]],
                          seed=e["seed"])
        entries.append({"status": int(got.status), "feasible": bool(got.feasible),
                        "score": _number(got.score), "step": _step(domain, got),
                        "checks": int(got.checks)})
    raws = []
    for r in store["raw"]:
        got = domain.raw_plan(store["instances"][r["instance"]], seed=r["seed"])
        raws.append({"status": int(got.plan.status), "score": _number(got.plan.score),
                     "step": _step(domain, got.plan), "checks": int(got.plan.checks),
                     "constraint": [_number(v) for v in got.constraint]})
    return {"entries": entries, "raw": raws}


DISCRETE = {"entries": ("status", "feasible", "step", "checks"),
            "raw": ("status", "step", "checks")}
FLOATS = {"entries": ("score",), "raw": ("score", "constraint")}


def _float(value):
    return np.nan if value is None else np.asarray(
        [np.nan if v is None else v for v in value] if isinstance(value, list) else value,
        dtype=float)


def compare(expected: dict, got: dict) -> list[str]:
    """Breaches of the contract between two replays of one store (``[]``: none): discrete
    outcomes must be equal, floats within RTOL/ATOL."""
    problems = []
    for kind in ("entries", "raw"):
        for k, (a, b) in enumerate(zip(expected[kind], got[kind], strict=True)):
            where = f"{kind}[{k}]"
            problems += [f"{where}.{f}: {a[f]} != {b[f]}" for f in DISCRETE[kind]
                         if a[f] != b[f]]
            problems += [f"{where}.{f}: {a[f]} vs {b[f]}" for f in FLOATS[kind]
                         if not agree(_float(a[f]), _float(b[f]))]
    return problems


def largest_difference(expected: dict, got: dict) -> float:
    """The largest relative difference of any float (scores, constraint features)."""
    worst = 0.0
    for kind in ("entries", "raw"):
        for a, b in zip(expected[kind], got[kind], strict=True):
            for f in FLOATS[kind]:
                x, y = np.atleast_1d(_float(a[f])), np.atleast_1d(_float(b[f]))
                both = np.isfinite(x) & np.isfinite(y)
                if both.any():
                    rel = np.abs(x[both] - y[both]) / np.maximum(np.abs(x[both]), 1e-300)
                    worst = max(worst, float(rel.max()))
    return worst


def code_paths() -> dict[str, dict[str, str]]:
    """Environments that make this machine compute as an older CPU would: NumPy without
    its dispatched SIMD kernels, OpenBLAS with an older core's kernels, and both; plus BLAS
    with one thread and with two (a Dask worker and a notebook).  Empty entries are left
    out (nothing to disable on this machine)."""
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__

    from pipeline.environment import fingerprint

    simd = " ".join(f for f in __cpu_dispatch__ if __cpu_features__.get(f))
    import platform

    older_core = {"x86_64": "Prescott", "AMD64": "Prescott", "aarch64": "ARMV8",
                  "arm64": "ARMV8"}.get(platform.machine())
    if older_core and any(older_core.lower() in b.lower() for b in fingerprint()["blas"]):
        older_core = None  # this machine's BLAS runs that core's kernels already
    paths = {"blas-1-thread": {"OPENBLAS_NUM_THREADS": "1"},
             "blas-2-threads": {"OPENBLAS_NUM_THREADS": "2"}}
    if simd:
        paths["numpy-baseline-simd"] = {"NPY_DISABLE_CPU_FEATURES": simd}
    if older_core:
        paths[f"openblas-{older_core.lower()}"] = {"OPENBLAS_CORETYPE": older_core}
    if simd and older_core:
        paths["both"] = {"NPY_DISABLE_CPU_FEATURES": simd, "OPENBLAS_CORETYPE": older_core}
    return paths


def child_env(extra: dict[str, str]) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in INHERITED_SETTINGS}
    return {**env, "PYTHONPATH": str(ROOT), **extra}


def replay_in_child(extra: dict[str, str], out: Path) -> dict:
    """Replay every stored store in a child process with ``extra`` set; its fingerprint too."""
    subprocess.run([sys.executable, "-m", "tests.replay", str(out)], cwd=ROOT,
                   env=child_env(extra), check=True, capture_output=True, text=True,
                   timeout=1200)
    return json.loads(out.read_text())


def main(out: str) -> None:
    from pipeline.environment import fingerprint

    Path(out).write_text(json.dumps({"environment": fingerprint(),
                                     "stores": [replay_store(s) for s in stored()["stores"]]}))


if __name__ == "__main__":
    main(sys.argv[1])
