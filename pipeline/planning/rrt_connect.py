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
        d = self._dim
        a = np.fromiter((s1[i] for i in range(d)), float, d)
        b = np.fromiter((s2[i] for i in range(d)), float, d)
        return self._budget.edge_free(a, b, self._res)


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
        setup.setStateValidityChecker(
            lambda s: budget.states_free(np.fromiter((s[i] for i in range(d)), float, d)[None]))
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
        return np.array([[s[i] for i in range(d)] for s in states])

    def shortcut(self, path: np.ndarray, budget: Budget, rng: np.random.Generator) -> np.ndarray:
        """Replace random sub-paths by straight edges when those are free.

        At most ``shortcut_attempts`` tries, and none once the budget is spent.
        """
        res = self.settings.resolution
        for _ in range(self.settings.shortcut_attempts):
            if len(path) < 3 or budget.spent:
                break
            i, j = sorted(rng.choice(len(path), size=2, replace=False))
            if j - i < 2:
                continue
            if budget.edge_free(path[i], path[j], res):
                path = np.concatenate([path[: i + 1], path[j:]])
        return path


def _ompl_seed(seed: int) -> int:
    """A positive 31-bit seed (OMPL refuses 0) derived from a seed >= 0."""
    return int(np.random.SeedSequence(int(seed)).generate_state(1)[0] % (2**31 - 1)) + 1
