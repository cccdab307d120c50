"""Checks before any work: the cluster keys, and each worker that connects."""

from __future__ import annotations

from pipeline.cluster.errors import ClusterError, ClusterFailed
from pipeline.configs import ClusterKind


def connect_first(cfg) -> bool:
    """Check the ``cluster.*`` keys (ClusterError) and say whether the run should connect
    before it touches the store: yes for a scheduler elsewhere (address, SLURM), which can
    be unreachable or missing; a LocalCluster cannot be, so it starts only when a block
    needs computing (a finished store starts no cluster)."""
    check_config(cfg)
    return cfg.kind is not ClusterKind.local


def check_config(cfg) -> None:
    """Refuse bad ``cluster.*`` values with one line naming the key (ClusterError, exit 2)."""
    if cfg.n_workers is not None and cfg.n_workers < 1:
        raise ClusterError(f"cluster.n_workers must be >= 1 (or null), got {cfg.n_workers}")
    if cfg.retries < 0:
        raise ClusterError(f"cluster.retries must be >= 0, got {cfg.retries}")
    for key in ("connect_timeout", "worker_timeout"):
        if not getattr(cfg, key) > 0:
            raise ClusterError(f"cluster.{key} must be > 0 seconds, got {getattr(cfg, key)}")
    if not cfg.host:
        raise ClusterError("cluster.host must name an address to listen on (e.g. 127.0.0.1)")
    if cfg.dashboard_address is not None and ":" not in cfg.dashboard_address:
        raise ClusterError(f"cluster.dashboard_address must be host:port (port 0: any free "
                           f"one), got {cfg.dashboard_address!r}")
    if cfg.kind is ClusterKind.address and not cfg.address:
        raise ClusterError("cluster=address needs cluster.address=tcp://host:port")
    if cfg.kind is ClusterKind.slurm:
        s = cfg.slurm
        if s.cores < 1:
            raise ClusterError(f"cluster.slurm.cores must be >= 1, got {s.cores}")
        if s.max_replacements < 0:
            raise ClusterError(f"cluster.slurm.max_replacements must be >= 0, got "
                               f"{s.max_replacements}")
        from dask.utils import parse_bytes

        try:
            if parse_bytes(s.memory_per_worker) <= 0:
                raise ValueError
        except (ValueError, TypeError):
            raise ClusterError(f"cluster.slurm.memory_per_worker must be a size like 4GB, got "
                               f"{s.memory_per_worker!r}") from None


def check_workers(client, addresses, expected_digest: str, say) -> None:
    """Probe newly connected workers: stop the run (ClusterFailed) when one cannot import
    this package or runs other code; say one line when one lacks the tuning."""
    from pipeline.cluster import worker_side

    results = client.run(worker_side.probe, workers=sorted(addresses), on_error="return")
    untuned = []
    for address, info in sorted(results.items()):
        if isinstance(info, BaseException):
            continue  # it left meanwhile: the watchdog counts workers, not this probe
        if info["digest"] is None:
            raise ClusterFailed(f"worker {address} cannot import this package "
                                f"({', '.join(worker_side.PACKAGES)}): start workers from an "
                                "environment where it is installed")
        if info["digest"] != expected_digest:
            raise ClusterFailed(f"worker {address} runs another version of this package "
                                f"(code digest {info['digest']}, here {expected_digest}): "
                                "install the same version on the workers")
        tuned = not info["env"] and all(info["config"][k] == v
                                        for k, v in worker_side.TUNED_CONFIG.items())
        if not tuned:
            untuned.append(address)
    if untuned:
        say(f"[yellow]warning: {len(untuned)} worker(s) run without the planning tuning "
            f"(e.g. {untuned[0]}: started without a nanny?); planning may be 25-40 % slower")
