"""Planning tries: a planning call that can stop at a check cap and later go on from where
it stopped, with the result of one uninterrupted call (docs/architecture.md, "Resumable
tries").

A try is made by ``Planner.start(...)`` (one motion) or ``Domain.start(...)`` (one score
entry π(ω, θ)); :meth:`PlanningTry.advance` runs it until it has used ``allowance`` checks
in all, counted from its start, or until it ends.  It returns None while paused and the
:class:`~pipeline.planning.result.PlanResult` once it has ended (again on every later
call).  A try pauses only between two steps of its search, never by refusing a check, so
its result, checks and path are those of the uninterrupted call however its checks are
sliced; a slice may go past its allowance by the checks of one step.

A try that cannot pause (:class:`WholeTry`) runs the whole call in its first advance,
whatever the allowance: TrajOpt (restartable, not resumable), OMPL algorithms not shown to
resume exactly, and the domains without their own try.
"""

from __future__ import annotations

import abc
import time
from collections.abc import Callable

from pipeline.planning.result import PlanResult


class PlanningTry(abc.ABC):
    """One planning call, run in slices.  ``result`` is None until it ends; ``time`` is
    the time spent inside :meth:`advance` (pauses excluded) and becomes the result's."""

    def __init__(self):
        self.result: PlanResult | None = None
        self.time = 0.0

    @property
    def done(self) -> bool:
        return self.result is not None

    def advance(self, allowance: int | None = None) -> PlanResult | None:
        """Go on until the try has used ``allowance`` checks in all (None: until it ends);
        the result once it has ended, None when it paused."""
        if self.result is not None:
            return self.result
        t0 = time.perf_counter()
        try:
            result = self._advance(allowance, t0)
        finally:
            self.time += time.perf_counter() - t0
        if result is not None:
            result.time = self.time
            self.result = result
        return result

    @abc.abstractmethod
    def _advance(self, allowance: int | None, now: float) -> PlanResult | None:
        """One slice, begun at ``now`` (``time.perf_counter()``): the result when the call
        ended in it, None when it paused."""


class WholeTry(PlanningTry):
    """A call that cannot pause: ``call()`` runs whole in the first advance, whatever the
    allowance (so its checks may exceed it)."""

    def __init__(self, call: Callable[[], PlanResult]):
        super().__init__()
        self._call = call

    def _advance(self, allowance, now) -> PlanResult:
        return self._call()
