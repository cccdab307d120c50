"""Stage ``scores``: every (instance, constraint) entry of D, block by block on the workers."""

from __future__ import annotations

from pipeline import worker
from pipeline.execution import Task
from pipeline.stages.run import Run, instance_inputs
from pipeline.stages.todo import lost_table
from pipeline.store import layout
from pipeline.store.layout import FEASIBLE, SCORES


def stage_scores(run: Run) -> None:
    run.require("constraints", "scores")
    store = run.store
    n, m = run.cfg.instances.n, store.stage_info("constraints")["m"]
    bi, bj = run.cfg.store.block_instances, run.cfg.store.block_constraints
    reason = run.todo("scores")
    if reason is None:
        run.say(f"scores: already complete ({n} x {m}); nothing to do")
        return
    if lost_table(store, SCORES):
        run.say(f"[yellow]scores: {reason}")
    size = layout.size_of(store.attrs)
    coords = layout.coords(SCORES, run.domain, size, seeds=store.instance_seeds(),
                           sources=store.source_instances())
    if not store.has_table(SCORES) or store.missing_arrays(SCORES):
        layout.create(store, SCORES, run.domain, size, coords)
    pending = run.pending_blocks(SCORES, coords)
    store.forget_stage("scores")
    specs, seeds = instance_inputs(run)
    theta = store.theta()
    tasks = []
    for i, j in pending:
        rows, cols = slice(i * bi, min((i + 1) * bi, n)), slice(j * bj, min((j + 1) * bj, m))
        tasks.append(Task(key=f"scores-{run.token}-{i}-{j}", fn=worker.score_block,
                          args=(run.domain_spec, run.cfg.seed, specs[rows], seeds[rows],
                                theta[cols], cols.start),
                          entries=(rows.stop - rows.start) * (cols.stop - cols.start),
                          block=(i, j)))
    todo = sum(t.entries for t in tasks)
    if todo < n * m:
        run.say(f"scores: resuming, {n * m - todo} of {n * m} entries already done")
    statuses = run.run_blocks(SCORES, tasks, "scores")
    feasible = store.result(SCORES, FEASIBLE)
    run.finish("scores", feasible_fraction=float(feasible.mean()))
    mix = ", ".join(f"{k} {v}" for k, v in statuses.most_common()) or "none this run"
    run.say(f"scores: {n} x {m} complete, {feasible.mean():.1%} feasible (computed now: {mix})")

