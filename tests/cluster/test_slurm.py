"""cluster=slurm end to end against a real single-node SLURM (scripts/provision_slurm.sh),
inside a private network namespace with loopback only."""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

import pytest

from tests import pipeline_runs as pr

ROOT = Path(__file__).resolve().parents[2]
NETNS = "boxslurm-test"
IN_NS = ["nsenter", f"--net=/run/netns/{NETNS}"]


@pytest.fixture(scope="module")
def slurm():
    """Provision (or reuse) SLURM; stopped after the module.  Skipped, with the script's
    reason, where this machine cannot provide it (not root, no packages, no namespaces)."""
    script = [str(ROOT / "scripts" / "provision_slurm.sh")]
    env = {**os.environ, "BOX_SLURM_NETNS": NETNS}
    if os.geteuid() != 0:
        pytest.skip("SLURM tests need root (scripts/provision_slurm.sh installs and starts "
                    "daemons)")
    res = subprocess.run(script, capture_output=True, text=True, env=env)
    if res.returncode != 0:
        reason = (res.stderr.strip().splitlines() or ["no reason given"])[-1]
        pytest.skip(f"scripts/provision_slurm.sh: {reason}")
    try:
        yield
    finally:
        subprocess.run([*script, "stop"], env=env, check=False)


def slurm_command(store: Path, *overrides: str) -> list[str]:
    return [*IN_NS, *pr.command(store, "cluster=slurm", "cluster.n_workers=2",
                                "cluster.slurm.memory_per_worker=1GB", *overrides)]


def start(store: Path, *overrides: str) -> subprocess.Popen:
    return subprocess.Popen(slurm_command(store, *overrides), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, cwd=store.parent, env=pr.env(),
                            start_new_session=True)


def our_jobs() -> list[str]:
    out = subprocess.run([*IN_NS, "squeue", "-h", "-o", "%i", "-t", "R"], capture_output=True,
                         text=True, check=True).stdout
    return out.split()


def wait_for_blocks(store: Path, proc: subprocess.Popen) -> int:
    while (done := pr.done_count(store)) < 1:
        assert proc.poll() is None, proc.stdout.read()
        time.sleep(0.1)
    return done


def test_slurm_run_with_a_cancelled_job(slurm, tmp_path, local_reference):
    store = tmp_path / "s.zarr"
    proc = start(store)
    try:
        assert wait_for_blocks(store, proc) < 24 * 15  # cancelled mid-run
        jobs = our_jobs()
        assert jobs
        subprocess.run([*IN_NS, "scancel", jobs[0]], check=True)
        out = proc.communicate()[0]
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, out
    assert "SLURM workers connected" in out and " 0 of 2 SLURM" not in out
    assert f"SLURM job {jobs[0]} ended early; submitting a replacement" in out
    assert "without the planning tuning" not in out  # the probe found every worker tuned
    assert pr.same_matrix(pr.matrix(store), local_reference)
    assert not list(tmp_path.glob("slurm-*.out"))  # logs go to the run's output folder
    assert list(tmp_path.glob("outputs/*/*/slurm-logs/*.err"))


def test_all_jobs_cancelled_watchdog_stops_the_run(slurm, tmp_path):
    store = tmp_path / "s.zarr"
    proc = start(store, "cluster.slurm.max_replacements=0", "cluster.worker_timeout=5")
    try:
        wait_for_blocks(store, proc)
        subprocess.run([*IN_NS, "scancel", *our_jobs()], check=True)
        out = proc.communicate()[0]
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1, out
    assert "not replaced (cluster.slurm.max_replacements=0 reached)" in out
    assert "no Dask worker connected for 5 s (cluster.worker_timeout)" in out
    assert "re-run the same command to resume" in out
    assert pr.done_count(store) > 0
