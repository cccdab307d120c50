"""One BLAS thread for numerical code whose result must not depend on the process.

OpenBLAS splits some products and factorisations differently with one thread than with
several, and the last bits of the result follow the split.  Dask workers run with one
BLAS thread (the nanny sets ``OPENBLAS_NUM_THREADS=1``) while the coordinating process, a
test or a notebook has one per core, so an optimiser that calls BLAS (TrajOpt) gave plans
that differed in the 7th digit between a worker and the coordinator.  Inside
:func:`single_thread` every process computes with one thread, the same way.
"""

from __future__ import annotations

import functools

from threadpoolctl import ThreadpoolController


@functools.cache
def _controller() -> ThreadpoolController:
    """The BLAS libraries loaded in this process (looked up once: ~0.1 ms)."""
    return ThreadpoolController()


def single_thread():
    """A context manager under which numpy's and scipy's BLAS use one thread (~20 µs)."""
    return _controller().limit(limits=1, user_api="blas")
