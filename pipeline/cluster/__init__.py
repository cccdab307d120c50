"""Where the planning runs: a LocalCluster, an existing Dask scheduler, or SLURM.

``connect`` gives a run its checked client; its ``watchdog`` stops a run that has no usable
worker left; ``worker_side`` is what travels to the workers (tuning plugin, probe).
"""

from pipeline.cluster.errors import ClusterError, ClusterFailed, TaskFailed
from pipeline.cluster.session import connect, connect_first, tune_workers
from pipeline.cluster.slurm import available_cores

__all__ = ["ClusterError", "ClusterFailed", "TaskFailed", "available_cores", "connect",
           "connect_first", "tune_workers"]
