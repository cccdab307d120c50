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

The package: :mod:`~pipeline.stages.run` (the :class:`Run` of one invocation and what every
stage shares), :mod:`~pipeline.stages.todo` (why a stage must run), a module per
store-writing stage (``instances``, ``raw``, ``constraints``, ``scores``, ``evaluate``), and
here :func:`run_pipeline`, which runs them in order, then ``report`` or ``solve``.
"""

from __future__ import annotations

from pathlib import Path

from rich.console import Console

from pipeline.configs import Stage
from pipeline.execution import connect_first
from pipeline.stages.constraints import stage_constraints
from pipeline.stages.evaluate import stage_evaluate
from pipeline.stages.instances import instance_seeds, stage_instances
from pipeline.stages.raw import stage_raw
from pipeline.stages.run import INPUTS, Run
from pipeline.stages.scores import stage_scores
from pipeline.store import StoreDamaged, metadata, write_error

__all__ = ["INPUTS", "STAGES", "Run", "instance_seeds", "plan_stages", "run_pipeline",
           "stage_constraints", "stage_evaluate", "stage_instances", "stage_raw",
           "stage_scores"]

GENERATE = ("instances", "raw", "constraints", "scores")
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


def report_paths(run: Run) -> list[Path]:
    """The stores a report of this run covers: ``report.stores``, else the run's own."""
    return [Path(p).expanduser().absolute() for p in run.plain["report"]["stores"]] or [
        run.path]


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
    make_report(report_paths(run), output_dir(settings["dir"], "report"), settings,
                say=run.say, beside=run.report_jobs)


def start_report_jobs(run: Run) -> None:
    """``stage=all``, before ``evaluate`` runs: start the report's learning curve and C
    tuning of this run's store in two other processes (:mod:`pipeline.report.jobs`).  They
    need the finished score matrix only, and ``evaluate`` leaves part of the second core
    idle; the report then takes their results.  Not where the report covers other stores,
    or on one core.  (``Run`` has checked the ``report.*`` values already.)"""
    from pipeline.cluster import available_cores
    from pipeline.evaluation import evaluated_selectors, hidden_constraints, own_constraints
    from pipeline.report.jobs import JobsBeside, store_jobs

    settings = run.plain["report"]
    if available_cores() < 2 or run.path not in report_paths(run):
        return
    store, evaluate = run.store, run.plain["evaluate"]
    scores, feasible, times, _ = store.score_matrix()
    jobs = store_jobs(scores, times=times, feasible=feasible,
                      forbidden=hidden_constraints(own_constraints(store), evaluate),
                      seed=run.cfg.seed,
                      failure_rule=evaluate["failure_rule"],
                      evaluated=evaluated_selectors(evaluate), settings=settings)
    run.report_jobs = JobsBeside(len(jobs), niceness=19)
    run.on_close(run.report_jobs.close)
    for job in jobs:
        run.report_jobs.start(job)
    run.say("report: its learning curve and C tuning start now, beside evaluate, at the "
            "lowest priority")


def stage_solve(run: Run) -> None:
    from pipeline.solve import solve

    solve(run.context(), output_dir(run.plain["solve"]["dir"], "solve"))


def run_pipeline(cfg, console: Console, explicit=frozenset()) -> None:
    """Run ``cfg.stage`` (raises StoreError / ValueError for bad input, StoreDamaged when
    ``stage=status`` finds damage).  ``explicit``: the keys the command line set
    (:class:`Run`)."""
    stage = cfg.stage if isinstance(cfg.stage, Stage) else Stage(cfg.stage)
    run = Run(cfg, console, explicit)
    if stage is Stage.status:
        from pipeline.store.status import damaged, print_status

        report = print_status(run.location, console)
        if damaged(report):
            raise StoreDamaged(f"store {run.location} is damaged: {damaged(report)}")
        return
    try:
        writing = plan_stages(stage)
        if writing:
            _write_stages(run, writing, start_report=stage is Stage.all)
        if stage in (Stage.report, Stage.all):
            stage_report(run)
        if stage is Stage.solve:
            stage_solve(run)
    finally:
        run.close()


def _write_stages(run: Run, names, start_report: bool = False) -> None:
    """Run the store-writing stages ``names``: checked read-only first, written (under the
    lock) only from the first stage that has work.  Metadata documents are checked before
    any array is read: a damaged one is repaired (or refused) first.  ``start_report``:
    a report follows, whose longest jobs start beside ``evaluate``
    (:func:`start_report_jobs`)."""
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
            if name == "evaluate" and start_report:
                start_report_jobs(run)
            STAGES[name](run)
            run.store.consolidate()  # if this stage changed a metadata document
        if run.wrote:
            latest = run.recorded_config()
            if run.store.attrs.get("config") != latest:
                run.store.set_attrs(config=latest)  # the settings of the latest run
            run.store.consolidate()
    except OSError as exc:
        raise write_error(run.location, exc) from None
