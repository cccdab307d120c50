"""Planner names, their settings (the schema of ``conf/planner/*.yaml``) and the one place
that turns settings into a planner for a kind of robot.  Importing this module loads no
planner; each is imported on first use.  Adding a planner: its own module with a
:class:`~pipeline.planning.interface.Planner` subclass, a line in ``PLANNERS`` and its keys
in ``PlannerSettings`` (docs/architecture.md)."""

from __future__ import annotations

import importlib
from dataclasses import dataclass

#: name -> "module:class"
PLANNERS = {
    "rrt_connect": "pipeline.planning.rrt_connect:RRTConnect",
    "trajopt": "pipeline.planning.trajopt:TrajOpt",
    "noop": "pipeline.planning.noop:Noop",
}


#: collision checking: sphere pre-check then pybullet, or pybullet everywhere
COLLISION = ("spheres", "exact")


@dataclass
class PlannerSettings:
    """Settings of one planning call (schema of ``conf/planner/*.yaml``; a store's identity
    holds all of them, so keys are only ever added, with defaults).

    ``max_checks``, ``wall_cap_s`` and ``resolution`` (of edge checks) apply to every
    planner; ``range`` and ``shortcut_attempts`` to ``rrt_connect``; the ``trajopt_*``
    keys to ``trajopt`` (checked by it, :class:`pipeline.planning.trajopt.TrajOpt`).
    ``noop`` plans nothing: the pipeline records "skipped" for every score entry.
    ``collision``: ``spheres`` gives a planner robots whose checks run a sphere pre-check and
    ask pybullet only what it cannot clear (:mod:`pipeline.sim.fast_check`; the same
    answers and counts as ``exact``, pybullet on every configuration).  It changes the cost
    of a score matrix, never its contents, so it is left out of a store's identity.
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
            raise ValueError("planner.trajopt_waypoints must be >= 3, got "
                             f"{self.trajopt_waypoints}")
        if (self.trajopt_margin < 0 or self.trajopt_penalty <= 0
                or self.trajopt_penalty_rounds < 1 or self.trajopt_iterations < 1
                or self.trajopt_trust_radius <= 0):
            raise ValueError("planner.trajopt_*: margin must be >= 0, penalty and "
                             "trust_radius > 0, penalty_rounds and iterations >= 1")


def planner_class(name: str):
    if name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; known: {', '.join(PLANNERS)}")
    module, cls = PLANNERS[name].split(":")
    return getattr(importlib.import_module(module), cls)


def plans_nothing(settings: PlannerSettings) -> bool:
    return planner_class(settings.name).plans_nothing


def make_planner(settings: PlannerSettings, robot):
    """The planner ``settings`` name for ``robot`` (a robot model or its class).

    A planner that plans nothing is replaced by its stand-in (RAWPLANNER still needs
    solutions).  A planner that needs a capability the robot lacks is refused here, with
    the one message every domain gives.
    """
    from pipeline.planning.base import capabilities

    cls = planner_class(settings.name)
    if cls.stand_in is not None:
        cls = planner_class(cls.stand_in)
    missing = cls.requires - capabilities(robot)
    if missing:
        raise ValueError(f"planner={settings.name} needs {', '.join(sorted(missing))}, which "
                         f"{robot.description} does not provide; use planner=rrt_connect")
    return cls(settings)
