"""Stage ``report``: a sentence per store stating how BOX compares with its strongest
competitor, the plot of every ratio to BOX behind it, figures like the paper's, the
distribution of times to a first feasible plan, a learning curve, BOX's sensitivity to C and
renders of the first feasible plan BOX finds, as report.md and a self-contained report.html."""

from __future__ import annotations

import contextlib
import json
import math
from dataclasses import asdict
from pathlib import Path

from box_core.stats import (
    INTERVAL_METHOD,
    INTERVAL_NOTE,
    MEAN_INTERVAL_METHOD,
    RATIO_INTERVAL_METHOD,
)
from pipeline.report import figures
from pipeline.report.conclusions import conclude
from pipeline.report.data import StoreResults, load, tell_apart
from pipeline.report.document import Document
from pipeline.report.jobs import JobsBeside, LoocvJob, store_jobs
from pipeline.report.renders import render_first_feasible

__all__ = ["StoreResults", "fmt", "load", "make_report", "summary_rows"]


def fmt(x, digits: int = 4) -> str:
    """A number for a table: 4 significant digits, "-" for missing."""
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}g}"


def summary_rows(res: StoreResults) -> tuple[list[str], list[list[str]]]:
    """The evaluation's summary table (the numbers stage evaluate computed and stored)."""
    ref = figures.label(res.summary["reference"])
    header = ["selector", "found", "mean time (s)", "95% CI", "median (s)", "tries",
              f"x {ref}", f"95% CI of x {ref}"]
    rows = []
    for line in res.summary["selectors"]:
        rows.append([
            figures.label(line["name"]), f"{line['found']}/{line['rows']}",
            fmt(line["mean_time"]), f"[{fmt(line['ci_low'])}, {fmt(line['ci_high'])}]",
            fmt(line["median_time"]), fmt(line["mean_tries"], 3), fmt(line["speedup"], 3),
            f"[{fmt(line['speedup_low'], 3)}, {fmt(line['speedup_high'], 3)}]"])
    return header, rows


def leakage_statement(res: StoreResults) -> str:
    """Whether held-out rows could try constraints taken from their own raw solution."""
    leak = res.leakage
    if leak is None:
        return ("Leave-one-out: evaluated before constraint leakage was recorded "
                "(own constraints not hidden).")
    rows = leak["own_constraint_rows"]
    if rows == 0:
        return ("Leave-one-out: no constraint comes from an instance's raw solution, so no "
                "held-out instance can see its own answer.")
    if leak["hidden"]:
        return (f"Leave-one-out without leakage: the {rows} instances whose raw solution gave "
                "a constraint never try it when held out (evaluate.exclude_own_constraints="
                "true).")
    return (f"Leave-one-out WITH leakage: {rows} held-out instances may try the constraint "
            "extracted from their own raw solution, which is feasible for them by "
            "construction (evaluate.exclude_own_constraints=false).")


def _dataset_rows(results) -> tuple[list[str], list[list[str]]]:
    header = ["store", "domain", "planner", "n", "m", "feasible entries",
              "instances with a feasible constraint", "RAWPLANNER solved", "config hash"]
    rows = []
    for res in results:
        n, m = res.shape
        rows.append([str(res.path), res.domain, res.planner, str(n), str(m),
                     f"{res.feasible.mean():.1%}", f"{int(res.eligible.sum())}/{n}",
                     f"{int(res.raw_feasible.sum())}/{n}", res.config_hash])
    return header, rows


def _jobs_of(res: StoreResults, settings: dict) -> tuple[LoocvJob, LoocvJob]:
    """(learning curve, C tuning) of a store, as :mod:`pipeline.report.jobs` names them."""
    return store_jobs(res.scores, times=res.times, feasible=res.feasible,
                      forbidden=res.forbidden, seed=res.seed,
                      failure_rule=res.settings.get("failure_rule", "magnitude"),
                      evaluated=res.order, settings=settings)


def _jsonable(d: dict) -> dict:
    """NaN as null, as the stored summary writes it (strict JSON has no NaN)."""
    return {k: None if isinstance(v, float) and math.isnan(v) else v for k, v in d.items()}


def make_report(paths, out_dir: Path, settings: dict, say=print,
                beside: JobsBeside | None = None) -> dict[str, Path]:
    """Write the report for the stores at ``paths`` into ``out_dir``; return what was written.

    ``settings``: the ``report.*`` config (renders, fractions, repeats, c_grid, c_folds,
    formats).  ``beside``: jobs started earlier (``stage=all`` starts a store's learning
    curve and C tuning beside ``evaluate``); those of its results that are this report's
    own jobs are used instead of computing them again.
    """
    results = [load(p) for p in paths]
    tell_apart(results)
    jobs = [_jobs_of(res, settings) for res in results]
    early = sum(beside.has(job) for pair in jobs for job in pair) if beside else 0
    if early:  # the jobs started beside evaluate are this report's own (same inputs)
        say(f"report: {early} of its {2 * len(jobs)} leave-one-out jobs were started "
            "beside evaluate")
    with _curves_beside(jobs, beside) as running:
        return _write(results, jobs, running, Path(out_dir), settings, say)


@contextlib.contextmanager
def _curves_beside(jobs, beside: JobsBeside | None):
    """Where the report's jobs run.  With a second core the learning curves not started
    yet are computed in a second process while this one draws the figures and tunes C (the
    two are the report's longest computations, about 15 s each at 1000 × 162, rows
    stopping at their first plan); on one core everything is computed here.  The numbers
    are the same either way: both are seeded functions of the matrix alone."""
    from pipeline.cluster import available_cores

    missing = [curve for curve, _ in jobs if beside is None or not beside.has(curve)]
    if not missing or available_cores() < 2:
        yield beside
        return
    running = beside or JobsBeside(1)
    try:
        for curve in missing:
            running.start(curve)
        yield running
    finally:
        if running is not beside:
            running.close()


def _outcome(job: LoocvJob, running: JobsBeside | None):
    """The job's result: from the process it was started in, else computed here."""
    return running.result(job) if running is not None and running.has(job) else job.run()


def _write(results, jobs, running, out_dir: Path, settings: dict, say) -> dict[str, Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    formats = settings["formats"]
    doc = Document("BOX: constraint selection in score space")
    written = {}
    doc.heading("Result")
    conclusions = [conclude(res) for res in results]
    for conclusion in conclusions:
        doc.lead(conclusion.sentence)
    written["ratios"] = figures.ratio_forest(results, out_dir, formats)["png"]
    doc.image(written["ratios"], "Each selector's mean time to first feasible plan over "
              "BOX's, on the instances both solved (leave-one-out): right of the line at 1 "
              f"BOX is faster; bars: 95 % {RATIO_INTERVAL_METHOD} intervals; hollow: oracles, "
              "which see the held-out truth.")
    doc.text(f"{len(results)} store(s). Times are seconds of planning (plus each selector's "
             "own compute time in the leave-one-out tables) on the machine that computed the "
             f"store. 95 % intervals. {INTERVAL_NOTE}")
    doc.heading("Datasets")
    doc.table(*_dataset_rows(results))

    doc.heading("Time to first feasible plan")
    doc.text("FASTEST is the time-optimal oracle (the feasible constraint with the least time "
             "in the true row, tried first) and ORACLE the best-score oracle: both see the "
             "held-out truth and mark how much any selector could gain. EIPS is the cost-aware "
             "selector (probability of a feasible plan per expected second, learnt from the "
             "training rows' feasibility and times).")
    for res in results:
        doc.heading(f"{res.label} ({res.shape[0]} x {res.shape[1]})", 3)
        doc.text(leakage_statement(res))
        doc.table(*summary_rows(res))
    doc.text(f"Intervals in these tables: 95 % {INTERVAL_METHOD}.")
    written["fig3"] = figures.first_feasible(results, out_dir, formats)["png"]
    doc.image(written["fig3"], "Fig. 3 analogue: mean time to first feasible plan per "
              f"selector, leave-one-out, log scale, bars: 95 % {MEAN_INTERVAL_METHOD} "
              "interval.")
    written["distribution"] = figures.time_distributions(results, out_dir, formats)["png"]
    doc.image(written["distribution"], "Distribution of the time to first feasible plan: "
              "the share of instances with a feasible constraint that each selector has "
              "solved by each time (log scale), as OMPL's Planner Arena shows planners; "
              "dashed: oracles.")

    doc.heading("Best score versus time")
    written["fig4"] = figures.score_versus_time(results, out_dir, formats)["png"]
    doc.image(written["fig4"], "Fig. 4 analogue: mean best score found by each time over "
              "instances with a feasible constraint; dashed magenta: ORACLE's optimum, dotted: "
              f"{figures.OPTIMAL_SHARE:.0%} of the way from the failure value to it; the axis "
              "ends at 3x the time the first curve reaches that line.")

    # C is tuned here while the learning curves are computed beside (their section is first)
    tunings = [_outcome(tuning, running) for _, tuning in jobs]

    doc.heading("Learning curve")
    doc.text("Each repeat holds out 20 % of the instances and trains on growing shares of the "
             f"rest ({settings['repeats']} repeats, planning time only).")
    curves = []
    for res, (curve, _) in zip(results, jobs, strict=True):
        points = _outcome(curve, running)
        curves.append(points)
        doc.heading(res.label, 3)
        doc.table(["selector", "share of rows", "training instances", "mean time (s)",
                   "95% CI", "held-out runs"],
                  [[figures.label(p.selector), f"{p.fraction:g}", str(p.n_train), fmt(p.mean),
                    f"[{fmt(p.low)}, {fmt(p.high)}]", str(p.rows)] for p in points])
    written["learning"] = figures.learning_curves(results, curves, out_dir, formats)["png"]
    doc.image(written["learning"], "Time to first feasible plan of BOX, EIPS and STATIC versus "
              "the number of training instances; bands: 95 % interval.")

    doc.heading("Sensitivity to C")
    doc.text("The paper fixes C = 1.96. Here each instance is also run with C chosen by "
             f"{settings['c_folds']}-fold nested cross-validation: the C of a fold is the one "
             "with the lowest leave-one-out mean over the other folds only, so a held-out "
             "instance never influences its own C.")
    for res, tuning in zip(results, tunings, strict=True):
        s = tuning.summary()
        doc.heading(res.label, 3)
        rows = [[f"{c:g}", fmt(v[0]), f"[{fmt(v[1])}, {fmt(v[2])}]"]
                for c, v in tuning.sensitivity.items()]
        doc.table(["C", "mean time (s), leave-one-out", "95% CI"], rows)
        doc.table(["BOX on the same folds", "mean time (s)", "95% CI", "C per fold"], [
            ["C tuned by nested CV", fmt(s["tuned"][0]),
             f"[{fmt(s['tuned'][1])}, {fmt(s['tuned'][2])}]",
             ", ".join(f"{c:g}" for c in tuning.chosen)],
            [f"C = {tuning.fixed_c:g}", fmt(s["fixed"][0]),
             f"[{fmt(s['fixed'][1])}, {fmt(s['fixed'][2])}]", "fixed"]])
    written["c"] = figures.c_sensitivity(results, tunings, out_dir, formats)["png"]
    doc.image(written["c"], "BOX's mean time to first feasible plan versus C (leave-one-out) "
              "and the nested-CV tuned result.")

    doc.heading("The first feasible plan BOX finds")
    doc.text("On the first instances (in row order) where BOX's leave-one-out order reaches "
             "a feasible constraint: that constraint planned again with the entry's own seed "
             "and drawn, above a strip of BOX's tries on the instance.")
    render_dir = out_dir / "renders"
    render_dir.mkdir(exist_ok=True)
    for k, res in enumerate(results):
        for path, caption in render_first_feasible(res, settings["renders"], render_dir,
                                                   f"store{k}"):
            doc.image(path, caption)
    written["md"], written["html"] = doc.write(out_dir)
    numbers = {str(res.path): {"conclusion": _jsonable(asdict(conclusion)), "summary": res.summary,
                               "learning_curve": [asdict(p) for p in curve],
                               "c_tuning": tuning.summary()}
               for res, conclusion, curve, tuning
               in zip(results, conclusions, curves, tunings, strict=True)}
    written["json"] = out_dir / "report.json"
    written["json"].write_text(json.dumps(numbers, indent=1, default=float))
    say(f"report: {written['html']}")
    return written
