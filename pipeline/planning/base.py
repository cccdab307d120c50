"""What every planner and robot share (OMPL's ``base``): the robot model planners see,
collision checks charged to a counted budget, and straight-line interpolation.

A robot model (:class:`RobotModel`) is the whole contract between a domain's simulator and
a planner: joint limits ``lower``/``upper``, ``check(states)`` and ``check_motion(a, b,
resolution, limit)``, and optionally (:data:`CAPABILITIES`) ``distance_model(query)``
(signed distances and their gradients, for optimising planners), ``certified()`` (the same
model with faster checks that give the same answers and counts) and
``bounded_distance_model(query)`` (the same distances, computed faster).  Planners call
nothing else: the validity checker belongs to the robot model (as in OMPL, to the space
information), so a new robot model brings its own and no planner changes.  See
docs/architecture.md.

Budget.  A planning call may check at most ``limit`` configurations.  Once the budget is
spent every further check fails, so a planner cannot grow its search and stops at its next
termination check.  The result therefore depends on the count, not on machine speed; the
wall-clock cap is only a safety net and is reported as its own status when it fires.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np

#: ``contacts(q) -> (d, g)``: signed distances (k,) of the pairs closer than the query
#: distance at configuration q, and their gradients (k, dof).
DistanceModel = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]

#: Optional robot capabilities, by the method that provides each: signed distances
#: (``distance_model(query)``), checks with the same answers and counts made faster
#: (``certified()``, for ``planner.collision=spheres``) and the same distances made faster
#: (``bounded_distance_model(query)``).
CAPABILITIES = {"distances": "distance_model", "certified": "certified",
                "bounded_distances": "bounded_distance_model"}


@runtime_checkable
class RobotModel(Protocol):
    """What a planner may ask of a robot (its configuration space and its checks)."""

    lower: np.ndarray  # (dof,) joint limits
    upper: np.ndarray

    def check(self, states: np.ndarray) -> tuple[bool, int]:
        """Check the rows of ``states`` in order, stop at the first colliding one; return
        whether all were free and how many were checked."""

    def check_motion(self, a: np.ndarray, b: np.ndarray, resolution: float,
                     limit: int) -> tuple[bool, int]:
        """Check the straight motion a→b (a excluded) with at most ``limit`` checks;
        return whether it is free and how many checks were used."""


def capabilities(robot) -> frozenset[str]:
    """The optional capabilities a robot (an instance or a class) provides."""
    return frozenset(c for c, method in CAPABILITIES.items()
                     if callable(getattr(robot, method, None)))


def certified(robot):
    """``robot`` with its faster checks of the same answers (its ``certified``
    capability), or ``robot`` itself when it has none.  Call it when a planning call
    starts: such a model reads the world when it is made."""
    make = getattr(robot, "certified", None)
    return make() if callable(make) else robot


def fast_distance_model(robot, query: float) -> DistanceModel:
    """``robot.distance_model(query)``, computed the faster way when the robot offers one
    (its ``bounded_distances`` capability; the same numbers)."""
    make = getattr(robot, "bounded_distance_model", None)
    return make(query) if callable(make) else robot.distance_model(query)


class Robot:
    """Base class of robot models: ``check_motion`` from ``check`` (override either).

    The motion's states are checked end point first, then coarse to fine, so collisions
    show up after few checks; a subclass that replaces this must use the same count of
    checks for the same outcome where stored figures must replay.
    """

    #: one line naming the robot in refusals ("the planar disc robot")
    description: ClassVar[str] = "this robot"
    lower: np.ndarray
    upper: np.ndarray

    def check(self, states: np.ndarray) -> tuple[bool, int]:
        raise NotImplementedError

    def check_motion(self, a, b, resolution: float, limit: int) -> tuple[bool, int]:
        states = interpolate(a, b, resolution)
        ok, used = self.check(states[check_order(len(states))][:limit])
        return ok and used >= len(states), used


def interpolate(a: np.ndarray, b: np.ndarray, resolution: float) -> np.ndarray:
    """Configurations on the segment a→b, excluding a, including b, at most ``resolution``
    apart in every coordinate (so a 0.01 rad resolution bounds every joint's step)."""
    steps = max(1, math.ceil(float(np.max(np.abs(b - a))) / resolution))
    t = np.arange(1, steps + 1) / steps
    return a + t[:, None] * (b - a)


@functools.lru_cache(maxsize=4096)
def check_order(k: int) -> np.ndarray:
    """End point first, then the rest coarse to fine: collisions show up after few checks.
    (Cached, read-only: edges of the same length share it.)"""
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
    """Counts the configuration checks of one planning call (one or several motions);
    refuses every check once ``limit`` is reached."""

    def __init__(self, robot: RobotModel, limit: int, wall_cap_s: float):
        self.robot = robot
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
        ok, used = self.robot.check(states[: self.limit - self.used])
        self.used += used
        return ok and len(states) <= used

    def edge_free(self, a: np.ndarray, b: np.ndarray, resolution: float) -> bool:
        if self.spent:
            return False
        ok, used = self.robot.check_motion(a, b, resolution, self.limit - self.used)
        self.used += used
        return ok

    def stop(self) -> bool:
        if time.perf_counter() > self.deadline:
            self.timed_out = True
        return self.spent or self.timed_out


def recheck(robot: RobotModel, path: np.ndarray, resolution: float) -> tuple[bool, int]:
    """Check a whole path densely, every edge at ``resolution`` from its start, stopping at
    the first collision: (free?, checks used)."""
    ok, checks = robot.check(path[:1])
    for a, b in zip(path[:-1], path[1:], strict=True):
        if not ok:
            break
        ok, used = robot.check(interpolate(a, b, resolution))
        checks += used
    return ok, checks


def path_is_free(path: np.ndarray, check, resolution: float) -> bool:
    """Re-check a whole path, every edge at ``resolution``; ``check`` is a robot model or
    its ``check`` function (for tests and users)."""
    check = getattr(check, "check", check)
    if not check(path[:1])[0]:
        return False
    return all(check(interpolate(a, b, resolution))[0] for a, b in zip(path[:-1], path[1:],
                                                                       strict=True))
