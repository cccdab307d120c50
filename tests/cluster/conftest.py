"""Real Dask processes on 127.0.0.1: a ``dask scheduler`` and ``dask worker`` subprocesses,
started from this virtual environment and always stopped (killed if need be)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests import pipeline_runs as pr

DASK = Path(sys.executable).parent / "dask"


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def kill(proc: subprocess.Popen) -> None:
    """kill -9 a worker (nanny and worker process: its whole process group)."""
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


class DaskProcesses:
    """Starts a scheduler and workers in ``folder``; ``close`` stops every one."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.procs: list[subprocess.Popen] = []
        self.address: str | None = None

    def _spawn(self, args: list[str], env: dict | None = None) -> subprocess.Popen:
        log = open(self.folder / f"dask-{len(self.procs)}.log", "w")  # noqa: SIM115
        proc = subprocess.Popen([str(DASK), *args], stdout=log, stderr=subprocess.STDOUT,
                                cwd=self.folder, env=env or pr.env(), start_new_session=True)
        log.close()
        self.procs.append(proc)
        return proc

    def scheduler(self) -> str:
        file = self.folder / "scheduler.json"
        proc = self._spawn(["scheduler", "--host", "127.0.0.1", "--port", "0",
                            "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(file)])
        while not file.exists() or not file.read_text().strip():
            assert proc.poll() is None, (self.folder / "dask-0.log").read_text()
            time.sleep(0.1)
        self.address = json.loads(file.read_text())["address"]
        return self.address

    def worker(self, *args: str, env: dict | None = None) -> subprocess.Popen:
        return self._spawn(["worker", self.address, "--host", "127.0.0.1", "--nthreads", "1",
                            "--no-dashboard", *args], env=env)

    def wait_for_workers(self, n: int) -> None:
        from distributed import Client

        with Client(self.address, timeout="30s") as client:
            client.wait_for_workers(n)

    def close(self) -> None:
        for proc in reversed(self.procs):
            _stop(proc)


@pytest.fixture
def dask_procs(tmp_path):
    procs = DaskProcesses(tmp_path)
    try:
        yield procs
    finally:
        procs.close()


@pytest.fixture(scope="session")
def local_reference(made):
    """D of the small planar run on a LocalCluster: what every cluster must reproduce (the
    session's run of it, ``made``: D is the same whatever the stage that computed it)."""
    return pr.matrix(made[0])
