"""SLURM through dask-jobqueue: sizing, where logs go, and replacing lost jobs."""

from __future__ import annotations

import getpass
import math
import os
import subprocess
import sys
import time
from pathlib import Path

from dask.utils import format_bytes, parse_bytes

from pipeline.cluster.dashboard import no_dashboard
from pipeline.cluster.errors import ClusterError


def available_cores() -> int:
    """Cores this process may use: inside a SLURM allocation (sbatch, srun, Hydra's submitit
    launcher) the allocation's, else the CPU affinity mask's (cgroups, taskset); never the
    whole machine's ``os.cpu_count()`` when less was granted."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    for var in ("SLURM_CPUS_PER_TASK", "SLURM_CPUS_ON_NODE"):
        value = os.environ.get(var, "")
        if value.isdigit() and int(value) > 0:
            cores = min(cores, int(value)) if cores else int(value)
            break
    return cores or os.cpu_count() or 1


def run_output_dir() -> Path:
    """The run's Hydra output folder (outputs/<date>/<time>/ by default), else ./outputs."""
    try:
        from hydra.core.hydra_config import HydraConfig

        return Path(HydraConfig.get().runtime.output_dir)
    except (ImportError, ValueError):
        return Path.cwd() / "outputs"


def start_slurm_cluster(cfg, n_workers: int):
    """A dask-jobqueue SLURMCluster asking for ``n_workers`` single-threaded workers in jobs
    of ``cluster.slurm.cores`` processes.  Returns (cluster, jobs, log directory)."""
    try:
        from dask_jobqueue import SLURMCluster
    except ImportError:
        raise ClusterError('cluster=slurm needs dask-jobqueue: pip install -e ".[slurm]"') \
            from None
    s = cfg.slurm
    logs = Path(s.log_directory).expanduser() if s.log_directory else \
        run_output_dir() / "slurm-logs"
    logs = logs.absolute()
    logs.mkdir(parents=True, exist_ok=True)
    memory = format_bytes(parse_bytes(s.memory_per_worker) * s.cores)
    if s.interface:
        scheduler = {"interface": s.interface, "dashboard_address": cfg.dashboard_address}
    else:
        scheduler = {"host": cfg.host, "dashboard_address": cfg.dashboard_address,
                     **no_dashboard(cfg)}
    cluster = SLURMCluster(
        queue=s.queue, account=s.account, cores=s.cores, processes=s.cores, memory=memory,
        walltime=s.walltime, interface=s.interface, job_extra_directives=s.job_extra_directives,
        job_script_prologue=s.job_script_prologue, local_directory=s.local_directory,
        log_directory=str(logs), python=sys.executable, scheduler_options=scheduler)
    jobs = math.ceil(n_workers / s.cores)
    cluster.scale(jobs=jobs)
    return cluster, jobs, logs


class JobKeeper:
    """Keeps ``jobs`` SLURM jobs queued or running: a job that SLURM no longer lists
    (cancelled, timed out, node failure) is replaced, at most ``limit`` times per run.
    SLURM is asked (``squeue``) at most once per ``interval`` seconds."""

    def __init__(self, cluster, jobs: int, limit: int, say, interval: float = 5.0):
        self.cluster, self.jobs, self.limit, self.say = cluster, jobs, limit, say
        self.interval, self.last = interval, -float("inf")
        self.replaced = 0
        self.warned = False
        self.seen: dict[str, str] = {}  # worker name -> SLURM job id, of every job seen

    def _listed(self) -> set[str] | None:
        try:
            out = subprocess.run(["squeue", "-h", "-o", "%i", "-u", getpass.getuser(),
                                  "-t", "PD,CF,R,S"], capture_output=True, text=True,
                                 timeout=30, check=True).stdout
        except (OSError, subprocess.SubprocessError):
            return None  # squeue unavailable for now: try again at the next check
        return set(out.split())

    def replace_lost(self, force: bool = False) -> None:
        """Replace the jobs SLURM no longer lists.  ``force``: ask SLURM now (a worker has
        just left), not only once per ``interval``.  Jobs are remembered from the first time
        they are seen, because the cluster forgets a job whose worker left some seconds
        later, and the loss must still be found then."""
        self.seen.update({name: job.job_id for name, job in list(self.cluster.workers.items())
                          if getattr(job, "job_id", None)})
        if not force and time.monotonic() - self.last < self.interval:
            return
        self.last = time.monotonic()
        submitted = dict(self.seen)
        if not submitted:
            return
        listed = self._listed()
        if listed is None:
            return
        lost = sorted(name for name, job_id in submitted.items() if job_id not in listed)
        replaced = 0
        for name in lost:
            if self.replaced >= self.limit:
                if not self.warned:
                    self.say(f"[yellow]SLURM job {submitted[name]} ended early; not replaced "
                             f"(cluster.slurm.max_replacements={self.limit} reached)")
                    self.warned = True
                break
            self.cluster.worker_spec.pop(name, None)
            self.seen.pop(name, None)
            self.replaced += 1
            replaced += 1
            self.say(f"[yellow]SLURM job {submitted[name]} ended early; submitting a "
                     f"replacement ({self.replaced} of cluster.slurm.max_replacements="
                     f"{self.limit})")
        if replaced:
            self.cluster.scale(jobs=self.jobs)
