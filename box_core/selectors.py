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
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.spatial.distance import cdist

from box_core import validation
from box_core.gaussian import GaussianPosterior, argmax_untried
from box_core.prior import FoldPriors, Prior

SELECTORS: dict[str, type[Policy]] = {}


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

    ``true_scores`` is the held-out truth, for the ORACLE only; ``seeds`` are entropy for
    ``numpy.random.default_rng``, one per instance.
    """

    prior: FoldPriors
    seeds: Sequence
    features: np.ndarray | None = None
    true_scores: np.ndarray | None = None
    horizon: int | None = None  # how many tries are planned, if known (sizes buffers)

    @property
    def size(self) -> int:
        return self.prior.size

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

    def __init__(self, ctx: FoldContext):
        self.ctx = ctx
        self.tried = np.zeros((ctx.size, ctx.m), dtype=bool)
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


class _OrderPolicy(Policy):
    """Tries columns in a fixed per-instance order, skipping any already tried."""

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


@register("box")
class Box(Policy):
    """BOX (paper Algorithm 1): argmax of posterior mean + c * posterior std."""

    defaults = {"c": 1.96}

    def __init__(self, ctx: FoldContext, c: float = 1.96):
        super().__init__(ctx)
        if not (math.isfinite(c) and c >= 0):
            raise ValueError(f"c must be a finite number >= 0, got {c!r}")
        self.c = float(c)
        self.posterior = GaussianPosterior(ctx.prior, capacity=ctx.horizon or 16)

    @classmethod
    def fold_batch(cls, n: int, m: int, k: int) -> int:
        # Keep each batch's W (B x k x m doubles) near 8 MiB: it stays in cache while
        # stepping, and bounds memory whatever n is.
        return int(max(1, min(n, (8 << 20) // (8 * k * m))))

    def coefficient(self) -> float:
        return self.c

    def variance_factor(self) -> float:
        return 1.0

    def propose(self) -> np.ndarray:
        post = self.posterior
        factor = self.variance_factor()
        std = post.std() if factor == 1.0 else np.sqrt(factor * np.maximum(post.var, 0.0))
        ucb = post.mean + self.coefficient() * std
        return argmax_untried(ucb, self.tried, post.scale)

    def update(self, cols: np.ndarray, scores: np.ndarray) -> None:
        super().update(cols, scores)
        self.posterior.observe(cols, scores)


@register("pembo")
class PemBo(Box):
    """PEM-BO (Wang, Kim and Kaelbling, NeurIPS 2018), GP-UCB with an estimated prior.

    With N training rows and t observations on this instance, the conditioned variance is
    scaled by (N - 1) / (N - t - 1), the unbiased estimator of the posterior variance, and
    the UCB coefficient for iteration t' = t + 1 is

        zeta = sqrt(6 (N - 3 + t' + 2 sqrt(t' L) + 2 L) / (delta N (N - t' - 1))) + sqrt(2 L),
        L = log(4 / delta).

    Both are only defined while N - t - 1 > 0; beyond (more observations than training rows
    allow) the denominators are held at 1, an extension of ours, not of the paper.
    """

    defaults = {"delta": 0.01}

    def __init__(self, ctx: FoldContext, delta: float = 0.01):
        if not 0 < delta < 1:
            raise ValueError(f"delta must lie in (0, 1), got {delta!r}")
        super().__init__(ctx, c=0.0)
        self.delta = float(delta)

    def coefficient(self) -> float:
        return pembo_zeta(self.t + 1, self.ctx.prior.n_train, self.delta)

    def variance_factor(self) -> float:
        N = self.ctx.prior.n_train
        return (N - 1) / max(N - self.t - 1, 1)


def pembo_zeta(t: int, N: int, delta: float) -> float:
    """PEM-BO's UCB coefficient at iteration ``t`` (1-based) with ``N`` training rows."""
    L = math.log(4.0 / delta)
    inner = 6.0 * (N - 3 + t + 2.0 * math.sqrt(t * L) + 2.0 * L)
    return math.sqrt(max(inner, 0.0) / (delta * N * max(N - t - 1, 1))) + math.sqrt(2.0 * L)


@register("doo")
class Doo(Policy):
    """DOO over the discrete constraint set (Munos 2011, as adapted in the paper).

    The optimistic bound of an untried column i is min over tried j of
    J_j + lam * ||theta_i - theta_j|| (Euclidean on the constraint features); the first
    column is drawn at random from the instance's seeded generator.
    """

    defaults = {"lam": 1.0}
    needs_features = True

    def __init__(self, ctx: FoldContext, lam: float = 1.0):
        super().__init__(ctx)
        if not (math.isfinite(lam) and lam >= 0):
            raise ValueError(f"lam must be a finite number >= 0, got {lam!r}")
        self.lam = float(lam)
        self._dist = cdist(ctx.features, ctx.features)
        self._bound = np.full((ctx.size, ctx.m), np.inf)
        self._first = np.array([np.random.default_rng(s).integers(ctx.m) for s in ctx.seeds])
        self._scale = np.zeros(ctx.size)

    def propose(self) -> np.ndarray:
        if self.t == 0:
            return self._first.copy()
        return argmax_untried(self._bound, self.tried, self._scale)

    def update(self, cols: np.ndarray, scores: np.ndarray) -> None:
        super().update(cols, scores)
        np.minimum(self._bound, scores[:, None] + self.lam * self._dist[cols], out=self._bound)
        self._scale = np.maximum(self._scale, np.abs(scores))


def check_selector(name: str, params: dict, *, features) -> type[Policy]:
    """The policy class for ``name``, after checking its parameters and requirements."""
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
    if cls.needs_features and features is None:
        raise ValueError(f"selector {name!r} needs constraint features (an m x p array)")
    return cls


class Selector:
    """A live selector for one new instance: ``propose()`` a column, then ``update`` it."""

    def __init__(self, policy: Policy):
        self._policy = policy
        self.history: list[tuple[int, float]] = []

    @property
    def name(self) -> str:
        return self._policy.name

    @property
    def m(self) -> int:
        return self._policy.ctx.m

    @property
    def tried(self) -> np.ndarray:
        """Boolean mask (m,) of the columns tried so far."""
        return self._policy.tried[0].copy()

    def propose(self) -> int:
        """The next column to try (never one already tried)."""
        if len(self.history) == self.m:
            raise RuntimeError(f"all {self.m} constraints have been tried")
        return int(self._policy.propose()[0])

    def update(self, index: int, score: float) -> None:
        """Report the score observed for column ``index`` (failed plans: the failure value)."""
        index = int(index)
        if not 0 <= index < self.m:
            raise ValueError(f"index {index} out of range for {self.m} constraints")
        if self._policy.tried[0, index]:
            raise ValueError(f"constraint {index} was already tried")
        score = float(score)
        if not math.isfinite(score):
            raise ValueError(f"score must be finite, got {score!r}")
        self._policy.update(np.array([index]), np.array([score]))
        self.history.append((index, score))


def make_selector(name: str, train_scores, *, features=None, seed=0, true_scores=None, **params):
    """Build selector ``name`` from a training score matrix (n x m, failures already scored).

    ``features`` (m x p) are needed by ``doo``; ``true_scores`` (m,) by ``oracle``;
    ``seed`` (an int or a sequence of ints) seeds ``rand`` and ``doo``.
    Further keyword arguments are the selector's parameters (``c`` for box, ``lam`` for
    doo, ``delta`` for pembo).
    """
    prior = Prior.fit(train_scores)
    if features is not None:
        features = validation.feature_matrix(features, prior.m)
    cls = check_selector(name, params, features=features)
    truth = None
    if cls.needs_truth:
        if true_scores is None:
            raise ValueError(f"selector {name!r} needs true_scores (the instance's score row)")
        truth = validation.score_vector(true_scores, prior.m, name="true_scores")[None, :]
    ctx = FoldContext(prior=prior.batch(), seeds=[seed], features=features, true_scores=truth)
    return Selector(cls(ctx, **params))
