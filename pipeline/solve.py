"""Stage ``solve``: new instances solved live, the prior fitted from a store.

The leave-one-out figures replay planning times recorded in D; this stage checks the claim
with the real planner.  For each fresh instance (a seed the store never used), every chosen
selector proposes constraints one at a time and each proposal is planned for real, within a
budget of planning calls or seconds; RAWPLANNER runs on the same instance.  Times are wall
clock inside one worker process: selector compute plus planning, from the first proposal to
the end of the first feasible plan.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

import box_core
from box_core.stats import mean_ci, paired_ratio
from pipeline.configs import RAWPLANNER
from pipeline.context import StageContext
from pipeline.report import fmt
from pipeline.report.figures import label
from pipeline.store import ScoreStore, StoreError
from pipeline.store.layout import CHECKS, SCORES

#: Fresh instance i of run ``seed`` is drawn from SeedSequence([seed, SOLVE_STREAM, i]);
#: the store's instances use SeedSequence([seed, i]).  Collisions are skipped explicitly.
SOLVE_STREAM = 2**32 + 1


def fresh_seeds(seed: int, n: int, used) -> list[int]:
    used = {int(s) for s in used}
    out, i = [], 0
    while len(out) < n:
        s = int(np.random.SeedSequence([seed, SOLVE_STREAM, i]).generate_state(1)[0])
        if s not in used:
            out.append(s)
            used.add(s)
        i += 1
    return out


def training_matrix(store: ScoreStore, use_incomplete: bool, failure_rule: str):
    """(filled scores of the usable rows, their feasibility and times, theta, failure
    value, rows used).  :func:`training_context` reads those rows' features and checks."""
    if store.stage_info("constraints") is None or not store.has_results(SCORES):
        raise StoreError(f"{store.path} has no score matrix yet; run stage=generate first")
    done = store.done(SCORES)
    complete = done.all(axis=1)
    if store.stage_info("scores") is None:
        if not use_incomplete:
            raise StoreError(
                f"{store.path} is incomplete: {int(done.sum())} of {done.size} score entries "
                f"done ({int(complete.sum())} complete rows); finish it with stage=generate, "
                "or pass solve.use_incomplete=true to fit on the complete rows only")
        if complete.sum() < 3:
            raise StoreError(f"{store.path} has only {int(complete.sum())} complete rows; "
                             "the prior needs at least 3")
        scores, feasible, times, theta = store.score_matrix(rows=complete)
    else:
        scores, feasible, times, theta = store.score_matrix()
    if not feasible.any():
        raise StoreError(f"{store.path}: no feasible entry in the training rows; BOX has "
                         "nothing to learn from")
    d = box_core.failure_value(scores, feasible, failure_rule)
    return (box_core.fill_failures(scores, feasible, d), feasible, times, theta, d,
            np.flatnonzero(complete))


def training_context(store: ScoreStore, rows: np.ndarray) -> tuple:
    """(instance features (rows, q) or None, collision checks (rows, m)) of the training
    rows: what the contextual selectors learn besides the scores."""
    found = store.instance_features()
    features = None if found is None else found.values[rows]
    return features, store.result(SCORES, CHECKS)[rows]


def selector_settings(names: list[str], train, train_feasible, train_times, train_checks,
                      train_features, c: float) -> dict[str, dict]:
    """Each selector's parameters for :func:`box_core.make_selector`: BOX's C, and the
    settings a tuned selector (contextual) chooses on the training rows, tuned once here
    rather than for every instance (the same settings: they depend on those rows only)."""
    out = {}
    for name in names:
        if name == "box":
            out[name] = {"c": c}
        elif getattr(box_core.SELECTORS[name], "tuned", None) is not None:
            out[name] = {"settings": box_core.tuned_settings(
                name, train, feasible=train_feasible, times=train_times, checks=train_checks,
                instance_features=train_features)}
        else:
            out[name] = {}
    return out


def solve_instance(spec: dict, instance: dict, inst_seed: int, run_seed: int, train, theta,
                   d: float, selectors: list[str], params: dict[str, dict],
                   max_evaluations: int, max_seconds: float | None, order_flip: bool = False,
                   train_feasible=None, train_times=None, train_checks=None,
                   train_features=None) -> dict:
    """One fresh instance: every selector live, then RAWPLANNER (runs in a worker).

    A selector's try may be capped (contextual_capped): it runs as a planning try
    (:meth:`Domain.start_try`) that pauses at its allowance of collision checks and, when
    the selector proposes it again, resumes where it stopped.  ``max_evaluations``
    counts the tries that ended; the times include the paused slices."""
    from pipeline.worker import RAW_ENTRY, domain_for, entry_seed

    domain = domain_for(spec)
    inst = domain.check_instance(instance)
    context = {}
    if train_features is not None:
        context = {"instance_features": train_features,
                   "new_instance_features": domain.instance_features(inst)}
    # untimed warm-up: the worker's simulator loads this instance (and on its first task
    # builds its scene) here, not inside whichever method happens to run first
    domain.plan(inst, theta[0], seed=entry_seed(run_seed, inst_seed, 0))
    out = {"seed": inst_seed, "selectors": {}}
    methods = [*selectors, RAWPLANNER]
    if order_flip:  # alternate which method runs first: caches favour neither
        methods.reverse()
    for name in methods:
        if name == RAWPLANNER:
            out["selectors"][name] = _raw(domain, inst, entry_seed(run_seed, inst_seed,
                                                                   RAW_ENTRY), d)
            continue
        k = selectors.index(name)
        sel = box_core.make_selector(name, train, features=theta, seed=[run_seed, inst_seed, k],
                                     feasible=train_feasible, times=train_times,
                                     checks=train_checks, **context, **params[name])
        tries, best, first = [], None, math.nan
        paused: dict[int, object] = {}  # column -> its planning try
        ended = 0
        start = time.perf_counter()
        while ended < min(max_evaluations, theta.shape[0]):
            j, allowance = sel.propose_try()
            if math.isinf(allowance) and j not in paused:
                plan = domain.plan(inst, theta[j], seed=entry_seed(run_seed, inst_seed, j))
                slice_time = plan.time
            else:
                attempt = paused.pop(j, None) or domain.start_try(
                    inst, theta[j], seed=entry_seed(run_seed, inst_seed, j))
                t0 = time.perf_counter()
                plan = attempt.advance(None if math.isinf(allowance) else int(allowance))
                slice_time = time.perf_counter() - t0
                if plan is None:
                    paused[j] = attempt
                    sel.report(j, paused=True)
                    tries.append({"constraint": j, "status": "paused", "time": slice_time,
                                  "allowance": int(allowance), "length": None})
                    if max_seconds is not None and time.perf_counter() - start >= max_seconds:
                        break
                    continue
            ended += 1
            sel.report(j, score=plan.score if plan.feasible else d)
            elapsed = time.perf_counter() - start
            tries.append({"constraint": j, "status": plan.status.name.lower(),
                          "time": slice_time, "length": plan.length if plan.feasible else None,
                          "allowance": None if math.isinf(allowance) else int(allowance)})
            if plan.feasible:
                if math.isnan(first):
                    first = elapsed
                if best is None or plan.score > best[1].score:
                    best = (j, plan)
            if max_seconds is not None and elapsed >= max_seconds:
                break
        paused.clear()  # frees the searches of tries never resumed
        out["selectors"][name] = {
            "first_feasible_time": first, "tries": tries,
            "first_feasible_try": next((t + 1 for t, r in enumerate(tries) if r["length"]
                                        is not None), None),
            "best_score": best[1].score if best else d,
            "best_constraint": best[0] if best else None,
            "best_path": best[1].path if best else None}
    out["selectors"] = {name: out["selectors"][name] for name in [*selectors, RAWPLANNER]}
    return out


def _raw(domain, inst, seed: int, d: float) -> dict:
    raw = domain.raw_plan(inst, seed=seed)
    ok = raw.plan.feasible
    return {"first_feasible_time": raw.time if ok else math.nan, "tries": raw.tries,
            "first_feasible_try": raw.tries if ok else None,
            "best_score": raw.plan.score if ok else d,
            "best_constraint": raw.constraint.tolist() if ok else None,
            "best_path": raw.plan.path if ok else None}


#: Columns of :func:`live_table` (by position) left out at narrow widths, in this order:
#: best score, tries, median, the interval of the mean, then the speed-up over BOX (its
#: interval first); method, solved, mean and the speed-up over RAWPLANNER with its
#: interval always stay (solve.json keeps every column).
LIVE_DROP = {6: 1, 5: 2, 4: 3, 3: 4, 10: 5, 9: 6}


def live_table(records: list[dict], names: list[str], level: float = 0.95):
    """Header and rows: live time to first feasible per method and its speed-up over
    RAWPLANNER and over BOX (paired, on the same instances), where they ran."""
    times = {n: np.array([r["selectors"][n]["first_feasible_time"] for r in records],
                         dtype=np.float64) for n in names}
    references = [r for r in (RAWPLANNER, "box") if r in times]
    header = ["method", "solved", "mean (s)", "95% CI", "median (s)", "tries", "best score"]
    for reference in references:
        header += [f"x faster than {label(reference)}", "95% CI"]
    rows = []
    for n in names:
        t = times[n]
        found = ~np.isnan(t)
        mean, lo, hi = mean_ci(t, level)
        tries = [r["selectors"][n]["first_feasible_try"] for r in records]
        tries = [x for x in tries if x is not None]
        best = np.mean([r["selectors"][n]["best_score"] for r in records])
        row = [label(n), f"{int(found.sum())}/{t.size}", fmt(mean), f"[{fmt(lo)}, {fmt(hi)}]",
               fmt(float(np.median(t[found])) if found.any() else math.nan),
               fmt(float(np.mean(tries)) if tries else math.nan, 3), fmt(best)]
        for reference in references:
            ratio = paired_ratio(times[reference], t, level)
            row += [fmt(ratio[0], 3), f"[{fmt(ratio[1], 3)}, {fmt(ratio[2], 3)}]"]
        rows.append(row)
    return header, rows


def _jsonable(record: dict) -> dict:
    out = {"seed": record["seed"], "selectors": {}}
    for name, r in record["selectors"].items():
        clean = {k: v for k, v in r.items() if k != "best_path"}
        clean = {k: (None if isinstance(v, float) and math.isnan(v) else v)
                 for k, v in clean.items()}
        out["selectors"][name] = clean
    return out


def solve(ctx: StageContext, out_dir: Path) -> dict:
    """Run stage solve for ``ctx``'s run (its store must exist); write results into
    ``out_dir``."""
    from pipeline.execution import Task, run_tasks
    from pipeline.tables import Column, FittedTable
    from pipeline.worker import domain_for

    settings = ctx.config["solve"]
    if settings["n"] < 1:
        raise ValueError(f"solve.n must be >= 1, got {settings['n']}")
    budget = settings["max_evaluations"]
    if budget is not None and budget < 1:
        raise ValueError(f"solve.max_evaluations must be >= 1 or null, got {budget}")
    if settings["max_seconds"] is not None and settings["max_seconds"] <= 0:
        raise ValueError(f"solve.max_seconds must be > 0 or null, got {settings['max_seconds']}")
    names = list(dict.fromkeys(s for s in settings["selectors"] if s != RAWPLANNER))
    for name in names:
        if box_core.SELECTORS.get(name) is not None and box_core.SELECTORS[name].needs_truth:
            raise ValueError(f"solve.selectors: {name} needs the true scores of a new "
                             "instance, which live solving does not have")
        box_core.selectors.check_selector(name, {"c": 1.0} if name == "box" else {},
                                          features=np.zeros((1, 1)))
    store = ScoreStore.open(ctx.path)
    spec = store.domain_spec()
    train, train_feasible, train_times, theta, d, rows = training_matrix(
        store, settings["use_incomplete"], ctx.config["evaluate"]["failure_rule"])
    train_features, train_checks = training_context(store, rows)
    params = selector_settings(names, train, train_feasible, train_times, train_checks,
                               train_features, ctx.config["evaluate"]["c"])
    seed = int(store.attrs["config"]["seed"])
    domain = domain_for(spec)
    seeds = fresh_seeds(seed, settings["n"], store.instance_seeds())
    instances = [domain.sample_instance(s) for s in seeds]
    ctx.say(f"solve: {len(seeds)} fresh {spec['name']} instances, prior from {rows.size} rows "
            f"x {theta.shape[0]} constraints of {store.path}")
    records: dict[int, dict] = {}
    max_eval = budget or theta.shape[0]
    tasks = [Task(key=f"solve-{ctx.token}-{k}-{s}", fn=solve_instance,
                  args=(spec, instances[k], s, seed, train, theta, d, names, params,
                        max_eval, settings["max_seconds"], k % 2 == 1, train_feasible,
                        train_times, train_checks, train_features),
                  entries=1, block=k) for k, s in enumerate(seeds)]
    run_tasks(ctx.client(), tasks, lambda task, rec: records.__setitem__(task.block, rec),
              retries=ctx.retries, label="solve", console=ctx.console,
              progress=ctx.progress, every_s=ctx.config["progress_every"])
    ordered = [records[k] for k in range(len(seeds))]
    out_dir.mkdir(parents=True, exist_ok=True)
    plans = out_dir / "plans"
    plans.mkdir(exist_ok=True)
    for k, rec in enumerate(ordered):
        _save_best(domain, instances[k], rec, theta, plans / f"instance{k:03d}")
    methods = [*names, RAWPLANNER]
    header, rows_ = live_table(ordered, methods)
    ctx.console.print(FittedTable(
        [Column(h, "left" if i == 0 else "right", drop=LIVE_DROP.get(i), wrap=i in (7, 9))
         for i, h in enumerate(header)], rows_,
        title=f"live solving: {len(seeds)} fresh instances, budget {max_eval} calls"
              + (f" / {settings['max_seconds']} s" if settings["max_seconds"] else "")))
    doc = {"store": str(store.path), "config_hash": store.attrs["config_hash"],
           "training_rows": int(rows.size), "failure_value": d, "settings": settings,
           "instances": instances, "records": [_jsonable(r) for r in ordered],
           "table": {"header": header, "rows": rows_}}
    (out_dir / "solve.json").write_text(json.dumps(doc, indent=1))
    ctx.say(f"solve: results in {out_dir}")
    return doc


def _save_best(domain, instance: dict, record: dict, theta, stem: Path) -> None:
    """The best plan any method found on this instance: path as .npz and a render."""
    best = max(record["selectors"].items(), key=lambda kv: kv[1]["best_score"])
    name, r = best
    if r["best_path"] is None:
        return
    constraint = (np.asarray(r["best_constraint"], dtype=np.float64) if name == RAWPLANNER
                  else theta[r["best_constraint"]])
    np.savez(stem.with_suffix(".npz"), path=r["best_path"], constraint=constraint,
             method=name, score=r["best_score"])
    from pipeline.planning import PlanResult, Status

    plan = PlanResult(Status.OK, path=r["best_path"], length=-r["best_score"])
    domain.render(instance, plan, stem.with_suffix(".png"), constraint=constraint)
