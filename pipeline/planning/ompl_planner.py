"""``planner=ompl``: one of OMPL's geometric planners by name (``planner.algorithm``, one of
:data:`pipeline.planning.ompl_adapter.ALGORITHMS`), its parameters by OMPL's names
(``planner.params``, e.g. ``{goal_bias: 0.1}``; set through the planner's setters, as
OMPL's ParamSet does), then rrt_connect's shortcutting
(``planner.shortcut_attempts``; 0: none).  ``planner.range`` > 0 sets the ``range``
parameter (of the algorithms that have one).

Optimising planners (RRTstar, BITstar, ...) stop at their first exact solution: the
problem's objective is path length with an infinite cost threshold, which the first
solution satisfies.  So ``max_checks`` bounds the search for a path for every algorithm
alike, and a call's figures depend on the count of checks only (module
:mod:`pipeline.planning.ompl_adapter`).
"""

from __future__ import annotations

from ompl import geometric as og

from pipeline.planning.ompl_adapter import (
    RESUMABLE,
    OmplGeometric,
    set_params,
    stop_at_first_solution,
)
from pipeline.planning.settings import OmplSettings


class OmplPlanner(OmplGeometric):
    """``og.<settings.algorithm>`` with ``settings.params``."""

    name = "ompl"
    settings_class = OmplSettings

    @property
    def resumable(self) -> bool:
        """Whether ``start`` gives a try that pauses: the algorithms of
        :data:`~pipeline.planning.ompl_adapter.RESUMABLE`."""
        return self.settings.algorithm in RESUMABLE

    def make(self, si):
        planner = getattr(og, self.settings.algorithm)(si)
        values = dict(self.settings.params)
        if self.settings.range > 0:
            values.setdefault("range", self.settings.range)
        set_params(planner, values)
        return planner

    def prepare(self, setup):
        stop_at_first_solution(setup)
