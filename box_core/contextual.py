"""CONTEXTUAL: BOX's score-space posterior plus what the instance itself looks like.

The paper's selectors see a new instance only through the scores observed on it.  When
the instances come with features (an (n, q) array, one row per instance: a target's pose,
what is near it), the training instances most like this one say which constraints are
likely to work and what they cost here.  The name says that: the choice is made in the
context of the instance, not in score space alone.

Model, per instance (scores in box_core's internal unit):

- *Features*: those :func:`select_features` picks on the training rows (the ones whose
  neighbourhoods predict feasibility; on grasp_arm the target's pose, not the obstacle
  counts); with none picked, BOX.
- *Neighbours*: the ``k`` training rows nearest to the instance in those features,
  standardised by the training rows' means and standard deviations (constant features
  count for nothing; ties in distance go to the lower row), each with weight 1.  After
  every try before the first plan, a neighbour whose outcome at that column differs from
  the observed one (a plan where the instance had none, or the other way round) has its
  weight multiplied by ``mismatch`` (as :class:`~box_core.selectors.Eips` does with all
  training rows): the failures seen so far move the estimate towards the neighbours that
  failed where this instance failed.
- *Feasibility and cost*: with weights w, M = sum w, and ``prior_rows`` = a pseudo-rows at
  the training rows' column means,

      p_j   = (sum_r w_r [r plans at j within the cap] + a pbar_j) / (M + a)
      tau_j = (sum_r w_r T[r, j] share_rj + a tbar_j) / (M + a)

  where share_rj = min(1, cap / checks[r, j]) (1 without a cap): the expected planning
  seconds of a try, arithmetic means (the cost of a budget-exhausting failure counts in
  full: it is what the time to a first plan pays).
- *Order*: until a plan is found, the largest p_j / tau_j (Kadane's order for independent
  tries, re-estimated after each try); where every candidate has p_j / tau_j = 0, BOX's
  choice.  After the first plan, BOX: argmax of posterior mean + c * std, the posterior
  conditioned on every observed score exactly as BOX does.

Without instance features (none given, or q = 0) it *is* BOX: the same orders.

``contextual_capped`` adds capped tries (:mod:`box_core.tries`).  The cap is the
``cap_quantile`` quantile of the checks of the training rows' feasible entries.  Each
column offers up to three candidates, all ranked by p / tau: a first try capped (p and tau
as above), a first try uncapped (p and tau with no cap), and, for a paused try, resuming
it uncapped (p and tau over the neighbours whose try there went past the cap: the chance
of a plan after the cap and the expected remaining seconds).  So a column whose
neighbours sometimes run out of budget is tried capped, one whose plans often take long
uncapped, and a paused try is resumed when it is the best bet left.  Without stored
checks, or without a cap, it is ``contextual``.

Settings not given (the features, ``k``, and ``cap_quantile`` for the capped one) are
tuned by :func:`tune` on training rows only; see its docstring and docs/box_core.md.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from box_core.gaussian import argmax_sequence, argmax_untried, argmax_untried_at
from box_core.prior import Prior
from box_core.row_sums import RowTable
from box_core.selectors import TIME_FLOOR, Box, FoldContext, TrainingOutcomes, register
from box_core.tries import FAILED, FEASIBLE, PAUSED, simulate

#: Neighbour counts and cap quantiles the tuning chooses from (None: no cap)
K_GRID = (10, 20, 40, 80)
CAP_GRID = (0.8, 0.9, 0.95, 0.99, None)
#: Leave-one-out within the training rows evaluates at most this many of them
INNER_ROWS = 1000
#: Leave-one-out evaluation tunes the settings of held-out rows in this many groups
GROUPS = 10
#: Feature selection scores subsets by the neighbour estimate of feasibility with this
#: many neighbours, for at most SELECTION_ROWS training rows (drawn with the seed)
SELECTION_K = 20
SELECTION_ROWS = 400


def standardised_distances(train: np.ndarray, query: np.ndarray,
                           held_out: np.ndarray) -> np.ndarray:
    """Squared distances (B, n) from each query row to each training row, in features
    standardised by the training rows' mean and standard deviation; a query's own
    training row (``held_out[b] >= 0``) is left out of its statistics and set at inf."""
    n, q = train.shape
    B = query.shape[0]
    weight = np.ones((B, n))
    own = np.flatnonzero(held_out >= 0)
    weight[own, held_out[own]] = 0.0
    count = weight.sum(axis=1)[:, None]
    mean = weight @ train / count
    var = np.zeros((B, q))
    for f in range(q):
        dev = train[None, :, f] - mean[:, f:f + 1]
        var[:, f] = (weight * dev * dev).sum(axis=1) / count[:, 0]
    sd = np.sqrt(var)
    out = np.zeros((B, n))
    for f in range(q):
        live = sd[:, f] > 0
        d = (query[:, f:f + 1] - train[None, :, f]) / np.where(live, sd[:, f], 1.0)[:, None]
        out += np.where(live[:, None], d * d, 0.0)
    out[own, held_out[own]] = np.inf
    return out


def neighbour_ranks(train, query, held_out, k: int) -> np.ndarray:
    """(B, k): each query's k nearest training rows, nearest first (ties: lower row),
    its own row (``held_out``) never among them."""
    dist = standardised_distances(train, query, held_out)
    k = min(k, dist.shape[1])
    if k < dist.shape[1]:
        # the k smallest, then their order: the same rows as a full stable sort
        part = np.argpartition(dist, k - 1, axis=1)[:, :k]
        cut = np.take_along_axis(dist, part, axis=1).max(axis=1, keepdims=True)
        keys = np.where(dist <= cut, dist, np.inf)
        return np.argsort(keys, axis=1, kind="stable")[:, :k]
    return np.argsort(dist, axis=1, kind="stable")


class NeighbourModel:
    """p_j and tau_j of the module docstring for B instances, with the paused-try
    counterparts; updated after each try (see :meth:`observe`)."""

    def __init__(self, outcomes: TrainingOutcomes, train: np.ndarray, query: np.ndarray,
                 k: int, mismatch: float, prior_rows: float, cap: float,
                 ranks: np.ndarray | None = None):
        F, T = outcomes.feasible, outcomes.times
        n, m = F.shape
        held = outcomes.held_out
        B = query.shape[0]
        k = min(k, n - int((held >= 0).any()))
        if ranks is None or ranks.shape[1] < k:
            ranks = neighbour_ranks(train, query, held, k)
        self._nb = ranks[:, :k]  # (B, k) rows, nearest first
        self._w = np.ones((B, k))
        self.rho, self.a = float(mismatch), float(prior_rows)
        cap = math.inf if outcomes.checks is None else cap
        if outcomes.memo.get("neighbour cap") != cap:  # one cap at a time: (n, 6m) each
            outcomes.memo["neighbour cap"] = cap
            outcomes.memo["neighbour tables"] = _entry_tables(F, T, outcomes.checks, cap)
        self._cls, self._blocks, self._A, total = outcomes.memo["neighbour tables"]
        own = held >= 0
        if own.all():  # every instance a training row (the tuning's inner runs)
            self._mean = self._A.rows[held]
            np.subtract(total, self._mean, out=self._mean)
            self._mean /= n - 1
        else:
            self._mean = np.repeat((total / n)[None, :], B, axis=0)
            if own.any():
                self._mean[own] = (total - self._A.rows[held[own]]) / (n - 1)
        from scipy import sparse  # here: see box_core.stats on import times

        rows = np.repeat(np.arange(B), k)
        W = sparse.csr_matrix((self._w.ravel(), (rows, self._nb.ravel())), shape=(B, n))
        self._sums = self._A.weighted(W)
        self._mass = self._w.sum(axis=1)
        self.m = m

    def _block(self, a, i, rows=None):
        at = self._blocks.index(i)
        if rows is None:
            return a[:, at * self.m:(at + 1) * self.m]
        return a[rows, at * self.m:(at + 1) * self.m]

    def _parts(self, rows):
        """(a, mass + a, block) for instances ``rows`` (None: all)."""
        M = self._mass if rows is None else self._mass[rows]
        return self.a, M[:, None] + self.a, lambda a, i: self._block(a, i, rows)

    def fresh(self, rows=None) -> tuple[np.ndarray, np.ndarray]:
        """(p, tau) of a first (capped) try of each column, (B, m) each (of instances
        ``rows`` only: the same numbers)."""
        a, Ma, block = self._parts(rows)
        S, G = self._sums, self._mean
        p = (block(S, 1) + a * block(G, 1)) / Ma
        tau = (block(S, 4) + a * block(G, 4)) / Ma
        return p, tau

    def uncapped(self, rows=None) -> tuple[np.ndarray, np.ndarray]:
        """(p, tau) of a first try of each column without a cap, (B, m) each."""
        a, Ma, block = self._parts(rows)
        S, G = self._sums, self._mean
        p = (block(S, 1) + block(S, 2) + a * (block(G, 1) + block(G, 2))) / Ma
        tau = (block(S, 4) + block(S, 5) + a * (block(G, 4) + block(G, 5))) / Ma
        return p, tau

    def resumed(self, rows=None) -> tuple[np.ndarray, np.ndarray]:
        """(p, tau) of resuming a paused try of each column, (B, m) each (p = 0 where no
        training row went past the cap there)."""
        a, _, block = self._parts(rows)
        S, G = self._sums, self._mean
        ok = block(S, 2) + a * block(G, 2)
        mass = ok + block(S, 3) + a * block(G, 3)
        rest = block(S, 5) + a * block(G, 5)
        with np.errstate(divide="ignore", invalid="ignore"):
            p = np.where(mass > 0, ok / mass, 0.0)
            tau = np.where(mass > 0, rest / mass, 0.0)
        return p, tau

    def observe(self, rows: np.ndarray, cols: np.ndarray, outcome: np.ndarray,
                resumed: np.ndarray) -> None:
        """Instances ``rows`` tried ``cols`` with ``outcome`` (``resumed``: continuing a
        paused try).  A neighbour disagrees when it planned where the instance did not,
        or the other way round, as far as the try has shown: a pause disagrees with a
        plan within the cap, an ended try with the opposite feasibility; each neighbour
        that disagrees at a column has its weight multiplied by mismatch once."""
        if not rows.size:
            return
        cls = self._cls[self._nb[rows], cols[:, None]]  # (R, k)
        out, res = outcome[:, None], resumed[:, None]
        planned = (cls == 1) | (cls == 2)
        ended_opposite = np.where(out == FEASIBLE, ~planned, planned)
        seen = np.where(out == PAUSED, cls == 1,  # no plan within the cap
                        np.where(res, ended_opposite & (cls != 1), ended_opposite))
        r, i = np.nonzero(seen)  # row-major: r ascending
        if not r.size:
            return
        b = rows[r]
        change = self._w[b, i] * (self.rho - 1.0)
        self._w[b, i] += change
        # Only the instances with a changed weight get a product: one sparse row each
        # (b ascending), added to their sums as the product of all B rows would add it
        # (a row with no change would add zeros).
        moved, first = np.unique(b, return_index=True)
        indptr = np.append(first, b.size)
        from scipy import sparse

        delta = sparse.csr_matrix((change, self._nb[b, i], indptr),
                                  shape=(moved.size, self._A.shape[0]))
        self._sums[moved] += self._A.weighted(delta)
        self._mass += np.bincount(b, weights=change, minlength=self._w.shape[0])

    def keep(self, folds: np.ndarray) -> None:
        self._nb, self._w = self._nb[folds], self._w[folds]
        self._sums, self._mean, self._mass = self._sums[folds], self._mean[folds], \
            self._mass[folds]


class DeferredPosterior:
    """BOX's posterior, conditioned only when something reads it.

    Before its first plan an instance's tries follow p / tau; BOX's bounds are read only
    where no candidate has a positive rate, and after the first plan.  A run that stops at
    the first plan (the tuning's inner leave-one-out) rarely reads them at all, yet
    conditioning every try was a fifth of its time.  So :meth:`observe` and :meth:`keep`
    are queued, and any other use first applies the queue in order to the posterior:
    the same calls with the same arguments, so the same numbers as conditioning at once.
    ``inert`` is fixed when the posterior is made and reads nothing queued."""

    def __init__(self, posterior):
        self._posterior = posterior
        self._queue: deque[tuple] = deque()
        self.inert = posterior.inert

    def observe(self, cols, scores, skip=None) -> None:
        self._queue.append((np.array(cols), np.array(scores),
                            None if skip is None else np.array(skip)))

    def keep(self, folds) -> None:
        self._queue.append((np.array(folds),))

    def __getattr__(self, name):
        if name.startswith("__") or "_posterior" not in self.__dict__:
            raise AttributeError(name)  # copy and pickle look up hooks on a bare object
        post = self.__dict__["_posterior"]
        queue = self.__dict__["_queue"]
        while queue:  # each call leaves the queue as it is applied: none applied twice
            call = queue.popleft()
            if len(call) == 1:
                post.keep(call[0])
            else:
                post.observe(call[0], call[1], skip=call[2])
        return getattr(post, name)


def _entry_tables(F, T, C, cap):
    """(class of each training entry, the blocks kept, the (n, m * blocks) table whose
    weighted row sums the model keeps, its column totals): the same for every batch of an
    evaluation.  Blocks: 0-3 whether an entry is of class 0-3, 4 its seconds within the cap,
    5 those after it.  Block 0 is never read (the mass is kept apart), and without a cap
    neither are 2, 3 and 5 (all zero): only the others are kept, a third of the table
    without a cap (each column's sum is the same number either way)."""
    n, m = F.shape
    if math.isinf(cap):
        within = np.ones((n, m), dtype=bool)
        share = np.ones((n, m))
    else:
        within = C <= cap
        with np.errstate(divide="ignore", invalid="ignore"):
            share = np.where(within, 1.0, cap / C)
    # class of each training entry: 0 fails within the cap, 1 plans within it,
    # 2 plans after it, 3 fails after it
    cls = np.where(within, F.astype(np.int8), np.where(F, 2, 3).astype(np.int8))
    kept = (1, 4) if math.isinf(cap) else (1, 2, 3, 4, 5)
    A = np.empty((n, len(kept) * m))
    for at, b in enumerate(kept):  # each block written in place: tens of MB each
        block = A[:, at * m:(at + 1) * m]
        if b <= 3:
            np.equal(cls, b, out=block, casting="unsafe")
        else:
            np.multiply(T, share if b == 4 else 1.0 - share, out=block)
    return cls, kept, RowTable(A), A.sum(axis=0)


def _rate(p: np.ndarray, tau: np.ndarray) -> np.ndarray:
    return p / np.maximum(tau, TIME_FLOOR)


@register("contextual")
class Contextual(Box):
    """CONTEXTUAL: chooses constraints in the context of the instance's own features;
    see the module docstring of :mod:`box_core.contextual`.

    ``k`` neighbours (tuned when not given), ``mismatch`` (weight factor of a neighbour
    that disagrees with an observed outcome), ``prior_rows`` (pseudo-rows at the column
    means), ``c`` (BOX's coefficient after the first plan), ``select_features`` (1: the
    features are selected in the training rows, :func:`select_features`; 0: all are
    used).  Without instance features, BOX.
    """

    defaults = {"k": None, "mismatch": 0.1, "prior_rows": 1.0, "c": 1.96,
                "select_features": 1}
    needs_outcomes = True
    shares_tables = True
    relative_cost = 3.1
    #: settings :func:`tune` chooses when not given
    tuned: tuple[str, ...] = ("k",)

    def __init__(self, ctx: FoldContext, k: int = 20, mismatch: float = 0.1,
                 prior_rows: float = 1.0, c: float = 1.96, cap: float = math.inf,
                 feature_mask: np.ndarray | None = None,
                 ranks: np.ndarray | None = None):
        super().__init__(ctx, c=c)
        check_settings(k=k, mismatch=mismatch, prior_rows=prior_rows)
        if not cap > 0:
            raise ValueError(f"cap must be > 0, got {cap!r}")
        self.cap = float(cap) if ctx.outcomes.checks is not None else math.inf
        self.paused = np.zeros_like(self.tried)
        self.found = np.zeros(ctx.size, dtype=bool)
        self._threshold = ctx.outcomes.threshold
        self._model = None
        X, query = ctx.instance_features, ctx.query
        if feature_mask is not None and has_features(X):  # the features tuning selected
            keep = np.asarray(feature_mask, dtype=bool)
            if keep.shape != (X.shape[1],):
                raise ValueError(f"feature_mask must be a mask of the {X.shape[1]} instance "
                                 f"features, got shape {keep.shape}")
            X, query = X[:, keep], query[:, keep]
        if has_features(X):
            self._model = NeighbourModel(ctx.outcomes, X, query, int(k), mismatch,
                                         prior_rows, self.cap, ranks)
            self.posterior = DeferredPosterior(self.posterior)

    @classmethod
    def drops_tried(cls) -> bool:
        # BOX's values are read only where no try has ended, and a try's score is observed
        # when it ends (a paused try is observed when it is resumed): never twice
        return True

    # the live and uncapped interface (propose / update)

    def propose(self) -> np.ndarray:
        if self._model is None:
            return super().propose()
        return self.propose_tries()[0]

    def update(self, cols: np.ndarray, scores: np.ndarray) -> None:
        if self._model is None:
            return super().update(cols, scores)
        self.record(cols, self.outcome_of_scores(scores), scores)

    def outcome_of_scores(self, scores: np.ndarray) -> np.ndarray:
        """FEASIBLE or FAILED of ended tries by their scores (internal unit): above the
        training rows' threshold between failures and plans."""
        return np.where(scores > self._threshold, FEASIBLE, FAILED)

    def settled(self) -> np.ndarray:
        done = super().settled()
        return done if self._model is None else done & self.found

    def remaining(self, folds: np.ndarray, steps: int) -> np.ndarray:
        ended = (self.tried & ~self.paused)[folds]
        return argmax_sequence(self.values()[folds], ended, self.posterior.scale[folds],
                               steps)

    # capped tries (box_core.tries.simulate)

    def propose_tries(self) -> tuple[np.ndarray, np.ndarray]:
        """(columns, allowances) of the next try of each instance (inf: uncapped)."""
        B, m = self.tried.shape
        ended = self.tried & ~self.paused
        allow = np.full(B, math.inf)
        if self._model is None:
            cols = argmax_untried(self.values(), ended, self.posterior.scale)
            return cols, allow
        # Before its first plan an instance takes the best of its candidates (a capped
        # first try, an uncapped first try, resuming a paused try) where one has a positive
        # rate; BOX chooses otherwise, and after the first plan.
        cols = np.zeros(B, dtype=np.intp)
        box = self.found.copy()
        seek = np.flatnonzero(~self.found)
        if seek.size:
            rows = None if seek.size == B else seek  # all: the model's arrays as they are
            tried = self.tried if rows is None else self.tried[rows]
            paused = self.paused if rows is None else self.paused[rows]
            rates = np.full((seek.size, 3 * m), -np.inf)
            rates[:, :m] = np.where(tried, -np.inf, _rate(*self._model.fresh(rows)))
            if math.isfinite(self.cap):
                rates[:, m:2 * m] = np.where(tried, -np.inf,
                                             _rate(*self._model.uncapped(rows)))
            if paused.any():
                rates[:, 2 * m:] = np.where(paused, _rate(*self._model.resumed(rows)),
                                            -np.inf)
            pick = np.argmax(rates, axis=1)
            best = rates[np.arange(seek.size), pick]
            cols[seek] = pick % m
            allow[seek] = np.where(pick < m, self.cap, math.inf)
            box[seek[~(best > 0)]] = True
        post = self.posterior
        if box.any() and post.slots is not None and not (box & ~self.found).any():
            # BOX after the first plan, among the columns whose try has not ended: the
            # posterior's live columns (paused tries are not observed), as BOX's own
            # propose reads them
            at = np.flatnonzero(box)
            bounds = self._bounds(post.mean_slots[at], post.var_slots[at])
            cols[at] = argmax_untried_at(bounds, post.dead_slots[at], post.scale[at],
                                         post.slots[at])
        elif box.any():
            values = self.values()[box]
            open_ = ~(self.tried[box] & ~self.paused[box])  # not ended
            fresh_left = (open_ & ~self.paused[box]).any(axis=1)
            # before a plan, BOX among fresh columns (capped); after it, uncapped
            mask = np.where((fresh_left & ~self.found[box])[:, None],
                            self.tried[box], ~open_)
            cols[box] = argmax_untried(values, mask, self.posterior.scale[box])
            allow[box] = np.where(self.paused[box, cols[box]] | self.found[box], math.inf,
                                  self.cap)
        return cols, allow

    def record(self, cols: np.ndarray, outcome: np.ndarray, scores: np.ndarray) -> None:
        """Report the tries of :meth:`propose_tries`: ``outcome`` FAILED, FEASIBLE or
        PAUSED per instance, ``scores`` (internal unit; ignored where paused)."""
        rows = self._rows
        resumed = self.paused[rows, cols]
        ended = outcome != PAUSED
        self.tried[rows, cols] = True
        self.paused[rows, cols] = ~ended
        self.t += 1
        self.posterior.observe(cols, scores, skip=None if ended.all() else ~ended)
        self._open -= ~self.posterior.inert[cols] & ended
        if self._model is not None:
            # the model is read only for instances still without a plan: one that planned
            # now is not updated (most of its neighbours disagree with a plan, so this
            # left-out update was about a third of the model's work)
            seeking = np.flatnonzero(~self.found & (outcome != FEASIBLE))
            self._model.observe(seeking, cols[seeking], outcome[seeking], resumed[seeking])
        self.found |= outcome == FEASIBLE

    def keep(self, folds: np.ndarray) -> None:
        super().keep(folds)
        self.paused, self.found = self.paused[folds], self.found[folds]
        if self._model is not None:
            self._model.keep(folds)


@register("contextual_capped")
class ContextualCapped(Contextual):
    """CONTEXTUAL with capped, resumable tries: fresh tries stop at the ``cap_quantile``
    quantile of the training rows' successful checks (tuned when not given; 1 or more:
    no cap) and may be resumed later (see :mod:`box_core.contextual`)."""

    defaults = {**Contextual.defaults, "cap_quantile": None}
    tuned = ("k", "cap_quantile")
    relative_cost = 4.4


def has_features(x) -> bool:
    return x is not None and x.ndim == 2 and x.shape[1] > 0


def check_settings(**settings) -> None:
    """ValueError naming a setting out of its range."""
    k = settings.get("k")
    if k is not None and (isinstance(k, bool) or not float(k).is_integer() or k < 1):
        raise ValueError(f"k must be an integer >= 1, got {k!r}")
    rho = settings.get("mismatch")
    if rho is not None and not (math.isfinite(rho) and 0 <= rho <= 1):
        raise ValueError(f"mismatch must lie in [0, 1], got {rho!r}")
    a = settings.get("prior_rows")
    if a is not None and not (math.isfinite(a) and a > 0):
        raise ValueError(f"prior_rows must be a finite number > 0, got {a!r}")
    q = settings.get("cap_quantile")
    if q is not None and not (math.isfinite(q) and 0 < q):
        raise ValueError(f"cap_quantile must be a number > 0, got {q!r}")


def cap_of(quantile, feasible: np.ndarray, checks: np.ndarray | None) -> float:
    """The check allowance of ``quantile`` (None or >= 1: no cap) over the feasible
    entries' checks."""
    if quantile is None or quantile >= 1 or checks is None or not feasible.any():
        return math.inf
    return float(np.quantile(checks[feasible], quantile))


def tune(cls, Dn, F, T, checks, X, params: dict, seed: int = 0, forbidden=None,
         memo: dict | None = None) -> dict:
    """The settings of ``cls`` for instances outside the training rows given (``Dn``
    (internal unit), ``F``, ``T``, ``checks`` and ``X``: those rows only): what ``params``
    fixes, the rest chosen by leave-one-out on these rows.

    Leave-one-out inside the training rows: each of (at most :data:`INNER_ROWS`, drawn
    with ``seed``) training rows with a feasible entry is held out from the others (exact
    prior downdate, its own row out of the neighbours and the standardisation) and the
    policy runs to its first plan; the setting with the least mean time to it wins (ties:
    the first in the grid).  The features are chosen first (:func:`select_features`),
    then ``k`` over :data:`K_GRID` (uncapped), then ``cap_quantile`` over :data:`CAP_GRID`
    with that k.  Returns the constructor's keyword arguments (``cap`` in checks).
    ``memo``: a dict kept between calls on the same rows, which then share the features
    and k (contextual and contextual_capped evaluated side by side).
    """
    fixed = {key: v for key, v in params.items() if v is not None}
    check_settings(**fixed)
    kwargs = {key: fixed.get(key, cls.defaults[key]) for key in ("mismatch", "prior_rows", "c")}
    if not has_features(X):
        return {"c": kwargs["c"]}
    memo = {} if memo is None else memo
    key = (seed, tuple(sorted((name, v) for name, v in fixed.items()
                              if name != "cap_quantile")))
    if not fixed.get("select_features", 1):
        mask = np.ones(X.shape[1], dtype=bool)
    else:
        if "mask" not in memo:
            memo["mask"] = select_features(F, X, seed)
        mask = memo["mask"]
    if not mask.any():  # BOX
        out = {"c": kwargs["c"], "feature_mask": mask}
        return {**out, "cap": math.inf} if "cap_quantile" in cls.defaults else out
    kwargs["feature_mask"] = mask
    X = X[:, mask]
    n = Dn.shape[0]
    eligible = np.flatnonzero(F.any(axis=1))
    rng = np.random.default_rng((seed, n))
    if eligible.size > INNER_ROWS:
        eligible = np.sort(rng.choice(eligible, INNER_ROWS, replace=False))
    if "k" in fixed:
        kwargs["k"] = int(fixed["k"])
    capped = "cap_quantile" in cls.defaults
    if ("k" not in fixed and key not in memo) or (capped and "cap_quantile" not in fixed):
        if ("runs", key) not in memo:  # the same rows and features: shared by both classes
            memo["runs", key] = _InnerRuns(Dn, F, T, checks, X, eligible, forbidden, seed)
        runner = memo["runs", key]
    known = {}  # {setting: mean time} already measured with these kwargs
    if "k" not in fixed:
        if key not in memo:
            grid = [k for k in K_GRID if k < n - 1] or [max(1, n - 2)]
            memo[key] = runner.best(cls, "k", grid, {**kwargs, "cap": math.inf})
        kwargs["k"], known[math.inf] = memo[key]
    if capped:
        if "cap_quantile" in fixed:
            kwargs["cap"] = cap_of(fixed["cap_quantile"], F, checks)
        else:  # no cap is the uncapped run the k was chosen by: its time is known
            grid = [cap_of(q, F, checks) for q in CAP_GRID]
            kwargs["cap"] = runner.best(cls, "cap", grid, kwargs, known)[0]
    return kwargs


class _InnerRuns:
    """Leave-one-out runs of a policy on some training rows, by setting."""

    def __init__(self, Dn, F, T, checks, X, rows, forbidden, seed):
        prior = Prior.fit(Dn)
        self.truth = (Dn[rows], F[rows], T[rows], None if checks is None else checks[rows])
        outcomes = TrainingOutcomes.of(Dn, F, T, rows, checks)
        self.ctx = FoldContext(prior=prior.folds(rows), seeds=[(seed, int(i)) for i in rows],
                               horizon=16, outcomes=outcomes,
                               forbidden=None if forbidden is None else forbidden[rows],
                               instance_features=X, query=X[rows])
        # the neighbours of the largest k, shared by every setting
        self.ranks = neighbour_ranks(X, X[rows], rows, max(K_GRID))

    def mean_time(self, cls, kwargs) -> float:
        kwargs = {key: v for key, v in kwargs.items() if key != "feature_mask"}  # X: selected
        policy = cls(self.ctx, ranks=self.ranks, **kwargs)
        D, F, T, C = self.truth
        m = F.shape[1]
        trace = simulate(policy, D, F, T, C, m, until_feasible=True, full_width=False)
        return float(trace.cost.sum(axis=1).mean()) if trace.cost.size else 0.0

    def best(self, cls, name, grid, kwargs, known=None) -> tuple:
        """(the value of ``name`` in ``grid`` with the least mean time (ties: the first),
        that time); ``known``: {value: mean time} measured before (the policy is a
        deterministic function of the setting, so it would measure the same)."""
        known = known or {}
        times = [known[value] if value in known else
                 self.mean_time(cls, {**kwargs, name: value}) for value in grid]
        at = int(np.argmin(times))
        return grid[at], times[at]


def select_features(F: np.ndarray, X: np.ndarray, seed: int = 0) -> np.ndarray:
    """(q,) bool: the instance features worth measuring distances in, chosen on training
    rows only by greedy forward selection.

    A subset is scored by how well its k = min(:data:`SELECTION_K`, max(3, n / 5)) nearest
    neighbours (features
    standardised over these rows, each row out of its own neighbours) predict a row's
    feasibility: the mean squared error of p_rj = (plans among the neighbours at j +
    pbar_j) / (k + 1) against F[r, j], over at most :data:`SELECTION_ROWS` rows.  Starting
    from no feature (p = pbar), the feature that lowers the error most is added while it
    lowers it by 0.1 % or more.  Features that say nothing about feasibility (or are
    constant) stay out; with none selected the selector is BOX."""
    n, q = X.shape
    chosen = np.zeros(q, dtype=bool)
    if n < 3:
        return chosen
    rng = np.random.default_rng((seed, n, 1))
    rows = np.arange(n)
    if n > SELECTION_ROWS:
        rows = np.sort(rng.choice(n, SELECTION_ROWS, replace=False))
    sd = X.std(axis=0)
    k = min(SELECTION_K, max(3, n // 5), n - 1)  # a neighbourhood, not every row
    pbar = F.mean(axis=0)
    truth = F[rows].astype(np.float64)

    def error(dist):
        near = np.argpartition(dist, k - 1, axis=1)[:, :k]
        p = (F[near].sum(axis=1) + pbar) / (k + 1)
        return float(((p - truth) ** 2).mean())

    best = float(((pbar - truth) ** 2).mean())
    current = np.zeros((rows.size, n))
    current[np.arange(rows.size), rows] = np.inf  # never one's own neighbour
    while True:
        trials = []
        for f in np.flatnonzero(~chosen & (sd > 0)):
            z = X[:, f] / sd[f]
            trials.append((error(current + (z[rows, None] - z[None, :]) ** 2), f))
        if not trials:
            break
        err, f = min(trials)
        if not err < best * (1 - 1e-3):
            break
        best, chosen[f] = err, True
        z = X[:, f] / sd[f]
        current += (z[rows, None] - z[None, :]) ** 2
    return chosen


def tuning_groups(n: int, seed: int, groups: int = GROUPS) -> np.ndarray:
    """(n,) group of each row, G = min(groups, n) groups of near-equal size, assigned by
    a permutation from ``seed``: rows of group g get settings tuned without group g."""
    g = min(groups, n)
    out = np.empty(n, dtype=np.intp)
    out[np.random.default_rng((seed, 26)).permutation(n)] = np.arange(n) % g
    return out
