"""The environment that computes a block, and the reproducibility contract
(docs/reproducibility.md).

What a planning call returns depends on its inputs and, in the last bits of its floats, on
where it ran: NumPy and OpenBLAS pick SIMD kernels by CPU (AVX-512, AVX2, FMA...), glibc's
libm picks FMA variants, and another release of a library may round differently.  So:

* **exact everywhere**: status, feasibility, failed step, collision checks, the chosen
  constraint: every discrete outcome;
* **within tolerance across environments** (:data:`RTOL`, :data:`ATOL`): scores, lengths,
  paths and extracted constraints;
* **bitwise within one environment**: everything but the measured times.

A store records, for each block, which environment computed it (:func:`fingerprint`, an
entry of the root attribute ``environments``), so a store resumed elsewhere, or computed by
workers on several kinds of machine, says so.
"""

from __future__ import annotations

import functools
import platform
import sys
from importlib import metadata
from pathlib import Path

import numpy as np

#: Relative tolerance of floats between environments.  Measured by tests/data/make_replay.py
#: (its figures are kept in tests/data/replay.json): at most 2.5e-9 relative with OpenBLAS
#: forced to its oldest x86-64 kernels (Prescott) on one machine, 2.7e-10 between two real
#: machines (an Intel development machine and an AMD EPYC); discrete outcomes identical in
#: both.  1e-8 leaves a margin of 4x over the worst case seen and is still far below any
#: real change (another path or IK solution moves a score by 1e-4 or more).
RTOL = 1e-8
#: Absolute tolerance, for values near zero (joint angles of a path, constraint features).
ATOL = 1e-8

#: Distributions whose code computes D (their version is part of the environment).
PACKAGES = ("box-planning", "numpy", "scipy", "pybullet", "ompl")


def agree(a, b) -> bool:
    """Whether floats (scalars or arrays, NaN equal to NaN) agree within the contract."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return a.shape == b.shape and bool(np.allclose(a, b, rtol=RTOL, atol=ATOL,
                                                   equal_nan=True))


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith(("model name", "hardware", "cpu model")):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _simd() -> str:
    """The SIMD extensions NumPy dispatches to here (NPY_DISABLE_CPU_FEATURES removes some)."""
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__

    return " ".join(f for f in __cpu_dispatch__ if __cpu_features__.get(f))


def _blas() -> list[str]:
    """Each BLAS library loaded (NumPy's, SciPy's): implementation, version and the kernel
    family it chose for this CPU (OPENBLAS_CORETYPE overrides it)."""
    import scipy.linalg  # noqa: F401 (loads SciPy's BLAS, which the planners use)
    from threadpoolctl import threadpool_info

    return sorted({f"{i.get('internal_api')} {i.get('version')} {i.get('architecture', '')}"
                   .strip() for i in threadpool_info() if i.get("user_api") == "blas"})


@functools.cache
def _fingerprint() -> tuple:
    from pipeline.cluster.worker_side import code_digest

    versions = {}
    for dist in PACKAGES:
        try:
            versions[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            versions[dist] = "not installed"
    libc = " ".join(platform.libc_ver()).strip() or "unknown"
    record = {"python": platform.python_version(), "implementation": sys.implementation.name,
              "platform": f"{platform.system()} {platform.machine()} {libc}",
              "cpu": _cpu_model(), "simd": _simd(), "blas": _blas(), "packages": versions,
              "source": code_digest() or "unknown"}
    return tuple(record.items())


def fingerprint() -> dict:
    """This process's environment as the store records it (computed once per process): what
    can change the last bits of D, and nothing that cannot (no host name, no thread
    counts: TrajOpt runs its BLAS with one thread everywhere)."""
    return dict(_fingerprint())


def difference(old: dict, new: dict) -> str:
    """What differs between two fingerprints, in words (``cpu A -> B; numpy 2.3 -> 2.4``)."""
    parts = []
    for key in sorted(old.keys() | new.keys()):
        a, b = old.get(key), new.get(key)
        if a == b:
            continue
        if isinstance(a, dict) and isinstance(b, dict):
            parts += [f"{k} {a.get(k)} -> {b.get(k)}" for k in sorted(a.keys() | b.keys())
                      if a.get(k) != b.get(k)]
        elif isinstance(a, list) or isinstance(b, list):
            parts.append(f"{key} {', '.join(a or []) or 'none'} -> "
                         f"{', '.join(b or []) or 'none'}")
        else:
            parts.append(f"{key} {a or 'none'} -> {b or 'none'}")
    return "; ".join(parts)


def describe(record: dict) -> str:
    """One line: CPU, SIMD level, BLAS kernels, key versions, source digest."""
    simd = (record.get("simd") or "").split()
    packages = record.get("packages") or {}
    return (f"{record.get('cpu', '?')} ({simd[-1] if simd else 'no SIMD'}; BLAS "
            f"{', '.join(b.split()[-1] for b in record.get('blas') or []) or '?'}), python "
            f"{record.get('python', '?')}, numpy {packages.get('numpy', '?')}, pybullet "
            f"{packages.get('pybullet', '?')}, ompl {packages.get('ompl', '?')}, source "
            f"{record.get('source', '?')}")
