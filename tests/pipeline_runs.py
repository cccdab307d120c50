"""Helpers that run ``python -m pipeline`` the way a user does, on small planar stores."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import zarr

#: A small planar run: 4 x 3 blocks of 6 x 5 entries (24 x 15 = 360 planning calls).  No
#: dashboard: starting Bokeh's server costs a run about 0.6 s, and what the dashboard does is
#: tested on its own (tests/cluster/test_settings.py).
SMALL = ("domain=planar", "instances.n=24", "constraints.m=15", "store.block_instances=6",
         "store.block_constraints=5", "progress=false", "cluster.n_workers=2",
         "planner.max_checks=4000", "cluster.dashboard_address=null")


def command(store: Path, *overrides: str) -> list[str]:
    return [sys.executable, "-m", "pipeline", *SMALL, f"store.path={store}", *overrides]


def env() -> dict:
    # faulthandler: a child stopped by finish() prints every thread's stack
    return {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]),
            "PYTHONFAULTHANDLER": "1"}


def run(store: Path, *overrides: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(command(store, *overrides), capture_output=True, text=True,
                          cwd=cwd or store.parent, env=env(), timeout=600)


def start(store: Path, *overrides: str, cwd: Path | None = None) -> subprocess.Popen:
    """A run in the background, as a user's terminal would start it: Ctrl-C (SIGINT)
    interrupts it even when these tests run where SIGINT is ignored (a shell's background
    job), which the child would otherwise inherit."""
    return subprocess.Popen(command(store, *overrides), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, cwd=cwd or store.parent,
                            env=env(), start_new_session=True, preexec_fn=_default_sigint)


def finish(proc: subprocess.Popen, limit_s: float = 600) -> str:
    """The output of a run started by :func:`start`, once it exits.  A run that has not
    exited after ``limit_s`` (a hang, not slowness: the runs here take seconds) is stopped
    with SIGABRT, so its output ends with every thread's stack, and the test fails there."""
    try:
        return proc.communicate(timeout=limit_s)[0]
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGABRT)
        out = proc.communicate()[0]
        raise AssertionError(f"the run did not exit within {limit_s:g} s; its output and "
                             f"stacks:\n{out}") from None


def worker_processes(pid: int) -> list:
    """The Dask worker processes of the run ``pid``: the forks of its fork server
    (``pipeline.cluster.forked_workers``)."""
    import psutil

    return [p for p in psutil.Process(pid).children(recursive=True)
            if "forkserver" in " ".join(p.parent().cmdline())]


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def matrix(store: Path) -> dict[str, np.ndarray]:
    """The deterministic part of D (everything but times)."""
    g = zarr.open_group(store, mode="r", use_consolidated=False)
    return {name: g[f"scores/{name}"][...] for name in ("score", "feasible", "status", "checks",
                                                         "length", "step")}


def done_count(store: Path) -> int:
    try:
        return int(zarr.open_array(store / "scores" / "done", mode="r")[...].sum())
    except Exception:  # noqa: BLE001 (not created yet)
        return 0


def same_matrix(a: dict, b: dict) -> bool:
    return all(a[k].tobytes() == b[k].tobytes() for k in a)
