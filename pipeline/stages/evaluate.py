"""Stage ``evaluate``: box_core's LOOCV on the finished score matrix, written to
``evaluation/`` (derived data: replaced as a whole when it must run again)."""

from __future__ import annotations

from pipeline.stages.run import INPUTS, Run
from pipeline.store import evaluation as evaluation_store


def stage_evaluate(run: Run) -> None:
    from pipeline import evaluation

    run.require("scores", "evaluate")
    store = run.store
    reason = run.todo("evaluate")
    if reason is not None and store.stage_info("evaluate") is not None:
        run.say(f"evaluate: running again: {reason}")
    if reason is not None:
        store.forget_stage("evaluate")  # derived data: replaced as a whole
        evaluation_store.remove(store)
    evaluation.evaluate(run.context())
    if reason is not None:
        keys = [k for k in INPUTS["evaluate"] if store.has(k)]
        store.update_stage("evaluate", inputs=store.array_digests(keys),
                           **evaluation_store.record(store))
        run.wrote = True

