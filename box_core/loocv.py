"""Leave-one-out cross-validation of constraint selectors on a score matrix.

For every row i, a selector is built from the exact prior of the other n - 1 rows and run
against row i as if it were a new instance: its trace is the sequence of columns it tries,
and each try costs ``times[i, column]``.  From the traces come the time to the first
feasible plan and the best score found versus time (paper Figs. 3 and 4).

All held-out rows of a batch advance in lockstep through the same policy code that
:func:`box_core.make_selector` runs live (see :mod:`box_core.selectors`).
"""

from __future__ import annotations

import contextlib
import math
import os
import pickle
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np

from box_core import validation
from box_core.contextual import Contextual, tune, tuning_groups
from box_core.failure import RULES, fill_failures
from box_core.failure import failure_value as _failure_value
from box_core.prior import Prior
from box_core.selectors import (
    FoldContext,
    Policy,
    TrainingOutcomes,
    check_selector,
    score_unit,
    standardise,
)
from box_core.summary import Summary, summarize
from box_core.tries import FAILED, FEASIBLE, TryTrace, empty_trace, simulate

DEFAULT_SELECTORS = ("box", "static", "rand", "doo")


@dataclass(eq=False)
class LoocvResult:
    """Traces and derived measures, per selector name (all arrays indexed by held-out row).

    ``order[name]``                 (n, k) columns tried, in order (-1 after the last try)
    ``first_feasible_step[name]``   (n,) 0-based step of the first feasible try, -1 if none
    ``first_feasible_time[name]``   (n,) time up to and including that try: planning time
                                    plus the selector's own compute time; NaN if none
    ``first_feasible_planning_time[name]``  the same without the selector's compute time
    ``overhead[name]``              (n, k) the selector's compute seconds per step
                                    (batch wall time divided by the batch size: an
                                    amortised cost, below what one live selector pays per
                                    step; benchmarks/bench_loocv.py prints both)
    ``best_score[name]``            (n, G) best score found by each time of ``time_grid``
                                    (the failure value before any plan is found)

    Selectors that give capped tries (``contextual_capped`` with ``checks``) have traces of
    *tries*, not columns: a paused column appears again when it is resumed, ``order`` has
    up to 2k entries (-1 after the last), and for them only:

    ``allowance[name]``             (n, K) cumulative collision checks each try was allowed
                                    (inf: uncapped; 0 after the last try)
    ``try_time[name]``              (n, K) planning seconds of each try: the share of the
                                    entry's time its checks took (see box_core.tries)

    ``first_feasible_*`` and ``best_score`` count those shares (paused tries included).
    ``settings[name]``: for selectors that tune settings (``contextual``...), {setting:
    (n,) value used for each held-out row}, chosen without that row (docs/box_core.md).
    ``tuning_seconds[name]``: their tuning's wall time in all.  It is training, like
    fitting BOX's prior, and not in ``overhead``: a live selector tunes once on the
    training rows before its first instance (pipeline/solve.py), not per instance.
    """

    selectors: tuple[str, ...]
    k: int
    failure_value: float
    eligible: np.ndarray  # rows with at least one feasible constraint
    optimal_score: np.ndarray  # best score of each row (ORACLE's first try)
    time_grid: np.ndarray
    order: dict[str, np.ndarray] = field(default_factory=dict)
    first_feasible_step: dict[str, np.ndarray] = field(default_factory=dict)
    first_feasible_time: dict[str, np.ndarray] = field(default_factory=dict)
    first_feasible_planning_time: dict[str, np.ndarray] = field(default_factory=dict)
    overhead: dict[str, np.ndarray] = field(default_factory=dict)
    best_score: dict[str, np.ndarray] = field(default_factory=dict)
    allowance: dict[str, np.ndarray] = field(default_factory=dict)
    try_time: dict[str, np.ndarray] = field(default_factory=dict)
    settings: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    tuning_seconds: dict[str, float] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return self.eligible.shape[0]

    def summary(self, reference: str = "box", level: float = 0.95, others=None) -> Summary:
        """Mean time to first feasible plan per selector, its interval and speed-ups;
        ``others``: {name: per-row times measured elsewhere}, e.g. RAWPLANNER's."""
        return summarize(self, reference=reference, level=level, others=others)


def loocv(
    scores,
    *,
    times=None,
    feasible=None,
    selectors: Iterable[str] | str = DEFAULT_SELECTORS,
    k: int | None = None,
    features=None,
    seed: int = 0,
    params: Mapping[str, Mapping] | None = None,
    failure_rule: str = "magnitude",
    time_grid=None,
    measure_overhead: bool = True,
    forbidden=None,
    instance_features=None,
    checks=None,
    until_feasible: bool = False,
    until_best: bool = False,
    workers: int = 1,
) -> LoocvResult:
    """Leave-one-out evaluation of ``selectors`` on a score matrix (n x m, higher is better).

    ``feasible`` (n x m bool): which entries are feasible plans; infeasible entries get the
    failure value of ``failure_rule`` (see :func:`box_core.failure_value`).  Without it the
    matrix is taken to already hold failures at its minimum value: entries above the minimum
    are feasible.  ``times`` (n x m, seconds) defaults to 1 per try.  ``params`` maps a
    selector name to its parameters, e.g. ``{"box": {"c": 1.0}}``.  Fold i seeds its random
    choices with ``(seed, i)``.  ``measure_overhead=False`` leaves the selectors' compute time
    out of the times, which makes the result fully deterministic.

    ``forbidden`` (n x m bool): columns held-out row i may not try, e.g. the constraints
    extracted from row i's own raw solution (which are feasible for row i by
    construction, so trying them would leak the answer).  Every selector, the oracles
    included, treats them as already tried, and a row's eligibility and optimum count only
    its allowed columns.  Every row gets the same number of tries, so ``k`` is capped at m
    minus the largest number of columns hidden from one row.

    Selectors see the scores through :func:`~box_core.selectors.standardise`, so the result
    is the same for scores in any positive unit.

    ``until_feasible=True`` is for callers that need only the time to the first feasible
    plan (C's tuning, learning curves): a row stops at its first feasible try, so ``order``
    ends there (-1 after it) and ``best_score`` counts the tries up to it; every
    ``first_feasible_*`` value is the one a full run gives, bit for bit.

    ``until_best=True`` is for callers that read the first feasible plans and the best
    score curves (the summary, Fig. 4, the pipeline's stored evaluation): a row stops once
    it has its first plan (or has none among the columns it may try) and has ended a try
    at a column of its optimal score, after which neither can change; ``order`` ends there
    (-1 after it).  Every ``first_feasible_*`` value and, on the same ``time_grid``, every
    ``best_score`` curve is the one a full run gives, bit for bit; the default grid ends at
    the longer of the traces and the time of every try a row may make.  With both flags a
    row stops at its first plan.

    ``workers=2`` (or more) starts a second process that shares the work: each tuning group
    of the selectors that tune their settings (``contextual``, ``contextual_capped``:
    nested leave-one-out), and from 64 held-out rows on each half of the rows of every
    other selector, is one piece, and each process takes the next piece the other has not
    taken, so the one that finishes its pieces first takes more.  The result is the same
    (each process measures its own selectors' overhead).
    """
    return _loocv(scores, times=times, feasible=feasible, selectors=selectors, k=k,
                  features=features, seed=seed, params=params, failure_rule=failure_rule,
                  time_grid=time_grid, measure_overhead=measure_overhead, forbidden=forbidden,
                  instance_features=instance_features, checks=checks,
                  until_feasible=until_feasible, until_best=until_best, workers=workers)


def _loocv(scores, *, times, feasible, selectors, k, features, seed, params, failure_rule,
           time_grid, measure_overhead, forbidden, rows=None, fast: bool = True,
           instance_features=None, checks=None, until_feasible: bool = False,
           until_best: bool = False, workers=1, claims=None):
    """:func:`loocv`; ``rows``: hold out only these rows (each still with the prior of
    all the others; the result's rows are these); ``fast=False``: the unoptimised path
    (every instance through every step, nothing skipped: the same result, slower);
    ``claims``: the folder of a first process's pieces of work (:class:`_Claims`): just
    the pieces this one takes (what a second process returns)."""
    again = partial(_loocv, scores, times=times, feasible=feasible, selectors=selectors,
                    k=k, features=features, seed=seed, params=params,
                    failure_rule=failure_rule, time_grid=time_grid,
                    measure_overhead=measure_overhead, forbidden=forbidden, rows=rows,
                    fast=fast, instance_features=instance_features, checks=checks,
                    until_feasible=until_feasible, until_best=until_best)
    setup = _Setup.check(scores, times, feasible, selectors, k, features, params,
                         failure_rule, min_rows=3, forbidden=forbidden,
                         instance_features=instance_features, checks=checks)
    prior = Prior.fit(setup.Dn)
    n = setup.D.shape[0]
    rows = np.arange(n) if rows is None else _row_indices(rows, n, "rows")

    outcomes = TrainingOutcomes.of(setup.Dn, setup.feas, setup.T, [], setup.checks).holding_out

    groups = tuning_groups(n, seed)

    def tuning(test):  # held-out rows of group g get settings tuned without group g
        return [(np.flatnonzero(groups[test] == g), np.flatnonzero(groups != g))
                for g in np.unique(groups[test])]

    return setup.evaluate(prior.folds, outcomes, rows, seed, time_grid, measure_overhead,
                          fast=fast, train=np.arange(n), tuning=tuning,
                          until_feasible=until_feasible, until_best=until_best,
                          workers=workers, again=again, claims=claims)


def holdout(
    scores,
    train,
    test,
    *,
    times=None,
    feasible=None,
    selectors: Iterable[str] | str = DEFAULT_SELECTORS,
    k: int | None = None,
    features=None,
    seed: int = 0,
    params: Mapping[str, Mapping] | None = None,
    failure_rule: str = "magnitude",
    time_grid=None,
    measure_overhead: bool = True,
    forbidden=None,
    instance_features=None,
    checks=None,
    until_feasible: bool = False,
    until_best: bool = False,
    workers: int = 1,
) -> LoocvResult:
    """Like :func:`loocv`, but every row of ``test`` is run with the one prior fitted on the
    rows ``train`` (learning curves, nested cross-validation).  The result's rows are the
    ``test`` rows, in that order; row i of D still seeds its random choices with
    ``(seed, i)``, and the failure value comes from the whole matrix, as in :func:`loocv`;
    ``forbidden`` (n x m) as in :func:`loocv` (only the ``test`` rows' masks matter);
    ``instance_features`` and ``checks`` as in :func:`loocv` (settings the selector tunes
    are tuned on the ``train`` rows); ``until_feasible``, ``until_best`` and ``workers``
    as in :func:`loocv`.
    """
    return _holdout(scores, train, test, times=times, feasible=feasible, selectors=selectors,
                    k=k, features=features, seed=seed, params=params,
                    failure_rule=failure_rule, time_grid=time_grid,
                    measure_overhead=measure_overhead, forbidden=forbidden,
                    instance_features=instance_features, checks=checks,
                    until_feasible=until_feasible, until_best=until_best, workers=workers)


def _holdout(scores, train, test, *, times, feasible, selectors, k, features, seed, params,
             failure_rule, time_grid, measure_overhead, forbidden, fast: bool = True,
             instance_features=None, checks=None, until_feasible: bool = False,
             until_best: bool = False, workers=1, claims=None):
    """:func:`holdout`; ``fast=False`` and ``claims`` as in :func:`_loocv`."""
    again = partial(_holdout, scores, train, test, times=times, feasible=feasible,
                    selectors=selectors, k=k, features=features, seed=seed, params=params,
                    failure_rule=failure_rule, time_grid=time_grid,
                    measure_overhead=measure_overhead, forbidden=forbidden, fast=fast,
                    instance_features=instance_features, checks=checks,
                    until_feasible=until_feasible, until_best=until_best)
    setup = _Setup.check(scores, times, feasible, selectors, k, features, params,
                         failure_rule, min_rows=2, forbidden=forbidden,
                         instance_features=instance_features, checks=checks)
    n = setup.D.shape[0]
    train = _row_indices(train, n, "train")
    test = _row_indices(test, n, "test")
    if train.size < 2:
        raise ValueError(f"train needs at least 2 rows, got {train.size}")
    if test.size < 1:
        raise ValueError("test is empty")
    if np.intersect1d(train, test).size:
        raise ValueError("train and test share rows")
    prior = Prior.fit(setup.Dn[train])

    training = TrainingOutcomes.of(setup.Dn[train], setup.feas[train], setup.T[train], [],
                                   None if setup.checks is None else setup.checks[train])

    def outcomes(held_out):
        return training.holding_out(np.full(held_out.size, -1))

    def tuning(test):
        return [(np.arange(test.size), train)]

    return setup.evaluate(lambda rows: prior.batch(rows.size), outcomes, test, seed,
                          time_grid, measure_overhead, fast=fast, train=train, tuning=tuning,
                          until_feasible=until_feasible, until_best=until_best,
                          workers=workers, again=again, claims=claims)


def _row_indices(rows, n: int, name: str) -> np.ndarray:
    r = np.asarray(rows)
    if r.dtype == bool:
        if r.shape != (n,):
            raise ValueError(f"{name}: a boolean mask must have shape ({n},), got {r.shape}")
        return np.flatnonzero(r)
    if r.ndim != 1 or (r.size and not np.issubdtype(r.dtype, np.integer)):
        raise ValueError(f"{name} must be a 1-D array of row indices or a boolean mask")
    r = r.astype(np.intp)
    if r.size and (r.min() < 0 or r.max() >= n):
        raise ValueError(f"{name}: row indices must lie in [0, {n})")
    if np.unique(r).size != r.size:
        raise ValueError(f"{name} has repeated rows")
    return r


@dataclass(eq=False)
class _Setup:
    """Checked inputs shared by :func:`loocv` and :func:`holdout`."""

    D: np.ndarray  # failures filled with the failure value
    Dn: np.ndarray  # standardise(D, score_unit(D)): what the selectors see
    T: np.ndarray
    feas: np.ndarray
    d: float
    theta: np.ndarray | None
    names: tuple[str, ...]
    classes: dict
    params: dict
    k: int
    forbidden: np.ndarray | None
    X: np.ndarray | None = None  # instance features (n, q), None if none
    checks: np.ndarray | None = None

    @classmethod
    def check(cls, scores, times, feasible, selectors, k, features, params, failure_rule,
              min_rows, forbidden=None, instance_features=None, checks=None):
        D = validation.score_matrix(scores, min_rows=min_rows, feasible=feasible)
        n, m = D.shape
        if times is None:
            T = np.ones((n, m))
        else:
            T = validation.matching_matrix(times, D.shape, name="times")
        if (T < 0).any():
            raise ValueError("times must be >= 0")
        theta = None if features is None else validation.feature_matrix(features, m)
        X = None if instance_features is None else validation.instance_features(
            instance_features, n)
        if X is not None and X.shape[1] == 0:
            X = None
        C = None if checks is None else validation.checks_matrix(checks, D.shape)
        if failure_rule not in RULES:
            raise ValueError(f"unknown failure rule {failure_rule!r}; "
                             f"choose one of {', '.join(RULES)}")
        names = (selectors,) if isinstance(selectors, str) else tuple(selectors)
        if not names:
            raise ValueError("selectors is empty")
        if len(set(names)) != len(names):
            raise ValueError(f"selectors has duplicates: {names}")
        if forbidden is not None:
            forbidden = validation.boolean_matrix(forbidden, D.shape, name="forbidden")
            if forbidden.all(axis=1).any():
                row = int(np.flatnonzero(forbidden.all(axis=1))[0])
                raise ValueError(f"forbidden hides every column from row {row}")
            if not forbidden.any():
                forbidden = None
        allowed = m if forbidden is None else m - int(forbidden.sum(axis=1).max())
        k = allowed if k is None else k
        if isinstance(k, bool) or not isinstance(k, int | np.integer) or not 1 <= k <= m:
            raise ValueError(f"k must be an integer between 1 and m = {m}, got {k!r}")
        k = min(int(k), allowed)
        params = dict(params or {})
        stray = set(params) - set(names)
        if stray:
            raise ValueError("params given for selectors not evaluated: "
                             f"{', '.join(sorted(stray))}")
        classes = {
            name: check_selector(name, dict(params.get(name, {})), features=theta)
            for name in names
        }
        if feasible is None:
            d = float(D.min())
            feas = D > d
            if not feas.any():
                raise ValueError("every score equals the minimum: no entry can be told feasible")
        else:
            feas = validation.boolean_matrix(feasible, D.shape, name="feasible")
            d = _failure_value(D, feas, failure_rule)
            D = fill_failures(D, feas, d)
        return cls(D=D, Dn=standardise(D, score_unit(D)), T=T, feas=feas, d=d, theta=theta,
                   names=names, classes=classes, params=params, k=int(k), forbidden=forbidden,
                   X=X, checks=C)

    def evaluate(self, fold_priors, fold_outcomes, test, seed, time_grid,
                 measure, fast: bool = True, train=None, tuning=None,
                 until_feasible: bool = False, until_best: bool = False,
                 workers: int = 1, again=None, claims=None) -> LoocvResult:
        """Run every selector on the ``test`` rows; ``fold_priors(rows)`` and
        ``fold_outcomes(rows)`` give their priors and training outcomes, ``train`` the
        rows the folds train on (their instance features), ``tuning(test)`` the groups
        [(positions in ``test``, the rows to tune their settings on)].  ``fast=False``
        runs every instance through every step with no arithmetic skipped (the same
        result, up to the measured overhead; what the tests compare the fast path with).
        ``workers`` >= 2: ``again(workers=..., claims=folder)`` in a second process shares
        the pieces of work (:func:`_pieces`); ``claims``: this is that second process,
        which returns the pieces it took."""
        D, T, feas, k = self.D[test], self.T[test], self.feas[test], self.k
        hidden = None if self.forbidden is None else self.forbidden[test]
        allowed = D if hidden is None else np.where(hidden, -np.inf, D)
        optimal = allowed.max(axis=1)
        peak = allowed == optimal[:, None]  # the columns at the row's optimal score
        hopeless = ~(feas if hidden is None else feas & ~hidden).any(axis=1)
        folds = _Folds(fold_priors, fold_outcomes, self.Dn[test], T, feas, hidden, self.theta,
                       test, seed, k, fast,
                       checks=None if self.checks is None else self.checks[test],
                       train_features=None if self.X is None else self.X[train],
                       query=None if self.X is None else self.X[test],
                       until_feasible=until_feasible, until_best=until_best, peak=peak,
                       hopeless=hopeless)
        names = self.names
        tuned = tuple(n for n in names if issubclass(self.classes[n], Contextual))
        plain = tuple(n for n in names if n not in tuned)
        pieces = _pieces(tuned, plain, tuning(test) if tuned else [], test.size,
                         workers if again is not None else 1,
                         lambda group: sum(self.classes[n].relative_cost for n in group))

        def work(claims):
            return {i: self._piece(piece, folds, measure, fast)
                    for i, piece in enumerate(pieces) if claims is None or claims.take(i)}

        if claims is not None:  # a second process
            return work(_Claims(claims))
        if workers < 2 or again is None or not _beside(tuned, test.size) or len(pieces) < 2:
            done = work(None)
        else:
            with tempfile.TemporaryDirectory(prefix="box-loocv-") as folder, \
                    _second_process(partial(again, workers=workers, claims=folder)) as theirs:
                done = work(_Claims(folder))
                done.update(theirs.result())
        traces, settings, tuning_seconds = _gathered(done.values(), test.size, tuned)
        traces = {n: traces[n] for n in names}  # the order selectors were given in
        if hidden is not None:
            feas = feas & ~hidden
        rows = np.arange(test.size)[:, None]
        totals = {  # cumulative time after each try: planning plus the selector's own time
            name: np.cumsum(tr.cost + tr.overhead, axis=1) for name, tr in traces.items()
        }
        every = None  # until_best: the time of every try a row may make, for the tails
        if until_best:
            every = (T if hidden is None else np.where(hidden, 0.0, T)).sum(axis=1).max()
        grid = _default_grid(totals, T, every) if time_grid is None else _checked_grid(time_grid)
        result = LoocvResult(
            selectors=self.names,
            k=k,
            failure_value=self.d,
            eligible=feas.any(axis=1),
            optimal_score=optimal,
            time_grid=grid,
            settings=settings,
            tuning_seconds=tuning_seconds,
        )
        for name, tr in traces.items():
            order = tr.order
            hit = tr.outcome == FEASIBLE
            found = hit.any(axis=1)
            step = np.where(found, hit.argmax(axis=1), -1)
            at = np.maximum(step, 0)[:, None]
            planning = np.cumsum(tr.cost, axis=1)
            result.order[name] = order
            result.overhead[name] = tr.overhead
            result.first_feasible_step[name] = step
            planning_at = planning[rows, at][:, 0]
            result.first_feasible_planning_time[name] = np.where(found, planning_at, np.nan)
            result.first_feasible_time[name] = np.where(found, totals[name][rows, at][:, 0],
                                                        np.nan)
            if np.isfinite(tr.allowance).any():
                result.allowance[name] = tr.allowance
                result.try_time[name] = tr.cost
            scores = np.where((tr.outcome == FEASIBLE) | (tr.outcome == FAILED),
                              D[rows, np.maximum(order, 0)], self.d)
            result.best_score[name] = _best_by_time(totals[name], scores, grid, self.d)
        return result

    def _piece(self, piece, folds, measure, fast):
        """(positions in the held-out rows, {selector: its trace of those rows}, settings
        {selector: {setting: values}}, tuning seconds {selector: seconds}) of one of
        :func:`_pieces`: a tuning group of the tuned selectors (they share what they tune
        alike) or some rows of one selector that tunes nothing.  With ``until_feasible``
        or ``until_best`` each trace ends where its row was done."""
        names, positions, train = piece
        part = folds.restrict(positions)
        run = _run_fast if fast else _run
        traces, settings, seconds, memo = {}, {}, {}, {}
        for name in names:
            cls, params = self.classes[name], dict(self.params.get(name, {}))
            if train is None:
                traces[name] = _uncapped(*run(cls, params, part, measure), part.T, part.feas)
            else:
                traces[name], settings[name], seconds[name] = self._tuned(
                    cls, params, part, train, measure, run, memo)
            if part.until_feasible or part.until_best:
                _end_where_done(traces[name], part)
        return positions, traces, settings, seconds

    def _tuned(self, cls, params, folds, train, measure, run, memo):
        """A :class:`Contextual` selector over the held-out rows of ``folds``, with the
        settings tuned on the rows ``train``: (trace, {setting: (B,) values}, the tuning's
        seconds, which the trace's overhead leaves out); ``memo``: what selectors tuned
        alike on these rows share."""
        B = folds.Dn.shape[0]
        clock = time.perf_counter()
        kwargs = tune(cls, self.Dn[train], self.feas[train], self.T[train],
                      None if self.checks is None else self.checks[train],
                      None if self.X is None else self.X[train], params, folds.seed,
                      None if self.forbidden is None else self.forbidden[train], memo=memo)
        tuning_seconds = time.perf_counter() - clock
        # tries are capped only with features, stored checks and a finite cap
        if math.isfinite(kwargs.get("cap", math.inf)) and self.X is not None:
            trace = _run_tries(cls, kwargs, folds, measure)
        else:
            trace = _uncapped(*run(cls, kwargs, folds, measure), folds.T, folds.feas)
        chosen = {key: np.repeat(np.asarray(value, dtype=np.float64)[None], B, axis=0)
                  for key, value in kwargs.items()}  # numbers, and the features' mask
        return trace, chosen, tuning_seconds


#: Fewest held-out rows from which a second process shares the work of selectors that
#: tune nothing (:func:`_beside`), each one's rows in halves (:func:`_pieces`): below it
#: a second process takes longer to start (about 1 s) than the rows it would take.
HALVES_MIN_ROWS = 64


def _beside(tuned, rows: int) -> bool:
    """Whether a second process is worth starting: for tuned selectors (nested
    leave-one-out, seconds per tuning group), or from :data:`HALVES_MIN_ROWS` rows on."""
    return bool(tuned) or rows >= HALVES_MIN_ROWS


def _pieces(tuned, plain, groups, rows: int, workers: int, cost) -> list[tuple]:
    """The work of an evaluation as pieces (selectors, positions of held-out rows, the
    rows their settings are tuned on or None): each tuning group of the ``tuned``
    selectors, and each ``plain`` selector's rows, in halves where a second process shares
    the work and there are at least :data:`HALVES_MIN_ROWS`.  They are listed costliest
    first by ``cost(selectors)`` per row (:attr:`Policy.relative_cost`), the order in
    which processes take them, so that the last pieces are small.  A row's trace depends
    on its own fold and seed only, so how the rows are cut changes no result."""
    out = [(tuned, positions, train) for positions, train in groups]
    everything = np.arange(rows)
    cut = workers >= 2 and rows >= HALVES_MIN_ROWS
    parts = (everything[:rows // 2], everything[rows // 2:]) if cut else (everything,)
    out += [((name,), p, None) for name in plain for p in parts]
    return sorted(out, key=lambda piece: -cost(piece[0]) * piece[1].size)  # stable


@dataclass(frozen=True)
class _Claims:
    """Pieces of work two processes share through a folder: taking piece i creates the
    file ``i`` there, which succeeds for one process only (``O_EXCL``), so each piece is
    done once and a process that finishes its pieces early takes more."""

    folder: str

    def take(self, i: int) -> bool:
        try:
            os.close(os.open(os.path.join(self.folder, str(i)),
                             os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            return False
        return True


def _gathered(done, size: int, tuned) -> tuple[dict, dict, dict]:
    """(traces, settings, tuning seconds) of every selector over the ``size`` held-out rows
    from the ``done`` pieces (:meth:`_Setup._piece`, from either process)."""
    parts, settings, seconds = {}, {}, {name: 0.0 for name in tuned}
    for positions, traces, chosen, spent in done:
        for name, trace in traces.items():
            parts.setdefault(name, []).append((positions, trace))
        for name, values in chosen.items():
            into = settings.setdefault(name, {})
            for key, v in values.items():
                into.setdefault(key, np.full((size,) + v.shape[1:], np.nan))[positions] = v
        for name, spent_here in spent.items():
            seconds[name] += spent_here
    return {name: _merged(size, *p) for name, p in parts.items()}, settings, seconds


def _merged(size: int, *parts) -> TryTrace:
    """One trace of ``size`` rows from (positions, trace of those rows) ``parts``, padded
    (-1 / 0 / -1) to the widest, and where no part has the row."""
    width = max((tr.order.shape[1] for _, tr in parts), default=0)
    out = empty_trace(size, width)
    for positions, tr in parts:
        w = tr.order.shape[1]
        for key in ("order", "allowance", "cost", "outcome", "overhead"):
            getattr(out, key)[positions, :w] = getattr(tr, key)
    return out


@contextlib.contextmanager
def _second_process(call):
    """A handle whose ``result()`` is ``call()`` computed by a second Python process (None
    when ``call`` is None).

    The child is a fresh interpreter running :func:`_serve` (``python -c``), given this
    process's ``sys.path`` and the pickled call on its stdin: unlike multiprocessing's
    spawn it never imports the caller's main script, so a script without an
    ``if __name__ == "__main__"`` guard, or code piped to ``python -``, works as well."""
    if call is None:
        yield None
        return
    child = subprocess.Popen([sys.executable, "-c", "from box_core.loocv import _serve; _serve()"],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             env={**os.environ, "PYTHONPATH": os.pathsep.join(
                                 p for p in sys.path if p)})
    try:
        with child.stdin:
            pickle.dump(call, child.stdin)
        yield _ChildResult(child)
    finally:
        if child.poll() is None:
            child.kill()
        child.wait()


@dataclass(eq=False)
class _ChildResult:
    child: subprocess.Popen

    def result(self):
        with self.child.stdout:
            try:
                ok, value = pickle.load(self.child.stdout)
            except EOFError:  # it died without a reply (killed, out of memory)
                ok, value = False, RuntimeError(
                    f"loocv's second process ended with exit code {self.child.wait()} "
                    "before it replied")
        self.child.wait()
        if not ok:
            raise value
        return value


def _serve() -> None:
    """The second process of :func:`_second_process`: one call from stdin, its result (or
    the exception it raised) to stdout."""
    call = pickle.load(sys.stdin.buffer)
    try:
        reply = (True, call())
    except Exception as exc:  # the caller raises it
        reply = (False, exc)
    pickle.dump(reply, sys.stdout.buffer)
    sys.stdout.buffer.flush()


def _end_where_done(trace: TryTrace, folds: _Folds) -> None:
    """Clear what ``trace`` holds after the try at which each row was done
    (:meth:`_Folds.done`: loocv's ``until_feasible`` or ``until_best``; the fast path may
    have stopped there, the others went on)."""
    order = trace.order
    rows = np.arange(order.shape[0])[:, None]
    ended = (trace.outcome == FEASIBLE) | (trace.outcome == FAILED)
    found = np.logical_or.accumulate(trace.outcome == FEASIBLE, axis=1)
    peaked = np.logical_or.accumulate(ended & folds.peak[rows, np.maximum(order, 0)], axis=1)
    done = folds.done(rows, found, peaked)  # (B, width): done by each try
    step = np.where(done.any(axis=1), done.argmax(axis=1), order.shape[1])
    after = np.arange(order.shape[1])[None, :] > step[:, None]
    order[after] = -1
    trace.allowance[after] = 0.0
    trace.cost[after] = 0.0
    trace.overhead[after] = 0.0
    trace.outcome[after] = -1


def _uncapped(order, overhead, T, feas) -> TryTrace:
    """The trace of uncapped tries in ``order``: each costs its time and ends."""
    rows = np.arange(order.shape[0])[:, None]
    return TryTrace(order=order, allowance=np.full(order.shape, np.inf),
                    cost=T[rows, order], outcome=feas[rows, order].astype(np.int8),
                    overhead=overhead)


def _run_tries(cls, kwargs, folds, measure) -> TryTrace:
    """A selector that gives capped tries over the held-out rows, simulated from their
    stored checks (:func:`box_core.tries.simulate`) in one batch."""
    rows = np.arange(folds.Dn.shape[0])
    clock = time.perf_counter()
    ctx = replace(folds.context(rows, cls), horizon=16)  # W grows as tries go on
    policy = cls(ctx, **kwargs)
    setup = time.perf_counter() - clock
    trace = simulate(policy, folds.Dn, folds.feas, folds.T, folds.checks, folds.k,
                     measure=measure, done=folds.done, peak=folds.peak)
    if measure and trace.overhead.size:
        trace.overhead[:, 0] += setup / rows.size
    return trace


@dataclass(frozen=True, eq=False)
class _Folds:
    """What every selector's run over the held-out rows shares (``Dn``, ``T``, ``feas``
    and ``hidden`` hold just those rows)."""

    priors: object  # rows -> FoldPriors
    outcomes: object  # rows -> TrainingOutcomes
    Dn: np.ndarray
    T: np.ndarray
    feas: np.ndarray
    hidden: np.ndarray | None
    features: np.ndarray | None
    test: np.ndarray
    seed: int
    k: int
    fast: bool = True
    checks: np.ndarray | None = None  # (B, m) of the held-out rows
    train_features: np.ndarray | None = None  # instance features of the training rows
    query: np.ndarray | None = None  # instance features of the held-out rows
    #: rows may stop at their first feasible try (loocv's ``until_feasible``)
    until_feasible: bool = False
    #: rows may stop once nothing later can change their curves (loocv's ``until_best``):
    #: ``peak`` (B, m) the columns at the row's optimal score, ``hopeless`` (B,) the rows
    #: without a feasible column they may try
    until_best: bool = False
    peak: np.ndarray | None = None
    hopeless: np.ndarray | None = None

    def restrict(self, positions: np.ndarray) -> _Folds:
        """These folds for the held-out rows at ``positions`` only."""

        def rows(a):
            return None if a is None else a[positions]

        return replace(self, Dn=self.Dn[positions], T=self.T[positions],
                       feas=self.feas[positions], hidden=rows(self.hidden),
                       test=self.test[positions], checks=rows(self.checks),
                       query=rows(self.query), peak=rows(self.peak),
                       hopeless=rows(self.hopeless))

    def done(self, here, found, peaked) -> np.ndarray:
        """Which instances (rows ``here``, or a column of them against a (B, width)
        ``found`` and ``peaked``) may stop: a plan ``found`` (until_feasible), or, with
        until_best, a plan found (or none to find) and the optimal score ``peaked``; none
        otherwise."""
        if self.until_feasible:
            return found
        if self.until_best:
            return (found | self.hopeless[here]) & peaked
        return np.zeros(here.size, dtype=bool)

    def context(self, rows: np.ndarray, cls: type[Policy]) -> FoldContext:
        held = self.test[rows]
        return FoldContext(
            prior=self.priors(held),
            seeds=[(self.seed, int(i)) for i in held],
            features=self.features,
            true_scores=self.Dn[rows],
            horizon=self.k,
            outcomes=self.outcomes(held) if cls.needs_outcomes else None,
            true_times=self.T[rows],
            true_feasible=self.feas[rows],
            forbidden=None if self.hidden is None else self.hidden[rows],
            skip_inert=self.fast,
            instance_features=self.train_features,
            query=None if self.query is None else self.query[rows],
        )


def _run(cls: type[Policy], kwargs, folds: _Folds, measure):
    """One selector over the held-out rows: (order (B, k), overhead seconds (B, k)),
    every instance through every step (the unoptimised path)."""
    n, m = folds.Dn.shape
    k = folds.k
    order = np.full((n, k), -1, dtype=np.intp)
    overhead = np.zeros((n, k))
    batch = cls.fold_batch(n, m, k)
    for start in range(0, n, batch):
        rows = np.arange(start, min(n, start + batch))
        clock = time.perf_counter()
        policy = cls(folds.context(rows, cls), **kwargs)
        setup = time.perf_counter() - clock
        for t in range(k):
            clock = time.perf_counter()
            cols = policy.propose()
            policy.update(cols, folds.Dn[rows, cols])
            overhead[rows, t] = (time.perf_counter() - clock) / rows.size
            order[rows, t] = cols
        overhead[rows, 0] += setup / rows.size
    if not measure:
        overhead[:] = 0.0
    return order, overhead


#: The fast path's batches keep their per-step buffers (BOX's W) within this many bytes per
#: entry of the held-out rows they run (a piece of work, :func:`_pieces`: with two
#: processes each runs at most half of a selector's rows at once, so both together stay
#: within it), or MIN_BATCH_BYTES if that is more (the evaluation holds about as much per
#: entry anyway: its inputs, and per selector the orders and times).
BATCH_BYTES_PER_ENTRY = 128
MIN_BATCH_BYTES = 8 << 20
#: ... times as much for a policy whose steps read a table the batch shares
#: (``Policy.shares_tables``), where rows stop early (``until_feasible``,
#: ``until_best``).  EIPS's update reads its (n, 3m) table of training outcomes once per
#: step whatever the batch, CONTEXTUAL its neighbours' (n, 5m) one.  On the pick_place
#: store (1500 x 1000, until_best, one core) EIPS took 30.1 s instead of 42.0 s and
#: CONTEXTUAL 21.8 s instead of 27.2 s.  BOX, PEM-BO and DOO, which read W per instance,
#: were slower in larger batches (20.8 s against 15.8 s at 16 times).  Rows that stop
#: early leave the batch, and its W stays far below the budget; a run through every try
#: keeps the plain budget, which bounds W.
SHARED_TABLE_BATCH_FACTOR = 8


def _run_fast(cls: type[Policy], kwargs, folds: _Folds, measure):
    """:func:`_run` with the same orders, doing only the work that can change them.

    An instance stops being updated once the policy says it is settled (no observation
    can change its later proposals: BOX once every untried column is constant, the fixed
    orders from the start); its remaining proposals are then listed at once.  With
    ``until_feasible`` an instance also stops at its first feasible try, with
    ``until_best`` once it has a plan (or none to find) and its optimal score (nothing
    after it is listed).  Instances that stopped leave the batch once they are a quarter
    of it (what leaving costs is a copy of the batch's state; staying, every step's
    arithmetic on them).  A batch holds as many instances
    as the policy's buffers allow within :data:`BATCH_BYTES_PER_ENTRY` (BOX keeps a row of
    W per observed column that is not constant; :data:`SHARED_TABLE_BATCH_FACTOR` times
    that for a policy that shares a table across the batch); policies that never settle
    run in their usual batches.
    """
    n, m = folds.Dn.shape
    k = folds.k
    order = np.full((n, k), -1, dtype=np.intp)
    overhead = np.zeros((n, k))
    settles = cls.settled is not Policy.settled
    # rows that are done may leave the batch of a policy that can drop rows (its own keep)
    stops = settles or ((folds.until_feasible or folds.until_best)
                        and cls.keep is not Policy.keep)
    if settles:
        per = cls.bytes_per_instance(m, m, k)
        if per:
            live = m - int(folds.priors(folds.test).inert().sum())
            if live == m and not (folds.until_feasible or folds.until_best):
                # no constant column: nothing settles before the last try
                return _run(cls, kwargs, folds, measure)
            per = cls.bytes_per_instance(m, live, k)
        budget = max(MIN_BATCH_BYTES, BATCH_BYTES_PER_ENTRY * n * m)
        if cls.shares_tables and (folds.until_feasible or folds.until_best):
            budget *= SHARED_TABLE_BATCH_FACTOR
        batch = n if per == 0 else int(max(1, min(n, budget // per)))
    else:
        batch = cls.fold_batch(n, m, k)
    for start in range(0, n, batch):
        rows = np.arange(start, min(n, start + batch))
        clock = time.perf_counter()
        policy = cls(folds.context(rows, cls), **kwargs)
        overhead[rows, 0] = (time.perf_counter() - clock) / rows.size
        here = rows  # the test row of each instance of the batch
        stepping = np.ones(rows.size, dtype=bool)  # not settled yet
        found = np.zeros(rows.size, dtype=bool)  # a plan found
        peaked = np.zeros(rows.size, dtype=bool)  # the row's optimal score found
        for t in range(k):
            clock = time.perf_counter()
            if stops:
                ended = stepping & folds.done(here, found, peaked)
                listed = stepping & ~ended & policy.settled()
                if listed.any():
                    at = np.flatnonzero(listed)
                    order[here[at], t:] = policy.remaining(at, k - t)
                    overhead[here[at], t:] += (time.perf_counter() - clock) / (at.size * (k - t))
                if listed.any() or ended.any():
                    stepping &= ~(listed | ended)
                    if not stepping.any():
                        break
                    clock = time.perf_counter()
                    if 4 * stepping.sum() <= 3 * stepping.size:  # those done leave
                        kept = np.flatnonzero(stepping)
                        policy.keep(kept)
                        here, stepping = here[kept], stepping[kept]
                        found, peaked = found[kept], peaked[kept]
            cols = policy.propose()
            policy.update(cols, folds.Dn[here, cols])
            live_rows = here[stepping]
            overhead[live_rows, t] += (time.perf_counter() - clock) / live_rows.size
            order[live_rows, t] = cols[stepping]
            found |= folds.feas[here, cols]
            if folds.until_best:
                peaked |= folds.peak[here, cols]
        del policy  # its buffers go before the next batch's are made
    if not measure:
        overhead[:] = 0.0
    return order, overhead


def _default_grid(totals, T, every=None) -> np.ndarray:
    """0 followed by 199 log-spaced times from the cheapest try to the longest trace, or
    to ``every`` (the longest time a row's every try could take) if that is later."""
    longest = max(float(total[:, -1].max()) for total in totals.values())
    if every is not None:
        longest = max(longest, float(every))
    positive = T[T > 0]
    shortest = float(positive.min()) if positive.size else 1.0
    longest = max(longest, shortest)
    return np.concatenate([[0.0], np.geomspace(shortest, longest, 199)])


def _checked_grid(grid) -> np.ndarray:
    g = np.asarray(grid, dtype=np.float64)
    if g.ndim != 1 or g.size == 0 or not np.isfinite(g).all() or (np.diff(g) < 0).any():
        raise ValueError("time_grid must be a non-empty, finite, non-decreasing 1-D array")
    return g


def _best_by_time(total: np.ndarray, tried_scores: np.ndarray, grid, d: float) -> np.ndarray:
    """Best score completed by each grid time, per row; ``d`` before the first plan."""
    best = np.maximum.accumulate(tried_scores, axis=1)
    out = np.empty((total.shape[0], grid.size))
    for i in range(total.shape[0]):
        done = np.searchsorted(total[i], grid, side="right")
        out[i] = np.where(done > 0, best[i, np.maximum(done - 1, 0)], d)
    return out
