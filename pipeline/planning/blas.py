"""One BLAS thread for numerical code whose result must not depend on the process.

OpenBLAS splits some products and factorisations differently with one thread than with
several, and the last bits of the result follow the split.  Dask workers run with one
BLAS thread (the nanny sets ``OPENBLAS_NUM_THREADS=1``) while the coordinating process, a
test or a notebook has one per core, so an optimiser that calls BLAS (TrajOpt) gave plans
that differed in the 7th digit between a worker and the coordinator.  Inside
:func:`single_thread` every process computes with one thread, the same way.
"""

from __future__ import annotations

import contextlib
import functools
import os

from threadpoolctl import ThreadpoolController

#: what numeric libraries read for their thread count when a process starts
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@functools.cache
def _controller() -> ThreadpoolController:
    """The BLAS libraries loaded in this process (looked up once: ~0.1 ms)."""
    return ThreadpoolController()


def single_thread():
    """A context manager under which numpy's and scipy's BLAS use one thread (~20 µs)."""
    return _controller().limit(limits=1, user_api="blas")


@contextlib.contextmanager
def single_thread_with_children():
    """:func:`single_thread`, and one BLAS thread in the processes started meanwhile (they
    read it from the environment, which is restored after).  For box_core's leave-one-out
    with a second process: two processes on two cores each with a BLAS thread per core
    fought over the cores (``box evaluate`` of stage evaluate's ten selectors on a 1500 x
    1000 store, 2 cores: 2 min 3 s against 1 min 27 s with one thread each), and one thread
    everywhere makes the result independent of the machine's core count."""
    saved = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    os.environ.update(dict.fromkeys(THREAD_VARIABLES, "1"))
    try:
        with single_thread():
            yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
