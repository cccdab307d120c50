"""RRT-Connect (OMPL) over a robot's box-bounded configuration space, with a counted budget
(:class:`pipeline.planning.base.Budget`), then bounded random shortcutting.

Reproducibility.  OMPL draws every random number from RNG objects seeded by one
process-global seed generator, and the state sampler RRT-Connect uses cannot be replaced
from Python (the binding exposes no ``setStateSamplerAllocator``).  ``ou.RNG.setSeed``
re-seeds that generator each time it is called, so every call seeds it from the call's own
seed and then builds a fresh space, setup and planner: the sampler, the nearest-neighbour
structure and the planner receive the same seeds whatever ran before in the process.
Everything else that is random here (shortcutting) draws from a numpy Generator seeded per
call.  OMPL's log is silenced during a call (re-seeding logs an error by design) and
restored after it, so importing or calling this module changes no global setting.
"""

from __future__ import annotations

import contextlib
import time

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from pipeline.planning.base import Budget, RobotModel
from pipeline.planning.interface import Planner
from pipeline.planning.result import PlanResult, Status, path_length


@contextlib.contextmanager
def _quiet_ompl():
    previous = ou.getLogLevel()
    ou.setLogLevel(ou.LogLevel.LOG_NONE)
    try:
        yield
    finally:
        ou.setLogLevel(previous)


class _EdgeValidator(ob.MotionValidator):
    """Checks a whole edge in one Python call (OMPL would call back once per state)."""

    def __init__(self, si, budget: Budget, dim: int, resolution: float):
        super().__init__(si)
        self._budget, self._dim, self._res = budget, dim, resolution

    def checkMotion(self, s1, s2):  # noqa: N802 (OMPL's name)
        d = self._dim  # a slice of a state is a list of its coordinates
        return self._budget.edge_free(np.array(s1[0:d]), np.array(s2[0:d]), self._res)


class RRTConnect(Planner):
    """Bidirectional RRT between two configurations, then bounded random shortcutting."""

    name = "rrt_connect"

    def plan(self, robot: RobotModel, start, goal, seed: int,
             budget: Budget | None = None) -> PlanResult:
        """Plan start→goal, charging every configuration check to ``budget``.

        ``seed`` (an int >= 0) fixes OMPL's and the shortcutter's random numbers.
        """
        if seed < 0:
            raise ValueError(f"planning seed must be >= 0, got {seed}")
        lower, upper = np.asarray(robot.lower, float), np.asarray(robot.upper, float)
        if lower.shape != upper.shape or np.any(lower >= upper):
            raise ValueError("planner bounds: need lower < upper in every coordinate")
        budget = budget if budget is not None else self.budget(robot)
        t0 = time.perf_counter()
        start = np.asarray(start, float)
        goal = np.asarray(goal, float)
        used0 = budget.used
        for q, status in ((start, Status.START_IN_COLLISION), (goal, Status.GOAL_IN_COLLISION)):
            if np.any(q < lower) or np.any(q > upper) or not budget.states_free(q[None]):
                if budget.spent:  # an earlier leg used the whole budget: q was never checked
                    status = Status.BUDGET_EXHAUSTED
                return self._result(status, budget, used0, t0)
        if np.array_equal(start, goal):
            path = start[None]
        else:
            with _quiet_ompl():
                path = self._solve(lower, upper, start, goal, budget, seed)
            if path is None:
                status = Status.TIMEOUT if budget.timed_out else Status.BUDGET_EXHAUSTED
                return self._result(status, budget, used0, t0)
            path = self.shortcut(path, budget, np.random.default_rng([seed, 1]))
        return PlanResult(Status.OK, path=path, length=path_length(path),
                          checks=budget.used - used0, time=time.perf_counter() - t0)

    def _result(self, status, budget, used0, t0) -> PlanResult:
        return PlanResult(status, checks=budget.used - used0, time=time.perf_counter() - t0)

    def _solve(self, lower, upper, start, goal, budget: Budget,
               seed: int) -> np.ndarray | None:
        ou.RNG.setSeed(_ompl_seed(seed))
        d = len(lower)
        space = ob.RealVectorStateSpace(d)
        bounds = ob.RealVectorBounds(d)
        for i in range(d):
            bounds.setLow(i, float(lower[i]))
            bounds.setHigh(i, float(upper[i]))
        space.setBounds(bounds)
        setup = og.SimpleSetup(space)
        si = setup.getSpaceInformation()
        setup.setStateValidityChecker(lambda s: budget.states_free(np.array([s[0:d]])))
        validator = _EdgeValidator(si, budget, d, self.settings.resolution)
        si.setMotionValidator(validator)
        endpoints = []
        for q in (start, goal):
            state = space.allocState()
            for i in range(d):
                state[i] = float(q[i])
            endpoints.append(state)
        setup.setStartAndGoalStates(endpoints[0], endpoints[1])
        planner = og.RRTConnect(si)
        if self.settings.range > 0:
            planner.setRange(self.settings.range)
        setup.setPlanner(planner)
        setup.solve(ob.PlannerTerminationCondition(budget.stop))
        if not setup.haveExactSolutionPath():
            return None
        states = setup.getSolutionPath().getStates()
        return np.array([s[0:d] for s in states])

    def shortcut(self, path: np.ndarray, budget: Budget, rng: np.random.Generator) -> np.ndarray:
        """Replace random sub-paths by straight edges when those are free.

        At most ``shortcut_attempts`` tries, and none once the budget is spent.
        """
        res = self.settings.resolution
        pairs = _Pairs(rng)
        try:
            for _ in range(self.settings.shortcut_attempts):
                if len(path) < 3 or budget.spent:
                    break
                i, j = pairs.draw(len(path))
                if j - i < 2:
                    continue
                if budget.edge_free(path[i], path[j], res):
                    path = np.concatenate([path[: i + 1], path[j:]])
        finally:
            pairs.close()
        return path


class _Pairs:
    """``sorted(rng.choice(n, size=2, replace=False))``, draw after draw, the very same
    numbers from the same generator, without numpy's per-call cost (about 14 µs, most of
    a short edge's check).

    numpy draws such a pair by Floyd's algorithm (v1 uniform in [0, n - 2], v2 uniform in
    [0, n - 1], v2 = n - 1 if equal; each by Lemire's method on 32-bit outputs), then
    shuffles the two (one 32-bit output).  PCG64 makes 32-bit outputs as halves of its
    64-bit ones, low half first; here those come in batches (``random_raw``), and
    :meth:`close` leaves the generator as numpy's draws would have.  Any other generator,
    or one with a half output pending, is left to ``rng.choice``."""

    def __init__(self, rng: np.random.Generator):
        self.rng, self.bits = rng, rng.bit_generator
        self.start = self.bits.state if type(self.bits) is np.random.PCG64 else None
        if self.start is not None and self.start["has_uint32"]:
            self.start = None
        self.words: list[int] = []
        self.used = 0

    def _next(self) -> int:
        if self.used == len(self.words):
            self.words += self.bits.random_raw(32).view(np.uint32).tolist()
        self.used += 1
        return self.words[self.used - 1]

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
        if self.start is None or not self.words:
            return
        half = self.used % 2  # a high half drawn and not used yet
        self.bits.state = self.start
        self.bits.advance(self.used // 2 + half)
        state = self.bits.state
        state["has_uint32"] = half
        state["uinteger"] = self.words[self.used] if half else self.words[self.used - 1]
        self.bits.state = state


def _ompl_seed(seed: int) -> int:
    """A positive 31-bit seed (OMPL refuses 0) derived from a seed >= 0."""
    return int(np.random.SeedSequence(int(seed)).generate_state(1)[0] % (2**31 - 1)) + 1
