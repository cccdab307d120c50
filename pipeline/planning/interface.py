"""The planner interface (OMPL's ``base::Planner``): settings in, a robot model and two
configurations per call, a :class:`PlanResult` out.  See docs/architecture.md."""

from __future__ import annotations

import abc
from typing import ClassVar

import numpy as np

from pipeline.planning.base import Budget, RobotModel, certified
from pipeline.planning.result import PlanResult
from pipeline.planning.resumable import PlanningTry, WholeTry
from pipeline.planning.settings import PlannerSettings, convert


class Planner(abc.ABC):
    """One motion planner.  Subclasses set ``name``, ``settings_class`` (their settings: a
    dataclass derived from :class:`~pipeline.planning.settings.PlannerSettings`, the
    schema of ``planner.*``) and ``requires`` (the optional robot capabilities of
    :data:`pipeline.planning.base.CAPABILITIES` they need; the registry refuses robots
    that lack one) and implement :meth:`plan`."""

    name: ClassVar[str]
    settings_class: ClassVar[type[PlannerSettings]] = PlannerSettings
    requires: ClassVar[frozenset[str]] = frozenset()
    #: True for a planner that plans nothing: domains record every score entry as skipped
    #: and leave RAWPLANNER (which needs real solutions) to ``stand_in``
    plans_nothing: ClassVar[bool] = False
    stand_in: ClassVar[str | None] = None
    #: True when :meth:`start` gives a try that pauses at its allowance (a property where
    #: it depends on the settings); False: the whole call runs in the first advance
    resumable: ClassVar[bool] = False

    def __init__(self, settings: PlannerSettings | None = None):
        """``settings``: an instance of ``settings_class`` (other settings give their
        common keys and the class's defaults for the rest; None: all defaults)."""
        self.settings = convert(settings or self.settings_class(), self.settings_class)

    def budget(self, robot: RobotModel) -> Budget:
        """A check budget for one call, to share between the motions of a multi-leg call;
        make it once the scene is set for the call (``planner.collision=spheres`` reads
        the world now)."""
        return Budget(self.check_model(robot), self.settings.max_checks,
                      self.settings.wall_cap_s)

    def check_model(self, robot: RobotModel) -> RobotModel:
        """The model that answers this planner's checks on ``robot``: with
        ``planner.collision=spheres``, the robot's faster checks of the same answers (its
        ``certified`` capability, which reads the world now), if any."""
        if getattr(self.settings, "collision", "exact") == "spheres":
            return certified(robot)
        return robot

    def start(self, robot: RobotModel, start: np.ndarray, goal: np.ndarray, seed: int,
              budget: Budget | None = None) -> PlanningTry:
        """:meth:`plan` as a try (:mod:`pipeline.planning.resumable`): this default cannot
        pause and plans the whole call in its first advance; resumable planners override
        it (and set :attr:`resumable`)."""
        return WholeTry(lambda: self.plan(robot, start, goal, seed, budget))

    @abc.abstractmethod
    def plan(self, robot: RobotModel, start: np.ndarray, goal: np.ndarray, seed: int,
             budget: Budget | None = None) -> PlanResult:
        """A path start→goal inside ``robot``'s limits, every configuration and edge
        checked by ``robot``.  ``seed`` (an int >= 0) fixes every random number; checks
        are charged to ``budget`` (a fresh one when None) and reported in ``checks``."""
