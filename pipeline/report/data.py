"""What a report needs from one finished store, read once into plain arrays."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.evaluation import own_constraints
from pipeline.planning.settings import planner_label
from pipeline.store import ScoreStore, StoreError
from pipeline.store import evaluation as evaluation_store
from pipeline.store.layout import FEASIBLE, LENGTH, RAW, TIME


@dataclass(eq=False)
class StoreResults:
    """One store's score matrix and its stored leave-one-out evaluation."""

    path: Path
    config_hash: str
    seed: int
    spec: dict
    scores: np.ndarray  # -(length) where feasible, 0 elsewhere (box_core fills failures)
    feasible: np.ndarray
    times: np.ndarray
    theta: np.ndarray
    instance_specs: np.ndarray
    instance_seeds: np.ndarray
    raw_feasible: np.ndarray
    raw_time: np.ndarray
    raw_length: np.ndarray
    summary: dict  # box_core.Summary.to_dict(), as stored by stage evaluate
    settings: dict  # evaluate.* the evaluation ran with
    failure_value: float
    time_grid: np.ndarray
    eligible: np.ndarray
    optimal_score: np.ndarray
    first_feasible_time: dict[str, np.ndarray]
    best_score: dict[str, np.ndarray]
    order: dict[str, np.ndarray]
    leakage: dict | None = None  # {"own_constraint_rows", "hidden"} as stage evaluate stored
    forbidden: np.ndarray | None = None  # (n, m) columns hidden from their own row, if any
    detail: str = ""  # what tells this store from others of the same domain and planner

    @property
    def domain(self) -> str:
        return self.spec["name"]

    @property
    def planner(self) -> str:
        """The planner's name, with its algorithm where it has one (``ompl-RRTstar``)."""
        return planner_label(self.spec["planner"])

    @property
    def label(self) -> str:
        base = f"{self.domain} / {self.planner}"
        return f"{base} ({self.detail})" if self.detail else base

    @property
    def shape(self) -> tuple[int, int]:
        return self.scores.shape

    @property
    def selectors(self) -> list[str]:
        return [line["name"] for line in self.summary["selectors"]]

    def line(self, name: str) -> dict:
        for line in self.summary["selectors"]:
            if line["name"] == name:
                return line
        raise KeyError(name)

    def raw_curve(self) -> np.ndarray:
        """RAWPLANNER's best score versus ``time_grid``, per row (its one plan, when found)."""
        return evaluation_store.raw_curve(self.raw_feasible, self.raw_time, self.raw_length,
                                          self.time_grid, self.failure_value)


def tell_apart(results: list[StoreResults]) -> None:
    """Give stores that share a domain and a planner a ``detail`` naming the settings in
    which they differ (``step_order=paper``), or their file names when none differ."""
    groups: dict[str, list[StoreResults]] = {}
    for res in results:
        groups.setdefault(res.label, []).append(res)
    for same in groups.values():
        if len(same) < 2:
            continue
        flat = [_flatten(r.spec) for r in same]
        keys = sorted({k for f in flat for k in f if len({repr(g.get(k)) for g in flat}) > 1})
        for res, f in zip(same, flat, strict=True):
            res.detail = (", ".join(f"{k.split('.')[-1]}={f.get(k)}" for k in keys)
                          or Path(str(res.path).rstrip("/")).name)


def _flatten(spec: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in spec.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def load(path) -> StoreResults:
    """Read a store whose ``evaluate`` stage has finished (StoreError naming what is missing)."""
    store = ScoreStore.open(path)  # a local path or a URL
    info = store.stage_info("evaluate")
    if info is None:
        raise StoreError(f"{store.path} has no evaluation yet; run stage=evaluate (or "
                         "stage=all) on it first")
    scores, feasible, times, theta = store.score_matrix()
    stored = evaluation_store.read(store)
    has_raw = store.stage_info("raw") is not None
    n = scores.shape[0]

    def raw(name, missing):
        return store.result(RAW, name) if has_raw else missing
    attrs = store.attrs
    return StoreResults(
        path=store.path,
        config_hash=attrs.get("config_hash", "?"),
        seed=int(attrs.get("config", {}).get("seed", 0)),
        spec=store.domain_spec(),
        scores=scores, feasible=feasible, times=times, theta=theta,
        instance_specs=store.instance_specs(),
        instance_seeds=store.instance_seeds(),
        raw_feasible=raw(FEASIBLE, np.zeros(n, bool)),
        raw_time=raw(TIME, np.full(n, np.nan)),
        raw_length=raw(LENGTH, np.full(n, np.nan)),
        summary=info["summary"], settings=info["settings"],
        failure_value=float(info["failure_value"]),
        time_grid=stored.time_grid, eligible=stored.eligible,
        optimal_score=stored.optimal_score, first_feasible_time=stored.first_feasible_time,
        best_score={k: v for k, v in stored.best_score.items() if k in stored.order},
        order=stored.order,
        leakage=info.get("leakage"),
        forbidden=own_constraints(store) if (info.get("leakage") or {}).get("hidden") else None,
    )
