"""Stage ``raw``: RAWPLANNER on every instance, block by block on the workers."""

from __future__ import annotations

from pipeline import worker
from pipeline.execution import Task
from pipeline.stages.run import Run, instance_inputs
from pipeline.stages.todo import lost_table
from pipeline.store import layout
from pipeline.store.layout import FEASIBLE, RAW


def stage_raw(run: Run) -> None:
    run.require("instances", "raw")
    store, n, b = run.store, run.cfg.instances.n, run.cfg.store.block_instances
    reason = run.todo("raw")
    if reason is None:
        run.say("raw: already complete; nothing to do")
        return
    if lost_table(store, RAW):
        run.say(f"[yellow]raw: {reason}")
    size = layout.size_of(store.attrs)
    coords = layout.coords(RAW, run.domain, size, seeds=store.instance_seeds())
    if not store.has_table(RAW) or store.missing_arrays(RAW):
        layout.create(store, RAW, run.domain, size, coords)
    pending = run.pending_blocks(RAW, coords)
    store.forget_stage("raw")
    specs, seeds = instance_inputs(run)
    tasks = []
    for (bi,) in pending:
        rows = slice(bi * b, min((bi + 1) * b, n))
        tasks.append(Task(key=f"raw-{run.token}-{bi}", fn=worker.raw_block,
                          args=(run.domain_spec, run.cfg.seed, specs[rows], seeds[rows]),
                          entries=rows.stop - rows.start, block=(bi,)))
    if len(pending) < -(-n // b):
        run.say(f"raw: resuming, {n - sum(t.entries for t in tasks)} of {n} already done")
    run.run_blocks(RAW, tasks, "raw")
    feasible = store.result(RAW, FEASIBLE)
    run.finish("raw", feasible=int(feasible.sum()))
    run.say(f"raw: RAWPLANNER solved {int(feasible.sum())} of {n} instances")

