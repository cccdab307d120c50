"""Where the planning runs: a LocalCluster, an existing Dask scheduler, or SLURM.

``connect`` gives a run its checked client; its ``watchdog`` stops a run that has no usable
worker left; ``worker_side`` is what travels to the workers (tuning plugin, probe).

``distributed`` is imported only when a cluster is started or reached (``connect``,
``tune_workers``): a command that starts none (a refused one, ``stage=status``, a re-run
with nothing to do, ``stage=evaluate`` or ``report`` alone) does not pay for importing it.
"""

from pipeline.cluster.checks import connect_first
from pipeline.cluster.errors import ClusterError, ClusterFailed, TaskFailed

__all__ = ["ClusterError", "ClusterFailed", "TaskFailed", "available_cores", "connect",
           "connect_first", "tune_workers"]

_LAZY = {"connect": "session", "tune_workers": "session", "available_cores": "slurm"}


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
