"""The Gaussian prior over score vectors, and its exact leave-one-out variants.

``Prior.fit(D)`` estimates mu = column means and Sigma = scatter / (n - 1) (paper eq. 1 and
the covariance below it).  Leave-one-out cross-validation needs, for every row i, the prior
fitted on D without row i.  Refitting costs O(n m^2) per fold; instead, with
S = (n - 1) Sigma and d_i = D_i - mu,

    mu_{-i} = (n mu - D_i) / (n - 1)
    S_{-i}  = S - n / (n - 1) * d_i d_i^T,        Sigma_{-i} = S_{-i} / (n - 2)

so a fold's covariance is a rank-one downdate of a shared matrix.  :class:`FoldPriors`
keeps it in that form and hands out single covariance rows in O(m), which is all the
incremental conditioning in :mod:`box_core.gaussian` needs: Sigma_{-i} is never formed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from box_core import validation

#: Relative jitter added to the diagonal of the tried block before conditioning:
#: epsilon = JITTER_REL * max(diag(Sigma)) (or JITTER_REL when every column is constant).
#: Real score matrices have constant and duplicate columns, so Sigma_II is often singular;
#: the jitter keeps the Cholesky factor finite while changing posteriors by about 1e-8 of
#: the score scale.
JITTER_REL = 1e-8


@dataclass(frozen=True, eq=False)
class Prior:
    """Empirical mean and covariance (ddof = 1) of a training score matrix."""

    mean: np.ndarray
    cov: np.ndarray
    n: int
    _scores: np.ndarray

    @classmethod
    def fit(cls, scores) -> Prior:
        """Fit mu and Sigma to ``scores`` (n x m, n >= 2, finite)."""
        D = validation.score_matrix(scores, min_rows=2).copy()  # later edits by the caller
        D.flags.writeable = False  # must not change the leave-one-out folds
        mean = D.mean(axis=0)
        centered = D - mean
        cov = centered.T @ centered / (D.shape[0] - 1)
        return cls(mean=mean, cov=cov, n=D.shape[0], _scores=D)

    @property
    def m(self) -> int:
        return self.mean.shape[0]

    def leave_one_out(self, i: int) -> Prior:
        """The prior fitted without row ``i``, formed explicitly (O(m^2)); for inspection.

        Evaluation code uses :meth:`folds`, which never forms the m x m matrix.
        """
        if self.n < 3:
            raise ValueError(f"leave-one-out needs at least 3 rows, the prior has {self.n}")
        if not 0 <= i < self.n:
            raise ValueError(f"row {i} out of range for a prior fitted on {self.n} rows")
        batch = self.folds(np.array([i]))
        d = batch.centered[0]
        cov = batch.scale * (batch.scatter - batch.coef * np.outer(d, d))
        rest = np.delete(self._scores, i, axis=0)
        return Prior(mean=batch.mean[0], cov=cov, n=self.n - 1, _scores=rest)

    def batch(self, size: int = 1) -> FoldPriors:
        """This prior for ``size`` instances at once, the form the selectors consume."""
        return FoldPriors(
            mean=np.repeat(self.mean[None, :], size, axis=0),
            scatter=self.cov,
            scale=1.0,
            centered=np.zeros((size, self.m)),
            coef=0.0,
            n_train=self.n,
        )

    def folds(self, rows) -> FoldPriors:
        """Exact leave-one-out priors for the given held-out ``rows``, as one batch."""
        if self.n < 3:
            raise ValueError(f"leave-one-out needs at least 3 rows, the prior has {self.n}")
        rows = np.asarray(rows, dtype=np.intp)
        n = self.n
        held_out = self._scores[rows]
        return FoldPriors(
            mean=(n * self.mean - held_out) / (n - 1),
            scatter=self.cov * (n - 1),
            scale=1.0 / (n - 2),
            centered=held_out - self.mean,
            coef=n / (n - 1),
            n_train=n - 1,
        )


@dataclass(frozen=True, eq=False)
class FoldPriors:
    """B priors sharing one scatter matrix: Sigma_b = scale * (scatter - coef * d_b d_b^T).

    ``coef = 0`` is an ordinary prior; leave-one-out folds use the rank-one downdate.
    """

    mean: np.ndarray  # (B, m)
    scatter: np.ndarray  # (m, m), shared, never copied per fold
    scale: float
    centered: np.ndarray  # (B, m)
    coef: float
    n_train: int

    @property
    def size(self) -> int:
        return self.mean.shape[0]

    @property
    def m(self) -> int:
        return self.mean.shape[1]

    def diag(self) -> np.ndarray:
        """Prior variances, (B, m)."""
        d = self.centered
        return self.scale * (np.diagonal(self.scatter)[None, :] - self.coef * d * d)

    def cov_rows(self, cols: np.ndarray, folds: np.ndarray | None = None) -> np.ndarray:
        """Row ``cols[b]`` of fold b's covariance, for every fold b: (B, m) in O(B m);
        with ``folds``, for those folds only (``cols`` then has one entry per fold given)."""
        d = self.centered if folds is None else self.centered[folds]
        at = d[np.arange(d.shape[0]), cols]
        rows = self.scatter[cols] - (self.coef * at)[:, None] * d
        return self.scale * rows

    def inert(self) -> np.ndarray:
        """(m,) bool: columns whose covariance row and column are exactly zero in every
        fold of the batch (constant columns: every training row and every held-out row
        has the same score there).  Conditioning on such a column changes no posterior
        mean or variance, and their own posterior never moves from the prior mean."""
        nonzero = self.scatter != 0
        zero = ~(nonzero.any(axis=0) | nonzero.any(axis=1))
        if self.coef != 0:
            zero &= ~(self.centered != 0).any(axis=0)
        return zero

    def subset(self, folds: np.ndarray) -> FoldPriors:
        """The same priors for the given folds only (the scatter matrix is shared)."""
        return FoldPriors(mean=self.mean[folds], scatter=self.scatter, scale=self.scale,
                          centered=self.centered[folds], coef=self.coef,
                          n_train=self.n_train)

    def jitter(self) -> np.ndarray:
        """Per-fold diagonal jitter (B,), relative to the largest prior variance."""
        top = self.diag().max(axis=1)
        return JITTER_REL * np.where(top > 0, top, 1.0)
