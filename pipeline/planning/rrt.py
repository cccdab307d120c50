"""RRT-Connect (OMPL) over a box-bounded configuration space, with a counted budget.

Reproducibility.  OMPL draws every random number from RNG objects seeded by one
process-global seed generator, and the state sampler RRT-Connect uses cannot be replaced
from Python (the binding exposes no ``setStateSamplerAllocator``).  ``ou.RNG.setSeed``
re-seeds that generator each time it is called (after the first seeds were handed out it
also logs an error, which we silence), so every call seeds it from the call's own seed and
then builds a fresh space, setup and planner: the sampler, the nearest-neighbour structure
and the planner receive the same seeds whatever ran before in the process.  Everything
else that is random here (shortcutting) draws from a numpy Generator seeded per call.

Budget.  A call may check at most ``max_checks`` configurations.  Once the budget is spent
every further check fails, so the planner cannot grow its trees and stops at its next
termination check.  The result therefore depends on the count, not on machine speed; the
wall-clock cap is only a safety net and is reported as its own status when it fires.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from pipeline.planning.result import PlanResult, Status, path_length

ou.setLogLevel(ou.LogLevel.LOG_NONE)

#: ``check(states) -> (ok, used)``: checks the rows of ``states`` in order, stops at the
#: first colliding one and returns whether all were free and how many it checked.
Checker = Callable[[np.ndarray], tuple[bool, int]]


PLANNERS = ("rrt_connect", "trajopt", "noop")
COLLISION = ("spheres", "exact")


@dataclass
class PlannerSettings:
    """Settings of one planning call (schema of ``conf/planner/*.yaml``).

    ``noop`` plans nothing: the pipeline records "skipped" for every score entry.
    ``collision``: ``spheres`` checks edges with the sphere pre-check and confirms only what
    it cannot clear (:mod:`pipeline.sim.fast_check`; same answers and counts as ``exact``,
    pybullet on every configuration).
    ``trajopt`` (:mod:`pipeline.planning.trajopt`) uses the ``trajopt_*`` keys, plus
    ``resolution`` for the dense re-check of its result and ``wall_cap_s``.
    """

    name: str = "rrt_connect"
    max_checks: int = 20_000
    wall_cap_s: float = 10.0
    resolution: float = 0.01
    range: float = 0.0
    shortcut_attempts: int = 40
    collision: str = "spheres"
    trajopt_waypoints: int = 20
    trajopt_margin: float = 0.02  # metres
    trajopt_penalty: float = 10.0  # initial hinge coefficient
    trajopt_penalty_rounds: int = 4  # each multiplies the coefficient by 10
    trajopt_iterations: int = 30  # SQP iterations per call, over all rounds
    trajopt_trust_radius: float = 0.3  # radians per joint

    def __post_init__(self):
        if self.name not in PLANNERS:
            raise ValueError(f"unknown planner {self.name!r}; known: {', '.join(PLANNERS)}")
        if self.max_checks < 1:
            raise ValueError(f"planner.max_checks must be positive, got {self.max_checks}")
        if not self.wall_cap_s > 0:
            raise ValueError(f"planner.wall_cap_s must be positive, got {self.wall_cap_s}")
        if not self.resolution > 0:
            raise ValueError(f"planner.resolution must be positive, got {self.resolution}")
        if self.collision not in COLLISION:
            raise ValueError(f"planner.collision must be one of {', '.join(COLLISION)}, got "
                             f"{self.collision!r}")
        if self.range < 0 or self.shortcut_attempts < 0:
            raise ValueError("planner.range and planner.shortcut_attempts must be >= 0")
        if self.trajopt_waypoints < 3:
            raise ValueError(f"planner.trajopt_waypoints must be >= 3, got "
                             f"{self.trajopt_waypoints}")
        if (self.trajopt_margin < 0 or self.trajopt_penalty <= 0
                or self.trajopt_penalty_rounds < 1 or self.trajopt_iterations < 1
                or self.trajopt_trust_radius <= 0):
            raise ValueError("planner.trajopt_*: margin must be >= 0, penalty and "
                             "trust_radius > 0, penalty_rounds and iterations >= 1")

    def trajopt_options(self):
        from pipeline.planning.trajopt import TrajOptOptions

        return TrajOptOptions(waypoints=self.trajopt_waypoints, margin=self.trajopt_margin,
                              penalty=self.trajopt_penalty,
                              penalty_rounds=self.trajopt_penalty_rounds,
                              iterations=self.trajopt_iterations,
                              trust_radius=self.trajopt_trust_radius)


def interpolate(a: np.ndarray, b: np.ndarray, resolution: float) -> np.ndarray:
    """Configurations on the segment a→b, excluding a, including b, at most ``resolution``
    apart in every coordinate (so a 0.01 rad resolution bounds every joint's step)."""
    steps = max(1, math.ceil(float(np.max(np.abs(b - a))) / resolution))
    t = np.arange(1, steps + 1) / steps
    return a + t[:, None] * (b - a)


@functools.lru_cache(maxsize=4096)
def _check_order(k: int) -> np.ndarray:
    """End point first, then the rest coarse to fine: collisions show up after few checks.
    (Cached: edges of the same length share it.)"""
    order = [k - 1]
    seen = {k - 1}
    step = k
    while len(order) < k:
        step = max(1, step // 2)
        for i in range(step - 1, k, step):
            if i not in seen:
                seen.add(i)
                order.append(i)
    out = np.asarray(order)
    out.flags.writeable = False
    return out


class Budget:
    """Counts configuration checks; refuses every check once ``limit`` is reached."""

    def __init__(self, check: Checker, limit: int, wall_cap_s: float):
        self._check = check
        self.limit = limit
        self.used = 0
        self.deadline = time.perf_counter() + wall_cap_s
        self.timed_out = False

    @property
    def spent(self) -> bool:
        return self.used >= self.limit

    def states_free(self, states: np.ndarray) -> bool:
        if self.spent:
            return False
        ok, used = self._check(states[: self.limit - self.used])
        self.used += used
        return ok and len(states) <= used

    def edge_free(self, a: np.ndarray, b: np.ndarray, resolution: float) -> bool:
        states = interpolate(a, b, resolution)
        return self.states_free(states[_check_order(len(states))])

    def stop(self) -> bool:
        if time.perf_counter() > self.deadline:
            self.timed_out = True
        return self.spent or self.timed_out


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


class RRTConnect:
    """Bidirectional RRT between two configurations, then bounded random shortcutting."""

    def __init__(self, lower, upper, settings: PlannerSettings):
        self.lower = np.asarray(lower, float)
        self.upper = np.asarray(upper, float)
        if self.lower.shape != self.upper.shape or np.any(self.lower >= self.upper):
            raise ValueError("planner bounds: need lower < upper in every coordinate")
        self.settings = settings

    @property
    def dim(self) -> int:
        return self.lower.shape[0]

    def budget(self, check: Checker) -> Budget:
        """A budget for one planning call; make it once the scene is set for the call."""
        if self.settings.collision == "spheres":
            from pipeline.sim.fast_check import certified

            check = certified(check)
        return Budget(check, self.settings.max_checks, self.settings.wall_cap_s)

    def plan(self, start, goal, budget: Budget, seed: int) -> PlanResult:
        """Plan start→goal, charging every configuration check to ``budget``.

        ``seed`` (an int >= 0) fixes OMPL's and the shortcutter's random numbers.
        """
        if seed < 0:
            raise ValueError(f"planning seed must be >= 0, got {seed}")
        t0 = time.perf_counter()
        start = np.asarray(start, float)
        goal = np.asarray(goal, float)
        used0 = budget.used
        for q, status in ((start, Status.START_IN_COLLISION), (goal, Status.GOAL_IN_COLLISION)):
            if np.any(q < self.lower) or np.any(q > self.upper) or not budget.states_free(q[None]):
                if budget.spent:  # an earlier leg used the whole budget: q was never checked
                    status = Status.BUDGET_EXHAUSTED
                return self._result(status, budget, used0, t0)
        if np.array_equal(start, goal):
            path = start[None]
        else:
            path = self._solve(start, goal, budget, seed)
            if path is None:
                status = Status.TIMEOUT if budget.timed_out else Status.BUDGET_EXHAUSTED
                return self._result(status, budget, used0, t0)
            path = self.shortcut(path, budget, np.random.default_rng([seed, 1]))
        return PlanResult(Status.OK, path=path, length=path_length(path),
                          checks=budget.used - used0, time=time.perf_counter() - t0)

    def _result(self, status, budget, used0, t0) -> PlanResult:
        return PlanResult(status, checks=budget.used - used0, time=time.perf_counter() - t0)

    def _solve(self, start, goal, budget: Budget, seed: int) -> np.ndarray | None:
        ou.RNG.setSeed(_ompl_seed(seed))
        space = ob.RealVectorStateSpace(self.dim)
        bounds = ob.RealVectorBounds(self.dim)
        for i in range(self.dim):
            bounds.setLow(i, float(self.lower[i]))
            bounds.setHigh(i, float(self.upper[i]))
        space.setBounds(bounds)
        setup = og.SimpleSetup(space)
        si = setup.getSpaceInformation()
        d = self.dim
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


def path_is_free(path: np.ndarray, check: Checker, resolution: float) -> bool:
    """Re-check a whole path, every edge at ``resolution`` (for tests and users)."""
    if not check(path[:1])[0]:
        return False
    return all(check(interpolate(a, b, resolution))[0] for a, b in zip(path[:-1], path[1:],
                                                                       strict=True))
