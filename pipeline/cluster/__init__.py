"""Where the planning runs: a LocalCluster, an existing Dask scheduler, or SLURM.

``connect`` gives a run its checked client; its ``watchdog`` stops a run that has no usable
worker left; ``worker_side`` is what travels to the workers (tuning plugin, probe).
"""

import os

os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")  # before distributed loads

from pipeline.cluster.errors import ClusterError, ClusterFailed, TaskFailed  # noqa: E402
from pipeline.cluster.session import connect, connect_first, tune_workers  # noqa: E402
from pipeline.cluster.slurm import available_cores  # noqa: E402

__all__ = ["ClusterError", "ClusterFailed", "TaskFailed", "available_cores", "connect",
           "connect_first", "tune_workers"]
