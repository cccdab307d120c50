"""Sparse-weighted row sums of a dense table, read from cache where it pays.

CONTEXTUAL and EIPS keep, per instance, weighted sums of training rows: the product of a
sparse (B, n) weight matrix with a dense (n, w) table.  scipy's CSR product reads, for each
nonzero weight, one whole row of the table.  At the pick_place shape (a few thousand
columns, tens of MB) those rows come from memory, and a batch's product touches most of
them many times over.  Read in column tiles of a few MB instead, each tile stays in cache
for every nonzero after the first: 2.5× faster for a product with as many nonzeros as 1000
instances × 80 neighbours on a 1350 × 5000 table, break-even at about two nonzeros per
table row, slower below (``benchmarks/bench_row_sums.py``).

Every entry of the result is the same sum, in the same order (the nonzeros of its row,
in the CSR layout's order), as the product with the whole table: tiling changes which
memory is read when, never the arithmetic.
"""

from __future__ import annotations

import numpy as np

#: Bytes of one column tile: a few tiles fit in the 2-core machine's L2 + L3
TILE_BYTES = 6 << 20
#: Tiles are used past this many nonzero weights per row of the table
TILES_PAST = 2


class RowTable:
    """A dense (n, w) table, ``rows``, and its products with sparse weights.

    A product with at most :data:`TILES_PAST` nonzeros per table row reads each row a
    few times at most, so it reads the whole table (the tiles' strided reads would only
    cost more); a larger one runs over column tiles, made at its first use."""

    def __init__(self, rows: np.ndarray):
        self.rows = rows
        self._tiles: list[tuple[int, np.ndarray]] | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.rows.shape

    def weighted(self, weights) -> np.ndarray:
        """``weights @ rows`` as a dense (B, w) array, for a scipy CSR (B, n) ``weights``."""
        n, w = self.rows.shape
        width = max(1, TILE_BYTES // (8 * max(n, 1)))
        if width >= w or weights.nnz <= TILES_PAST * n:
            return np.asarray(weights @ self.rows)
        if self._tiles is None:
            self._tiles = [(start, np.ascontiguousarray(self.rows[:, start:start + width]))
                           for start in range(0, w, width)]
        out = np.empty((weights.shape[0], w))
        for start, tile in self._tiles:
            out[:, start:start + tile.shape[1]] = weights @ tile
        return out
