"""Incremental Gaussian conditioning (paper eq. 2) for a batch of independent instances.

For each instance b of the batch we keep, after t observations at columns I:

    L      Cholesky factor of Sigma_II + eps I                      (t x t, implicit)
    W      L^{-1} Sigma_{I,:}                                       (t x m)
    alpha  L^{-1} (J_I - mu_I)                                      (t,)

so that the posterior mean is mu + W^T alpha and the posterior variance is
diag(Sigma) - sum over rows of W^2.  Observing column j with score y appends one row:

    l = W[:, j],   delta = sqrt(Sigma_jj + eps - l.l)
    w = (Sigma_{j,:} - l^T W) / delta,   a = (y - mu_j - l.alpha) / delta
    mean += a w,   var -= w^2

which costs O(t m) and needs a single covariance row, never an m x m solve.  Running a
whole batch of instances in lockstep turns per-step Python overhead into a few vectorised
NumPy calls, which is what makes leave-one-out evaluation take seconds.
"""

from __future__ import annotations

import heapq

import numpy as np

from box_core.prior import FoldPriors

#: Values within TIE_REL * scale of the best are ties and go to the lowest column index
#: (scale = max(|best|, largest prior standard deviation)).  Without it, columns that are
#: identical in exact arithmetic (duplicate columns of a real score matrix) could be
#: ordered by floating-point noise from BLAS summation order.
TIE_REL = 1e-9

#: ``drop_observed``: W's main columns are kept a multiple of SLOT_ALIGN (4 keeps each of
#: them in OpenBLAS's vector kernel, 8 also in each half of a product split over 2
#: threads), and W is repacked once REPACK_DEAD of them are dead.
SLOT_ALIGN = 8
REPACK_DEAD = 1 / 8
#: (m, t, width) -> whether the product over repacked columns rounds as the one over all
#: m columns (GaussianPosterior._exact_slots), per process, and its random numbers
_SLOT_VERDICT: dict[tuple[int, int, int], bool] = {}
_SLOT_PROBE = np.zeros((0, 0))


class GaussianPosterior:
    """Posterior over the score vectors of B instances, updated one observation at a time.

    Columns whose covariance row is exactly zero in every fold (:meth:`FoldPriors.inert`:
    constant columns, such as constraints never feasible on any row) are *inert*: their
    column of W is zero and their mean and variance never move, and observing one appends
    a zero row to W and moves nothing, so it costs O(m) rather than O(t m).  Batches of
    :attr:`NARROW_BATCH` or more where a quarter of the columns or more are inert do not
    store those zeros either: W keeps the rows of the other observations, over the columns
    that are not inert (plus the last m mod 4, see below).  Yet every number it computes
    is the one conditioning on everything in full computes, bit for bit:

    - the sums over the t observations (l^T W, one BLAS call per instance, and l.l and
      l.alpha) still run over all t terms with the zero ones in place: their positions
      decide how the sums are grouped, hence how they round;
    - over the narrow columns, the call rounds each column as the call over all m
      columns does (OpenBLAS computes each output alike except for the last m mod 4,
      which the narrow layout keeps last).  That is checked, never assumed: for every t
      the narrow call is compared with the full one on random numbers first, and where
      they differ in one bit W's rows are spread back to m columns for the call.

    Each instance's arithmetic is the same whatever else the batch holds.
    ``skip_inert=False`` conditions on inert columns in full (the unoptimised path).
    """

    #: W holds room for every row it may need (``capacity``, at most one per column that
    #: is not inert) when that takes at most BUFFER_BYTES; otherwise it starts at
    #: INITIAL_BYTES and doubles when full.
    BUFFER_BYTES = 1 << 30
    INITIAL_BYTES = 32 << 20
    #: Batches at least this large keep W's columns narrow (a live selector, a batch of
    #: one, would spend as much on the checks as it saves).
    NARROW_BATCH = 4
    #: The check of the narrow product at t rows multiplies a t x m random matrix; beyond
    #: this many entries it is not made and the product takes all m columns.
    PROBE_ENTRIES = 1 << 22
    #: Instances whose W has zero rows are multiplied in groups of this many bytes of W.
    SCRATCH_BYTES = 4 << 20

    def __init__(self, prior: FoldPriors, capacity: int = 16, skip_inert: bool = True,
                 drop_observed: np.ndarray | bool = False):
        self.prior = prior
        size, m = prior.size, prior.m
        self._mean = prior.mean.copy()
        self.prior_var = prior.diag()
        self._var = self.prior_var.copy()
        self.eps = prior.jitter()
        self.scale = np.sqrt(np.maximum(self.prior_var.max(axis=1), 0.0))
        # fixed from here on (contextual.DeferredPosterior reads it without conditioning)
        self.inert = prior.inert() if skip_inert else np.zeros(m, dtype=bool)
        self.t = 0
        self._layout(size)
        # compact: W keeps only the rows of observations that are not inert (and only its
        # narrow columns); otherwise every row, zero rows included, as conditioning in
        # full would (a batch of few inert columns gains little from leaving them out,
        # and spreading stored rows back to t rows for BLAS costs more than it saves)
        self._compact = self._cols is not None
        width = m if self._cols is None else self._cols.size
        # compact, W's rows can only come from columns that are not inert
        live = m - int(self.inert.sum()) if self._compact else m
        self._limit = max(1, min(capacity, live))
        first = self._limit
        if 8 * size * first * width > self.BUFFER_BYTES:
            first = min(first, max(16, self.INITIAL_BYTES // (8 * max(1, size * width))))
        self._W = np.empty((size, first, width))  # W's rows (compact: those not zero)
        self._step = np.empty((size, first), dtype=np.intp)  # the step of each
        self._count = np.zeros(size, dtype=np.intp)  # rows of _W in use, per instance
        self._alpha = np.empty((size, max(1, min(capacity, 64))))  # one entry per step
        self._rows = np.arange(size)
        self._full = True  # no inert observation yet: every instance's W is all stored
        self._scratch = np.zeros((0, 0, 0))
        self.slots = None
        # drop_observed (True, or the (B, m) mask of columns never to be observed, which
        # count as observed from the start): the caller never observes a column twice and
        # never reads the posterior of an observed column (BOX masks tried columns).  W's
        # columns of observed columns are then dead, and where W keeps all m columns each
        # instance keeps its own: ``slots`` (B, width) names the column of each of W's
        # columns (no column twice, dead ones marked in ``dead_slots``), and
        # ``mean_slots`` and ``var_slots`` hold the posterior there (``mean`` and ``var``,
        # (B, m), are filled in when asked for; at observed columns they mean nothing).
        # Once REPACK_DEAD of W's columns are dead, live ones move into dead ones' places
        # and W narrows (:meth:`_repack`): the products cost O(t (m - t)), not O(t m).
        if drop_observed is not False and skip_inert and self._cols is None and size:
            observed = (np.zeros((size, m), dtype=bool) if drop_observed is True
                        else np.array(drop_observed, dtype=bool, copy=True))
            tail = m & 3
            self._live_main = (m - tail) - observed[:, :m - tail].sum(axis=1)
            self.slots = np.tile(np.arange(m), (size, 1))
            self._slot = self.slots.copy()  # column -> its column of W (live ones)
            self.dead_slots = observed
            self.mean_slots, self.var_slots = self._mean.copy(), self._var.copy()
            self._cent = prior.centered.copy()
            self._scatter_flat = prior.scatter.reshape(-1)
            self._synced = True

    def _layout(self, size: int) -> None:
        """W's columns: all m, or (``_cols``) the columns that are not inert among the
        first m - m mod 4, zero columns up to a multiple of 4, then the last m mod 4."""
        m = self.inert.size
        self._cols = None
        tail = m & 3
        main = np.flatnonzero(~self.inert[:m - tail])
        if size < self.NARROW_BATCH or 4 * (main.size + 3 + tail) > 3 * m:
            return
        pad = -main.size % 4
        filler = int(np.flatnonzero(self.inert)[0])  # an inert column: its W column is 0
        self._cols = np.concatenate([main, np.full(pad, filler),
                                     np.arange(m - tail, m)]).astype(np.intp)
        self._real = np.concatenate([np.arange(main.size),
                                     main.size + pad + np.arange(tail)]).astype(np.intp)
        self._real_cols = self._cols[self._real]
        self._at = np.full(m, -1, dtype=np.intp)  # column -> its column of W
        self._at[self._real_cols] = self._real
        self._verdict: dict[int, bool] = {}
        self._probe = np.zeros((0, m))
        if not all(self._exact(t) for t in range(1, 9)):  # a BLAS that rounds otherwise
            self._cols = None
            return
        # the prior's covariance rows at W's columns (see FoldPriors.cov_rows)
        self._scatter = np.ascontiguousarray(self.prior.scatter[:, self._cols])
        self._centered = self.prior.centered[:, self._cols]

    @property
    def size(self) -> int:
        return self.prior.size

    def observe(self, cols: np.ndarray, scores: np.ndarray,
                skip: np.ndarray | None = None) -> None:
        """Condition instance b on score ``scores[b]`` at column ``cols[b]``, for every b;
        ``skip`` (B,) bool: instances that observe nothing at this step (their posterior
        stays as it is; a try paused before its outcome, see :mod:`box_core.tries`)."""
        t = self.t
        if t == self._alpha.shape[1]:
            alpha = np.empty((self.size, 2 * t))
            alpha[:, :t] = self._alpha
            self._alpha = alpha
        if self.slots is not None:
            if t:
                self._maybe_repack(t)
            seen = self._rows if skip is None else np.flatnonzero(~skip)
            self._live_main[seen] -= cols[seen] < self.inert.size - (self.inert.size & 3)
            self.dead_slots[seen, self._slot[seen, cols[seen]]] = True
        inert = self.inert[cols]
        if skip is not None:
            inert = inert | skip
        if not inert.any():
            self._condition(None, cols, scores, t)
        else:
            idle = np.flatnonzero(inert)
            # What conditioning computes for an inert column j, without the O(t m) product:
            # l = W[:, j] = 0, so the new row of W is 0, delta = sqrt(eps) and
            # alpha = (y - mu_j) / delta; mean and var do not move.  A skipped instance
            # takes the same zero row with alpha = 0: nothing observed, nothing moves.
            resid = scores[idle] - self.prior.mean[idle, cols[idle]]
            if skip is not None:
                resid = np.where(skip[idle], 0.0, resid)
            self._alpha[idle, t] = resid / np.sqrt(self.eps[idle])
            if self._compact:
                self._full = False
            else:  # the zero row, in place
                if t == self._W.shape[1]:
                    self._grow()
                self._W[idle, t, :] = 0.0
                self._step[idle, t] = t
                self._count[idle] += 1
            busy = np.flatnonzero(~inert)
            if busy.size:
                self._condition(busy, cols[busy], scores[busy], t)
        self.t = t + 1

    def _condition(self, folds, cols, scores, t) -> None:
        """The rank-one update of instances ``folds`` (None: all) at step ``t``."""
        rows = self._rows if folds is None else folds
        # full: every instance's W is stored in full (no inert observation in the batch)
        full = folds is None and self._full
        count = self._count[rows]
        if (t if full else count.max(initial=0)) == self._W.shape[1]:
            self._grow()
        if self.slots is not None:
            at = self._slot[rows, cols]
        else:
            at = cols if self._cols is None else self._at[cols]  # W's columns of cols
        dense = full or bool((count == t).all())  # W of these instances all stored
        if dense:
            lw = self._W[rows, :t, at]  # (B, t): W[b, :, cols[b]], the 'l' of the docstring
        else:
            lw = self._full_l(rows, at, count, t)
        cross = self._cov_rows(cols, folds)  # (B, width)
        if t and self.slots is not None and not self._exact_slots(t):
            self._subtract_spread(cross, rows, lw, t)
        elif t:
            exact = self._exact(t)
            if dense and folds is None and exact:
                cross -= np.matmul(lw[:, None, :], self._W[:, :t, :])[:, 0, :]
            elif dense and exact and self._full and 2 * folds.size >= self.size:
                # one batched call, the others' products wasted (each row's product is
                # the same whoever else is in the call)
                every = np.zeros((self.size, t))
                every[folds] = lw
                cross -= np.matmul(every[:, None, :], self._W[:, :t, :])[folds, 0, :]
            elif dense and exact:
                for i, b in enumerate(rows):
                    cross[i] -= np.matmul(lw[i], self._W[b, :t])
            else:
                self._subtract_products(cross, rows, lw, count, t)
        alpha = self._alpha[:, :t] if folds is None else self._alpha[rows, :t]
        eps = self.eps if folds is None else self.eps[rows]
        schur = self.prior_var[rows, cols] + eps - np.einsum("bt,bt->b", lw, lw)
        # In exact arithmetic the Schur complement of Sigma + eps I is >= eps.
        delta = np.sqrt(np.maximum(schur, eps))
        w = cross / delta[:, None]
        resid = scores - self.prior.mean[rows, cols] - np.einsum("bt,bt->b", lw, alpha)
        a = resid / delta
        if full:
            self._W[:, t, :] = w
            self._step[:, t] = t
            self._count += 1
            self._alpha[:, t] = a
        else:
            self._W[rows, count, :] = w
            self._step[rows, count] = t
            self._count[rows] = count + 1
            self._alpha[rows, t] = a
        if self.slots is not None:  # the same numbers, at each instance's own columns
            if folds is None:
                self.mean_slots += a[:, None] * w
                self.var_slots -= w * w
            else:
                self.mean_slots[rows] += a[:, None] * w
                self.var_slots[rows] -= w * w
            self._synced = False
            return
        if self._cols is not None:
            w = w[:, self._real]
            rows = np.ix_(rows, self._real_cols)
        elif folds is None:
            rows = slice(None)
        self._mean[rows] += a[:, None] * w
        self._var[rows] -= w * w

    def _cov_rows(self, cols, folds) -> np.ndarray:
        """:meth:`FoldPriors.cov_rows` at W's columns: the same numbers."""
        prior = self.prior
        if self.slots is not None:  # at each instance's own columns
            idx = self._rows if folds is None else folds
            at = prior.centered[idx, cols]
            d = self._cent if folds is None else self._cent[folds]
            scatter = np.take(self._scatter_flat, cols[:, None] * self.inert.size
                              + self.slots[idx])
            return prior.scale * (scatter - (prior.coef * at)[:, None] * d)
        if self._cols is None:
            return prior.cov_rows(cols, folds)
        idx = np.arange(prior.size) if folds is None else folds
        at = prior.centered[idx, cols]
        d = self._centered if folds is None else self._centered[folds]
        return prior.scale * (self._scatter[cols] - (prior.coef * at)[:, None] * d)

    def _full_l(self, rows, at, count, t) -> np.ndarray:
        """W[b, :t, at[b]] with W's zero rows in place, (len(rows), t)."""
        width = int(count.max()) if count.size else 0
        lw = np.zeros((rows.size, t))
        if width:
            stored = self._W[rows, :width, at]
            used = np.arange(width)[None, :] < count[:, None]
            i, k = np.nonzero(used)
            lw[i, self._step[rows[i], k]] = stored[i, k]
        return lw

    def _subtract_products(self, cross, rows, lw, count, t) -> None:
        """cross[i] -= lw[i] @ W_b for instance b = rows[i], W_b its t rows with the zero
        ones in place: one BLAS call per instance, each the call the whole W would make
        (made in groups through a scratch buffer that is zero but for W's stored rows)."""
        narrow = self._exact(t)
        width = self._W.shape[2] if narrow else self.inert.size
        group = int(max(1, min(rows.size, self.SCRATCH_BYTES // (8 * t * width))))
        have, room, wide = self._scratch.shape
        if wide != width:
            have = room = 0
        if room < t or have < group:
            room = room if room >= t else max(t, 2 * room)
            self._scratch = np.zeros((max(group, have), room, width))
        for start in range(0, rows.size, group):
            part = slice(start, min(rows.size, start + group))
            full = self._scratch[:part.stop - part.start, :t]
            at, k = np.nonzero(np.arange(int(count[part].max(initial=0)))[None, :]
                               < count[part, None])
            b, steps = rows[part][at], self._step[rows[part][at], k]
            if narrow:
                full[at, steps] = self._W[b, k]
            else:
                full[at[:, None], steps[:, None], self._real_cols] = self._W[b, k][:, self._real]
            product = np.matmul(lw[part, None, :], full)[:, 0, :]
            cross[part] -= product if narrow else product[:, self._cols]
            full[at, steps] = 0.0

    def _exact(self, t: int) -> bool:
        """Whether a product over W's narrow columns rounds as the one over all m
        columns at t rows (True where W has all m columns)."""
        if self._cols is None:
            return True
        verdict = self._verdict.get(t)
        if verdict is None and (t + 1) * self.inert.size > self.PROBE_ENTRIES:
            verdict = self._verdict[t] = False
        if verdict is None:
            m = self.inert.size
            if self._probe.shape[0] < t + 1 + t // m:
                rows = max(t + 1 + t // m, min(2 * self._probe.shape[0], m + 1,
                                               self.PROBE_ENTRIES // m))
                self._probe = np.random.default_rng(20170529).standard_normal((rows, m))
            W, lw = _probe_pair(self._probe, t)
            full = np.matmul(lw, W)
            narrow = np.matmul(lw, np.ascontiguousarray(W[:, self._cols]))
            verdict = bool(np.array_equal(full[self._real_cols], narrow[self._real]))
            self._verdict[t] = verdict
        return verdict

    @property
    def mean(self) -> np.ndarray:
        """Posterior means, (B, m)."""
        self._sync()
        return self._mean

    @property
    def var(self) -> np.ndarray:
        """Posterior variances, (B, m)."""
        self._sync()
        return self._var

    def _sync(self) -> None:
        if self.slots is not None and not self._synced:
            np.put_along_axis(self._mean, self.slots, self.mean_slots, axis=1)
            np.put_along_axis(self._var, self.slots, self.var_slots, axis=1)
            self._synced = True

    def _maybe_repack(self, t: int) -> None:
        m = self.inert.size
        main = self._W.shape[2] - (m & 3)
        need = -(-int(self._live_main.max(initial=0)) // SLOT_ALIGN) * SLOT_ALIGN
        if main - need >= REPACK_DEAD * main and need >= SLOT_ALIGN:
            self._repack(t, need)

    def _repack(self, t: int, main: int) -> None:
        """Narrow W to ``main`` main columns (then the last m mod 4, which the product over
        all m columns computes its own way, and so stay last): each instance's live
        columns beyond them move into dead columns' places (W's buffer is kept: the
        product reads W with its row stride)."""
        m = self.inert.size
        tail = m & 3
        old = self._W.shape[2] - tail
        W = self._W
        keep = (self.slots, self.dead_slots, self.mean_slots, self.var_slots, self._cent)
        for b in range(self.size):
            src = main + np.flatnonzero(~self.dead_slots[b, main:old])
            if src.size:
                dst = np.flatnonzero(self.dead_slots[b, :main])[:src.size]
                W[b, :t, dst] = W[b, :t, src]
                for a in keep:
                    a[b, dst] = a[b, src]
                self._slot[b, self.slots[b, dst]] = dst
        if tail:
            W[:, :t, main:main + tail] = W[:, :t, old:old + tail].copy()
            for a in keep:
                a[:, main:main + tail] = a[:, old:old + tail].copy()
            self._slot[:, m - tail:] = np.arange(main, main + tail)
        width = main + tail
        self._W = W[:, :, :width]
        self.slots, self.dead_slots, self.mean_slots, self.var_slots, self._cent = (
            np.ascontiguousarray(a[:, :width]) for a in keep)

    def _exact_slots(self, t: int) -> bool:
        """Whether the product over W's columns rounds each of them as the product over
        all m columns does, at t rows: checked like :meth:`_exact`, once per shape and
        process, on a random layout of the same shape (OpenBLAS computes each column alike
        but for the last m mod 4, which stay last, so which columns W keeps does not
        matter), read with W's row stride."""
        m, width = self.inert.size, self._W.shape[2]
        key = (m, t, width)
        verdict = _SLOT_VERDICT.get(key)
        if verdict is None:
            if width == m:
                verdict = True  # all columns, in place
            elif (t + 1) * m > self.PROBE_ENTRIES:
                verdict = False
            else:
                global _SLOT_PROBE
                if _SLOT_PROBE.shape[1] != m or _SLOT_PROBE.shape[0] < t + 1 + t // m:
                    rows = max(t + 1 + t // m, min(2 * _SLOT_PROBE.shape[0], m + 1,
                                                   self.PROBE_ENTRIES // m))
                    _SLOT_PROBE = np.random.default_rng(20170529).standard_normal((rows, m))
                tail = m & 3
                pick = np.random.default_rng(t).permutation(m - tail)[:width - tail]
                layout = np.concatenate([pick, np.arange(m - tail, m)])
                W, lw = _probe_pair(_SLOT_PROBE, t)
                full = np.matmul(lw, W)
                strided = np.empty((t, self._W.strides[1] // 8))
                strided[:, :width] = np.take(W, layout, axis=1)
                narrow = np.matmul(lw, strided[:, :width])
                verdict = bool(np.array_equal(full[layout], narrow))
            _SLOT_VERDICT[key] = verdict
        return verdict

    def _subtract_spread(self, cross, rows, lw, t) -> None:
        """cross[i] -= lw[i] @ W_b with W_b's columns back in their places among all m
        (the dead ones 0): where the product over W's columns would round otherwise."""
        m = self.inert.size
        for i, b in enumerate(rows):
            full = np.zeros((t, m))
            full[:, self.slots[b]] = self._W[b, :t]
            cross[i] -= np.matmul(lw[i], full)[self.slots[b]]

    def std(self) -> np.ndarray:
        """Posterior standard deviations, with round-off below zero clipped to 0."""
        return np.sqrt(np.maximum(self.var, 0.0))

    def keep(self, folds: np.ndarray) -> None:
        """Drop every instance but ``folds`` (in that order) from the batch (increasing
        ``folds`` reuse W's buffer)."""
        self.prior = self.prior.subset(folds)
        self._sync()
        self._mean = self._mean[folds]
        self.prior_var = self.prior_var[folds]
        self._var = self._var[folds]
        if self.slots is not None:
            self.slots, self._slot = self.slots[folds], self._slot[folds]
            self.dead_slots, self._live_main = self.dead_slots[folds], self._live_main[folds]
            self.mean_slots, self.var_slots = self.mean_slots[folds], self.var_slots[folds]
            self._cent = self._cent[folds]
        self.eps = self.eps[folds]
        self.scale = self.scale[folds]
        if self._cols is not None:
            self._centered = self._centered[folds]
        width = int(self._count[folds].max()) if folds.size else 0
        if (np.diff(folds) > 0).all():  # move rows forward in place: no new buffer
            for i, b in enumerate(folds):
                if b != i:
                    self._W[i, :width] = self._W[b, :width]
            self._W = self._W[:folds.size]
        else:
            W = np.empty((folds.size,) + self._W.shape[1:])
            W[:, :width] = self._W[folds, :width]
            self._W = W
        self._count = self._count[folds]
        self._step = self._step[folds]
        self._alpha = self._alpha[folds]
        self._rows = np.arange(folds.size)
        self._full = bool((self._count == self.t).all())

    def _grow(self) -> None:
        size, cap, width = self._W.shape
        new = min(2 * cap, self._limit) if cap < self._limit else 2 * cap
        W = np.empty((size, new, width))
        W[:, :cap] = self._W
        step = np.empty((size, new), dtype=np.intp)
        step[:, :cap] = self._step
        self._W, self._step = W, step


def _probe_pair(probe: np.ndarray, t: int) -> tuple[np.ndarray, np.ndarray]:
    """(W, l): the first t rows of the random ``probe`` (r x m, r >= t + 1 + t // m) and
    the t numbers after them (row t's first t where t <= m; a capped selector's steps,
    paused tries included, may outnumber the columns)."""
    return probe[:t], probe[t:].reshape(-1)[:t]


def argmax_untried(values: np.ndarray, tried: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Per row, the lowest untried column whose value is within tolerance of the best.

    ``values`` (B, m), ``tried`` (B, m) bool, ``scale`` (B,) the rows' score scales.
    Every row must have at least one untried column.
    """
    return argmax_masked(np.where(tried, -np.inf, values), scale)


def argmax_untried_at(values: np.ndarray, dead: np.ndarray, scale: np.ndarray,
                      columns: np.ndarray) -> np.ndarray:
    """:func:`argmax_untried` of values given at ``columns`` (B, w) only (each untried
    column once, in any order; ``dead`` marks the others): the same columns."""
    masked = np.where(dead, -np.inf, values)
    best = masked.max(axis=1)
    tol = TIE_REL * np.maximum(np.abs(best), scale)
    return np.where(masked >= (best - tol)[:, None], columns, np.iinfo(np.intp).max).min(axis=1)


def argmax_masked(masked: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """:func:`argmax_untried` of values whose tried entries are already -inf."""
    best = masked.max(axis=1)
    tol = TIE_REL * np.maximum(np.abs(best), scale)
    return np.argmax(masked >= (best - tol)[:, None], axis=1)


def argmax_sequence(values: np.ndarray, tried: np.ndarray, scale: np.ndarray,
                    steps: int) -> np.ndarray:
    """The next ``steps`` picks of :func:`argmax_untried` per row, each pick marked tried
    before the next, while ``values`` stay as they are: (B, steps), the same columns as
    calling it ``steps`` times, in O(r log r) per row of r untried columns.

    Every row must have at least ``steps`` untried columns.
    """
    out = np.empty((values.shape[0], steps), dtype=np.intp)
    if not out.size:
        return out
    # Rows whose untried values all lie within the tie tolerance of their best: every pick
    # is the lowest untried index (the usual case: all untried columns equal).
    best = np.where(tried, -np.inf, values).max(axis=1)
    low = np.where(tried, np.inf, values).min(axis=1)
    tied = low >= best - TIE_REL * np.maximum(np.abs(best), scale)
    if tied.any():
        out[tied] = np.argsort(tried[tied], axis=1, kind="stable")[:, :steps]
    for b in np.flatnonzero(~tied):
        cand = np.flatnonzero(~tried[b])
        out[b] = _sequence(values[b, cand], cand, float(scale[b]), steps)
    return out


def _sequence(v: np.ndarray, cand: np.ndarray, scale: float, steps: int) -> np.ndarray:
    """argmax_untried's picks among columns ``cand`` (ascending) of values ``v``.

    The best untried value can only fall as columns are taken, and the threshold
    best - TIE_REL * max(|best|, scale) falls with it, so a column once within the
    threshold stays within it: the candidates are a heap of column indices that grows
    as the best falls, and each pick is the lowest index in it.
    """
    desc = np.argsort(-v, kind="stable")
    vs = v[desc]
    cols = cand[desc]
    r = v.size
    taken = np.zeros(r, dtype=bool)  # by position in ``desc``
    heap: list[tuple[int, int]] = []
    picks: list[int] = []
    top = admitted = 0
    last = np.inf
    while len(picks) < steps:
        while taken[top]:
            top += 1
        best = vs[top]
        threshold = best - TIE_REL * max(abs(best), scale)
        if threshold > last:  # cannot happen (see above); never rely on it
            return _sequence_slowly(v, cand, scale, steps, picks)
        last = threshold
        while admitted < r and vs[admitted] >= threshold:
            heapq.heappush(heap, (int(cols[admitted]), admitted))
            admitted += 1
        if admitted == r:  # every remaining column ties: lowest index first
            rest = sorted(c for c, _ in heap)
            picks.extend(rest[:steps - len(picks)])
            break
        col, at = heapq.heappop(heap)
        taken[at] = True
        picks.append(col)
    return np.asarray(picks, dtype=np.intp)


def _sequence_slowly(v, cand, scale, steps, picks) -> np.ndarray:
    """:func:`_sequence` by calling :func:`argmax_untried` once per pick."""
    tried = np.isin(cand, picks)[None, :]
    out = list(picks)
    while len(out) < steps:
        i = int(argmax_untried(v[None, :], tried, np.array([scale]))[0])
        tried[0, i] = True
        out.append(int(cand[i]))
    return np.asarray(out, dtype=np.intp)
