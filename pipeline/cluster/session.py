"""Connecting to (or starting) the cluster of a run: local, an existing scheduler, SLURM."""

from __future__ import annotations

import atexit
import contextlib
from collections.abc import Iterator, Sequence

import cloudpickle
from distributed import Client

from pipeline.cluster import worker_side
from pipeline.cluster.checks import check_config
from pipeline.cluster.dashboard import no_dashboard
from pipeline.cluster.errors import ClusterError, ClusterFailed
from pipeline.cluster.forked_workers import use_forked_workers
from pipeline.cluster.slurm import JobKeeper, available_cores, start_slurm_cluster
from pipeline.cluster.watchdog import Watchdog
from pipeline.configs import ClusterKind

#: Plugin name on the scheduler: registering it twice is a no-op (WorkerTuning.idempotent).
TUNING_PLUGIN = "box-planning-worker-tuning"


class ClusterClient(Client):
    """A distributed Client that carries the run's ``watchdog`` (used by ``run_tasks``)."""

    watchdog: Watchdog | None = None


def tune_workers() -> None:
    """Set worker_side's tuning in this process's dask config, before it starts a
    LocalCluster: its nannies (in this process) then start tuned workers directly."""
    import dask

    environ = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}))
    for key in worker_side.UNSET_ENV:
        environ.pop(key, None)
    dask.config.set({"distributed.nanny.pre-spawn-environ": environ, **worker_side.TUNED_CONFIG})


def _start(cfg, say, preload: Sequence[str]):
    """(cluster or None, client, keeper or None, hint for the watchdog's message)."""
    if cfg.kind is ClusterKind.local:
        from distributed import LocalCluster

        tune_workers()
        use_forked_workers(preload)
        cluster = LocalCluster(n_workers=cfg.n_workers or available_cores(),
                               threads_per_worker=1, processes=True, host=cfg.host,
                               dashboard_address=cfg.dashboard_address,
                               scheduler_kwargs=no_dashboard(cfg))
        return cluster, ClusterClient(cluster), None, ""
    if cfg.kind is ClusterKind.address:
        try:
            client = ClusterClient(cfg.address, timeout=f"{cfg.connect_timeout}s")
        except (OSError, ValueError) as exc:  # TimeoutError is an OSError
            reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise ClusterError(f"cluster.address={cfg.address}: no Dask scheduler answered "
                               f"within {cfg.connect_timeout:g} s ({reason})") from None
        return None, client, None, f"; check that workers run for {cfg.address}"
    cluster, jobs, logs = start_slurm_cluster(cfg, cfg.n_workers or 1)
    hint = (f"; see squeue and the job logs in {logs}"
            + ("" if cfg.slurm.interface else
               "; workers on other nodes need cluster.slurm.interface (e.g. ib0)"))
    keeper = JobKeeper(cluster, jobs, cfg.slurm.max_replacements, say)
    try:
        client = ClusterClient(cluster)
    except Exception:
        cluster.close()
        raise
    return cluster, client, keeper, hint


def _describe(cfg, client, n: int) -> str:
    where = client.scheduler.address
    port = client.scheduler_info().get("services", {}).get("dashboard")
    board = ""
    if port and cfg.kind is not ClusterKind.address and cfg.dashboard_address:
        host = cfg.dashboard_address.rsplit(":", 1)[0]
        if host in ("", "0.0.0.0", "[::]"):
            host = where.split("://")[-1].rsplit(":", 1)[0]
        board = f"; dashboard http://{host}:{port}/status"
    if cfg.kind is ClusterKind.slurm:
        return (f"{n} of {cfg.n_workers or 1} SLURM workers connected (the rest join as their "
                f"jobs start) at {where}{board}")
    return f"{n} worker{'' if n == 1 else 's'} at {where}{board}"


#: cluster.reuse: the clients kept open for the next run in this process, by settings.
_KEPT: dict[str, ClusterClient] = {}


@contextlib.contextmanager
def connect(cfg, console, preload: Sequence[str] = ()) -> Iterator[ClusterClient]:
    """The run's client, connected (or its cluster started) and checked: at least one
    worker, every worker able to import this package at the same version, workers tuned.
    Raises ClusterError (bad settings, no scheduler: nothing was written) or ClusterFailed.
    Closed on exit, unless ``cluster.reuse`` keeps it for the next run in this process.
    ``preload``: modules a LocalCluster's workers import before they start
    (:mod:`pipeline.cluster.forked_workers`)."""

    def say(text: str) -> None:
        console.print(text, highlight=False)

    check_config(cfg)
    key = repr(cfg)
    client = _KEPT.get(key)
    if client is not None and client.status == "running":
        client.watchdog.say = say  # this run's console
        if client.watchdog.keeper is not None:
            client.watchdog.keeper.say = say
        client.watchdog.check(force=True)
        say(f"dask: reusing {_describe(cfg, client, len(client.watchdog.known))}")
        yield client
        return
    cluster, client, keeper, hint = _start(cfg, say, preload)
    try:
        cloudpickle.register_pickle_by_value(worker_side)  # for workers without this package
        _quiet_workers(client)  # first: workers the tuning restarts then rejoin with it
        if cfg.kind is not ClusterKind.local:
            client.register_plugin(worker_side.WorkerTuning(), name=TUNING_PLUGIN)
        client.watchdog = Watchdog(client, timeout=cfg.worker_timeout, say=say, keeper=keeper,
                                   digest=worker_side.code_digest(), hint=hint)
        n = client.watchdog.wait_for_first()
        say(f"dask: {_describe(cfg, client, n)}")
    except ClusterFailed as exc:  # before any work: nothing to resume
        _close(client, cluster)
        raise ClusterFailed(exc.cause, resumable=False) from None
    except BaseException:
        _close(client, cluster)
        raise
    if cfg.reuse:
        _KEPT[key] = client
        atexit.register(_close, client, cluster)
        yield client
        return
    try:
        yield client
    finally:
        _close(client, cluster)


def _quiet_workers(client) -> None:
    """Registers worker_side.QuietClose.  The scheduler keeps a worker plugin before it sends
    it to the workers, and a worker that joins or restarts later gets it from there; so a
    worker leaving or restarting meanwhile (another run's WorkerTuning on a shared
    scheduler), which makes the sending fail, is no reason to stop this run."""
    with contextlib.suppress(OSError):  # distributed's CommClosedError is an OSError
        client.register_plugin(worker_side.QuietClose())


def _close(client, cluster) -> None:
    client.close()
    if cluster is not None:
        cluster.close()
