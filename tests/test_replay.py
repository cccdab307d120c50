"""Stored figures survive code changes: entries of small stores made by an earlier version
(``tests/data/replay.json``, written by ``tests/data/make_replay.py``) replay unchanged
from their seeds: status, feasibility, score, failed step and collision checks."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from pipeline.domains import load_domain

STORES = json.loads((Path(__file__).parent / "data" / "replay.json").read_text())


def domain_of(store: dict):
    """The store's domain and planner; the wall-clock safety net out of reach, so that a
    loaded machine cannot turn a stored entry into "timeout"."""
    config = {k: v for k, v in store["domain"].items() if k != "name"}
    planner = {**store["planner"], "wall_cap_s": 1e6}
    return load_domain(store["domain"]["name"], planner=planner, **config)


def same(stored: float | None, replayed: float) -> bool:
    """Equal up to the last bits: TrajOpt's linear algebra rounds differently under
    multi-threaded BLAS (Dask workers run single-threaded); everything else is exact."""
    if stored is None:
        return math.isnan(replayed)
    return math.isclose(stored, replayed, rel_tol=1e-12, abs_tol=1e-12)


def step_index(domain, result) -> int:
    return domain.steps.index(result.step) if result.step else -1


@pytest.mark.parametrize("store", STORES, ids=[s["store"] for s in STORES])
def test_stored_entries_replay(store):
    domain = domain_of(store)
    theta = np.asarray(store["theta"], float)
    for e in store["entries"]:
        got = domain.plan(store["instances"][e["instance"]], theta[e["constraint"]],
                          seed=e["seed"])
        where = f"entry ({e['instance']}, {e['constraint']})"
        assert int(got.status) == e["status"], where
        assert got.feasible == e["feasible"], where
        assert same(e["score"], got.score), where
        assert step_index(domain, got) == e["step"], where
        assert got.checks == e["checks"], where


@pytest.mark.parametrize("store", STORES, ids=[s["store"] for s in STORES])
def test_stored_raw_solutions_replay(store):
    domain = domain_of(store)
    for r in store["raw"]:
        got = domain.raw_plan(store["instances"][r["instance"]], seed=r["seed"])
        where = f"raw solution of instance {r['instance']}"
        assert int(got.plan.status) == r["status"], where
        assert same(r["score"], got.plan.score), where
        assert step_index(domain, got.plan) == r["step"], where
        assert got.plan.checks == r["checks"], where
        assert all(same(a, b) for a, b in zip(r["constraint"], got.constraint, strict=True)), where
