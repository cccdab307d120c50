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
log is silenced while OMPL's own objects are made and while they search (re-seeding logs
an error by design) and restored after, so importing or calling this module changes no global
setting; a compiled search (the robot's own, :mod:`pipeline.planning.rrt_connect`) never
touches OMPL's log.  A call may also run as a
try that pauses and resumes on the same planner object (:class:`OmplSearch`,
:data:`RESUMABLE`; seeded once, when its problem is made).  Planners that plan in a
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
from pipeline.planning.resumable import PlanningTry
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

#: the algorithms of :data:`ALGORITHMS` whose tries pause and resume with the result of
#: the uninterrupted call (:class:`OmplSearch`; tests/test_resumable.py checks each); the
#: others plan the whole call in a try's first advance
RESUMABLE = ("RRTConnect", "RRT", "RRTstar", "InformedRRTstar", "SORRTstar", "BITstar",
             "KPIECE1")

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
    #: False: :meth:`start` plans the whole call in the first advance; a subclass whose
    #: algorithm resumes exactly (:data:`RESUMABLE`, :class:`OmplSearch`) says so
    resumable = False
    #: search and shortcut with the robot model's compiled versions where it has them
    #: (the same results; False: always OMPL's objects and the Python shortcutter, as the
    #: tests that compare the two set it)
    compiled = True

    def make(self, si) -> ob.Planner:
        """The OMPL planner for the space information ``si`` (called once per call, after
        the seed is set)."""
        raise NotImplementedError

    def prepare(self, setup: og.SimpleSetup) -> None:
        """Anything to set on the problem before solving (after :meth:`make`)."""

    def problem(self, lower, upper, start, goal, budget: Budget, seed: int):
        """The search of one call (seeded here): OMPL's problem (:class:`_Problem`)."""
        return _Problem(self, lower, upper, start, goal, budget, seed)

    def plan(self, robot: RobotModel, start, goal, seed: int,
             budget: Budget | None = None) -> PlanResult:
        """Plan start→goal, charging every configuration check to ``budget``.

        ``seed`` (an int >= 0) fixes OMPL's and the shortcutter's random numbers.
        """
        return OmplSearch(self, robot, start, goal, seed, budget).advance()

    def start(self, robot: RobotModel, start, goal, seed: int,
              budget: Budget | None = None):
        """:meth:`plan` as a try that pauses between two iterations of OMPL's search
        (:class:`OmplSearch`) when :attr:`resumable`, else one that plans the whole call
        in its first advance."""
        if not self.resumable:
            return super().start(robot, start, goal, seed, budget)
        return OmplSearch(self, robot, start, goal, seed, budget)


class OmplSearch(PlanningTry):
    """One call of an :class:`OmplGeometric` planner as a try: the end points' checks,
    then OMPL's ``solve`` called again on the same planner object after each pause, then
    shortcutting in the slice that found the path.

    Why resuming gives the uninterrupted result (OMPL 2.0, checked on its sources for
    RRTConnect): the trees, the tree to grow next (``startTree_``, a member since OMPL
    1.6), the goal states drawn so far and the state sampler all live on the planner
    object and survive between ``solve`` calls; a new ``solve`` adds no start state
    again, and its per-call locals (the approximate solution, scratch states) do not steer
    the search.  A pause is the termination condition returning true where the search
    would have asked it and gone on, so no check is refused or repeated.  Random numbers:
    OMPL gives every RNG object its own generator, seeded from a process-global seed
    generator when the object is made; the seed is set and every object made (the state
    sampler by the first ``solve``) in one slice, and drawing needs nothing global, so
    other tries may run between the slices of this one.  The wall-clock cap counts the
    time inside slices only.
    """

    def __init__(self, planner: OmplGeometric, robot: RobotModel, start, goal, seed: int,
                 budget: Budget | None = None):
        super().__init__()
        if seed < 0:
            raise ValueError(f"planning seed must be >= 0, got {seed}")
        lower, upper = np.asarray(robot.lower, float), np.asarray(robot.upper, float)
        if lower.shape != upper.shape or np.any(lower >= upper):
            raise ValueError("planner bounds: need lower < upper in every coordinate")
        self.planner, self.seed = planner, seed
        self.lower, self.upper = lower, upper
        self.start, self.goal = np.asarray(start, float), np.asarray(goal, float)
        self.budget = budget if budget is not None else planner.budget(robot)
        self.used0 = self.budget.used
        self._idle_since = time.perf_counter()
        self._problem: _Problem | None = None

    @property
    def checks(self) -> int:
        """Checks used so far."""
        return self.budget.used - self.used0

    def rebind(self, robot: RobotModel) -> None:
        """Check on ``robot`` from now on: the same robot model remade (a domain's scene
        was rebuilt or reloaded between two slices), which answers every check as before."""
        self.budget.robot = self.planner.check_model(robot)

    def _advance(self, allowance, now) -> PlanResult | None:
        budget = self.budget
        budget.deadline += now - self._idle_since  # the cap counts time inside slices
        if self._problem is None:  # the first slice: end points, then the search's problem
            ended = self._endpoints()
            if ended is not None:
                return ended
            if np.array_equal(self.start, self.goal):
                return self._found(self.start[None])
            self._problem = self.planner.problem(self.lower, self.upper, self.start,
                                                 self.goal, budget, self.seed)
        path = self._problem.solve(self._stop(allowance),
                                   None if allowance is None else self.used0 + allowance)
        if path is None and not (budget.spent or budget.timed_out) and self._paused:
            self._problem.forget_approximations()
            self._idle_since = time.perf_counter()
            return None
        self._problem = _ENDED  # frees OMPL's objects now (a paused try keeps them)
        if path is None:
            status = Status.TIMEOUT if budget.timed_out else Status.BUDGET_EXHAUSTED
            return self._failed(status)
        path = shortcut(path, budget, np.random.default_rng([self.seed, 1]),
                        self.planner.settings.resolution,
                        self.planner.settings.shortcut_attempts, self.planner.compiled,
                        rng_kept=False)
        return self._found(path)

    def _stop(self, allowance):
        """The termination condition of one slice: the budget's, and the pause once the
        try has used ``allowance`` checks (which sets ``_paused``)."""
        budget = self.budget
        self._paused = False
        if allowance is None:
            return budget.stop
        cap = self.used0 + allowance

        def stop() -> bool:
            if budget.stop():
                return True
            self._paused = budget.used >= cap
            return self._paused

        return stop

    def _endpoints(self) -> PlanResult | None:
        """Check start and goal (a failed result, or None when both are free)."""
        budget = self.budget
        for q, status in ((self.start, Status.START_IN_COLLISION),
                          (self.goal, Status.GOAL_IN_COLLISION)):
            if ((q < self.lower) | (q > self.upper)).any() or not budget.states_free(q[None]):
                if budget.spent:  # an earlier leg used the whole budget: q was never checked
                    status = Status.BUDGET_EXHAUSTED
                return self._failed(status)
        return None

    def _failed(self, status) -> PlanResult:
        return PlanResult(status, checks=self.checks)

    def _found(self, path) -> PlanResult:
        return PlanResult(Status.OK, path=path, length=path_length(path), checks=self.checks)


#: what an ended :class:`OmplSearch` holds instead of its problem (never advanced again)
_ENDED = object()


class _Problem:
    """OMPL's problem for one call: space, setup and planner, made once (the seed set
    just before), solved again after each pause.  Holds every object OMPL calls back into."""

    def __init__(self, planner: OmplGeometric, lower, upper, start, goal, budget: Budget,
                 seed: int):
        with quiet_ompl():  # re-seeding logs an error by design
            self._make(planner, lower, upper, start, goal, budget, seed)

    def _make(self, planner, lower, upper, start, goal, budget, seed) -> None:
        ou.RNG.setSeed(ompl_seed(seed))
        d = self.dim = len(lower)
        space = ob.RealVectorStateSpace(d)
        bounds = ob.RealVectorBounds(d)
        for i in range(d):
            bounds.setLow(i, float(lower[i]))
            bounds.setHigh(i, float(upper[i]))
        space.setBounds(bounds)
        setup = og.SimpleSetup(space)
        si = setup.getSpaceInformation()
        self.valid = lambda s: budget.states_free(np.array([s[0:d]]))
        setup.setStateValidityChecker(self.valid)
        self.validator = EdgeValidator(si, budget, d, planner.settings.resolution)
        si.setMotionValidator(self.validator)
        self.endpoints = []
        for q in (start, goal):
            state = space.allocState()
            for i in range(d):
                state[i] = float(q[i])
            self.endpoints.append(state)
        setup.setStartAndGoalStates(self.endpoints[0], self.endpoints[1])
        setup.setPlanner(planner.make(si))
        planner.prepare(setup)
        self.space, self.setup = space, setup

    def solve(self, stop, pause_at: int | None = None) -> np.ndarray | None:
        """Run (or go on with) the search until ``stop()``; the path once one is found.
        (``pause_at``, the count at which ``stop()`` pauses, is not needed here: OMPL asks
        ``stop()`` every iteration.)"""
        with quiet_ompl():
            self.setup.solve(ob.PlannerTerminationCondition(stop))
        if not self.setup.haveExactSolutionPath():
            return None
        d = self.dim
        return np.array([s[0:d] for s in self.setup.getSolutionPath().getStates()])

    def forget_approximations(self) -> None:
        """Drop the approximate path a paused ``solve`` leaves in the problem (the
        uninterrupted call has none there): only an exact one is ever read."""
        self.setup.getProblemDefinition().clearSolutionPaths()
