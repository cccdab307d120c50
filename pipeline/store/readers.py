"""Reading a store: the instances, constraints and results, the score matrix as box_core
takes it, and which blocks have finished.  A part of :class:`pipeline.store.ScoreStore`."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pipeline.store.blocks import block_region
from pipeline.store.errors import StoreError
from pipeline.store.layout import (
    INSTANCE_FEATURE,
    INSTANCE_FEATURE_UNITS,
    INSTANCE_FEATURES,
    INSTANCE_SEED,
    INSTANCE_SPEC,
    INSTANCES,
    SCORE,
    SCORES,
    SOURCE_INSTANCE,
    THETA,
    done_key,
    key,
    result_key,
)


def domain_spec_of(config: dict) -> dict:
    """The {"name", "config", "planner"} workers receive, from a plain run config (as a run
    resolves it, and as the store's ``config`` attribute holds it)."""
    domain = dict(config["domain"])
    return {"name": domain.pop("name"), "config": domain, "planner": config["planner"]}


class ScoreMatrix(NamedTuple):
    """A store's score matrix as box_core takes it."""

    scores: np.ndarray  # (n, m): -(path length) where feasible, 0 elsewhere
    feasible: np.ndarray  # (n, m) bool
    times: np.ndarray  # (n, m) seconds
    theta: np.ndarray  # (m, p): the constraints' features


class InstanceFeatures(NamedTuple):
    """A store's instance features: their names and units, and the (n, q) values."""

    names: tuple[str, ...]
    units: tuple[str, ...]
    values: np.ndarray


def path_scores(feasible, length) -> np.ndarray:
    """Scores as box_core takes them: -(path length) where feasible, 0 elsewhere (the
    failure value replaces those entries at analysis time)."""
    return np.where(feasible, -np.nan_to_num(length, nan=0.0), 0.0)



class Readers:
    """The store's readers (a mixin of :class:`pipeline.store.ScoreStore`)."""

    def domain_spec(self) -> dict:
        """The {"name", "config", "planner"} the store was made with (what workers receive)."""
        config = self.attrs.get("config") or {}
        if "name" not in (config.get("domain") or {}) or "planner" not in config:
            raise StoreError(f"{self.path}: the store's attributes hold no domain config "
                             "(damaged store?)")
        from pipeline.configs import with_earlier_values

        return domain_spec_of(with_earlier_values(config))

    def instance_seeds(self) -> np.ndarray:
        return self.array(INSTANCE_SEED)[...]

    def instance_specs(self) -> np.ndarray:
        """The instances' specs (JSON text)."""
        return self.array(INSTANCE_SPEC)[...]

    def instance_features(self) -> InstanceFeatures | None:
        """The instances' features (names, units, (n, q) values), as stage ``instances``
        stored them; None when the store holds none (its domain declares none, or a store of
        layout 4 or older not yet migrated)."""
        if not self.has(INSTANCE_FEATURES):
            return None
        names, units = (tuple(str(v) for v in self.array(key(INSTANCES, name))[...])
                        for name in (INSTANCE_FEATURE, INSTANCE_FEATURE_UNITS))
        return InstanceFeatures(names, units, self.array(INSTANCE_FEATURES)[...])

    def has_results(self, group: str) -> bool:
        """Whether result group ``group`` (``raw`` or ``scores``) has been created."""
        return self.has(done_key(group))

    def source_instances(self) -> np.ndarray:
        """(m,) the instance whose raw solution gave each constraint; -1: fixed."""
        return self.array(SOURCE_INSTANCE)[...]

    def theta(self) -> np.ndarray:
        """(m, p) the constraints' features."""
        return self.array(THETA)[...]

    def score_matrix(self, rows=None) -> ScoreMatrix:
        """The score matrix as box_core wants it.  With ``rows`` (indices or a mask), only
        those rows, unchecked (a partial store's complete rows); without, all rows, and a
        StoreError when an entry is missing or a feasible entry has no path length."""
        def read(key):
            values = self.array(key)[...]
            return values if rows is None else values[rows]

        if rows is None:
            self.require_done(SCORES)
        feasible, length, times = (read(result_key(SCORES, name))
                                   for name in ("feasible", "length", "time"))
        if rows is None and np.isnan(times).any():
            raise StoreError(f"{self.path}: {result_key(SCORES, 'time')} has missing "
                             "entries; is stage scores complete?")
        scores = path_scores(feasible, length)
        if rows is None and np.isnan(length[feasible]).any():
            raise StoreError(f"{self.path}: a feasible entry has no path length (damaged "
                             "store?)")
        return ScoreMatrix(scores, feasible, times, self.theta())

    def done(self, group: str) -> np.ndarray:
        """The ``done`` mask of ``group`` (read once under ``reading_once``)."""
        key = done_key(group)
        if self._kept is None:
            return self.array(key)[...]
        whole, _ = self.mask_chunks(key)
        if whole is None:
            raise StoreError(f"{self.path}: {key} has a chunk that does not decode")
        return whole.copy()

    def require_done(self, group: str) -> None:
        """A StoreError naming the unfinished blocks of ``group`` unless every entry's block
        finished: readers never take a missing entry for an infeasible one."""
        finished, pending = self.blocks(group)
        if pending:
            mask = self.done(group)
            shown = ", ".join(str(b) for b in pending[:3]) + (" …" if len(pending) > 3 else "")
            raise StoreError(
                f"{self.path}: {group} has {int((~mask).sum())} of {mask.size} entries in "
                f"{len(pending)} unfinished block(s) ({shown}); finish it with "
                "python -m pipeline stage=generate")

    def blocks(self, group: str) -> tuple[list[tuple[int, ...]], list[tuple[int, ...]]]:
        """(finished, pending) chunk indices of ``group`` according to its ``done`` mask."""
        mask = self.array(done_key(group))
        done = mask[...]
        finished, pending = [], []
        for block in np.ndindex(*mask.cdata_shape):
            (finished if done[block_region(block, mask.chunks)].all() else pending).append(block)
        return finished, pending


    def matrix_shape(self) -> tuple[int, int] | None:
        """(n, m) of the score matrix; None before stage ``scores`` created it."""
        if not self.has_results(SCORES):
            return None
        return self.array(done_key(SCORES)).shape

    def score_units(self) -> str:
        """The unit of the scores (the domain's length unit; "1" when none is recorded)."""
        return self.array(result_key(SCORES, SCORE)).attrs.get("units", "1")

    def result(self, group: str, name: str) -> np.ndarray:
        """The values of result array ``name`` of ``group`` (``raw`` or ``scores``)."""
        return self.array(result_key(group, name))[...]
