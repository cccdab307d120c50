"""RRT-Connect (OMPL's ``og.RRTConnect``) over a robot's box-bounded configuration space,
with a counted budget, then bounded random shortcutting: the OMPL scaffolding, seeding and
shortcutting are :mod:`pipeline.planning.ompl_adapter`'s.  Its stores' identity and figures
are those of the module before the adapter (tests/test_planar.py holds references)."""

from __future__ import annotations

from ompl import geometric as og

from pipeline.planning.ompl_adapter import OmplGeometric, ompl_seed
from pipeline.planning.settings import RRTConnectSettings


class RRTConnect(OmplGeometric):
    """Bidirectional RRT between two configurations, then bounded random shortcutting."""

    name = "rrt_connect"
    settings_class = RRTConnectSettings
    resumable = True  # OMPL's RRTConnect is in RESUMABLE

    def make(self, si):
        planner = og.RRTConnect(si)
        if self.settings.range > 0:
            planner.setRange(self.settings.range)
        return planner

    def problem(self, lower, upper, start, goal, budget, seed: int):
        """The robot's own compiled RRT-Connect where it has one (``rrt_connect_search``:
        the sphere checker's, :mod:`pipeline.sim.compiled_rrt`), else OMPL's."""
        search = getattr(budget.robot, "rrt_connect_search", None) if self.compiled else None
        problem = None if search is None else search(
            lower, upper, start, goal, budget, self.settings.range, self.settings.resolution,
            ompl_seed(seed))
        return problem or super().problem(lower, upper, start, goal, budget, seed)
