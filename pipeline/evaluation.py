"""Stage ``evaluate``: box_core's LOOCV on a finished score store, results written back."""

from __future__ import annotations

import numpy as np

import box_core
from pipeline.context import StageContext
from pipeline.store import SOURCE_INSTANCE, result_key
from pipeline.tables import summary_table

#: Measured outside the LOOCV: RAWPLANNER's time comes from stage ``raw``.
RAWPLANNER = "rawplanner"


def own_constraints(store) -> np.ndarray | None:
    """(n, m) bool: column j was extracted from row i's own raw solution, or None when the
    store's constraints come from no instance (constraints/source_instance all -1)."""
    if not store.has(SOURCE_INSTANCE):
        return None
    source = store.source_instances()
    if not (source >= 0).any():
        return None
    n = store.array(result_key("scores", "feasible")).shape[0]
    return source[None, :] == np.arange(n)[:, None]


def stored_revision(info: dict) -> int:
    """The box_core selector revision a stored evaluation was made with (1: before
    revisions were recorded)."""
    return int(info.get("selector_revision", 1))


def selector_params(names, settings) -> dict:
    """box_core parameters from the evaluate.* settings (BOX's C)."""
    return {"box": {"c": settings["c"]}} if "box" in names else {}


def evaluate(ctx: StageContext) -> None:
    store = ctx.store
    settings = ctx.config["evaluate"]
    info = store.stage_info("evaluate")
    if info is not None and info.get("settings") == settings and stored_revision(
            info) == box_core.SELECTOR_REVISION:
        ctx.say("evaluate: already complete with these settings; nothing to do")
        print_stored_summary(ctx)
        return
    names = list(dict.fromkeys(settings["selectors"]))
    with_raw = RAWPLANNER in names
    names = [s for s in names if s != RAWPLANNER]
    scores, feasible, times, theta = store.score_matrix()
    own = own_constraints(store)
    hide = own if settings.get("exclude_own_constraints", True) else None
    try:
        result = box_core.loocv(scores, times=times, feasible=feasible, features=theta,
                                selectors=names, k=settings["k"], seed=ctx.seed,
                                params=selector_params(names, settings),
                                failure_rule=settings["failure_rule"], forbidden=hide)
    except ValueError as exc:
        raise ValueError(f"evaluate: {exc}") from None
    others = {}
    if with_raw:
        raw_ok = store.array(result_key("raw", "feasible"))[...]
        others[RAWPLANNER] = np.where(raw_ok, store.array(result_key("raw", "time"))[...],
                                     np.nan)
    summary = result.summary(others=others)
    store.forget_stage("evaluate")  # derived data: replaced as a whole
    store.remove("evaluation")  # any kind of store: local, file:// or s3://
    _write(store, result, others)
    # what the report states about leakage: how many rows had constraints of their own,
    # and whether those were hidden from them
    leakage = {"own_constraint_rows": 0 if own is None else int(own.any(axis=1).sum()),
               "hidden": hide is not None}
    store.mark_finished("evaluate", settings=settings, failure_value=result.failure_value,
                        summary=summary.to_dict(), leakage=leakage,
                        selector_revision=box_core.SELECTOR_REVISION)
    n, m = scores.shape
    ctx.console.print(summary_table(summary, title=f"{ctx.path.name}  ({n} x {m})"))


def _write(store, result, others) -> None:
    inst, step, time = "instance", "step", "time"
    n, k = result.order[result.selectors[0]].shape
    b = max(1, min(n, 1000))
    store.create("evaluation/time_grid", result.time_grid.shape, result.time_grid.shape,
                 "float64", np.nan, (time,))[...] = result.time_grid
    store.create("evaluation/eligible", (n,), (b,), "bool", False, (inst,))[...] = result.eligible
    store.create("evaluation/optimal_score", (n,), (b,), "float64", np.nan,
                 (inst,))[...] = result.optimal_score
    for name in result.selectors:
        g = f"evaluation/{name}"
        store.create(f"{g}/order", (n, k), (b, k), "int32", -1, (inst, step))[...] = \
            result.order[name]
        store.create(f"{g}/first_feasible_step", (n,), (b,), "int32", -1,
                     (inst,))[...] = result.first_feasible_step[name]
        store.create(f"{g}/first_feasible_time", (n,), (b,), "float64", np.nan,
                     (inst,))[...] = result.first_feasible_time[name]
        curve = result.best_score[name]
        store.create(f"{g}/best_score", curve.shape, (b, curve.shape[1]), "float64", np.nan,
                     (inst, time))[...] = curve
    for name, values in others.items():
        store.create(f"evaluation/{name}/first_feasible_time", (n,), (b,), "float64", np.nan,
                     (inst,))[...] = values


def print_stored_summary(ctx: StageContext) -> None:
    info = ctx.store.stage_info("evaluate") or {}
    summary = info.get("summary")
    if summary:
        for line in summary.get("selectors", []):
            ctx.say(f"  {line['name']:<11} mean time to first feasible "
                    f"{line['mean_time']}  x {summary['reference']}: {line['speedup']}")
