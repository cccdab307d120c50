"""Constraint selectors: which column of the score matrix to try next on a new instance.

Every selector is a *policy over a batch* of independent instances (B rows): ``propose()``
returns one untried column per instance and ``update(cols, scores)`` reports what was
observed.  Leave-one-out evaluation runs many held-out rows in one batch; a live selector
(:func:`make_selector`) is the same class with a batch of one, so what is evaluated is
exactly what runs.

Adding a selector is one class decorated with ``@register("name")``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np

from box_core import validation
from box_core.gaussian import (
    GaussianPosterior,
    argmax_masked,
    argmax_sequence,
    argmax_untried,
    argmax_untried_at,
)
from box_core.prior import FoldPriors, Prior
from box_core.row_sums import RowTable
from box_core.tries import PAUSED

SELECTORS: dict[str, type[Policy]] = {}

#: Raised whenever a selector's choices change for the same inputs, so that evaluations
#: stored by an earlier revision are recognised as stale (2: eips's instance-conditioned
#: time model).
SELECTOR_REVISION = 2


def register(name: str):
    """Class decorator adding a policy to :data:`SELECTORS` under ``name``."""

    def add(cls):
        cls.name = name
        SELECTORS[name] = cls
        return cls

    return add


@dataclass(frozen=True, eq=False)
class FoldContext:
    """What a policy may know about its B instances before trying anything.

    Scores here are in box_core's internal unit (the caller's scores divided by one positive
    number, see :func:`score_unit`).  ``true_scores``, ``true_times`` and ``true_feasible``
    (B, m) are the held-out truth, for the oracles only; ``seeds`` are entropy for
    ``numpy.random.default_rng``, one per instance; ``outcomes`` are the training rows' times
    and feasibility (for ``eips``); ``forbidden`` (B, m) marks columns an instance may never
    try (leave-one-out without leakage), which every policy treats as tried from the start.
    ``skip_inert=False`` makes the posterior condition on constant columns in full rather
    than skipping the arithmetic that cannot change it, and ``eips`` keep every column's
    sums (the same choices, slower; the unoptimised path the tests compare against).
    """

    prior: FoldPriors
    seeds: Sequence
    features: np.ndarray | None = None
    true_scores: np.ndarray | None = None
    horizon: int | None = None  # how many tries are planned, if known (sizes buffers)
    outcomes: TrainingOutcomes | None = None
    true_times: np.ndarray | None = None
    true_feasible: np.ndarray | None = None
    forbidden: np.ndarray | None = None
    skip_inert: bool = True
    instance_features: np.ndarray | None = None  # (n_train, q): the training rows'
    query: np.ndarray | None = None  # (B, q): the features of the B instances

    @property
    def size(self) -> int:
        return self.prior.size

    def subset(self, folds: np.ndarray) -> FoldContext:
        """This context for the instances ``folds`` only, in that order."""

        def rows(a):
            return None if a is None else a[folds]

        outcomes = self.outcomes
        if outcomes is not None:
            outcomes = replace(outcomes, held_out=outcomes.held_out[folds])
        return replace(self, prior=self.prior.subset(folds),
                       seeds=[self.seeds[i] for i in folds], true_scores=rows(self.true_scores),
                       outcomes=outcomes, true_times=rows(self.true_times),
                       true_feasible=rows(self.true_feasible), forbidden=rows(self.forbidden),
                       query=rows(self.query))

    @property
    def m(self) -> int:
        return self.prior.m


class Policy:
    """Base class: tracks the tried set of each instance of the batch."""

    name: ClassVar[str] = "?"
    #: Keyword parameters the selector accepts, with their defaults.
    defaults: ClassVar[dict] = {}
    needs_features: ClassVar[bool] = False
    needs_truth: ClassVar[bool] = False
    needs_outcomes: ClassVar[bool] = False
    #: Whether each step reads a table the whole batch shares (EIPS's training outcomes,
    #: CONTEXTUAL's neighbours' outcomes): a step then costs about as much for one
    #: instance as for many, so leave-one-out runs such a policy in larger batches.
    shares_tables: ClassVar[bool] = False
    #: A held-out row's rough cost in leave-one-out against BOX's (each class's value
    #: measured alone on the 1500 x 1000 pick_place store, one core; the tuned ones with
    #: their tuning), for scheduling only: with two processes the costliest pieces of work
    #: go first, so the two end nearer together.  A wrong value changes no result, only
    #: which process ends last.
    relative_cost: ClassVar[float] = 1.0

    def __init__(self, ctx: FoldContext):
        self.ctx = ctx
        if ctx.forbidden is None:
            self.tried = np.zeros((ctx.size, ctx.m), dtype=bool)
        else:
            self.tried = np.array(ctx.forbidden, dtype=bool, copy=True)
        self.t = 0
        self._rows = np.arange(ctx.size)

    @classmethod
    def fold_batch(cls, n: int, m: int, k: int) -> int:
        """How many instances to run in one batch (memory-bound policies override)."""
        return n

    def propose(self) -> np.ndarray:
        raise NotImplementedError

    def update(self, cols: np.ndarray, scores: np.ndarray) -> None:
        self.tried[self._rows, cols] = True
        self.t += 1

    # Leave-one-out evaluation asks these to stop updating instances early.

    def settled(self) -> np.ndarray:
        """(B,) bool: instances whose later proposals no observation can change any more,
        so that :meth:`remaining` can list them now."""
        return np.zeros(self.ctx.size, dtype=bool)

    def remaining(self, folds: np.ndarray, steps: int) -> np.ndarray:
        """The next ``steps`` proposals of the settled instances ``folds``, (F, steps):
        what ``steps`` rounds of propose and update would give them."""
        raise NotImplementedError

    def keep(self, folds: np.ndarray) -> None:
        """Drop every instance but ``folds`` (in that order) from the batch."""
        self.ctx = self.ctx.subset(folds)
        self.tried = self.tried[folds]
        self._rows = np.arange(folds.size)

    @classmethod
    def bytes_per_instance(cls, m: int, live: int, steps: int) -> int:
        """Bytes of buffers an instance may hold over ``steps`` tries when ``live`` of the
        m columns are not inert (see :class:`GaussianPosterior`)."""
        return 0


class _OrderPolicy(Policy):
    """Tries columns in a fixed per-instance order, skipping any already tried."""

    relative_cost = 0.05

    def __init__(self, ctx: FoldContext, order: np.ndarray):
        super().__init__(ctx)
        self._order = order
        self._next = np.zeros(ctx.size, dtype=np.intp)

    def propose(self) -> np.ndarray:
        rows, nxt = self._rows, self._next
        while True:
            cols = self._order[rows, nxt]
            stale = self.tried[rows, cols]
            if not stale.any():
                return cols
            nxt[stale] += 1

    def settled(self) -> np.ndarray:
        return np.ones(self.ctx.size, dtype=bool)  # the order is fixed from the start

    def remaining(self, folds: np.ndarray, steps: int) -> np.ndarray:
        order = self._order[folds]
        open_ = ~np.take_along_axis(self.tried[folds], order, axis=1)
        first = np.argsort(~open_, axis=1, kind="stable")[:, :steps]  # untried, in order
        return np.take_along_axis(order, first, axis=1)

    def keep(self, folds: np.ndarray) -> None:
        super().keep(folds)
        self._order = self._order[folds]
        self._next = self._next[folds]


def _descending(values: np.ndarray) -> np.ndarray:
    """Column orders by decreasing value, ties to the lowest index."""
    return np.argsort(-values, axis=1, kind="stable")


@register("static")
class Static(_OrderPolicy):
    """STATIC: columns in order of decreasing prior mean (paper eq. 1)."""

    def __init__(self, ctx: FoldContext):
        super().__init__(ctx, _descending(ctx.prior.mean))


@register("rand")
class Rand(_OrderPolicy):
    """RAND: a uniformly random order from each instance's seeded generator."""

    def __init__(self, ctx: FoldContext):
        order = np.stack([np.random.default_rng(s).permutation(ctx.m) for s in ctx.seeds])
        super().__init__(ctx, order)


@register("oracle")
class Oracle(_OrderPolicy):
    """ORACLE: the true scores in decreasing order (best constraint in hindsight first)."""

    needs_truth = True

    def __init__(self, ctx: FoldContext):
        super().__init__(ctx, _descending(ctx.true_scores))


@register("fastest")
class Fastest(_OrderPolicy):
    """FASTEST, the time-optimal oracle: the true row's feasible columns by increasing time,
    then its infeasible ones by increasing time (ties: lowest index).

    Its time to first feasible plan is the least any selector can achieve on an instance:
    the headroom of a domain, where ORACLE (best score first) shows the best plan's cost.
    """

    needs_truth = True

    def __init__(self, ctx: FoldContext):
        # infeasible columns sort after every feasible one whatever their time
        key = np.where(ctx.true_feasible, 0.0, 1.0)
        order = np.lexsort((np.arange(ctx.m)[None, :].repeat(ctx.size, 0), ctx.true_times,
                            key), axis=1)
        super().__init__(ctx, order)


@register("box")
class Box(Policy):
    """BOX (paper Algorithm 1): argmax of posterior mean + c * posterior std."""

    defaults = {"c": 1.96}

    def __init__(self, ctx: FoldContext, c: float = 1.96):
        super().__init__(ctx)
        if not (math.isfinite(c) and c >= 0):
            raise ValueError(f"c must be a finite number >= 0, got {c!r}")
        self.c = float(c)
        self.posterior = _posterior(ctx, self.drops_tried())
        # untried columns whose posterior an observation can still move, per instance
        self._open = (~(self.tried | self.posterior.inert)).sum(axis=1)

    @classmethod
    def drops_tried(cls) -> bool:
        """Whether nothing reads a tried column's posterior, so that the posterior may
        forget those columns (GaussianPosterior's ``drop_observed``): true of BOX's own
        :meth:`propose`, not assumed of one that overrides it."""
        return cls.propose is Box.propose

    @classmethod
    def fold_batch(cls, n: int, m: int, k: int) -> int:
        # Keep the part of each batch's W that a step reads near 8 MiB: it stays in cache
        # while stepping, and bounds memory whatever n is.  A W that drops the columns
        # tried (drops_tried) is read at about t (m - t) doubles per instance at step t
        # (plus what a repack leaves), otherwise t m.
        if cls.drops_tried():
            t = min(k, m // 2)
            return int(max(1, min(n, (10 << 20) // (9 * t * (m - t) + 8 * m))))
        return int(max(1, min(n, (8 << 20) // (8 * k * m))))

    @classmethod
    def bytes_per_instance(cls, m: int, live: int, steps: int) -> int:
        # W: where a quarter of the columns or more are inert, a row per live column
        # tried, over the live columns and up to 6 more; otherwise a row per step over all
        # m columns (see GaussianPosterior)
        if 4 * (live + 3) <= 3 * m:
            return 8 * min(m, live + 6) * min(steps, live)
        return 8 * m * steps

    def coefficient(self) -> float:
        return self.c

    def variance_factor(self) -> float:
        return 1.0

    def values(self) -> np.ndarray:
        """The upper confidence bounds that :meth:`propose` maximises, (B, m)."""
        post = self.posterior
        factor = self.variance_factor()
        std = post.std() if factor == 1.0 else np.sqrt(factor * np.maximum(post.var, 0.0))
        return post.mean + self.coefficient() * std

    def propose(self) -> np.ndarray:
        post = self.posterior
        if post.slots is None:
            return argmax_untried(self.values(), self.tried, post.scale)
        # the same bounds at the untried columns (W's live columns): the same choice
        return argmax_untried_at(self._bounds(post.mean_slots, post.var_slots),
                                 post.dead_slots, post.scale, post.slots)

    def _bounds(self, mean: np.ndarray, var: np.ndarray) -> np.ndarray:
        """:meth:`values` from these posterior means and variances."""
        factor = self.variance_factor()
        std = (np.sqrt(np.maximum(var, 0.0)) if factor == 1.0
               else np.sqrt(factor * np.maximum(var, 0.0)))
        return mean + self.coefficient() * std

    def update(self, cols: np.ndarray, scores: np.ndarray) -> None:
        super().update(cols, scores)
        self.posterior.observe(cols, scores)
        self._open -= ~self.posterior.inert[cols]

    def settled(self) -> np.ndarray:
        # Every untried column is inert: its posterior is the prior mean with zero
        # variance whatever is observed, so its bound is that mean from now on.
        return self._open == 0

    def remaining(self, folds: np.ndarray, steps: int) -> np.ndarray:
        return argmax_sequence(self.values()[folds], self.tried[folds],
                               self.posterior.scale[folds], steps)

    def keep(self, folds: np.ndarray) -> None:
        super().keep(folds)
        self.posterior.keep(folds)
        self._open = self._open[folds]


def _posterior(ctx: FoldContext, drop_tried: bool) -> GaussianPosterior:
    """The Gaussian posterior of a batch; ``drop_tried``: one that may forget the columns
    tried (the forbidden ones from the start)."""
    drop = drop_tried and (True if ctx.forbidden is None else ctx.forbidden)
    return GaussianPosterior(ctx.prior, capacity=ctx.horizon or 16,
                             skip_inert=ctx.skip_inert, drop_observed=drop)


@register("pembo")
class PemBo(Box):
    """PEM-BO (Wang, Kim and Kaelbling, NeurIPS 2018): the paper's estimator, the authors'
    UCB schedule.

    GP-UCB with the estimated prior: with N training rows and t observations so far on this
    instance, the conditioned posterior variance is multiplied once by (N - 1) / (N - t - 1)
    (the unbiased estimate of the posterior variance of the paper, applied once to the
    conditioned variance; the authors' code compounds it step after step:
    :class:`PemBoCompounded`) and the UCB coefficient is :func:`pembo_zeta` (t, N).
    Where the factor's denominator N - t - 1 would fall below 1 it is held at 1.
    """

    defaults = {"delta": 0.01}

    def __init__(self, ctx: FoldContext, delta: float = 0.01):
        if not (isinstance(delta, int | float) and 0 < delta < 1):
            raise ValueError(f"delta must lie in (0, 1), got {delta!r}")
        super().__init__(ctx, c=0.0)
        self.delta = float(delta)

    def coefficient(self) -> float:
        return pembo_zeta(self.t, self.ctx.prior.n_train, self.delta)

    def variance_factor(self) -> float:
        N = self.ctx.prior.n_train
        return (N - 1) / max(N - self.t - 1, 1)


@register("pembo_compounded")
class PemBoCompounded(PemBo):
    """PEM-BO with the variance factor compounded step after step, as the authors' code for
    discrete domains does (its iterative GP conditions the previous step's scaled covariance
    and scales it again): after t observations the conditioned variance is multiplied by
    the product over s = 1..t of (N - 1) / (N - s - 1), each denominator held at 1 or more.
    The paper's estimator, and ``pembo``, apply the last factor once.  Conditioning does not
    depend on a common scale of the covariance, so the posterior mean is the same and the two
    differ only in how much the UCB explores; docs/box_core.md gives the measured effect."""

    def variance_factor(self) -> float:
        N = self.ctx.prior.n_train
        return math.prod((N - 1) / max(N - s - 1, 1) for s in range(1, self.t + 1))


def pembo_margin(delta: float) -> int:
    """The smallest r = N - t - 1 at which :func:`pembo_zeta`'s formula is defined:
    r >= 2 (so N - t - 2 >= 1) and 2 sqrt(log(6 / delta) / r) < 1."""
    r = max(2, math.floor(4.0 * math.log(6.0 / delta)) + 1)
    while 2.0 * math.sqrt(math.log(6.0 / delta) / r) >= 1.0:  # guards float rounding
        r += 1
    return r


def pembo_zeta(t: int, N: int, delta: float = 0.01) -> float:
    """PEM-BO's UCB coefficient after ``t`` observations with ``N`` training rows.

    The schedule of the authors' code (class ``AutomaticZetaUCB`` of their ``functions.py``),
    with L6 = log(6 / delta):

        iota_t = sqrt(6 (N - 2 + t + 2 sqrt(t L6) + 2 L6) / (delta N (N - t - 2)))
        b_t    = L6 / (N - t - 1)
        zeta_t = (iota_t + sqrt(2 log(3 / delta))) / sqrt(1 - 2 sqrt(b_t))

    It is undefined once N - t - 2 <= 0 or 2 sqrt(b_t) >= 1, i.e. once r = N - t - 1 drops
    below r_min = :func:`pembo_margin` (26 for delta = 0.01; the authors' code then produced
    NaN and re-picked one index forever).  Our finite continuation: r is held at r_min in
    both denominators (N - t - 2 becomes r_min - 1) while t keeps its value in the
    numerator.  It agrees with the formula wherever that is defined, is continuous, finite
    and non-decreasing in t, and for tiny N (N - 1 < r_min) gives a large coefficient,
    i.e. mostly exploration, which is where the formula itself tends.
    """
    L6 = math.log(6.0 / delta)
    r = max(N - t - 1, pembo_margin(delta))
    iota = math.sqrt(6.0 * (N - 2 + t + 2.0 * math.sqrt(t * L6) + 2.0 * L6)
                     / (delta * N * (r - 1)))
    shrink = math.sqrt(1.0 - 2.0 * math.sqrt(L6 / r))
    return (iota + math.sqrt(2.0 * math.log(3.0 / delta))) / shrink


@register("doo")
class Doo(Policy):
    """DOO over the discrete constraint set (Munos 2011, as adapted in the paper).

    The optimistic bound of an untried column i is min over tried j of
    J_j + lam * ||theta_i - theta_j|| (Euclidean on the constraint features); the first
    column is drawn at random from the instance's seeded generator.
    """

    relative_cost = 0.4

    defaults = {"lam": 1.0}
    needs_features = True

    def __init__(self, ctx: FoldContext, lam: float = 1.0):
        super().__init__(ctx)
        if not (math.isfinite(lam) and lam >= 0):
            raise ValueError(f"lam must be a finite number >= 0, got {lam!r}")
        self.lam = float(lam)
        from scipy.spatial.distance import cdist  # here: see box_core.stats on import times

        self._reach = self.lam * cdist(ctx.features, ctx.features)  # lam * ||theta_i - theta_j||
        # the bounds, with tried columns at -inf (as argmax_untried masks them)
        self._bound = np.where(self.tried, -np.inf, np.inf)
        self._work = np.empty((ctx.size, ctx.m))
        first = np.array([np.random.default_rng(s).integers(ctx.m) for s in ctx.seeds])
        # a forbidden first pick moves on to the next allowed column (cyclically)
        shift = np.argmin(np.take_along_axis(
            self.tried, (first[:, None] + np.arange(ctx.m)) % ctx.m, axis=1), axis=1)
        self._first = (first + shift) % ctx.m
        self._scale = np.zeros(ctx.size)

    @classmethod
    def fold_batch(cls, n: int, m: int, k: int) -> int:
        # every step reads and writes each row's m bounds: batches that stay in cache
        return int(max(1, min(n, (2 << 20) // (8 * m))))

    def propose(self) -> np.ndarray:
        if self.t == 0:
            return self._first.copy()
        return argmax_masked(self._bound, self._scale)

    def update(self, cols: np.ndarray, scores: np.ndarray) -> None:
        super().update(cols, scores)
        work = np.take(self._reach, cols, axis=0, out=self._work)
        work += scores[:, None]  # scores + lam * distance
        np.minimum(self._bound, work, out=self._bound)
        self._bound[self._rows, cols] = -np.inf
        self._scale = np.maximum(self._scale, np.abs(scores))

    def keep(self, folds: np.ndarray) -> None:
        super().keep(folds)
        self._bound, self._first, self._scale = (self._bound[folds], self._first[folds],
                                                 self._scale[folds])
        self._work = np.empty((folds.size, self.ctx.m))


@dataclass(frozen=True, eq=False)
class TrainingOutcomes:
    """The training rows' outcomes, which ``eips`` learns from besides the scores.

    ``feasible`` and ``times`` (n, m) cover the rows the prior was fitted on; ``held_out``
    (B,) names, per instance of the batch, one of those rows to leave out (its own row in
    leave-one-out, whose prior is the rank-one downdate), or -1.  ``threshold``: an
    observed score above it is a feasible plan (scores in the internal unit).  ``checks``
    (n, m), where known: the collision checks each training try used (capped tries).
    ``memo``: what selectors derive from these arrays alone, kept for the next batch of
    the same evaluation (:meth:`holding_out` shares it; the arrays are never changed).
    """

    feasible: np.ndarray
    times: np.ndarray
    held_out: np.ndarray
    threshold: float
    checks: np.ndarray | None = None
    memo: dict = field(default_factory=dict, repr=False)

    def holding_out(self, held_out) -> TrainingOutcomes:
        """The same outcomes for a batch that holds out ``held_out``."""
        return replace(self, held_out=np.asarray(held_out, dtype=np.intp))

    @classmethod
    def of(cls, scores: np.ndarray, feasible: np.ndarray, times: np.ndarray, held_out,
           checks: np.ndarray | None = None):
        """Outcomes of training ``scores`` (internal unit, failures filled), with the
        threshold halfway between the best failure and the worst feasible score."""
        fails, oks = scores[~feasible], scores[feasible]
        if not fails.size:
            threshold = -math.inf
        elif not oks.size:
            threshold = math.inf
        else:
            threshold = 0.5 * (float(fails.max()) + float(oks.min()))
        return cls(feasible=feasible, times=times,
                   held_out=np.asarray(held_out, dtype=np.intp), threshold=threshold,
                   checks=checks)


@register("eips")
class Eips(Policy):
    """EIPS, expected improvement per second: the untried column with the best expected
    gain per typical second of planning (after Snoek, Larochelle and Adams 2012), for this
    discrete, correlated setting.

    Feasibility model: the training rows, weighted by how well they agree with what this
    instance has shown.  Row r starts with weight 1 (0 for a held-out row); each try of
    column j multiplies it by ``mismatch`` when r's feasibility at j differs from the
    observed one (``mismatch = 0``: only rows with exactly the observed pattern count; the
    default 0.1 allows for the planner's own randomness: a sampling planner that runs out of
    budget on one instance may succeed on a near-identical one).  With those weights w and
    ``prior_rows`` = a pseudo-rows at the fold's column means pbar,

        p_j = (sum_r w_r F[r, j] + a pbar_j) / (sum_r w_r + a)     P(feasible at j | tries)

    the frequency of success among past instances that behaved like this one.  Why not the
    Gaussian posterior for feasibility: feasibility is binary and mostly failures (98 % of
    the entries of the authors' grasp matrix), which a Gaussian on scores models poorly,
    while these frequencies are the exact predictive distribution of the empirical instance
    distribution.  Only rows whose weight changes touch the sums, so a try costs
    O(m + changed rows * m); a row whose weight has become negligible
    (:data:`NEGLIGIBLE_WEIGHT`, some 23 mismatches at the default) is no longer updated, so
    each row is touched a bounded number of times and, once none is left to update, p and
    the typical times are computed once.  The feasibility model then is fixed, and what a
    try costs is the Gaussian posterior's update (the posterior forgets the tried columns,
    whose gains are never read).

    Cost model: tau_j = p_j s_j + (1 - p_j) f_j, where s_j and f_j are the typical times of
    column j's feasible and infeasible entries *on instances like this one*: geometric
    means (planning times are heavy-tailed: a failure that exhausts the planner's budget
    costs 1000 times one refuted at IK, so logarithms, not seconds, are averaged) over the
    training rows with the same weights w, plus ``time_rows`` pseudo-rows at the column's
    geometric mean over all training rows (of the whole column where one kind is missing):

        log s_j = (sum_r w_r F[r, j] log T[r, j] + b g_j) / (sum_r w_r F[r, j] + b)

    and f_j alike with 1 - F; times below :data:`TIME_FLOOR` count as the floor.  So the
    history conditions both what a try will yield and what it will cost: an instance whose
    failures look like those of instances where this grasp ran the planner out of budget
    expects that cost.

    Gain: while nothing feasible has been found, p_j, so the order is by p_j / tau_j.  For
    independent tries with success probabilities p_j and *expected* costs c_j, decreasing
    p_j / c_j is the order that minimises the expected time to the first success (Kadane);
    here it is a heuristic after that rule, not an optimum: tau_j is built from geometric
    means (a typical cost, below the expected one for heavy-tailed times), and the tries are
    not independent (p and tau are re-estimated after every try).  After the first
    feasible plan, the expected improvement of the best score under BOX's Gaussian
    posterior (all tries, failures at the failure value):
    EI_j = s (z Phi(z) + phi(z)), z = (mu_j - best) / s, s the posterior std (EI_j =
    max(mu_j - best, 0) when s = 0 or z >= :data:`Z_LIMIT`, 0 when z <= -Z_LIMIT), divided
    by tau_j.  Ties go to the lowest index.
    """

    defaults = {"prior_rows": 1.0, "mismatch": 0.1, "time_rows": 5.0}
    relative_cost = 4.3
    needs_outcomes = True
    shares_tables = True

    def __init__(self, ctx: FoldContext, prior_rows: float = 1.0, mismatch: float = 0.1,
                 time_rows: float = 5.0):
        super().__init__(ctx)
        if not (math.isfinite(prior_rows) and prior_rows > 0):
            raise ValueError(f"prior_rows must be a finite number > 0, got {prior_rows!r}")
        if not (math.isfinite(mismatch) and 0 <= mismatch < 1):
            raise ValueError(f"mismatch must lie in [0, 1), got {mismatch!r}")
        if not (math.isfinite(time_rows) and time_rows > 0):
            raise ValueError(f"time_rows must be a finite number > 0, got {time_rows!r}")
        out = ctx.outcomes
        self.a, self.rho, self.b = float(prior_rows), float(mismatch), float(time_rows)
        self._FT = np.ascontiguousarray(out.feasible.T)  # (m, n): a column's rows, contiguous
        self._threshold = out.threshold
        F = out.feasible.astype(np.float64)
        n = F.shape[0]
        own = out.held_out >= 0
        mine = out.held_out[own]
        self._w = np.ones((ctx.size, n))
        self._w[np.flatnonzero(own), mine] = 0.0
        # rows whose weight is still updated: not the own row, and not yet negligible
        self._live = self._w > 0
        self._cutoff = NEGLIGIBLE_WEIGHT * min(self.a, self.b) / float(max(n, 1)) ** 2

        def fold_sums(values):  # column sums over each fold's training rows, (B, m)
            sums = np.repeat(values.sum(axis=0)[None, :], ctx.size, axis=0)
            sums[own] -= values[mine]
            return sums

        self._sums = fold_sums(F)
        self._mass = self._w.sum(axis=1)
        self._pbar = self._sums / np.maximum(self._mass, 1.0)[:, None]
        logT = np.log(np.maximum(out.times, TIME_FLOOR))
        L = (F * logT, (1.0 - F) * logT)  # log times of feasible / infeasible entries
        self._lsums = [fold_sums(x) for x in L]  # their weighted column sums, (B, m)
        ok_n, fail_n = self._sums, self._mass[:, None] - self._sums
        mean_l = fold_sums(logT) / np.maximum(self._mass, 1.0)[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            self._g = (np.where(ok_n > 0, self._lsums[0] / ok_n, mean_l),
                       np.where(fail_n > 0, self._lsums[1] / fail_n, mean_l))
        self._best = np.full(ctx.size, -np.inf)
        self.posterior = _posterior(ctx, self.drops_tried())
        # Idle columns: constant, and infeasible on every training row.  In leave-one-out
        # (every instance's own row among the outcomes) the held-out row fails there too,
        # so a try changes no weight, sum, best score or posterior, and the column's gain
        # is 0 (p = 0 before a plan is found; after, the posterior there is a failure with
        # zero variance).  Only the other columns' sums are kept, column by column the
        # same numbers.
        idle = self.posterior.inert & ~out.feasible.any(axis=0)
        if not (out.held_out >= 0).all():
            idle[:] = False
        self._idle = idle
        self._open = (~(self.tried | idle)).sum(axis=1)
        self._cols = None if not idle.any() else np.flatnonzero(~idle)
        if self._cols is not None:
            kept = self._cols
            F, L = F[:, kept], tuple(x[:, kept] for x in L)
            self._sums, self._pbar = self._sums[:, kept], self._pbar[:, kept]
            self._lsums = [sums[:, kept] for sums in self._lsums]
            self._g = tuple(g[:, kept] for g in self._g)
        # F, L_ok and L_fail side by side: one sparse product updates the three sums
        # (column by column the same numbers as three products)
        self._FL = RowTable(np.ascontiguousarray(np.concatenate([F, *L], axis=1)))
        self._changing = int(self._live.sum())  # rows whose weight is still updated
        self._frozen = None  # (p, tau) once no weight changes any more

    fold_batch = Box.fold_batch
    bytes_per_instance = Box.bytes_per_instance

    @classmethod
    def drops_tried(cls) -> bool:
        return True  # values() reads the posterior everywhere, but propose masks tried

    def expected(self) -> tuple[np.ndarray, np.ndarray]:
        """(p, tau), each (B, m): probability of feasibility and expected time per column
        (of the kept columns only, where some are idle or tried by every instance)."""
        if self._frozen is not None:
            p, tau = self._frozen
            return p.copy(), tau
        p = (self._sums + self.a * self._pbar) / (self._mass + self.a)[:, None]
        p = np.clip(p, 0.0, 1.0)
        b = self.b
        ok_w = self._sums
        fail_w = np.maximum(self._mass[:, None] - ok_w, 0.0)
        t_ok = np.exp((self._lsums[0] + b * self._g[0]) / (ok_w + b))
        t_fail = np.exp((self._lsums[1] + b * self._g[1]) / (fail_w + b))
        tau = np.maximum(p * t_ok + (1.0 - p) * t_fail, 1e-12)
        if not self._changing:
            self._frozen = (p.copy(), tau)
        return p, tau

    def propose(self) -> np.ndarray:
        return argmax_untried(self.values(), self.tried, np.zeros(self.ctx.size))

    def values(self) -> np.ndarray:
        """Expected gain per typical second, (B, m): what :meth:`propose` maximises (0 at
        the columns whose sums are not kept: idle ones, and those every instance tried)."""
        gain, tau = self.expected()
        found = np.flatnonzero(np.isfinite(self._best))
        kept = self._cols
        if found.size:
            from scipy.special import ndtr  # here: see box_core.stats on import times

            post = self.posterior
            at = found if kept is None else np.ix_(found, kept)
            std = np.sqrt(np.maximum(post.var[at], 0.0))
            gap = post.mean[at] - self._best[found, None]
            with np.errstate(divide="ignore", invalid="ignore"):
                z = gap / std
            zc = np.clip(np.nan_to_num(z), -Z_LIMIT, Z_LIMIT)  # no subnormals, no overflow
            ei = std * (zc * ndtr(zc) + np.exp(-0.5 * zc * zc) / _SQRT_2PI)
            ei = np.where(z > -Z_LIMIT, ei, 0.0)
            gain[found] = np.where((std > 0) & (z < Z_LIMIT), ei, np.maximum(gap, 0.0))
        if kept is None:
            return gain / tau
        out = np.zeros((self.ctx.size, self.ctx.m))
        out[:, kept] = gain / tau
        return out

    def update(self, cols: np.ndarray, scores: np.ndarray) -> None:
        super().update(cols, scores)
        self.posterior.observe(cols, scores)
        ok = scores > self._threshold
        self._best = np.where(ok, np.maximum(self._best, scores), self._best)
        busy = np.flatnonzero(ok | ~self._idle[cols])  # an idle try changes no weight
        differs = self._FT[cols[busy]] != ok[busy, None]
        differs &= self._live[busy]
        b, r = np.divmod(np.flatnonzero(differs), differs.shape[1])
        b = busy[b]
        if b.size:
            change = self._w[b, r] * (self.rho - 1.0)
            self._w[b, r] += change
            stays = self._w[b, r] >= self._cutoff  # (mismatch 0: none)
            self._live[b, r] = stays
            self._changing -= b.size - int(stays.sum())
            if 3 * b.size >= self._w.size:  # a third of all weights: one BLAS product
                delta = np.zeros(self._w.shape)
                delta[b, r] = change
                added = delta @ self._FL.rows
            else:
                from scipy import sparse  # here: see box_core.stats on import times

                # the weight changes as a CSR matrix built directly (b is sorted, r
                # ascending within each b: the canonical layout), not through COO's
                indptr = np.zeros(self.ctx.size + 1, dtype=np.intp)
                np.cumsum(np.bincount(b, minlength=self.ctx.size), out=indptr[1:])
                delta = sparse.csr_matrix((change, r, indptr), shape=self._w.shape)
                added = self._FL.weighted(delta)
            width = self._sums.shape[1]
            self._sums += added[:, :width]
            self._lsums[0] += added[:, width:2 * width]
            self._lsums[1] += added[:, 2 * width:]
            self._mass += np.bincount(b, weights=change, minlength=self.ctx.size)
            if not self._changing:
                self._FL = None  # the sums are final: nothing reads the rows again
        self._open -= ~self._idle[cols]
        if self.ctx.skip_inert:
            self._narrow()

    def _narrow(self) -> None:
        """Stop keeping the sums of the columns every instance of the batch has tried
        once they are a quarter of those kept: no later choice reads them (tried columns
        are masked), and the sparse product of :meth:`update`, the costliest step, reads
        every kept column of every changed row.  The other columns' sums are the same
        numbers (each is its own column's running sum)."""
        width = self._sums.shape[1]
        kept = np.arange(self.ctx.m) if self._cols is None else self._cols
        done = self.tried[:, kept].all(axis=0)
        dropped = int(done.sum())
        if 4 * dropped < width or dropped == width:
            return
        at = np.flatnonzero(~done)
        self._cols = kept[at]
        if self._FL is not None:
            self._FL = RowTable(np.ascontiguousarray(self._FL.rows[:, np.concatenate(
                [at, width + at, 2 * width + at])]))
        self._frozen = None
        self._sums, self._pbar = self._sums[:, at], self._pbar[:, at]
        self._lsums = [sums[:, at] for sums in self._lsums]
        self._g = tuple(g[:, at] for g in self._g)

    def settled(self) -> np.ndarray:
        return self._open == 0  # every untried column is idle: all gains stay 0

    def remaining(self, folds: np.ndarray, steps: int) -> np.ndarray:
        return argmax_sequence(self.values()[folds], self.tried[folds],
                               np.zeros(folds.size), steps)

    def keep(self, folds: np.ndarray) -> None:
        super().keep(folds)
        self.posterior.keep(folds)
        self._w, self._live = self._w[folds], self._live[folds]
        self._changing, self._frozen = int(self._live.sum()), None
        self._sums, self._mass, self._pbar = self._sums[folds], self._mass[folds], \
            self._pbar[folds]
        self._lsums = [sums[folds] for sums in self._lsums]
        self._g = tuple(g[folds] for g in self._g)
        self._best, self._open = self._best[folds], self._open[folds]


_SQRT_2PI = math.sqrt(2.0 * math.pi)

#: EIPS stops updating a training row's weight once it is below NEGLIGIBLE_WEIGHT *
#: min(prior_rows, time_rows) / n^2 (n training rows): all such rows together weigh under
#: NEGLIGIBLE_WEIGHT * min(a, b) / n, so leaving their weights as they are (rather than
#: shrinking them further) moves each p_j (whose numerator is at least prior_rows / n
#: wherever a training row is feasible at j, and exactly 0 elsewhere) and each typical
#: time by under about NEGLIGIBLE_WEIGHT of itself: below the rounding that the running
#: sums carry anyway.  With the default mismatch 0.1 a row is frozen after some 23
#: mismatches, which most rows reach within the first hundred tries of a 1500-row matrix,
#: and the sums stop costing anything.
NEGLIGIBLE_WEIGHT = 1e-16

#: EIPS's cost model takes times below this (seconds) as this: logarithms need a floor
TIME_FLOOR = 1e-6

#: EIPS's expected improvement counts as 0 more than Z_LIMIT posterior standard deviations
#: below the best score, and as the plain gap more than Z_LIMIT above it (what the formula
#: gives there to double precision), which keeps its arithmetic away from subnormals.
Z_LIMIT = 30.0


def check_selector(name: str, params: dict, *, features, outcomes: bool = True) -> type[Policy]:
    """The policy class for ``name``, after checking its parameters and requirements
    (``outcomes``: whether training times and feasibility will be supplied)."""
    if name not in SELECTORS:
        raise ValueError(f"unknown selector {name!r}; choose from {', '.join(sorted(SELECTORS))}")
    cls = SELECTORS[name]
    unknown = set(params) - set(cls.defaults)
    if unknown:
        accepted = ", ".join(cls.defaults) or "none"
        raise ValueError(
            f"unknown parameter(s) {', '.join(sorted(unknown))} for selector {name!r} "
            f"(accepted: {accepted})"
        )
    for key, value in params.items():
        if isinstance(value, bool) or not isinstance(value, int | float | np.integer
                                                     | np.floating):
            raise ValueError(f"parameter {key} of selector {name!r} must be a number, "
                             f"got {value!r}")
    if cls.needs_features and features is None:
        raise ValueError(f"selector {name!r} needs constraint features (an m x p array)")
    if cls.needs_outcomes and not outcomes:
        raise ValueError(f"selector {name!r} needs the training rows' times and feasibility "
                         "(times=..., feasible=...)")
    return cls


def score_unit(scores: np.ndarray) -> float:
    """The positive number box_core divides scores by before any arithmetic: the largest
    magnitude (1 for an all-zero matrix).  See :func:`standardise`."""
    top = float(np.abs(scores).max()) if scores.size else 0.0
    return top if top > 0 and math.isfinite(top) else 1.0


#: Standardised scores are rounded to multiples of 2**-GRID_BITS (about 2e-10 of the
#: largest score): far below any meaningful difference, far above rounding error.
GRID_BITS = 32


def standardise(scores, unit: float) -> np.ndarray:
    """Scores as every selector sees them: divided by ``unit`` (:func:`score_unit`) and
    rounded to a fixed grid.

    Dividing makes all arithmetic independent of the caller's unit (no covariance overflows
    or underflows for scores of 1e150 or 1e-150); rounding removes the last-bit differences
    that multiplying by a factor leaves, which near-singular conditioning (rank-deficient
    real matrices) would otherwise amplify into different orders.  So orders, ties and
    times are the same for scores multiplied by any positive factor.  DOO's lam is in this
    unit.
    """
    scale = float(2**GRID_BITS)
    return np.round(np.asarray(scores, dtype=np.float64) / unit * scale) / scale


class Selector:
    """A live selector for one new instance.

    Uncapped: ``propose()`` a column, then ``update`` it with its score.  Every selector
    also offers tries with a check allowance, the one loop for all of them:
    ``propose_try()`` gives (column, allowance), the caller plans that column until it has
    used ``allowance`` collision checks in all (math.inf: to the end) and reports
    (:meth:`report`) whether it ended (its score) or paused.  Only a capped selector
    (``contextual_capped`` built with checks and a finite cap, :attr:`capped`) gives
    finite allowances; it may later propose a paused column again, with a larger
    allowance, to resume it.  Its choices are those of :func:`box_core.tries.simulate`
    (the same ``propose_tries`` and ``record``), given the same outcomes.
    """

    def __init__(self, policy: Policy, unit: float = 1.0):
        self._policy = policy
        self._unit = unit
        #: (column, score) of every try that ended, in order
        self.history: list[tuple[int, float]] = []
        #: (column, allowance, score or None when paused, checks_used or None) of every try
        self.tries: list[tuple[int, float, float | None, int | None]] = []
        self._pending: tuple[int, float] | None = None

    @property
    def name(self) -> str:
        return self._policy.name

    @property
    def m(self) -> int:
        return self._policy.ctx.m

    @property
    def tried(self) -> np.ndarray:
        """Boolean mask (m,) of the columns tried so far (paused ones included)."""
        return self._policy.tried[0].copy()

    @property
    def capped(self) -> bool:
        """Whether :meth:`propose_try` may give finite allowances (then use it, not
        :meth:`propose`)."""
        return math.isfinite(getattr(self._policy, "cap", math.inf))

    def propose(self) -> int:
        """The next column to try (never one already tried)."""
        if self.capped:
            raise RuntimeError(f"selector {self.name!r} gives capped tries: use propose_try "
                               "and report")
        self._check_left()
        return int(self._policy.propose()[0])

    def update(self, index: int, score: float) -> None:
        """Report the score observed for column ``index`` (failed plans: the failure value)."""
        if self.capped:
            raise RuntimeError(f"selector {self.name!r} gives capped tries: use propose_try "
                               "and report")
        index = self._column(index)
        if self._policy.tried[0, index]:
            raise ValueError(f"index {index}: that constraint was already tried")
        score = _finite_score(score)
        self._policy.update(np.array([index]), standardise(np.array([score]), self._unit))
        self.history.append((index, score))
        self.tries.append((index, math.inf, score, None))
        self._pending = None

    def propose_try(self) -> tuple[int, float]:
        """(column, allowance) of the next try: plan ``column`` until it has used
        ``allowance`` collision checks in all, counted from its first slice (math.inf: to
        its end; a paused column proposed again is resumed).  Asking again before
        :meth:`report` gives the same try."""
        if self._pending is None:
            self._check_left()
            if hasattr(self._policy, "propose_tries"):
                cols, allow = self._policy.propose_tries()
                self._pending = (int(cols[0]), float(allow[0]))
            else:
                self._pending = (int(self._policy.propose()[0]), math.inf)
        return self._pending

    def report(self, column: int, *, score: float | None = None, paused: bool = False,
               checks_used: int | None = None) -> None:
        """Report the try of :meth:`propose_try`: ``score`` when it ended (failed plans:
        the failure value), or ``paused=True`` (no score) when it stopped at its
        allowance.  ``checks_used`` (optional): the checks it has used in all; a paused
        try may have used more than its allowance (a planner pauses between two steps of
        its search), and the selector then takes that allowance as the one granted: its
        choices depend only on the outcomes, as in :func:`box_core.tries.simulate`."""
        column = self._column(column)
        if self._pending is None:
            raise ValueError("no try is pending: call propose_try first")
        want, allowance = self._pending
        if column != want:
            raise ValueError(f"column {column} was not proposed (the pending try is "
                             f"column {want})")
        if not isinstance(paused, bool | np.bool_):
            raise ValueError(f"paused must be True or False, got {paused!r}")
        if checks_used is not None:
            if (isinstance(checks_used, bool)
                    or not isinstance(checks_used, int | np.integer) or checks_used < 0):
                raise ValueError(f"checks_used must be a whole number >= 0, got "
                                 f"{checks_used!r}")
            checks_used = int(checks_used)
        if paused:
            if score is not None:
                raise ValueError(f"column {column}: a paused try has no score")
            if math.isinf(allowance):
                raise ValueError(f"column {column}: an uncapped try cannot pause")
            if checks_used is not None and checks_used < allowance:
                raise ValueError(f"column {column}: a paused try has used its allowance "
                                 f"({allowance:g} checks), got checks_used={checks_used}")
            value = 0.0  # ignored: a paused try observes nothing
        else:
            if score is None:
                raise ValueError(f"column {column}: a try that ended needs its score")
            value = score = _finite_score(score)
        internal = standardise(np.array([value]), self._unit)
        if hasattr(self._policy, "record"):
            outcome = (np.array([PAUSED]) if paused
                       else self._policy.outcome_of_scores(internal))
            self._policy.record(np.array([column]), outcome, internal)
        else:
            self._policy.update(np.array([column]), internal)
        self._pending = None
        self.tries.append((column, allowance, score, checks_used))
        if not paused:
            self.history.append((column, score))

    def _check_left(self) -> None:
        if len(self.history) == self.m:
            raise RuntimeError(f"all {self.m} constraints have been tried")

    def _column(self, index) -> int:
        if isinstance(index, bool) or not isinstance(index, int | np.integer):
            raise ValueError(f"index must be an integer constraint index, got {index!r}")
        index = int(index)
        if not 0 <= index < self.m:
            raise ValueError(f"index {index} out of range for {self.m} constraints")
        return index


def _finite_score(score) -> float:
    try:
        score = float(score)
    except (TypeError, ValueError):
        raise ValueError(f"score must be a finite number, got {score!r}") from None
    if not math.isfinite(score):
        raise ValueError(f"score must be finite, got {score!r}")
    return score


def _training_rows(train_scores, feasible, times, checks):
    """(scores in the internal unit, the unit, feasibility, times, checks) of checked
    training rows (see :func:`make_selector`)."""
    D = validation.score_matrix(train_scores, name="train_scores", min_rows=2)
    unit = score_unit(D)
    D = standardise(D, unit)
    if feasible is None:
        F = D > D.min()
    else:
        F = validation.boolean_matrix(feasible, D.shape, name="feasible", ref="train_scores")
    T = np.ones(D.shape) if times is None else validation.matching_matrix(
        times, D.shape, name="times", ref="train_scores")
    if (T < 0).any():
        raise ValueError("times must be >= 0")
    C = None if checks is None else validation.checks_matrix(checks, D.shape,
                                                              ref="train_scores")
    return D, unit, F, T, C


def tuned_settings(name: str, train_scores, *, times=None, feasible=None, checks=None,
                   instance_features=None, seed: int = 0, **params) -> dict:
    """The settings :func:`make_selector` would tune for selector ``name`` on these training
    rows (``{}`` for a selector that tunes nothing).  They depend on the training rows
    only, so a caller serving many new instances tunes once and passes them to each
    :func:`make_selector` as ``settings=``."""
    cls = check_selector(name, params, features=None)
    if getattr(cls, "tuned", None) is None:
        return {}
    D, _, F, T, C = _training_rows(train_scores, feasible, times, checks)
    X = None if instance_features is None else validation.instance_features(
        instance_features, D.shape[0], ref="train_scores")
    from box_core.contextual import tune

    return tune(cls, D, F, T, C, X, params, seed=seed)


def make_selector(name: str, train_scores, *, features=None, seed=0, true_scores=None,
                  times=None, feasible=None, true_times=None, instance_features=None,
                  new_instance_features=None, checks=None, settings=None, **params):
    """Build selector ``name`` from a training score matrix (n x m, failures already scored).

    ``features`` (m x p) are needed by ``doo``; ``times`` (n x m, seconds per try) and
    ``feasible`` (n x m bool) by ``eips`` (without ``feasible``, entries above the matrix
    minimum count as feasible; without ``times`` every try costs 1); ``true_scores`` (m,) by
    ``oracle`` and ``fastest``, which also needs ``true_times`` (m,); ``seed`` (an int or a
    sequence of ints) seeds ``rand`` and ``doo``.  Further keyword arguments are the
    selector's parameters (``c`` for box, ``lam`` for doo, ``delta`` for pembo,
    ``prior_rows``, ``mismatch`` and ``time_rows`` for eips; ``k``, ``mismatch``,
    ``prior_rows``, ``c`` and ``select_features`` for contextual, with ``cap_quantile`` for
    contextual_capped).

    ``instance_features`` (n x q, the training rows') and ``new_instance_features`` (q,),
    the new instance's) feed ``contextual``: settings not given are tuned on the training
    rows (:func:`box_core.contextual.tune`; ``checks`` (n x m) are the training rows'
    collision checks, which only capped tries use: ``contextual_capped`` keeps its tuned
    cap, so use :meth:`Selector.propose_try` and :meth:`Selector.report` with it).
    Without them, or with q = 0, ``contextual`` is BOX.  ``settings``: what
    :func:`tuned_settings` returned for the same training rows (tuning is then skipped).
    """
    D, unit, F, T, C = _training_rows(train_scores, feasible, times, checks)
    prior = Prior.fit(D)
    if features is not None:
        features = validation.feature_matrix(features, prior.m)
    cls = check_selector(name, params, features=features)
    outcomes = TrainingOutcomes.of(D, F, T, [-1], C)
    truth = true_t = true_f = None
    if cls.needs_truth:
        if true_scores is None:
            raise ValueError(f"selector {name!r} needs true_scores (the instance's score row)")
        truth = standardise(validation.score_vector(true_scores, prior.m, name="true_scores"),
                            unit)[None, :]
        true_f = truth > outcomes.threshold
        if name == "fastest":
            if true_times is None:
                raise ValueError(f"selector {name!r} needs true_times (the instance's times)")
            true_t = validation.score_vector(true_times, prior.m, name="true_times")[None, :]
    X = query = None
    if instance_features is not None:
        X = validation.instance_features(instance_features, D.shape[0], ref="train_scores")
        if new_instance_features is None:
            raise ValueError("new_instance_features (the new instance's feature row) is "
                             "needed with instance_features")
        query = validation.feature_row(new_instance_features, X.shape[1])[None, :]
    elif new_instance_features is not None:
        raise ValueError("new_instance_features needs instance_features (the training "
                         "rows' features)")
    ctx = FoldContext(prior=prior.batch(), seeds=[seed], features=features, true_scores=truth,
                      outcomes=outcomes, true_times=true_t, true_feasible=true_f,
                      instance_features=X, query=query)
    if settings is not None:
        if getattr(cls, "tuned", None) is None or params:
            raise ValueError(f"settings= is for a tuned selector's tuned_settings, without "
                             f"other parameters (selector {name!r})")
        params = dict(settings)
    elif getattr(cls, "tuned", None) is not None:
        from box_core.contextual import tune

        params = tune(cls, D, F, T, C, X, params, seed=seed if isinstance(seed, int) else 0)
    return Selector(cls(ctx, **params), unit)
