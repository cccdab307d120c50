"""What the coordinator sends to worker processes: two plugins (tuning, quiet closing) and a
probe.

This module imports only the standard library and dask/distributed, and the coordinator
pickles it *by value* (``cloudpickle.register_pickle_by_value``), so it works on a worker
that cannot import this package at all: that worker is then tuned and reports clearly that
the package is missing, instead of failing every task with ``ModuleNotFoundError``.
"""

from __future__ import annotations

import hashlib
import importlib.util
import logging
import os
import weakref
from pathlib import Path

from distributed.core import Status
from distributed.diagnostics.plugin import NannyPlugin, WorkerPlugin

#: Packages whose code must be identical on the coordinator and every worker.
PACKAGES = ("pipeline", "box_core")

#: Dask settings measured to cost planning throughput (benchmarks/bench_pipeline.py): the
#: statistical profiler and the 20 ms event-loop tick take the GIL from
#: the planning thread (5-10 %).
TUNED_CONFIG = {"distributed.worker.profile.enabled": False,
                "distributed.admin.tick.interval": "1s"}

#: The nanny exports MALLOC_TRIM_THRESHOLD_=65536 to its workers by default: glibc then
#: returns memory to the OS constantly and the planar planner runs 25-40 % slower.
UNSET_ENV = ("MALLOC_TRIM_THRESHOLD_",)


def _nested(flat: dict) -> dict:
    out: dict = {}
    for key, value in flat.items():
        *parents, leaf = key.split(".")
        node = out
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return out


def _get(config: dict, key: str):
    node = config
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


class WorkerTuning(NannyPlugin):
    """Applies TUNED_CONFIG and UNSET_ENV to the worker process of every nanny, including
    nannies that join later (SLURM replacements), restarting a running worker only when
    its settings differ: a worker's environment and config are fixed when it starts.

    ``idempotent``: registering it again (the next run of a sweep on the same scheduler)
    is a no-op, so a shared cluster's workers are not restarted under other runs."""

    idempotent = True
    restart = False

    def setup(self, nanny):
        import dask

        stale = [k for k in UNSET_ENV
                 if k in os.environ or k in nanny.env or k in nanny.pre_spawn_env]
        stale += [k for k, v in TUNED_CONFIG.items() if _get(nanny.config, k) != v]
        for key in UNSET_ENV:
            # the nanny copies pre_spawn_env into its own os.environ before spawning
            os.environ.pop(key, None)
            nanny.env.pop(key, None)
            nanny.pre_spawn_env.pop(key, None)
        nanny.config = dask.config.merge(nanny.config, _nested(TUNED_CONFIG))
        if getattr(nanny, "process", None) is not None:  # a restart reuses its config copy
            nanny.process.config = dask.config.merge(nanny.process.config,
                                                     _nested(TUNED_CONFIG))
        self.restart = bool(stale)


#: What distributed's worker logs, with two tracebacks, when a heartbeat to the scheduler fails.
HEARTBEAT_FAILED = "Failed to communicate with scheduler during heartbeat."
#: The statuses of a worker that is shutting down.
CLOSING = frozenset({Status.closing, Status.closing_gracefully, Status.closed})


class _ClosingHeartbeat(logging.Filter):
    """Drops HEARTBEAT_FAILED once ``worker`` is closing (or gone), and nothing else."""

    def __init__(self, worker):
        super().__init__()
        self.worker = weakref.ref(worker)

    def filter(self, record: logging.LogRecord) -> bool:
        if record.msg != HEARTBEAT_FAILED:
            return True
        worker = self.worker()
        return worker is not None and worker.status not in CLOSING


class QuietClose(WorkerPlugin):
    """A worker closing while its heartbeat is in flight aborts that heartbeat itself
    (``Worker.close`` closes its connection pool), and distributed then logs the aborted
    heartbeat as an error with two tracebacks: at the end of a run, or when a run that was
    suspended (SIGSTOP, a laptop's lid) resumes only to stop, the last thing a person reads
    is a traceback about a shutdown that went as meant.  This plugin makes each worker drop
    that one record once it is closing; a heartbeat failing while the worker still runs is
    logged as before.  The filter outlives the plugin on purpose: a worker removes its plugins
    before it closes its connection pool."""

    idempotent = True
    name = "box-planning-quiet-close"

    def setup(self, worker) -> None:
        log = logging.getLogger("distributed.worker")
        # by name: pickled by value, each registration brings its own copy of the class
        if not any(type(f).__name__ == _ClosingHeartbeat.__name__ and f.worker() is worker
                   for f in log.filters):
            log.addFilter(_ClosingHeartbeat(worker))


def code_digest() -> str | None:
    """A digest of the Python sources of PACKAGES as this process would import them, or
    None when one of them cannot be imported."""
    h = hashlib.sha256()
    for name in PACKAGES:
        try:
            spec = importlib.util.find_spec(name)
        except (ImportError, ValueError):
            spec = None
        if spec is None or not spec.submodule_search_locations:
            return None
        root = Path(list(spec.submodule_search_locations)[0])
        for path in sorted(root.rglob("*.py")):
            h.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()[:16]


def probe() -> dict:
    """Run on a worker (``client.run``): its code digest and the settings that matter."""
    import dask

    return {"digest": code_digest(),
            "env": {k: os.environ[k] for k in UNSET_ENV if k in os.environ},
            "config": {k: dask.config.get(k, None) for k in TUNED_CONFIG}}
