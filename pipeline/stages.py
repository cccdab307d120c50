"""The pipeline's stages (Algorithm 2 of the paper), run by ``python -m pipeline stage=...``.

Each stage is idempotent: it reads what is already done (and intact) from the store and
computes only the rest, so re-running an interrupted command resumes it and re-running a
finished one writes nothing.  Every stage has a ``todo`` check that only reads: a run first
checks every stage it was asked for on a read-only view of the store, and takes the lock and
opens the store for writing only when one of them has work (a finished store on a read-only
disk re-runs fine).  Workers compute; only this (coordinating) process writes the store.

Each stage records digests of the arrays it was computed from (``inputs`` in its record in
the root attribute ``stages``); a stage whose inputs changed since (a block recomputed after
damage, a changed setting) runs again and says why.
"""

from __future__ import annotations

import contextlib
import json
import logging
import uuid
from collections import Counter
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf
from rich.console import Console
from rich.text import Text

from box_core import SELECTOR_REVISION
from box_core.stats import INTERVAL_METHOD
from pipeline import configs, environment, validation, worker
from pipeline.configs import Stage
from pipeline.context import StageContext
from pipeline.domains import ConstraintSet, load_domain
from pipeline.evaluation import interval_method, stored_revision
from pipeline.execution import Task, connect_first, dask_client, run_tasks
from pipeline.provenance import Provenance
from pipeline.store import (
    LAYOUT_VERSION,
    LockError,
    ScoreStore,
    StoreDamaged,
    StoreError,
    StoreLock,
    check_is_ours,
    default_path,
    domain_spec_of,
    layout,
    metadata,
    write_error,
)
from pipeline.store import evaluation as evaluation_store
from pipeline.store.integrity import Damage
from pipeline.store.layout import (
    CONSTRAINTS,
    ENVIRONMENT,
    FEASIBLE,
    INSTANCES,
    RAW,
    RAW_CONSTRAINT,
    SCORES,
    STAGE_INPUTS,
    STATUS,
)
from pipeline.store.location import locate

GENERATE = ("instances", "raw", "constraints", "scores")
log = logging.getLogger("pipeline")

#: What each stage is computed from (its digests are recorded with the stage).
INPUTS = STAGE_INPUTS


def instance_seeds(seed: int, n: int) -> np.ndarray:
    """Seeds of instances 0..n-1 of run ``seed`` (instance i's seed does not depend on n)."""
    return np.array([np.random.SeedSequence([seed, i]).generate_state(1)[0] for i in range(n)],
                    dtype=np.int64)


def blocks_of(length: int, size: int) -> list[tuple[int, int]]:
    return [(a, min(a + size, length)) for a in range(0, length, size)]


class Run:
    """One invocation: the resolved config, the store, and a Dask client when needed."""

    def __init__(self, cfg, console: Console):
        self.cfg = cfg
        self.console = console
        self.plain = OmegaConf.to_container(cfg, resolve=True, enum_to_str=True)
        validation.check_values(self.plain)  # also when stages run without the entry point
        planner = configs.planner_settings(self.plain["planner"])
        self.domain_spec = domain_spec_of(self.plain)
        name = self.domain_spec["name"]
        self.domain = load_domain(name, planner=planner, **self.domain_spec["config"])
        self.location = locate(cfg.store.path or default_path(name, planner.name, cfg.seed),
                               self.plain["store"].get("storage_options"))
        self.path = self.location.path
        self.identity = configs.identity(cfg)
        self.identity_hash = configs.config_hash(self.identity)
        #: names this run's tasks: two runs on one scheduler never share a future
        self.token = (configs.config_hash({"store": str(self.location)})[:8] + "-"
                      + uuid.uuid4().hex[:8])
        self.store: ScoreStore | None = None
        self.writing = False
        self.wrote = False
        self._todo: dict[str, str | None] = {}
        self._stack = contextlib.ExitStack()
        self._client = None

    # -- resources -------------------------------------------------------------------------
    def open_for_reading(self) -> ScoreStore | None:
        """A read-only view of the existing store made with this config, or None when
        there is none yet (a foreign path or a different config is refused here unless
        ``store.mode=overwrite``, which needs writing)."""
        holder = StoreLock(self.location).held_by_other() if self.location.exists() else None
        if holder:
            raise LockError(f"store {self.location} is in use by a running pipeline ({holder}); "
                            "wait for it or stop it first")
        if self.location.is_empty():
            return None
        check_is_ours(self.location)
        store = ScoreStore(self.location, read_only=True)
        if store.attrs.get("identity") != self.identity:
            return None  # prepare() refuses it, or replaces it with store.mode=overwrite
        self.store = store
        return store

    def open_for_writing(self) -> ScoreStore:
        """Lock the store and open it for writing (created, replaced or migrated here)."""
        if self.writing:
            return self.store
        if self.location.local is not None:
            local = self.location.local
            if local.exists() and (not local.is_dir() or any(local.iterdir())):
                check_is_ours(self.location)  # refuse before touching anything near it
            local.parent.mkdir(parents=True, exist_ok=True)
        lock = self._stack.enter_context(StoreLock(self.location))
        self.store = ScoreStore.prepare(
            self.location, self.identity, self.recorded_config(),
            overwrite=self.cfg.store.mode is configs.StoreMode.overwrite)
        self.store.fence = lock.check
        note = metadata.repair_layout_version(self.store)
        if note:
            self.say(f"[yellow]store: {note}")
        if self.store.layout_version < LAYOUT_VERSION:
            from pipeline.store.migrate import migrate

            for note in migrate(self.store, self.domain):
                self.say(f"store: migrated to {note}")
        found = metadata.check(self.store, self.domain)
        if found:
            for note in metadata.repair(self.store, self.domain, found):
                self.say(f"[yellow]store: {note}")
            self.wrote = True
        self.writing = True
        return self.store

    def recorded_config(self) -> dict:
        """The resolved config as the store records it (storage options may hold secrets:
        only their keys are kept)."""
        store = dict(self.plain["store"])
        store["storage_options"] = dict.fromkeys(store.get("storage_options") or {}, "***")
        return {**self.plain, "store": store}

    @property
    def client(self):
        if self._client is None:
            self._client = self._stack.enter_context(dask_client(self.cfg.cluster, self.console))
        return self._client

    def close(self) -> None:
        self._stack.close()

    def context(self) -> StageContext:
        """What the evaluate and solve stages see of this run."""
        return StageContext(store=self.store, path=self.path, config=self.plain,
                            seed=self.cfg.seed, token=self.token,
                            retries=self.cfg.cluster.retries, progress=self.cfg.progress,
                            console=self.console, client=lambda: self.client)

    def say(self, text: str) -> None:
        """One line, never wrapped, on the console and in the run's log (Hydra's
        ``outputs/<date>/<time>/__main__.log``)."""
        self.console.print(text, highlight=False, soft_wrap=True)
        log.info(Text.from_markup(text).plain)

    def require(self, stage: str, needed_by: str) -> None:
        if self.store is None or self.store.stage_info(stage) is None:
            raise StoreError(f"stage {needed_by} needs stage {stage} first "
                             f"(run stage={stage}, or stage=generate for all of them)")

    # -- what changed ------------------------------------------------------------------------
    def todo(self, stage: str) -> str | None:
        """Why ``stage`` must run, or None (checked once per stage and run: the read-only
        check that decided to take the lock is not repeated)."""
        if stage not in self._todo:
            self._todo[stage] = TODO[stage](self)
        return self._todo.pop(stage) if self.writing else self._todo[stage]

    def changed_inputs(self, stage: str) -> list[str]:
        """Inputs of ``stage`` whose digests differ from those it recorded."""
        recorded = (self.store.stage_info(stage) or {}).get("inputs")
        if not recorded:
            return []  # not run, or run before inputs were recorded
        keys = [k for k in recorded if self.store.has(k)]
        current = self.store.array_digests(keys)
        return sorted(k for k in recorded if current.get(k) != recorded[k])

    def finish(self, stage: str, **info) -> None:
        """Mark ``stage`` finished, with the digests of its inputs."""
        keys = [k for k in INPUTS[stage] if self.store.has(k)]
        self.store.mark_finished(stage, inputs=self.store.array_digests(keys), **info)
        self.wrote = True

    # -- block groups ------------------------------------------------------------------------
    def block_state(self, group: str) -> tuple[list[tuple], Damage]:
        """(blocks to compute, damage found in finished ones) of a result group."""
        store = self.store
        if not store.has_table(group):
            finished, pending = store.blocks(group)  # a layout-1 store opened read-only
            damage = store.verify(group)
            return sorted(set(pending) | damage.blocks), damage
        finished = store.finished_blocks(group)
        damage = store.verify(group, finished)
        ok = set(finished) - damage.blocks
        return [b for b in np.ndindex(*store.grid(group)) if b not in ok], damage

    def pending_blocks(self, group: str, coords: dict) -> list[tuple[int, ...]]:
        """Blocks of ``group`` to compute; damaged finished ones are un-marked first (and
        the coordinates, derived from other groups, written again)."""
        changed = self.changed_inputs(group)
        if changed:
            self.say(f"[yellow]{group}: its inputs changed since it ran "
                     f"({', '.join(changed)}); computing every block again")
            self.store.forget_blocks(group, list(np.ndindex(*self.store.grid(group))))
            self.store.forget_stage(group)
        pending, damage = self.block_state(group)
        if damage:
            self.say(f"[yellow]{group}: {len(damage.blocks)} damaged block(s) found "
                     f"({damage.describe()}); recomputing them")
            self.store.forget_blocks(group, sorted(damage.blocks))
            self.store.forget_stage(group)
            names = [n for n in self.store.layout(group).names if n not in coords]
            self.store.write_coords(group, coords, names)
        return sorted(pending)

    def worker_environments(self) -> list[dict]:
        """The distinct environments of the workers connected now (this process's when
        they cannot be asked)."""
        try:
            found = list(self.client.run(environment.fingerprint).values())
        except Exception:  # noqa: BLE001 (the watchdog reports unusable workers)
            found = []
        return [r for k, r in enumerate(found) if r not in found[:k]] or \
            [environment.fingerprint()]

    def run_blocks(self, group: str, tasks: list[Task], label: str) -> Counter:
        statuses: Counter = Counter()
        provenance = Provenance(self.store, group, self.cfg.store.environment, self.say)
        if tasks:
            provenance.before(self.worker_environments())

        def finished(task: Task, result: tuple[dict, dict]) -> None:
            arrays, report = result
            where = provenance.index(report["environment"])
            arrays[ENVIRONMENT] = np.full(np.shape(arrays[STATUS]), where, dtype="int16")
            self.store.write_block(group, task.block, arrays)
            statuses.update(report["status"])
            for message in report["errors"]:
                self.say(f"[yellow]{label}: planning error in block: {message}")

        if tasks:
            self.wrote = True
            run_tasks(self.client, tasks, finished, retries=self.cfg.cluster.retries,
                      label=label, console=self.console, progress=self.cfg.progress,
                      every_s=self.cfg.progress_every)
        return statuses


# -- the checks every stage makes before writing anything --------------------------------------
def todo_whole(run: Run, stage: str, group: str) -> str | None:
    """Why a stage written whole (instances, constraints) must run, or None."""
    store = run.store
    if store is None or store.stage_info(stage) is None:
        return "not run yet"
    if lost_table(store, group):
        return "its integrity table is missing"
    changed = run.changed_inputs(stage)
    if changed:
        return f"its inputs changed ({', '.join(changed)})"
    damage = store.verify(group, expect_all=True)
    return f"damaged: {damage.describe()}" if damage else None


def lost_table(store, group: str) -> bool:
    """Whether ``group``'s integrity table is gone from a store that had one: its data can
    no longer be verified, so it is computed again (and compared, where it is an input)."""
    return store.layout_version >= 2 and store.has_group(group) and not store.has_table(group)


def todo_blocks(run: Run, stage: str) -> str | None:
    """Why a result stage (raw, scores) must run, or None."""
    store = run.store
    if store is None or not store.has_results(stage):
        return "not run yet"
    if lost_table(store, stage):
        return "its integrity table is missing: every block is computed again"
    changed = run.changed_inputs(stage)
    if changed:
        return f"its inputs changed ({', '.join(changed)})"
    pending, damage = run.block_state(stage)
    if damage:
        return f"damaged: {damage.describe()}"
    if pending or store.stage_info(stage) is None:
        return f"{len(pending)} blocks to compute"
    return None


def todo_evaluate(run: Run) -> str | None:
    store = run.store
    info = store.stage_info("evaluate") if store is not None else None
    if info is None:
        return "not run yet"
    if info.get("settings") != run.plain["evaluate"]:
        return "its settings changed"
    if stored_revision(info) != SELECTOR_REVISION:
        return (f"box_core's selectors changed (revision {stored_revision(info)} -> "
                f"{SELECTOR_REVISION})")
    if interval_method(info) != INTERVAL_METHOD:
        return f"its intervals are {interval_method(info)}, this version's are {INTERVAL_METHOD}"
    changed = run.changed_inputs("evaluate")
    if changed:
        return f"its inputs changed ({', '.join(changed)})"
    outputs = info.get("outputs")
    if outputs is None:
        return None  # run before outputs were recorded
    damage = store.verify_whole(outputs)
    return f"its results are damaged: {damage.describe()}" if damage else None


TODO = {"instances": lambda run: todo_whole(run, "instances", INSTANCES),
        "raw": lambda run: todo_blocks(run, RAW),
        "constraints": lambda run: todo_whole(run, "constraints", CONSTRAINTS),
        "scores": lambda run: todo_blocks(run, SCORES),
        "evaluate": todo_evaluate}


# -- stages --------------------------------------------------------------------------------
def stage_instances(run: Run) -> None:
    store, n = run.store, run.cfg.instances.n
    reason = run.todo("instances")
    if reason is None:
        run.say(f"instances: already complete ({n} instances); nothing to do")
        return
    seeds = instance_seeds(run.cfg.seed, n)
    specs = np.array([json.dumps(run.domain.sample_instance(int(s)), sort_keys=True)
                      for s in seeds], dtype=str)
    size = layout.size_of(store.attrs)
    coords = layout.coords(INSTANCES, run.domain, size)

    def make():
        layout.create(store, INSTANCES, run.domain, size, coords)

    repairing = store.stage_info("instances") is not None
    store.write_whole(INSTANCES, {**layout.instance_arrays(seeds, specs),
                                  **{k: v for k, (_, v, _) in coords.items()}}, make,
                      changed=lambda: run.changed_inputs("instances"))
    run.finish("instances", n=n)
    if repairing:
        run.say(f"instances: {reason}; sampled again from their seeds and repaired")
    else:
        run.say(f"instances: sampled {n} {run.domain.name} instances")


def _inputs(run: Run):
    specs = [str(s) for s in run.store.instance_specs()]
    seeds = run.store.instance_seeds()
    return specs, seeds


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
    specs, seeds = _inputs(run)
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


def stage_constraints(run: Run) -> None:
    store = run.store
    reason = run.todo("constraints")
    if reason is None:
        run.say(f"constraints: already complete "
                f"({store.stage_info('constraints')['m']} constraints); nothing to do")
        return
    domain = run.domain
    if domain.fixed_constraints:
        candidates = domain.constraints()
    else:
        run.require("raw", "constraints")
        features = store.array(RAW_CONSTRAINT)[...]
        extracted = ConstraintSet(features, np.arange(len(features)))
        candidates = domain.constraints(extracted)
    if candidates.m == 0:
        raise StoreError("constraints: no candidate constraints (RAWPLANNER solved no "
                         "instance); raise the raw planner's budget or instances.n")
    m = run.cfg.constraints.m
    keep = np.arange(candidates.m)
    if candidates.m > m:
        rng = np.random.default_rng([run.cfg.seed, 3])
        keep = np.sort(rng.choice(candidates.m, size=m, replace=False))
    theta = candidates.features[keep]
    size = layout.size_of(store.attrs)._replace(m=len(keep))
    coords = layout.coords(CONSTRAINTS, domain, size)

    def make():
        layout.create(store, CONSTRAINTS, domain, size, coords)

    repairing = store.stage_info("constraints") is not None and "damaged" in reason
    store.write_whole(CONSTRAINTS, {**layout.constraint_arrays(
                          theta, candidates.source_instance[keep]),
                      **{k: v for k, (_, v, _) in coords.items()}}, make,
                      changed=lambda: run.changed_inputs("constraints"))
    run.finish("constraints", m=len(keep), candidates=candidates.m, m_requested=m)
    if repairing:
        run.say(f"constraints: {reason}; computed again and repaired")
        return
    note = "" if len(keep) == m else f" (fewer than constraints.m = {m}: all candidates)"
    run.say(f"constraints: {len(keep)} of {candidates.m} candidates{note}")


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
    specs, seeds = _inputs(run)
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


STAGES = {"instances": stage_instances, "raw": stage_raw, "constraints": stage_constraints,
          "scores": stage_scores, "evaluate": stage_evaluate}


def plan_stages(stage: Stage) -> tuple[str, ...]:
    """The store-writing stages that ``stage`` runs, in order."""
    if stage is Stage.generate:
        return GENERATE
    if stage is Stage.all:
        return (*GENERATE, "evaluate")
    if stage in (Stage.report, Stage.solve, Stage.status):
        return ()
    return (stage.value,)


def output_dir(configured: str | None, name: str) -> Path:
    """Where ``report`` and ``solve`` write: the configured folder, else the run's Hydra
    output folder (outputs/<date>/<time>/ by default), else ./outputs/<name>."""
    if configured:
        return Path(configured).expanduser().absolute()
    try:
        from hydra.core.hydra_config import HydraConfig

        return Path(HydraConfig.get().runtime.output_dir) / name
    except (ImportError, ValueError):
        return Path.cwd() / "outputs" / name


def stage_report(run: Run) -> None:
    from pipeline.report import make_report

    settings = run.plain["report"]
    if settings["renders"] < 0 or settings["repeats"] < 1 or settings["c_folds"] < 2:
        raise ValueError("report.renders must be >= 0, report.repeats >= 1 and "
                         "report.c_folds >= 2")
    bad = set(settings["formats"]) - {"png", "svg", "pdf"}
    if bad or "png" not in settings["formats"]:
        raise ValueError(f"report.formats must include png and may add svg or pdf, got "
                         f"{settings['formats']}")
    paths = [Path(p).expanduser().absolute() for p in settings["stores"]] or [run.path]
    make_report(paths, output_dir(settings["dir"], "report"), settings, say=run.say)


def stage_solve(run: Run) -> None:
    from pipeline.solve import solve

    solve(run.context(), output_dir(run.plain["solve"]["dir"], "solve"))


def run_pipeline(cfg, console: Console) -> None:
    """Run ``cfg.stage`` (raises StoreError / ValueError for bad input, StoreDamaged when
    ``stage=status`` finds damage)."""
    stage = cfg.stage if isinstance(cfg.stage, Stage) else Stage(cfg.stage)
    run = Run(cfg, console)
    if stage is Stage.status:
        from pipeline.store.status import damaged, print_status

        report = print_status(run.location, console)
        if damaged(report):
            raise StoreDamaged(f"store {run.location} is damaged: {damaged(report)}")
        return
    try:
        writing = plan_stages(stage)
        if writing:
            _write_stages(run, writing)
        if stage in (Stage.report, Stage.all):
            stage_report(run)
        if stage is Stage.solve:
            stage_solve(run)
    finally:
        run.close()


def _write_stages(run: Run, names) -> None:
    """Run the store-writing stages ``names``: checked read-only first, written (under the
    lock) only from the first stage that has work.  Metadata documents are checked before
    any array is read: a damaged one is repaired (or refused) first."""
    store = run.open_for_reading()
    try:
        if store is not None and metadata.check(store, run.domain):
            run.open_for_writing()
        for name in names:
            if not run.writing and run.todo(name) is not None:
                if {"raw", "scores"} & set(names) and connect_first(run.cfg.cluster):
                    _ = run.client  # connect before the store is touched: a failure writes nothing
                run.open_for_writing()
                run.say(f"store: {run.path} (config {run.store.attrs['config_hash']})")
            if not run.writing and name == "evaluate":
                from pipeline.evaluation import evaluate

                evaluate(run.context())  # says "already complete" and shows the stored summary
                continue
            if not run.writing:
                run.say(f"{name}: already complete; nothing to do")
                continue
            STAGES[name](run)
            if run.wrote:
                run.store.consolidate()
        if run.wrote:
            run.store.set_attrs(config=run.recorded_config())  # the latest settings
            run.store.consolidate()
    except OSError as exc:
        raise write_error(run.location, exc) from None
