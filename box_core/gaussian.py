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

import numpy as np

from box_core.prior import FoldPriors

#: Values within TIE_REL * scale of the best are ties and go to the lowest column index
#: (scale = max(|best|, largest prior standard deviation)).  Without it, columns that are
#: identical in exact arithmetic (duplicate columns of a real score matrix) could be
#: ordered by floating-point noise from BLAS summation order.
TIE_REL = 1e-9


class GaussianPosterior:
    """Posterior over the score vectors of B instances, updated one observation at a time."""

    def __init__(self, prior: FoldPriors, capacity: int = 16):
        self.prior = prior
        size, m = prior.size, prior.m
        self.mean = prior.mean.copy()
        self.prior_var = prior.diag()
        self.var = self.prior_var.copy()
        self.eps = prior.jitter()
        self.scale = np.sqrt(np.maximum(self.prior_var.max(axis=1), 0.0))
        self.t = 0
        self._W = np.empty((size, max(1, capacity), m))
        self._alpha = np.empty((size, max(1, capacity)))
        self._rows = np.arange(size)

    @property
    def size(self) -> int:
        return self.prior.size

    def observe(self, cols: np.ndarray, scores: np.ndarray) -> None:
        """Condition instance b on score ``scores[b]`` at column ``cols[b]``, for every b."""
        t = self.t
        if t == self._W.shape[1]:
            self._grow()
        rows = self._rows
        W = self._W[:, :t, :]
        alpha = self._alpha[:, :t]
        lw = W[rows, :, cols]  # (B, t): W[b, :, cols[b]], the 'l' of the module docstring
        cross = self.prior.cov_rows(cols)  # (B, m)
        if t:
            cross -= np.matmul(lw[:, None, :], W)[:, 0, :]
        schur = self.prior_var[rows, cols] + self.eps - np.einsum("bt,bt->b", lw, lw)
        # In exact arithmetic the Schur complement of Sigma + eps I is >= eps.
        delta = np.sqrt(np.maximum(schur, self.eps))
        w = cross / delta[:, None]
        resid = scores - self.prior.mean[rows, cols] - np.einsum("bt,bt->b", lw, alpha)
        a = resid / delta
        self._W[:, t, :] = w
        self._alpha[:, t] = a
        self.mean += a[:, None] * w
        self.var -= w * w
        self.t = t + 1

    def std(self) -> np.ndarray:
        """Posterior standard deviations, with round-off below zero clipped to 0."""
        return np.sqrt(np.maximum(self.var, 0.0))

    def _grow(self) -> None:
        size, cap, m = self._W.shape
        W = np.empty((size, 2 * cap, m))
        W[:, :cap] = self._W
        alpha = np.empty((size, 2 * cap))
        alpha[:, :cap] = self._alpha
        self._W, self._alpha = W, alpha


def argmax_untried(values: np.ndarray, tried: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Per row, the lowest untried column whose value is within tolerance of the best.

    ``values`` (B, m), ``tried`` (B, m) bool, ``scale`` (B,) the rows' score scales.
    Every row must have at least one untried column.
    """
    masked = np.where(tried, -np.inf, values)
    best = masked.max(axis=1)
    tol = TIE_REL * np.maximum(np.abs(best), scale)
    return np.argmax(masked >= (best - tol)[:, None], axis=1)
