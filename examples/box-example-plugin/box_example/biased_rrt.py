"""``planner=biased_rrt``: OMPL's single-tree RRT with a goal bias of its own, a planner from
another package.  It reuses the pipeline's OMPL adapter (state space, counted budget,
seeding, shortcutting) and says only which OMPL planner to make, so it is as reproducible
as the built-in ones (the same seed and budget give the same checks and path).  Imported
only when ``planner=biased_rrt`` plans; its settings live in :mod:`box_example.planner_settings`."""

from __future__ import annotations

from ompl import geometric as og

from box_example.planner_settings import BiasedRRTSettings
from pipeline.planning.ompl_adapter import OmplGeometric


class BiasedRRT(OmplGeometric):
    """OMPL's ``og.RRT`` with ``goal_bias``, then the adapter's shortcutting."""

    name = "biased_rrt"
    settings_class = BiasedRRTSettings

    def make(self, si):
        planner = og.RRT(si)
        planner.setGoalBias(self.settings.goal_bias)
        if self.settings.range > 0:
            planner.setRange(self.settings.range)
        return planner
