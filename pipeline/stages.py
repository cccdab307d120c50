"""The pipeline's stages (Algorithm 2 of the paper), run by ``python -m pipeline stage=...``.

Each stage is idempotent: it reads what is already done from the store and computes only
the rest, so re-running an interrupted command resumes it and re-running a finished one
does nothing.  Only this (coordinating) process writes metadata and ``done`` masks.
"""

from __future__ import annotations

import contextlib
import json
from collections import Counter
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf
from rich.console import Console

from pipeline import configs, worker
from pipeline.configs import Stage
from pipeline.domains import ConstraintSet, load_domain
from pipeline.execution import Task, connect_first, dask_client, run_tasks
from pipeline.store import (
    RESULT_COLUMNS,
    ScoreStore,
    StoreError,
    StoreLock,
    block_region,
    check_is_ours,
    default_path,
)

GENERATE = ("instances", "raw", "constraints", "scores")


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
        self._check_values()
        planner = configs.planner_settings(self.plain["planner"])
        name = self.plain["domain"]["name"]
        overrides = {k: v for k, v in self.plain["domain"].items() if k != "name"}
        self.domain = load_domain(name, planner=planner, **overrides)
        self.domain_spec = {"name": name, "config": overrides, "planner": self.plain["planner"]}
        path = cfg.store.path or default_path(name, planner.name, cfg.seed)
        self.path = Path(path).expanduser().absolute()
        self.identity = configs.identity(cfg)
        self.identity_hash = configs.config_hash(self.identity)
        self.store: ScoreStore | None = None
        self._stack = contextlib.ExitStack()
        self._client = None

    def _check_values(self) -> None:
        c = self.cfg
        if c.instances.n < 3:
            raise ValueError(f"instances.n must be >= 3 (leave-one-out needs them), got "
                             f"{c.instances.n}")
        if c.constraints.m < 1:
            raise ValueError(f"constraints.m must be >= 1, got {c.constraints.m}")
        if c.store.block_instances < 1 or c.store.block_constraints < 1:
            raise ValueError("store.block_instances and store.block_constraints must be >= 1")
        if c.seed < 0:
            raise ValueError(f"seed must be >= 0, got {c.seed}")
        if c.cluster.retries < 0:
            raise ValueError(f"cluster.retries must be >= 0, got {c.cluster.retries}")

    # -- resources -------------------------------------------------------------------------
    def open_for_writing(self) -> ScoreStore:
        if self.path.exists() and (not self.path.is_dir() or any(self.path.iterdir())):
            check_is_ours(self.path)  # refuse before touching anything near a foreign path
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._stack.enter_context(StoreLock(self.path))
        self.store = ScoreStore.prepare(
            self.path, self.identity, self.plain,
            overwrite=self.cfg.store.mode is configs.StoreMode.overwrite)
        return self.store

    @property
    def client(self):
        if self._client is None:
            self._client = self._stack.enter_context(dask_client(self.cfg.cluster, self.console))
        return self._client

    def close(self) -> None:
        self._stack.close()

    def say(self, text: str) -> None:
        self.console.print(text, highlight=False)

    def require(self, stage: str, needed_by: str) -> None:
        if self.store.stage_info(stage) is None:
            raise StoreError(f"stage {needed_by} needs stage {stage} first "
                             f"(run stage={stage}, or stage=generate for all of them)")

    # -- helpers -----------------------------------------------------------------------
    def _pending(self, group: str) -> list[tuple[int, ...]]:
        """Chunk indices of ``group`` that still need computing: not done, or done but
        corrupted (those are un-marked here, then recomputed)."""
        finished, pending = self.store.blocks(group)
        names = [n for n in RESULT_COLUMNS if n != "time"]
        bad = self.store.corrupted_blocks(group, names + ["done"], finished)
        chunks = self.store.array(f"{group}/done").chunks
        for block in bad:
            self.store.set_done(group, block_region(block, chunks), False)
        if bad:
            self.say(f"[yellow]{group}: {len(bad)} corrupted block(s) found; recomputing them")
        return sorted(pending + bad)

    def _run_blocks(self, group: str, tasks: list[Task], label: str) -> Counter:
        statuses: Counter = Counter()

        def finished(task: Task, report: dict) -> None:
            self.store.set_done(group, task.block)
            statuses.update(report["status"])
            for message in report["errors"]:
                self.say(f"[yellow]{label}: planning error in block: {message}")

        if tasks:
            run_tasks(self.client, tasks, finished, retries=self.cfg.cluster.retries,
                      label=label, console=self.console, progress=self.cfg.progress)
        return statuses


# -- stages --------------------------------------------------------------------------------
def stage_instances(run: Run) -> None:
    store, n = run.store, run.cfg.instances.n
    if store.stage_info("instances"):
        run.say(f"instances: already complete ({n} instances); nothing to do")
        return
    seeds = instance_seeds(run.cfg.seed, n)
    specs = np.array([json.dumps(run.domain.sample_instance(int(s)), sort_keys=True)
                      for s in seeds], dtype=object)
    chunk = (run.cfg.store.block_instances,)
    store.create("instances/seed", (n,), chunk, "int64", 0, ("instance",))[:] = seeds
    store.create("instances/spec", (n,), chunk, str, "", ("instance",),
                 description="instance specs, JSON text")[:] = specs.astype(str)
    store.mark_finished("instances", n=n)
    run.say(f"instances: sampled {n} {run.domain.name} instances")


def stage_raw(run: Run) -> None:
    run.require("instances", "raw")
    store, n, b = run.store, run.cfg.instances.n, run.cfg.store.block_instances
    if not store.has("raw/done"):
        p = run.domain.n_features
        store.create("raw/tries", (n,), (b,), "int32", 0, ("instance",))
        store.create("raw/constraint", (n, p), (b, p), "float64", np.nan, ("instance", "feature"),
                     description="constraint extracted from the raw solution (NaN: none)")
        store.create_results("raw", (n,), (b,), ("instance",), run.domain.steps)
    pending = run._pending("raw")
    if not pending and store.stage_info("raw"):
        run.say("raw: already complete; nothing to do")
        return
    store.forget_stage("raw")
    tasks = []
    for (bi,) in pending:
        rows = (bi * b, min((bi + 1) * b, n))
        tasks.append(Task(key=f"raw-{run.identity_hash}-{bi}", fn=worker.raw_block,
                          args=(str(run.path), run.domain_spec, run.cfg.seed, rows),
                          entries=rows[1] - rows[0], block=(slice(*rows),)))
    if len(pending) < -(-n // b):
        run.say(f"raw: resuming, {n - sum(t.entries for t in tasks)} of {n} already done")
    run._run_blocks("raw", tasks, "raw")
    feasible = store.array("raw/feasible")[:]
    store.mark_finished("raw", feasible=int(feasible.sum()))
    run.say(f"raw: RAWPLANNER solved {int(feasible.sum())} of {n} instances")


def stage_constraints(run: Run) -> None:
    store = run.store
    if store.stage_info("constraints"):
        run.say(f"constraints: already complete "
                f"({store.stage_info('constraints')['m']} constraints); nothing to do")
        return
    domain = run.domain
    if domain.fixed_constraints:
        candidates = domain.constraints()
    else:
        run.require("raw", "constraints")
        features = store.array("raw/constraint")[...]
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
    bc = run.cfg.store.block_constraints
    store.create("constraints/theta", theta.shape, (bc, theta.shape[1]), "float64", np.nan,
                 ("constraint", "feature"))[...] = theta
    store.create("constraints/source_instance", (len(keep),), (bc,), "int64", -1,
                 ("constraint",), description="instance whose raw solution gave it; -1: fixed")
    store.array("constraints/source_instance", mode="r+")[...] = candidates.source_instance[keep]
    store.mark_finished("constraints", m=len(keep), candidates=candidates.m, m_requested=m)
    note = "" if len(keep) == m else f" (fewer than constraints.m = {m}: all candidates)"
    run.say(f"constraints: {len(keep)} of {candidates.m} candidates{note}")


def stage_scores(run: Run) -> None:
    run.require("constraints", "scores")
    store = run.store
    n, m = run.cfg.instances.n, store.stage_info("constraints")["m"]
    bi, bj = run.cfg.store.block_instances, run.cfg.store.block_constraints
    if not store.has("scores/done"):
        store.create_results("scores", (n, m), (bi, bj), ("instance", "constraint"),
                             run.domain.steps)
    pending = run._pending("scores")
    if not pending and store.stage_info("scores"):
        run.say(f"scores: already complete ({n} x {m}); nothing to do")
        return
    store.forget_stage("scores")
    tasks = []
    for i, j in pending:
        rows, cols = (i * bi, min((i + 1) * bi, n)), (j * bj, min((j + 1) * bj, m))
        tasks.append(Task(key=f"scores-{run.identity_hash}-{i}-{j}", fn=worker.score_block,
                          args=(str(run.path), run.domain_spec, run.cfg.seed, rows, cols),
                          entries=(rows[1] - rows[0]) * (cols[1] - cols[0]),
                          block=(slice(*rows), slice(*cols))))
    todo = sum(t.entries for t in tasks)
    if todo < n * m:
        run.say(f"scores: resuming, {n * m - todo} of {n * m} entries already done")
    statuses = run._run_blocks("scores", tasks, "scores")
    feasible = store.array("scores/feasible")[...]
    store.mark_finished("scores", feasible_fraction=float(feasible.mean()))
    mix = ", ".join(f"{k} {v}" for k, v in statuses.most_common()) or "none this run"
    run.say(f"scores: {n} x {m} complete, {feasible.mean():.1%} feasible (computed now: {mix})")


def stage_evaluate(run: Run) -> None:
    from pipeline import evaluation

    run.require("scores", "evaluate")
    evaluation.evaluate(run)


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

    solve(run, output_dir(run.plain["solve"]["dir"], "solve"))


def run_pipeline(cfg, console: Console) -> None:
    """Run ``cfg.stage`` (raises StoreError / ValueError for bad input)."""
    stage = cfg.stage if isinstance(cfg.stage, Stage) else Stage(cfg.stage)
    run = Run(cfg, console)
    if stage is Stage.status:
        from pipeline.status import print_status

        print_status(run.path, console)
        return
    try:
        writing = plan_stages(stage)
        if writing:
            if {"raw", "scores"} & set(writing) and connect_first(cfg.cluster):
                _ = run.client  # connect before the store is touched: a failure writes nothing
            run.open_for_writing()
            run.say(f"store: {run.path} (config {run.store.attrs['config_hash']})")
            for name in writing:
                STAGES[name](run)
                run.store.consolidate()
        if stage in (Stage.report, Stage.all):
            stage_report(run)
        if stage is Stage.solve:
            stage_solve(run)
    finally:
        run.close()
