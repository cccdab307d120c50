"""The score store: a Zarr v3 store of the score matrix of one run, and everything that
reads, writes, checks, locks, migrates and describes it.

The layout (groups, arrays, dimensions, attributes, the evaluation included) is declared once
in :mod:`pipeline.store.layout`; no module outside this package spells a group or array
name.  The parts:

=================  ========================================================================
``layout``         the names, the arrays of each group as a function of the identity
``score_store``    :class:`ScoreStore`: opening, identity, root attributes, arrays, documents
``blocks``         its writers: groups, coordinates, integrity tables, finished blocks
``verification``   its integrity checks: damage per chunk, digests of inputs
``readers``        its readers: instances, constraints, results, the score matrix
``evaluation``     the ``evaluation/`` dataset (stage ``evaluate`` writes, the report reads)
``integrity``      digests of chunks and what damage was found
``metadata``       every ``zarr.json`` checked against what can be known, and repaired
``migrate``        a store of an older layout brought to the current one
``status``         what a store holds and every damage found (stage/command ``status``)
``locking``        one writing run per store (flock, or a lease object)
``location``       where a store lives (a folder or an fsspec URL)
``storage_errors`` storage failures as one line
``errors``         the store's error types
=================  ========================================================================
"""

from pipeline.store.errors import LockError, StoreDamaged, StoreError
from pipeline.store.layout import (
    BLOCK_DIMS,
    ENVIRONMENT,
    FORMAT,
    INSTANCE_FEATURES,
    INSTANCE_SEED,
    INSTANCE_SPEC,
    LAYOUT_VERSION,
    RAW_CONSTRAINT,
    RESULT_COLUMNS,
    SOURCE_INSTANCE,
    THETA,
    UNKNOWN_ENVIRONMENT,
    result_key,
)
from pipeline.store.locking import LOCK_SUFFIX, StoreLock
from pipeline.store.readers import InstanceFeatures, ScoreMatrix, domain_spec_of, path_scores
from pipeline.store.score_store import (
    ScoreStore,
    check_is_ours,
    default_path,
    write_error,
)

__all__ = [
    "BLOCK_DIMS", "ENVIRONMENT", "FORMAT", "INSTANCE_FEATURES", "INSTANCE_SEED", "INSTANCE_SPEC",
    "LAYOUT_VERSION", "LOCK_SUFFIX", "RAW_CONSTRAINT", "RESULT_COLUMNS", "SOURCE_INSTANCE",
    "THETA", "UNKNOWN_ENVIRONMENT", "InstanceFeatures", "LockError", "ScoreMatrix", "ScoreStore",
    "StoreDamaged", "StoreError", "StoreLock", "check_is_ours", "default_path", "domain_spec_of",
    "path_scores", "result_key", "write_error",
]
