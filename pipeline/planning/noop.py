"""The planner that plans nothing: every score entry is recorded as skipped, so a run
measures the pipeline's own cost.  RAWPLANNER still needs solutions to extract constraints
from, so domains use ``stand_in`` for it (the registry hands that out, with the common keys
of these settings and its own defaults for the rest)."""

from __future__ import annotations

from pipeline.planning.interface import Planner
from pipeline.planning.result import PlanResult, Status
from pipeline.planning.settings import NoopSettings


class Noop(Planner):
    name = "noop"
    settings_class = NoopSettings
    plans_nothing = True
    stand_in = "rrt_connect"

    def plan(self, robot, start, goal, seed, budget=None) -> PlanResult:
        return PlanResult(Status.SKIPPED)
