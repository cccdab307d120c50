"""Stored figures survive code changes and machines: entries of small stores
(``tests/data/replay.json``, written by ``tests/data/make_replay.py``) replay from their
seeds under the reproducibility contract (docs/reproducibility.md): status, feasibility,
failed step and collision checks exactly, scores and extracted constraints within
``pipeline.environment.RTOL``/``ATOL``; and bitwise alike in every process of one
environment, whatever its BLAS thread count.

The stores were made on another machine than most that run this, so the first test is
itself a comparison across machines; the others force this machine's NumPy and OpenBLAS
onto other kernels (as an older CPU would run) in a child process.
"""

from __future__ import annotations

import functools
import json
import os
from concurrent.futures import ThreadPoolExecutor

import pytest

from pipeline.environment import ATOL, RTOL
from tests import replay

DOC = replay.stored()
STORES = DOC["stores"]
IDS = [s["store"] for s in STORES]


@functools.cache
def here() -> tuple[dict, ...]:
    """This process's replay of every store (shared by the tests below)."""
    return tuple(replay.replay_store(s) for s in STORES)


def test_the_file_records_the_contract_it_was_measured_under():
    assert DOC["contract"] == {"rtol": RTOL, "atol": ATOL}
    assert DOC["measured"] and all(m["breaches"] == 0 for m in DOC["measured"].values())
    assert all(m["largest_relative_difference"] < RTOL for m in DOC["measured"].values())


@pytest.mark.parametrize("k", range(len(STORES)), ids=IDS)
def test_stored_entries_and_raw_solutions_replay_within_the_contract(k):
    assert replay.compare(STORES[k], here()[k]) == []


@pytest.fixture(scope="module")
def forced(tmp_path_factory):
    """Every forced code path's replay, from child processes: name -> (env, result)."""
    out = tmp_path_factory.mktemp("forced")
    paths = replay.code_paths()
    # the children are independent processes: as many at once as there are cores
    with ThreadPoolExecutor(max_workers=max(1, os.cpu_count() or 1)) as pool:
        results = {name: pool.submit(replay.replay_in_child, env, out / f"{name}.json")
                   for name, env in paths.items()}
        return {name: (paths[name], result.result()) for name, result in results.items()}


def test_forced_code_paths_really_change_the_environment(forced):
    """Each child ran as asked: NumPy's SIMD and OpenBLAS's kernels are recorded in the
    environment's fingerprint, so a path that did not take effect would show here."""
    from pipeline.environment import fingerprint

    mine = fingerprint()
    for name, (env, result) in forced.items():
        theirs = result["environment"]
        if "NPY_DISABLE_CPU_FEATURES" in env:
            assert theirs["simd"] == "" != mine["simd"], name
        if "OPENBLAS_CORETYPE" in env:
            assert theirs["blas"] != mine["blas"], name
        if "OPENBLAS_CORETYPE" not in env and "NPY_DISABLE_CPU_FEATURES" not in env:
            assert theirs == mine, name  # thread counts are not part of the environment
    if len(forced) < 5:
        pytest.skip(f"only {sorted(forced)} can be forced on this machine")


@pytest.mark.parametrize("k", range(len(STORES)), ids=IDS)
def test_other_cpu_code_paths_keep_the_contract(forced, k):
    for name, (_, result) in forced.items():
        assert replay.compare(here()[k], result["stores"][k]) == [], name
        assert replay.compare(STORES[k], result["stores"][k]) == [], name


def test_one_environment_is_bitwise_whatever_the_blas_threads(forced):
    """A Dask worker (one BLAS thread), a notebook (one per core) and this process give
    the very same bits, TrajOpt included."""
    threads = [result["stores"] for name, (_, result) in forced.items()
               if name.startswith("blas-")]
    assert len(threads) == 2
    mine = json.loads(json.dumps(list(here())))  # through JSON, as the children's
    assert threads[0] == threads[1] == mine
