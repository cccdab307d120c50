"""OMPL's geometric planners over a robot's box-bounded configuration space, with a counted
budget (:class:`pipeline.planning.base.Budget`): the scaffolding every OMPL planner here
shares (the state space from the robot's limits, validity and motion checking through the
robot model, seeding, a quiet log), then bounded random shortcutting of the path.

A planner built on it (:class:`OmplGeometric`) only says which OMPL planner to make for a
space information (:meth:`OmplGeometric.make`): :mod:`pipeline.planning.rrt_connect`
(OMPL's RRTConnect) and :mod:`pipeline.planning.ompl_planner` (any algorithm of
:data:`ALGORITHMS` by name) are the two in this package.

Reproducibility.  OMPL draws every random number from RNG objects seeded by one
process-global seed generator, and the state sampler cannot be replaced from Python (the
binding exposes no ``setStateSamplerAllocator``).  ``ou.RNG.setSeed`` re-seeds that
generator each time it is called, so every call seeds it from the call's own seed and then
builds a fresh space, setup and planner: the sampler, the nearest-neighbour structure and
the planner receive the same seeds whatever ran before in the process.  Everything else
that is random here (shortcutting) draws from a numpy Generator seeded per call.  OMPL's
log is silenced during a call (re-seeding logs an error by design) and restored after it,
so importing or calling this module changes no global setting.  Planners that plan in a
second thread (PRM's roadmap) see a budget in an order no seed fixes, so they are refused
(:data:`REFUSED`).
"""

from __future__ import annotations

import contextlib
import math
import time

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from pipeline.planning.base import Budget, RobotModel
from pipeline.planning.interface import Planner
from pipeline.planning.result import PlanResult, Status, path_length
from pipeline.planning.settings import RRTConnectSettings
from pipeline.planning.shortcut import shortcut

#: OMPL geometric planners (``og.<name>``; those this binding exposes) whose checks and
#: paths are the same, call after call and process after process, for the same seed and
#: budget (tests/test_ompl_planners.py checks each).  Optimising ones (RRTstar, BITstar, ...)
#: stop at their first exact solution (:mod:`pipeline.planning.ompl_planner`), except AORRTC,
#: which spends the whole budget.  FMT and BFMT sample ``num_samples`` states (1000) before
#: connecting any: they need a large budget or fewer samples.
ALGORITHMS = ("RRTConnect", "RRT", "RRTstar", "InformedRRTstar", "SORRTstar", "BITstar",
              "AORRTC", "KPIECE1", "BKPIECE1", "LBKPIECE1", "FMT", "BFMT")

_THREADED = ("grows its roadmap in a second thread, whose checks call back into Python: "
             "their order depends on thread timing (and here the call never returns)")

#: OMPL geometric planners refused, with the reason (one line); tried: each hung, blocked,
#: on its first call with a counted budget
REFUSED = {"PRM": _THREADED, "PRMstar": _THREADED}


def check_algorithm(algorithm: str, params: dict) -> None:
    """Refuse (ValueError, one line naming the key) an algorithm not in
    :data:`ALGORITHMS` or a parameter it does not have."""
    if algorithm in REFUSED:
        raise ValueError(f"planner.algorithm={algorithm} is refused: {REFUSED[algorithm]}")
    if algorithm not in ALGORITHMS:
        raise ValueError(f"planner.algorithm={algorithm}: not one of OMPL's planners this "
                         f"pipeline accepts ({', '.join(ALGORITHMS)})")
    cls = getattr(og, algorithm)
    unknown = sorted(k for k in params if k not in parameters(cls))
    if unknown:
        raise ValueError(f"planner.params: {algorithm} has no parameter "
                         f"{', '.join(unknown)}; it has {', '.join(parameters(cls))}")


def setter_name(param: str) -> str:
    """The setter of an OMPL parameter: ``goal_bias`` -> ``setGoalBias`` (OMPL names its
    ParamSet entries after its setters; this binding cannot return a ParamSet, so the
    parameters are set through the setters)."""
    return "set" + "".join(part[:1].upper() + part[1:] for part in param.split("_"))


def parameters(cls) -> list[str]:
    """The parameter names of an OMPL planner class (its setters with a getter)."""
    out = []
    for attr in dir(cls):
        if (attr.startswith("set") and hasattr(cls, "get" + attr[3:]) and attr[3:4].isupper()
                and not hasattr(ob.Planner, attr)):
            name = attr[3:]
            out.append("".join("_" + c.lower() if c.isupper() else c for c in name)[1:])
    return sorted(out)


def set_params(planner, params: dict) -> None:
    """Set ``params`` (OMPL's parameter names -> values) on an OMPL planner, each value
    converted to the type of the parameter's current value; ValueError naming the key when
    one does not fit."""
    for key, value in params.items():
        setter = getattr(planner, setter_name(key), None)
        getter = getattr(planner, "get" + setter_name(key)[3:], None)
        if setter is None:
            raise ValueError(f"planner.params.{key}: {planner.getName()} has no such parameter")
        try:
            kind = type(getter()) if callable(getter) else None
            if kind is bool and isinstance(value, str):
                value = {"true": True, "false": False}[value.lower()]
            setter(kind(value) if kind in (bool, int, float) else value)
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"planner.params.{key}={value!r}: not a value "
                             f"{planner.getName()} accepts") from None


@contextlib.contextmanager
def quiet_ompl():
    previous = ou.getLogLevel()
    ou.setLogLevel(ou.LogLevel.LOG_NONE)
    try:
        yield
    finally:
        ou.setLogLevel(previous)


class EdgeValidator(ob.MotionValidator):
    """Checks a whole edge in one Python call (OMPL would call back once per state)."""

    def __init__(self, si, budget: Budget, dim: int, resolution: float):
        super().__init__(si)
        self._budget, self._dim, self._res = budget, dim, resolution

    def checkMotion(self, s1, s2):  # noqa: N802 (OMPL's name)
        d = self._dim  # a slice of a state is a list of its coordinates
        return self._budget.edge_free(np.array(s1[0:d]), np.array(s2[0:d]), self._res)


def stop_at_first_solution(setup: og.SimpleSetup) -> None:
    """Make an optimising planner stop at its first exact solution: path length with an
    infinite cost threshold, which any solution satisfies (planners that do not optimise
    ignore it)."""
    objective = ob.PathLengthOptimizationObjective(setup.getSpaceInformation())
    objective.setCostThreshold(ob.Cost(math.inf))
    setup.setOptimizationObjective(objective)


def ompl_seed(seed: int) -> int:
    """A positive 31-bit seed (OMPL refuses 0) derived from a seed >= 0."""
    return int(np.random.SeedSequence(int(seed)).generate_state(1)[0] % (2**31 - 1)) + 1


class OmplGeometric(Planner):
    """An OMPL geometric planner between two configurations, then bounded random
    shortcutting (``shortcut_attempts``; 0: none).  Subclasses implement :meth:`make`."""

    settings_class = RRTConnectSettings

    def make(self, si) -> ob.Planner:
        """The OMPL planner for the space information ``si`` (called once per call, after
        the seed is set)."""
        raise NotImplementedError

    def prepare(self, setup: og.SimpleSetup) -> None:
        """Anything to set on the problem before solving (after :meth:`make`)."""

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
            with quiet_ompl():
                path = self._solve(lower, upper, start, goal, budget, seed)
            if path is None:
                status = Status.TIMEOUT if budget.timed_out else Status.BUDGET_EXHAUSTED
                return self._result(status, budget, used0, t0)
            path = shortcut(path, budget, np.random.default_rng([seed, 1]),
                            self.settings.resolution, self.settings.shortcut_attempts)
        return PlanResult(Status.OK, path=path, length=path_length(path),
                          checks=budget.used - used0, time=time.perf_counter() - t0)

    def _result(self, status, budget, used0, t0) -> PlanResult:
        return PlanResult(status, checks=budget.used - used0, time=time.perf_counter() - t0)

    def _solve(self, lower, upper, start, goal, budget: Budget,
               seed: int) -> np.ndarray | None:
        ou.RNG.setSeed(ompl_seed(seed))
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
        validator = EdgeValidator(si, budget, d, self.settings.resolution)
        si.setMotionValidator(validator)
        endpoints = []
        for q in (start, goal):
            state = space.allocState()
            for i in range(d):
                state[i] = float(q[i])
            endpoints.append(state)
        setup.setStartAndGoalStates(endpoints[0], endpoints[1])
        setup.setPlanner(self.make(si))
        self.prepare(setup)
        setup.solve(ob.PlannerTerminationCondition(budget.stop))
        if not setup.haveExactSolutionPath():
            return None
        states = setup.getSolutionPath().getStates()
        return np.array([s[0:d] for s in states])
