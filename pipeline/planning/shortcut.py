"""Bounded random shortcutting of a path (every OMPL planner here applies it): replace random
sub-paths by straight edges when those are free, every check charged to the call's budget."""

from __future__ import annotations

import numpy as np

from pipeline.planning.base import Budget


def shortcut(path: np.ndarray, budget: Budget, rng: np.random.Generator, resolution: float,
             attempts: int, compiled: bool = True, rng_kept: bool = True) -> np.ndarray:
    """At most ``attempts`` tries, and none once the budget is spent; the pairs of
    waypoints are ``sorted(rng.choice(len(path), size=2, replace=False))`` (:class:`Pairs`).
    A robot model with its own compiled shortcutting (``shortcut_search``: the sphere
    checker's) does the same with it, unless ``compiled`` is False.  ``rng_kept=False``:
    the caller drops ``rng`` afterwards, so it is not left as numpy's draws would leave it
    (the same pairs; spares restoring its state)."""
    pairs = Pairs(rng, rng_kept)
    search = getattr(budget.robot, "shortcut_search", None) if compiled else None
    if search is not None and pairs.start is not None:
        try:
            shorter = search(path, budget, pairs, resolution, attempts)
        finally:
            pairs.close()
        if shorter is not None:
            return shorter
        pairs = Pairs(rng, rng_kept)
    try:
        for _ in range(attempts):
            if len(path) < 3 or budget.spent:
                break
            i, j = pairs.draw(len(path))
            if j - i < 2:
                continue
            if budget.edge_free(path[i], path[j], resolution):
                path = np.concatenate([path[: i + 1], path[j:]])
    finally:
        pairs.close()
    return path


class Pairs:
    """``sorted(rng.choice(n, size=2, replace=False))``, draw after draw, the very same
    numbers from the same generator, without numpy's per-call cost (about 14 µs, most of
    a short edge's check).

    numpy draws such a pair by Floyd's algorithm (v1 uniform in [0, n - 2], v2 uniform in
    [0, n - 1], v2 = n - 1 if equal; each by Lemire's method on 32-bit outputs), then
    shuffles the two (one 32-bit output).  PCG64 makes 32-bit outputs as halves of its
    64-bit ones, low half first; here those come in batches (``random_raw``), and
    :meth:`close` leaves the generator as numpy's draws would have.  Any other generator,
    or one with a half output pending, is left to ``rng.choice``.  ``restore=False``:
    :meth:`close` leaves the generator as it is (its owner drops it)."""

    def __init__(self, rng: np.random.Generator, restore: bool = True):
        self.rng, self.bits, self.restore = rng, rng.bit_generator, restore
        self.start = self.bits.state if type(self.bits) is np.random.PCG64 else None
        if self.start is not None and self.start["has_uint32"]:
            self.start = None
        self.words: list[int] = []
        self.used = 0

    def _next(self) -> int:
        if self.used == len(self.words):
            self.more()
        self.used += 1
        return self.words[self.used - 1]

    def more(self) -> None:
        """64 more 32-bit outputs in ``words``."""
        self.words += self.bits.random_raw(32).view(np.uint32).tolist()

    def _bounded(self, r: int) -> int:
        """Uniform in [0, r] (numpy's buffered_bounded_lemire_uint32)."""
        excl = r + 1
        m = self._next() * excl
        if m & 0xFFFFFFFF < excl:
            threshold = (0xFFFFFFFF - r) % excl
            while m & 0xFFFFFFFF < threshold:
                m = self._next() * excl
        return m >> 32

    def draw(self, n: int) -> tuple[int, int]:
        if self.start is None:
            i, j = sorted(self.rng.choice(n, size=2, replace=False))
            return int(i), int(j)
        v1 = self._bounded(n - 2) if n > 2 else 0
        v2 = self._bounded(n - 1)
        if v2 == v1:
            v2 = n - 1
        self._next()  # the shuffle of the pair
        return (v1, v2) if v1 < v2 else (v2, v1)

    def close(self) -> None:
        """The generator as after ``self.used`` 32-bit outputs from where it started."""
        if self.start is None or not self.words or not self.restore:
            return
        half = self.used % 2  # a high half drawn and not used yet
        self.bits.state = self.start
        self.bits.advance(self.used // 2 + half)
        state = self.bits.state
        state["has_uint32"] = half
        state["uinteger"] = self.words[self.used] if half else self.words[self.used - 1]
        self.bits.state = state
