"""Stage ``evaluate``: box_core's LOOCV on a finished score store, results written back."""

from __future__ import annotations

import numpy as np

import box_core
from box_core.stats import INTERVAL_METHOD
from pipeline.configs import RAWPLANNER
from pipeline.context import StageContext
from pipeline.store import evaluation as evaluation_store
from pipeline.store.evaluation import StoredEvaluation, raw_curve
from pipeline.store.layout import (
    CHECKS,
    FEASIBLE,
    LENGTH,
    RAW,
    SCORES,
    SOURCE_INSTANCE,
    TIME,
    result_key,
)
from pipeline.tables import summary_table


def own_constraints(store) -> np.ndarray | None:
    """(n, m) bool: column j was extracted from row i's own raw solution, or None when the
    store's constraints come from no instance (constraints/source_instance all -1)."""
    if not store.has(SOURCE_INSTANCE):
        return None
    source = store.source_instances()
    if not (source >= 0).any():
        return None
    n = store.array(result_key(SCORES, FEASIBLE)).shape[0]
    return source[None, :] == np.arange(n)[:, None]


def evaluated_selectors(settings: dict) -> list[str]:
    """The selectors box_core runs for these ``evaluate.*`` settings, in order (RAWPLANNER
    is not one: its times come from the store's raw stage)."""
    return [s for s in dict.fromkeys(settings["selectors"]) if s != RAWPLANNER]


def hidden_constraints(own: np.ndarray | None, settings: dict) -> np.ndarray | None:
    """What leave-one-out hides from each held-out row (``forbidden``): its own
    constraints ``own`` (:func:`own_constraints`) unless
    ``evaluate.exclude_own_constraints`` is false."""
    return own if settings.get("exclude_own_constraints", True) else None


def instance_features(store) -> np.ndarray | None:
    """The store's instance features (n, q) for the contextual selectors, or None when its
    domain declares none (those selectors are then BOX)."""
    found = store.instance_features()
    return None if found is None else found.values


def stored_revision(info: dict) -> int:
    """The box_core selector revision a stored evaluation was made with (1: before
    revisions were recorded)."""
    return int(info.get("selector_revision", 1))


def interval_method(info: dict) -> str:
    """The interval method of a stored evaluation's summary (percentile bootstrap before
    the method was recorded)."""
    return info.get("interval_method", "percentile bootstrap")


def selector_params(names, settings) -> dict:
    """box_core parameters from the evaluate.* settings (BOX's C)."""
    return {"box": {"c": settings["c"]}} if "box" in names else {}


#: From this many entries on, a second process shares the evaluation (box_core.loocv's
#: ``workers``: the two take its pieces of work in turn): below it they take about as long
#: as starting one (~1 s); at the main job's 162,000 about 15 s.
BESIDE_ENTRIES = 50_000


def loocv_workers(entries: int) -> int:
    """box_core.loocv's ``workers`` for a matrix of ``entries``: the cores this process
    may use from :data:`BESIDE_ENTRIES` on, else 1."""
    from pipeline.cluster import available_cores  # dask: only where it is used

    return available_cores() if entries >= BESIDE_ENTRIES else 1


def store_loocv(store, settings: dict, seed: int, **options) -> box_core.LoocvResult:
    """box_core's leave-one-out of the ``evaluate.*`` ``settings`` on a finished store, as
    stage ``evaluate`` runs it: each row's own constraints hidden (unless the settings say
    otherwise), its instance features and checks for the contextual selectors, the cores
    this process may use, one BLAS thread in each process, and every row stopped once
    nothing stored can change (``until_best``); ``options`` override box_core.loocv's
    arguments."""
    from pipeline.planning.blas import single_thread_with_children

    names = evaluated_selectors(settings)
    scores, feasible, times, theta = store.score_matrix()
    if "forbidden" not in options:  # the stage passes what it has read already
        options["forbidden"] = hidden_constraints(own_constraints(store), settings)
    with single_thread_with_children():
        return box_core.loocv(**{
            "scores": scores, "times": times, "feasible": feasible, "features": theta,
            "selectors": names, "k": settings["k"], "seed": seed,
            "params": selector_params(names, settings),
            "failure_rule": settings["failure_rule"],
            "instance_features": instance_features(store),
            "checks": store.result(SCORES, CHECKS), "until_best": True,
            "workers": loocv_workers(scores.size), **options})


def evaluate(ctx: StageContext) -> None:
    store = ctx.store
    settings = ctx.config["evaluate"]
    info = store.stage_info("evaluate")
    if info is not None and info.get("settings") == settings and stored_revision(
            info) == box_core.SELECTOR_REVISION:
        if interval_method(info) == INTERVAL_METHOD:
            ctx.say("evaluate: already complete with these settings; nothing to do")
            print_stored_summary(ctx)
            return
    with_raw = RAWPLANNER in settings["selectors"]
    own = own_constraints(store)
    hide = hidden_constraints(own, settings)
    try:
        result = store_loocv(store, settings, ctx.seed, forbidden=hide)
    except ValueError as exc:
        raise ValueError(f"evaluate: {exc}") from None
    others, curves = {}, {}
    if with_raw:
        raw_ok, raw_time, raw_length = (store.result(RAW, name)
                                        for name in (FEASIBLE, TIME, LENGTH))
        others[RAWPLANNER] = np.where(raw_ok, raw_time, np.nan)
        curves[RAWPLANNER] = raw_curve(raw_ok, raw_time, raw_length, result.time_grid,
                                       result.failure_value)
    summary = result.summary(others=others)
    store.forget_stage("evaluate")  # derived data: replaced as a whole
    evaluation_store.write(store, StoredEvaluation(
        selectors=[*result.selectors, *others], time_grid=result.time_grid,
        eligible=result.eligible, optimal_score=result.optimal_score,
        first_feasible_time={**result.first_feasible_time, **others},
        best_score={**result.best_score, **curves},
        first_feasible_step=result.first_feasible_step, order=result.order),
        score_units=store.score_units())
    # what the report states about leakage: how many rows had constraints of their own,
    # and whether those were hidden from them
    leakage = {"own_constraint_rows": 0 if own is None else int(own.any(axis=1).sum()),
               "hidden": hide is not None}
    store.mark_finished("evaluate", settings=settings, failure_value=result.failure_value,
                        summary=summary.to_dict(), leakage=leakage,
                        selector_revision=box_core.SELECTOR_REVISION,
                        interval_method=INTERVAL_METHOD)
    n, m = store.array(result_key(SCORES, FEASIBLE)).shape
    ctx.console.print(summary_table(summary, title=f"{ctx.path.name}  ({n} x {m})"))


def print_stored_summary(ctx: StageContext) -> None:
    info = ctx.store.stage_info("evaluate") or {}
    summary = info.get("summary")
    if summary:
        for line in summary.get("selectors", []):
            ctx.say(f"  {line['name']:<11} mean time to first feasible "
                    f"{line['mean_time']}  x {summary['reference']}: {line['speedup']}")
